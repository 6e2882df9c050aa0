"""One config object per stage (dataclasses, saved as YAML/JSON), and the two families.

``paper`` is the authors' size (for GPUs); ``small`` trains on a 2-core CPU in about an
hour on the Bandai corpus. Every ablation of the paper is a field here, so a variant is
one YAML override away (see ``umf train --set``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from umf.errors import UMFError


@dataclass
class VAEConfig:
    """Motion VAE (paper Sec. 4.1): multi-token latent through the latent adapter."""

    feature_dim: int = 262
    d_model: int = 512
    num_layers: int = 9  # long-skip transformer: L//2 in, 1 middle, L//2 out
    num_heads: int = 4
    ff_dim: int = 1024
    dropout: float = 0.1
    num_tokens: int = 16  # p; 1 = the single-token ablation
    latent_dim: int = 64  # r (the paper text also mentions 16 x 32)
    latent_adapter: bool = True  # False: latent width = d_model, no projection (ablation)
    max_frames: int = 300
    # what the transformer models: "body" = root trajectory + pose in the body's heading
    # frame (umf.body_frame), recomposed exactly into the global 262-d output; "global" =
    # the 262-d scene-frame feature as is (the authors' release; it learns placement and
    # collapses the pose to a mean pose on the Bandai corpus: results/vae-recipe)
    target: str = "body"
    frames_per_token: int = 1  # consecutive frames per transformer token (k > 1: k x fewer)
    # latent token j stands for the frames around (j + 1/2) * max_frames / num_tokens: a
    # direct path from each token to its frames (models.vae.token_alignment); False = the
    # authors' design, where only cross-attention links frames and tokens
    aligned_tokens: bool = True
    token_span: float = 0.0  # frames per aligned token; 0 = max_frames / num_tokens
    group_balanced: bool = True
    # decoded positions follow the decoded velocities frame to frame (no shaking) and the
    # decoded positions over longer spans: representation.fuse_positions; 0 = raw output.
    # Smaller = smoother: 0.1 halved a wave's wrist motion, 1 keeps most of it and still
    # removes two thirds of the frame-to-frame shake.
    position_fusion: float = 1.0
    # The pelvis's floor path trusts the decoded velocities for seconds: the decoded
    # absolute path jitters by centimetres every frame and drifts slowly (real wavers
    # reconstructed by the bundled VAE travel 0.125 m/s net at 0.005, 0.072 at 0.0002, real
    # 0.002; walks 1.16 and 1.27 m/s, real 1.26: research/vae_root_drift.py). Chosen on the
    # val split (results/umf-small-bandai-20261127): FID 19.0 -> 10.3, pairs 34.2 -> 24.9
    root_fusion: float = 0.0002
    # the pelvis's height; None = root_fusion. The decoded height is reliable and its
    # velocity integrated over seconds is not (at 0.0002 feet sank 1.1 cm into the floor)
    height_fusion: float | None = 1.0
    # the floor path of people 2..N (S-Flow's), who are placed relative to person 1:
    # at 0.0002 the val pairs' "distance" checks fell from 90 to 80 %, at 0.001 they stay
    # at 90 %. None = root_fusion
    reaction_root_fusion: float | None = 0.001
    # a generated person 1's fused floor path (a single person's too) is moved to start
    # over the origin (where every training crop starts it, representation.pin_floor_start)
    # rather than where its decoded positions sit on average: a P-Flow runner's positions
    # travel half as far as its velocities, the fused start lands 1-2 m behind the origin
    # and people 2..N, placed relative to the origin, run ahead of it
    pin_leader_start: bool = False

    def fusion_weights(self, reaction: bool = False) -> tuple[float, float, float | None]:
        """(position, root, height) weights of representation.fuse_positions for person 1
        or (``reaction``) people 2..N: how the pipeline decodes them."""
        root = self.root_fusion
        if reaction and self.reaction_root_fusion is not None:
            root = self.reaction_root_fusion
        return self.position_fusion, root, self.height_fusion

    # loss weights (paper Eq. 5). The geometric terms (metres, on the recomposed global
    # joints) are off as in the authors' release: on the Bandai corpus they dominate the
    # gradient with placement errors and the pose stops learning (memorising 32 crops,
    # 100 steps: pose R^2 0.24 with them at 0.5/0.5/0.1/0.1, 0.71 without;
    # results/vae-recipe). Each stays configurable.
    w_recon: float = 1.0
    w_kl: float = 1e-4
    w_pos: float = 0.0
    w_vel: float = 0.0
    w_contact: float = 0.0
    w_bone: float = 0.0
    w_interaction: float = 0.0
    # L1 between the decoded and the real pelvis's horizontal velocity slot (m/s), which
    # the decoded path mostly follows (root_fusion). The group-balanced SmoothL1 leaves a
    # 0.05 m/s drift almost free (a few hundredths of the slot's std, in its quadratic
    # part). Off in training from scratch; for fine-tuning the decoder
    # (train_vae.decoder_only)
    w_root_vel: float = 0.0


@dataclass
class DenoiserConfig:
    """Skip transformer over [time, text, (dataset), latent tokens]."""

    d_model: int = 512
    num_layers: int = 9
    num_heads: int = 4
    ff_dim: int = 1024
    dropout: float = 0.1
    text_width: int = 768  # trainable 2-layer text head on the frozen encoder
    text_heads: int = 8
    text_ff_dim: int = 2048
    text_layers: int = 2
    branch_layers: int = 2  # per-dataset output branches (P-Flow only)
    # a prompt of the person's own beside the scene's: its text token, through the same
    # text head and a zero-initialised projection, is added to the scene's (a model
    # fine-tuned with it starts as the model it came from)
    person_text: bool = False
    # read own prompts through a text head of their own (same shape as the scene's) instead
    # of the scene's: the S-Flow's scene captions never name a gesture, so its head gives
    # "raises both hands", "raises the right hand" and "... the left hand" one token (cosine
    # 0.86-0.95) and person 2 could not be told which (results/umf-small-bandai-20261204c)
    person_head: bool = False


# the P-Flow's dataset token: the single-person corpus, the multi-person one
SINGLE_PERSON, MULTI_PERSON = 0, 1


@dataclass
class PFlowConfig:
    """Pyramidal flow for the first person (paper Sec. 4.2.1)."""

    denoiser: DenoiserConfig = field(default_factory=DenoiserConfig)
    layout: str = "1d"  # "1d" token pyramid or "2d" token grid
    num_stages: int = 2  # 1 = no pyramid (ablation)
    g: float | None = None  # block-noise correlation; None = 1/(b-1)
    # where each stage starts on the flow's time axis, coarse -> fine (s_K = 0 first);
    # None = uniform (0, 1/K, ...). An earlier finest stage leaves it more noise to
    # decide fine detail (a wave's swing) at full resolution
    starts: tuple[float, ...] | None = None
    steps: tuple[int, ...] = (45, 5)  # coarse -> fine
    # also standardise each latent channel's fine detail (a token less the mean of its
    # pair or block) to unit variance over the training latents. Why: standardised per
    # token and channel, a wave's swing is 2 % of the latent's variance and sits below the
    # noise until the last few flow steps, so the flow never makes it (results/wave-20261127)
    detail_norm: bool = False
    solver: str = "euler"
    guidance: float = 3.0
    # CFG scale of the finest stage (None: ``guidance``). Guidance pulls every sample
    # towards what the text makes likely and so shrinks the spread of the fine detail the
    # last stage adds (a wave's swing); the coarse stages fix what the motion is
    fine_guidance: float | None = None
    p_uncond: float = 0.1
    # chance a training item's own prompt is dropped (with the scene's, always, at p_uncond)
    p_person_drop: float = 0.3
    # chance an item that keeps its own prompt loses the scene's: the own prompt alone must
    # say what the person does. Without it a flow sees own prompts beside scene prompts that
    # mostly name the same action already (single clips, most relations), and leans on the
    # scene's: "Someone bows politely." under "Two people stand facing each other." bowed 2-8 cm
    p_scene_drop: float = 0.0
    # CFG scale of an own prompt, apart from the scene prompt's (None: the same scale):
    # v_u + guidance * (v_scene - v_u) + person_guidance * (v_both - v_scene)
    person_guidance: float | None = None
    # how an own prompt joins the scene's when sampling (umf.flows.composed_guidance):
    # "joint" guides scene + own against the scene alone; "and" conjoins the own prompt as
    # a prompt alone, v_u + guidance (v_scene - v_u) + person_guidance (v_own - v_u). Under
    # "Two people stand facing each other." the joint form bowed 3-9 cm for "Someone bows
    # politely." (1 of 8 seeds past 8 cm), the conjoined one 13-27 cm (8 of 8;
    # results/umf-small-bandai-20261207)
    person_composition: str = "joint"
    # loss scale of the single-person corpus (the authors': 0.1 for HumanML3D's size); the
    # small family uses 1: on Bandai the actions and gestures are in the single clips
    single_person_weight: float = 0.1
    num_datasets: int = 2  # learned dataset token: SINGLE_PERSON, MULTI_PERSON


@dataclass
class SFlowConfig:
    """Semi-noise reaction flow (paper Sec. 4.2.2)."""

    denoiser: DenoiserConfig = field(default_factory=lambda: DenoiserConfig(num_layers=13))
    context_layers: int = 2
    context_heads: int = 4
    context_ff_dim: int = 1024
    context_adapter: bool = True  # False: C = mean of previous latents (ablation)
    context_positional: bool = False
    steps: int = 10
    # steps when the scene has two people; None = ``steps``. The bundled model sets 4,
    # chosen on the val split for pairs (fewer steps: lower FID, worse placement;
    # results/umf-small-bandai-20261126c), while groups of 3+ lost relation checks at 3
    # steps with the previous S-Flow (results/umf-small-bandai-h200-20261126b, sflow-3-steps)
    pair_steps: int | None = None
    solver: str = "euler"
    guidance: float = 3.0
    p_uncond: float = 0.1
    p_person_drop: float = 0.3  # as PFlowConfig.p_person_drop
    p_scene_drop: float = 0.0  # as PFlowConfig.p_scene_drop
    person_guidance: float | None = None  # as PFlowConfig.person_guidance
    lambda_recon: float = 1.0  # 0 = no reconstruction loss (ablation)
    reaction_only: bool = False  # noise-free reaction path (ablation)
    context_noise: float = 0.0  # perturb real context latents to look generated
    # reaction half starts at C + reaction_noise * eps' (0: the authors' path, from C)
    reaction_noise: float = 0.0
    shared_backbone: bool = False  # share the P-Flow transformer (ablation)
    # people already generated enter the context as the encoder's posterior mean of their
    # decoded motion, person 1 re-centred on its first frame: what S-Flow trained on (the
    # flows' own latents decode to a person 1 up to 0.7 m and 100 degrees off the canonical
    # start, and a context that is not a posterior mean; False: the sampled latents as is)
    reencode_context: bool = False
    # > 0: after the usual pass, each added person is sampled again from this time on the
    # path towards a proposal (warm_proposal): the near-deterministic start glides
    warm_start: float = 0.0  # (umf.warm_start)
    warm_start_group: float = 0.0  # > 0: that time beside 2+ people (umf.warm_start)
    # what the warm start starts from: "pflow" (the P-Flow's motion: person 1's role) or
    # "retrieved" (one of the warm_neighbours real training reactions nearest to the first
    # pass: its role; the model directory's reactions.safetensors, umf.reaction_bank)
    warm_proposal: str = "pflow"
    warm_neighbours: int = 4
    # > 0: only people whose first pass glides (warm_start.glide_score above this) pass again
    warm_glide: float = 0.0
    # > 0: retrieve among the reactions whose pelvis velocity (person 1's frame) is within
    # this fraction of the first pass's (its path keeps pace and direction where its legs
    # do not); a bank without velocities (written before them) is used without it
    warm_pace: float = 0.0
    # > 0: where the first pass travels with person 1 (both pelvises at least
    # umf.warm_start.MOVING m/s, their floor velocities' cosine at least this), warm_pace
    # compares the bank with person 1's velocity instead: people walking or running together
    # keep the leader's pace and heading, where the first pass lags and drifts outwards
    warm_together: float = 0.0
    # with warm_together: a reaction retrieved for a row travelling with person 1 is played at
    # person 1's pace (data.extension.played_at), taken at any own pace, moved sideways to
    # keep its joints 0.4 m from the leader's, at most 1.3 m out (clearance.clear_of)
    warm_play: bool = False
    warm_follow: float | None = None  # with warm_play, d: such a reaction also follows
    # person 1's path where it turns over d degrees (umf.path_follow); None: off
    # person k >= 3 keeps off where people 2..k - 1 start (reaction_bank.SPOT), where the
    # S-Flow, trained on pairs, puts a partner of person 1 (results/reactions-20261208): one
    # travelling with person 1 moved beyond the one whose spot it takes (clearance.beyond),
    # anyone else retrieved away and turned to a free bearing (turned_free); warm_clear > 0:
    # also off the bodies of people 1..k - 1, every joint, every frame (m; touches);
    # warm_extend: one travelling with person 1 behind whom person 2 does starts behind
    # person k - 1 as far as person 2 did behind person 1 (a file; formation_end)
    warm_apart: bool = False
    warm_clear: float = 0.0
    warm_extend: bool = False
    warm_shortlist: int = 0  # > 0: retrieve among the reactions whose captions best fit
    # with a shortlist: for a prompt naming a side, only reactions whose captions are at least
    # as near it as its mirror image (side words swapped): people on the side it names
    warm_side: bool = False
    warm_margin: float = 0.0  # > 0: see umf.reaction_bank.ReactionBank._shortlisted (margin)
    # > 0: where the reactions of the prompt's nearest caption waited a median of at least
    # this many frames after their person 1 (the bank's lags), a real answer retrieved among
    # them is moved in time to wait as long after the generated person 1, and replaces the
    # first pass whether it glides or not: the first pass answers a bow back at the average
    # delay it saw (umf.warm_start.answers, timed_proposal); 0: off
    warm_timing: float = 0.0
    # > 0: a person 2..N with an own prompt is sampled again from this time on the path
    # towards the P-Flow's single-person motion for that prompt alone (whatever
    # warm_proposal says for the others), every such person, gliding or not: the S-Flow's
    # own prompts, trained beside scene captions that name no gesture, raise no hands
    # (results/umf-small-bandai-20261204c); the P-Flow's do (umf.warm_start)
    own_warm: float = 0.0
    # > 0: a prompt worded like a real take whose people touch (a salsa couple: the
    # vocabulary's contact) has people 1 and 2 sampled again from this time on the paths
    # towards both people of one crop of those takes (the bank's takes; umf.take_start):
    # the flows' own leader and partner each dance, but their hands do not meet. In the
    # P-Flow it is local time on the finest stage (global 0.85 for 0.7 in two stages)
    warm_take: float = 0.0
    # the context C also enters the transformer beside the state, clean at every t (not in
    # the paper): the state shows C only blurred by noise early on, so a noisier reaction
    # start (reaction_noise) lost where person 2 stands (results/flows-long-h200-20261126)
    context_condition: bool = False

    def steps_for(self, num_people: int) -> int:
        """ODE steps per added person in a scene of ``num_people``."""
        if num_people == 2 and self.pair_steps is not None:
            return self.pair_steps
        return self.steps


@dataclass
class TextConfig:
    encoder: str = "minilm"  # or "clip"
    path: str | None = None  # local weights directory for CLIP
    max_length: int = 128
    # prompts are respelled into the training captions' spelling before encoding,
    # "unseen=seen" word pairs: the Bandai captions say "backwards" and never "backward",
    # and "A person walks backward." walked back at 0.30 m/s against 0.71 for "backwards"
    # (real 0.75). None: training fills it from the corpus (train.datasets.preferred_spellings)
    respell: tuple[str, ...] | None = None


@dataclass
class EvaluatorConfig:
    """Contrastive text-motion evaluator, InterGen's InterCLIP architecture (SPEC 8)."""

    d_model: int = 1024  # motion transformer
    num_layers: int = 8
    num_heads: int = 8
    ff_dim: int = 2048
    dropout: float = 0.1
    embed_dim: int = 512
    text_width: int = 768  # text transformer
    text_layers: int = 8
    text_heads: int = 8
    text_ff_dim: int = 2048
    # "minilm" / "clip": frozen token states; "clip-tokens": CLIP token ids (InterGen layout)
    text_encoder: str = "minilm"
    text_path: str | None = None  # local CLIP directory ("clip", "clip-tokens")
    text_max_length: int = 77
    latent_scale_init: float = 1.0  # embeddings have this norm; logits = scale^2 * cosine
    max_frames: int = 300  # longest motion scored (InterHuman's limit)
    # consecutive frames concatenated into one motion token; 1 = InterCLIP exactly, more is
    # our cheaper variant for CPUs (attention cost falls with its square)
    frames_per_token: int = 1


@dataclass
class TrainConfig:
    """Optimisation of one stage (AdamW + cosine, paper Sec. 5.1)."""

    lr: float = 1e-4
    weight_decay: float = 0.0
    betas: tuple[float, float] = (0.9, 0.999)
    warmup_steps: int = 500
    max_steps: int = 100_000
    batch_size: int = 64
    grad_clip: float = 1.0
    ema_decay: float | None = None  # e.g. 0.999
    min_frames: int = 30
    max_frames: int = 150  # training crop length (frames at 30 fps)
    val_every: int = 1000
    ckpt_every: int = 1000
    log_every: int = 50
    num_workers: int = 0
    seed: int = 0
    latent_passes: int = 0  # flows: pre-encode this many epochs of crops (0 = encode per batch)
    # single-person training items (VAE, P-Flow; not the S-Flow's scenes) of rare content
    # labels repeat (most/count)**balance_labels times per epoch, 0 <= balance_labels <= 1
    # (0 = as in the corpus, 1 = every label equal; umf.train.datasets.label_repeats)
    balance_labels: float = 0.0
    # only single-person clips of these content labels, e.g. [wave-right-hand] (empty: all);
    # the VAE and P-Flow then train on them alone, without scene batches (a scene's people
    # carry several labels), so a stage can be fine-tuned or probed on one kind of motion
    labels: tuple[str, ...] = ()
    # give half the training captions the other spelling of direction words (backwards,
    # forwards, towards without the s, and back; umf.train.datasets.respell_caption)
    respell_captions: bool = False
    # single-person items take, with this chance, the caption of a random clip that shares
    # their caption_mix_within metadata (content label and style) instead of their own
    # (umf.train.datasets.SingleMotionDataset): a per-clip wording then no longer names a few
    # crops for the flow to copy (0 = always their own)
    caption_mix: float = 0.0
    caption_mix_within: tuple[str, ...] = ("content", "style")
    # and only from clips whose metadata match these "key=value" pairs (e.g. style=normal)
    caption_mix_from: tuple[str, ...] = ()
    # single-person clips shorter than min_frames that end at rest hold their last pose up to
    # a full crop (umf.data.extension.ends_at_rest): a gesture ends standing, not gliding off
    hold_rest: bool = False
    # and those that end in a steady, straight gait repeat their last cycle up to a full crop
    # (umf.data.extension.gait_period): a 4 s run keeps running instead of slowing to a glide
    repeat_gait: bool = False
    # scene batches: and short composed scenes whose people travel together, all end in a
    # steady gait and keep their relation (umf.data.extension.scene_gait_periods): a 4 s
    # sprint side by side, which Bandai's short runs never composed
    repeat_scene_gait: bool = False
    # P-Flow only: and those whose person 1 does, the others held (datasets.SceneDataset)
    repeat_leader_gait: bool = False
    # and those that end neither, but slowly (every end speed under 1 m/s: a getup cut while
    # the pelvis still rises), are eased to a stop over their last frames, then held
    # (umf.data.extension.settle_times): a 4 s "get up" ends standing instead of bending again
    settle: bool = False
    # VAE only: train the decoder and hold the encoder (and so every latent, and the flows
    # trained on them) fixed; needs a VAE to start from (`umf train vae --init MODEL`)
    decoder_only: bool = False
    # scene batches (VAE, P-Flow dataset 1, S-Flow): each real multi-person clip (a take
    # captured together, e.g. CMU salsa) appears this many times per epoch, each its own crop,
    # beside the composed scenes: a dozen takes among 3,000 scenes are otherwise rarely seen
    real_repeats: int = 1
    # scene batches: composed scenes of these relations appear this many times per epoch,
    # "relation=times" (e.g. stand_facing=4: the scenes whose actions only the per-person
    # captions name, one relation of 13 otherwise); label_repeats: single-person items of
    # these content labels that many times more, after balance_labels (e.g. jump=4)
    relation_repeats: tuple[str, ...] = ()
    label_repeats: tuple[str, ...] = ()
    # VAE fine-tuned with --init: refit the body-frame statistics on this corpus (balanced as
    # training draws it) and restate the VAE's weights to compute the same function
    # (models.vae.MotionVAE.restate_body): a crawl, a backflip are then a few deviations
    refit_body: bool = False
    # S-Flow only: weight of the loss on the decoded reaction's feet (m/frame they slide
    # where the real reaction's are planted; umf.train.foot_slide), on flow times from
    # foot_loss_min_t. 0 = off (the paper's loss alone)
    foot_loss: float = 0.0
    foot_loss_min_t: float = 0.5
    # S-Flow only: weight of the loss on where the decoded reaction stands (m between its
    # pelvis floor path and the real reaction's; umf.train.placement), on flow times up to
    # place_loss_max_t, where the state does not yet say where. 0 = off
    place_loss: float = 0.0
    place_loss_max_t: float = 0.5
    # S-Flow only: weight of the loss on where every joint of the decoded reaction is (mean 3-D
    # distance in m from the real reaction's, in person 1's frame; umf.train.placement), on
    # the place loss's flow times: hands held, a bow at its time. 0 = off
    joint_loss: float = 0.0


@dataclass
class UMFConfig:
    """Everything needed to rebuild a model; saved as config.json in checkpoints."""

    family: str = "paper"
    fps: float = 30.0
    text: TextConfig = field(default_factory=TextConfig)
    vae: VAEConfig = field(default_factory=VAEConfig)
    pflow: PFlowConfig = field(default_factory=PFlowConfig)
    sflow: SFlowConfig = field(default_factory=SFlowConfig)
    train_vae: TrainConfig = field(default_factory=lambda: TrainConfig(batch_size=128))
    train_pflow: TrainConfig = field(default_factory=TrainConfig)
    train_sflow: TrainConfig = field(default_factory=TrainConfig)
    evaluator: EvaluatorConfig = field(default_factory=EvaluatorConfig)
    train_evaluator: TrainConfig = field(
        default_factory=lambda: TrainConfig(batch_size=96, max_frames=300, val_every=2000)
    )

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> UMFConfig:
        return _from_dict(cls, _legacy_decoding(d))

    def save_yaml(self, path: str | Path) -> None:
        from umf.io import write_text_atomic

        write_text_atomic(path, yaml.safe_dump(_plain(self.to_dict()), sort_keys=False))

    @classmethod
    def load_yaml(cls, path: str | Path) -> UMFConfig:
        try:
            data = yaml.safe_load(Path(path).read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise UMFError(f"{path}: cannot read config ({exc})") from exc
        family = data.pop("family", "paper") if isinstance(data, dict) else "paper"
        base = family_config(family).to_dict()
        return cls.from_dict(_merge(base, _legacy_decoding(data)))


def _legacy_decoding(data: Any) -> Any:
    """A whole saved config (every VAE option written out) from before ``height_fusion``
    and ``reaction_root_fusion`` existed decoded everything at ``root_fusion``: keep it so,
    rather than giving an old model the new defaults' decoding."""
    vae = data.get("vae") if isinstance(data, dict) else None
    if isinstance(vae, dict) and "w_interaction" in vae and "height_fusion" not in vae:
        vae = {"height_fusion": None, "reaction_root_fusion": None, **vae}
        return {**data, "vae": vae}
    return data


def _plain(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return x


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _from_dict(cls, d: dict[str, Any]):
    if not isinstance(d, dict):
        raise UMFError(f"expected a mapping for {cls.__name__}, got {type(d).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = set(d) - set(fields)
    if unknown:
        raise UMFError(f"unknown {cls.__name__} option(s): {', '.join(sorted(unknown))}")
    kwargs = {}
    hints = {f.name: f.type for f in dataclasses.fields(cls)}
    for name, value in d.items():
        default = getattr(cls(), name) if name in fields else None
        if dataclasses.is_dataclass(default):
            kwargs[name] = _from_dict(type(default), value)
        elif isinstance(default, tuple) and isinstance(value, list):
            kwargs[name] = tuple(value)
        elif "tuple" in str(hints[name]) and isinstance(value, list):
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return cls(**kwargs)


def set_option(cfg: UMFConfig, assignment: str) -> UMFConfig:
    """Apply ``a.b.c=value`` (value parsed as YAML) and return a new config."""
    if "=" not in assignment:
        raise UMFError(f"--set expects key=value, got {assignment!r}")
    key, raw = assignment.split("=", 1)
    value = yaml.safe_load(raw)
    tree: Any = value
    for part in reversed(key.strip().split(".")):
        tree = {part: tree}
    return UMFConfig.from_dict(_merge(cfg.to_dict(), tree))


def small_config() -> UMFConfig:
    """Trains on this 2-core CPU in about an hour on the Bandai corpus (all stages).

    Measured here: VAE 0.91 s/step (2,000 steps, 32 min), flows 0.5-0.7 s/step on
    pre-encoded latents (1,000 steps each) plus about 7 min each to encode their latents.
    """
    den = DenoiserConfig(
        d_model=192,
        num_layers=5,
        num_heads=4,
        ff_dim=384,
        dropout=0.1,
        text_width=192,
        text_heads=4,
        text_ff_dim=384,
        text_layers=2,
        branch_layers=1,
    )
    # flows train on nearly full-length crops: the latent's tokens are aligned in time, so a
    # latent of a short crop has empty tail tokens, and a flow that learnt those would
    # make motions that stop early; a shorter motion is decoded as a prefix instead
    flow_train = dict(
        lr=3e-4, batch_size=128, warmup_steps=200, min_frames=140, max_frames=160,
        val_every=250, ckpt_every=250, latent_passes=4,
    )  # fmt: skip
    # evaluators: 4 frames per motion token, about 4 minutes each on this CPU (one thread)
    evaluator = EvaluatorConfig(
        d_model=128, num_layers=3, num_heads=4, ff_dim=256, embed_dim=128,
        text_width=128, text_layers=2, text_heads=4, text_ff_dim=256,
        latent_scale_init=3.0, frames_per_token=4,
    )  # fmt: skip
    train_evaluator = TrainConfig(
        lr=1e-3, batch_size=64, max_steps=500, warmup_steps=40, min_frames=45,
        max_frames=240, val_every=100, ckpt_every=100, log_every=25,
    )  # fmt: skip
    return UMFConfig(
        family="small",
        vae=VAEConfig(
            d_model=192,
            num_layers=3,
            num_heads=4,
            ff_dim=384,
            num_tokens=16,
            latent_dim=16,
            max_frames=300,
            dropout=0.0,  # a VAE this small underfits; dropout only slowed it (measured)
            frames_per_token=4,  # 4x fewer tokens: the same pose learning 3x faster (measured)
            token_span=10.0,  # 16 tokens cover 160 frames (5.3 s), the training crops
        ),
        pflow=PFlowConfig(denoiser=den, single_person_weight=1.0),
        sflow=SFlowConfig(denoiser=dataclasses.replace(den), context_ff_dim=128),
        train_vae=TrainConfig(
            lr=1e-3,
            batch_size=32,
            max_steps=2000,
            warmup_steps=100,
            min_frames=30,
            max_frames=160,
            val_every=200,
            ckpt_every=200,
        ),
        train_pflow=TrainConfig(max_steps=1000, **flow_train),
        train_sflow=TrainConfig(max_steps=500, **flow_train),
        evaluator=evaluator,
        train_evaluator=train_evaluator,
    )


def family_config(name: str) -> UMFConfig:
    if name == "paper":
        return UMFConfig()
    if name == "small":
        return small_config()
    raise UMFError(f"unknown config family {name!r} (choose paper or small)")


def key_times(values: Sequence[str], where: str = "relation_repeats") -> dict[str, int]:
    """``["stand_facing=4", ...]`` as {key: times}; one error line for anything else."""
    out = {}
    for key, value in metadata_pairs(values, where):
        if not value.isdigit() or not 1 <= int(value) <= 1000:
            raise UMFError(f"{where}: times must be a whole number 1-1000, got {key}={value}")
        out[key] = int(value)
    return out


def metadata_pairs(values: Sequence[str], where: str = "caption_mix_from") -> list[list[str]]:
    """``["style=normal", ...]`` as [key, value] pairs; one error line for anything else."""
    pairs = [v.split("=", 1) for v in values]
    if any(len(pair) != 2 or not pair[0] for pair in pairs):
        eg = {"label_repeats": "jump=4", "relation_repeats": "stand_facing=4"}
        eg = eg.get(where.split(".")[-1], "style=normal")
        raise UMFError(f"{where} takes key=value pairs (e.g. {eg}), got {list(values)}")
    return pairs
