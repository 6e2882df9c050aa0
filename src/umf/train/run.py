"""Run the stages end to end: config resolution, data loaders, the three stages, export.

A run directory holds ``config.yaml`` and one sub-directory per stage (``vae/``,
``pflow/``, ``sflow/``, each with ``last/``, ``best/``, ``metrics.csv`` and
``loss_curves.png``); ``export`` collects the best weights into one model directory that
``UMFPipeline.from_pretrained`` loads.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from umf.checkpoint import (
    find_checkpoint,
    load_checkpoint,
    load_first_good,
    previous_path,
    read_weights,
    save_checkpoint,
)
from umf.config import TrainConfig, UMFConfig, family_config, key_times, set_option
from umf.data.corpus import Corpus
from umf.errors import UMFError
from umf.io import atomic_path, write_json_atomic
from umf.representation import Normalizer
from umf.train.batching import MixedBatches, make_loader
from umf.train.datasets import SceneDataset, SingleMotionDataset, check_labels

STAGES = ("vae", "pflow", "sflow")


@dataclass
class Launch:
    """Where and how to run (Lightning Fabric): the same command from a CPU to a cluster."""

    accelerator: str = "cpu"
    devices: int | str = 1
    num_nodes: int = 1
    strategy: str = "auto"
    precision: str = "32-true"
    progress: bool = True
    tensorboard: bool = False


def resolve_config(
    run_dir: Path, family: str | None, config_file: Path | None, overrides: Sequence[str]
) -> UMFConfig:
    """Config of a run: the saved one when resuming, else family + file + --set overrides."""
    saved = run_dir / "config.yaml"
    if saved.exists() and family is None and config_file is None:
        cfg = UMFConfig.load_yaml(saved)
    elif config_file is not None:
        cfg = UMFConfig.load_yaml(config_file)
    else:
        cfg = family_config(family or "small")
    for o in overrides:
        cfg = set_option(cfg, o)
    check_run_config(cfg)
    return cfg


def check_run_config(cfg: UMFConfig) -> None:
    """Types and ranges of every option and a dry-run build of the model (meta device, no
    memory), so a bad ``--set`` fails before anything is written to the run directory."""
    from umf.pipeline import check_model_config
    from umf.train.loop import check_train_config

    check_model_config(cfg)
    for stage in (*STAGES, "evaluator"):
        t = getattr(cfg, f"train_{stage}")
        try:
            check_train_config(t)
        except UMFError as exc:
            raise UMFError(f"train_{stage}: {exc}") from exc
        if stage != "vae" and t.decoder_only:
            raise UMFError(f"train_{stage}.decoder_only: only the VAE stage has a decoder to "
                           "fine-tune alone")  # fmt: skip
        for name in ("labels", "label_repeats"):
            if stage in ("sflow", "evaluator") and getattr(t, name):
                raise UMFError(f"train_{stage}.{name}: only the VAE and P-Flow train on "
                               "single-person clips, with one content label each")  # fmt: skip
        if stage != "pflow" and t.repeat_leader_gait:
            raise UMFError(f"train_{stage}.repeat_leader_gait: only the P-Flow (person 1)")


def _train_cfg(cfg: UMFConfig, stage: str, max_steps: int | None) -> TrainConfig:
    t: TrainConfig = getattr(cfg, f"train_{stage}")
    if max_steps is not None:
        t = TrainConfig(**{**vars(t), "max_steps": max_steps})
    return t


def _loaders(stage: str, corpus: Corpus, cfg: UMFConfig, t: TrainConfig, vae=None,
             progress: bool = True, stats_vae=None, bank_device: str = "cpu",
             normalizer: Normalizer | None = None):  # fmt: skip
    """(train, val, latents) of a stage.

    VAE and P-Flow alternate single-person and scene batches (SPEC 6), S-Flow sees scenes
    only. Only VAE training places people randomly (they may start anywhere, facing
    anywhere: SPEC 2); only training crops are mirrored. With ``vae`` given, the flows
    train on a latent bank of ``t.latent_passes`` epochs of crops encoded once. With
    ``stats_vae`` given (a flow stage), ``latents`` (N, p, r) are the stage's training
    latents (P-Flow: first people, S-Flow: everybody) for its latent normaliser: from the
    bank, or one encoded epoch when training encodes per batch; else None.
    """
    from umf.train.latents import LatentBankDataset, build_bank

    normalizer = corpus.normalizer if normalizer is None else normalizer
    most = min(t.max_frames, cfg.vae.max_frames)
    frames = dict(min_frames=min(t.min_frames, most), max_frames=most)
    latents: list = []
    bank_kw = dict(device=bank_device, num_workers=t.num_workers, progress=progress)

    def loader(kind: str, split: str):
        train = split == "train"
        common = dict(mirror=train, seed=t.seed, respell=train and t.respell_captions, **frames)
        if kind == "single":
            place = train and stage == "vae"
            more = key_times(t.label_repeats, "label_repeats") if train else None
            # hold_rest / repeat_gait / settle define the target, so validation is extended too
            ds = SingleMotionDataset(corpus, split, normalizer, random_placement=place,
                                     balance=t.balance_labels if train else 0.0,
                                     hold_rest=t.hold_rest, repeat_gait=t.repeat_gait,
                                     settle=t.settle, labels=t.labels, label_times=more,
                                     caption_mix=t.caption_mix if train else 0.0,
                                     caption_mix_within=t.caption_mix_within,
                                     caption_mix_from=t.caption_mix_from,
                                     **common)  # fmt: skip
        else:
            ds = SceneDataset(
                corpus,
                split,
                normalizer,
                real_repeats=t.real_repeats if train else 1,
                relation_repeats=key_times(t.relation_repeats) if train else None,
                repeat_gait=t.repeat_scene_gait,  # defines the target: validation too
                leader_gait=t.repeat_leader_gait,
                **common,
            )
        bank = None
        if vae is not None:
            passes = t.latent_passes if train else 1
            bank = build_bank(vae, ds, passes, desc=f"latents {kind} {split}", **bank_kw)
        elif train and stats_vae is not None:
            bank = build_bank(stats_vae, ds, 1, desc=f"latent stats {kind}", **bank_kw)
        if train and stats_vae is not None:
            z, present = bank["z"], bank["people_mask"]
            latents.append(z[:, 0] if stage == "pflow" else z[present])
        if vae is not None:
            ds = LatentBankDataset(bank, first_person_only=(stage == "pflow"))
        workers = 0 if vae is not None else t.num_workers  # bank items need no workers
        return make_loader(ds, t.batch_size, shuffle=train, num_workers=workers, seed=t.seed)

    if stage == "sflow":
        train, val = loader("scene", "train"), loader("scene", "val")
    elif t.labels:  # one kind of motion: single-person clips only
        train, val = loader("single", "train"), loader("single", "val")
    else:
        train = MixedBatches(loader("single", "train"), loader("scene", "train"))
        val = MixedBatches(loader("single", "val"), loader("scene", "val"))
    return train, val, (torch.cat(latents) if latents else None)


def bank_device(launch: Launch) -> str:
    """Where latent banks are encoded: the training GPU when there is one."""
    wants_gpu = launch.accelerator in ("gpu", "cuda", "auto")
    return "cuda" if wants_gpu and torch.cuda.is_available() else "cpu"


def body_normalizer(corpus: Corpus, radius: float, max_frames: int = 100_000, seed: int = 0,
                    balance: float = 0.0):  # fmt: skip
    """Body-frame statistics (:func:`umf.body_frame.fit_body_normalizer`) of train clips,
    visited in a seeded order until ``max_frames`` frames are seen; the trajectory slots
    account for the random placement of VAE training within ``radius``. ``balance``: clips
    of rare content labels count as often as training draws them (``balance_labels``)."""
    import numpy as np

    from umf.body_frame import fit_body_normalizer
    from umf.train.datasets import label_repeats

    clips = corpus.split_clips("train")
    if balance:
        repeats = label_repeats([c.meta.get("content") for c in clips], balance)
        clips = [c for c, r in zip(clips, repeats, strict=True) for _ in range(r)]
    feats, seen = [], 0
    for i in np.random.default_rng(seed).permutation(len(clips)):
        f = torch.from_numpy(corpus.clip_features(clips[i]))
        feats.append(f.reshape(-1, f.shape[-1]))
        seen += feats[-1].shape[0]
        if seen >= max_frames:
            break
    return fit_body_normalizer(torch.cat(feats), placement_radius=radius)


def _init_model(model: Path, stage: str, run_dir: Path, log: Callable[[str], None],
                own_vae: bool = False) -> Path:  # fmt: skip
    """Check a fine-tuning source; give the run that model's VAE if it has none yet (a run
    that has one must have this very VAE: the flow's weights were trained on its latents),
    unless ``own_vae``: the run fine-tuned that VAE itself (``umf train finetune``), and the
    flows start from the model's weights to follow its latents."""
    import shutil

    model = Path(model)
    if stage == "vae":  # the VAE itself is what is fine-tuned: nothing to hand the run
        if not (model / "vae.safetensors").exists():
            raise UMFError(f"{model}: not a model directory (no vae.safetensors)")
        return model
    for name in ("vae", stage):
        if not (model / f"{name}.safetensors").exists():
            raise UMFError(f"{model}: not a model directory (no {name}.safetensors)")
    have = best_or_last(run_dir / "vae")
    if have is None:
        (run_dir / "vae").mkdir(parents=True, exist_ok=True)
        tmp = run_dir / "vae" / "best.tmp"
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.copytree(model, tmp)
        tmp.rename(run_dir / "vae" / "best")
        log(f"vae: the run uses the VAE of {model}")
        return model
    if own_vae:
        log(f"{stage}: starting from {model}'s weights on this run's fine-tuned VAE")
        return model
    ours, theirs = read_weights(have, "vae"), read_weights(model, "vae")
    same = ours.keys() == theirs.keys() and all(
        ours[k].shape == theirs[k].shape and torch.equal(ours[k].float(), theirs[k].float())
        for k in ours
    )
    if not same:
        raise UMFError(f"{run_dir / 'vae'}: this run's VAE is not the one of {model}; "
                       "fine-tune into a new --out")  # fmt: skip
    return model


def _load_frozen(stage_dir: Path, name: str, module: torch.nn.Module, log=print) -> None:
    """A trained stage's weights: best, else last, else the last before it (warned about)."""
    if best_or_last(stage_dir) is None:
        raise UMFError(f"{stage_dir}: no {name} checkpoint; train the {name} stage first")
    load_first_good(checkpoint_candidates(stage_dir), lambda p: load_checkpoint(p, {name: module}),
                    log)  # fmt: skip


def stage_normalizer(stage: str, corpus: Corpus, run_dir: Path, init: Path | None) -> Normalizer:
    """The feature statistics a stage must train with: those its VAE was trained with.

    From scratch that is the corpus's. Fine-tuning on another corpus (``--init``) keeps the
    model's: a VAE fine-tuned from it, and flows on its latents, read features normalised as
    the model was trained, whatever the new corpus's own statistics are.
    """
    if stage == "vae":
        if init is not None and (Path(init) / "normalizer.safetensors").exists():
            return Normalizer.load(Path(init) / "normalizer.safetensors")
        return corpus.normalizer
    found = best_or_last(run_dir / "vae")
    if found is not None:
        candidates = checkpoint_candidates(run_dir / "vae")
        ck = load_first_good(candidates, load_checkpoint, lambda _: None)
        if ck.normalizer is not None:
            return ck.normalizer
    return corpus.normalizer


def checkpoint_candidates(stage_dir: Path) -> list[Path]:
    """Where a stage's trained weights may be, in order of preference."""
    return [stage_dir / "best", stage_dir / "last", previous_path(stage_dir / "last")]


def best_or_last(stage_dir: Path) -> Path | None:
    for cand in checkpoint_candidates(stage_dir):
        found = find_checkpoint(cand)
        if found is not None:
            return found
    return None


def corpus_captions(corpus: Corpus, respell: bool = False) -> list[str]:
    """Every caption training can ask for: clips (and the own captions of a take's people),
    scenes, their mirrored forms (and with
    ``respell`` their respelled forms: ``train_*.respell_captions``), and ''. Respelled
    forms only when asked, so a text cache built without them still serves every run
    that does not respell."""
    from umf.train.datasets import mirror_caption, respell_caption

    texts = {""}
    for c in corpus.clips:
        texts.update(c.captions)
        for own in c.meta.get("person_captions") or []:  # a take's people (per-person prompts)
            texts.update(own)
    for recipes in corpus.scenes.values():
        for r in recipes:
            texts.update(r["captions"])
    texts.update([mirror_caption(t) for t in texts])
    if respell:
        texts.update([respell_caption(t) for t in texts])
    return sorted(texts)


def text_cache(cfg: UMFConfig, corpus: Corpus, progress: bool = True):
    """Frozen text features of the whole corpus, encoded once in large batches.

    Encoding captions batch by batch during training would cost more than the flow
    steps themselves on a CPU; the cache also persists on disk next to the corpus.
    """
    from tqdm import tqdm

    from umf.text import CachedTextEncoder, TextFeatureCache, build_text_encoder

    cache_dir = corpus.root / "text-cache"
    try:
        enc = build_text_encoder(cfg.text.encoder, cfg.text.path, max_length=cfg.text.max_length)
    except UMFError:
        # a node without the encoder's weights trains from a cache built elsewhere
        if not (cache_dir / CachedTextEncoder.MANIFEST).exists():
            raise
        enc = CachedTextEncoder.load(cache_dir)
        if enc.name != cfg.text.encoder.lower():
            raise UMFError(f"{cache_dir}: text cache of {enc.name!r}, the config asks for "
                           f"{cfg.text.encoder!r}") from None  # fmt: skip
    cache = TextFeatureCache(enc, cache_dir=cache_dir)
    stages = (cfg.train_vae, cfg.train_pflow, cfg.train_sflow, cfg.train_evaluator)
    texts = corpus_captions(corpus, respell=any(t.respell_captions for t in stages))
    chunk = 256
    for i in tqdm(range(0, len(texts), chunk), desc="text features", disable=not progress):
        cache.encode(texts[i : i + chunk])
    if not isinstance(enc, CachedTextEncoder):
        CachedTextEncoder.write(cache_dir, enc)
    return cache


def train_stage(
    stage: str,
    corpus_dir: Path,
    run_dir: Path,
    cfg: UMFConfig,
    launch: Launch,
    *,
    resume: bool = False,
    max_steps: int | None = None,
    init: Path | None = None,
    own_vae: bool = False,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Train one stage of a run; the flow stages load the run's trained VAE (frozen).

    ``init``: a model directory whose weights for this stage start the training
    (fine-tuning); for a flow stage its VAE becomes the run's when the run has none, and
    its latent statistics come with the weights. A resumed run continues from its own
    checkpoint instead.
    """
    from umf.models.pflow import PFlow
    from umf.models.vae import MotionVAE
    from umf.train.loop import check_train_config, train
    from umf.train.stages import PFlowStage, SFlowStage, VAEStage

    if stage not in STAGES:
        raise UMFError(f"unknown stage {stage!r} (choose {', '.join(STAGES)})")
    check_run_config(cfg)
    resuming = resume and best_or_last(run_dir / stage) is not None
    if init is not None and resuming:
        log(f"{stage}: resuming the run's own checkpoint; --init {init} is not used")
        init = None
    if init is not None:
        init = _init_model(init, stage, run_dir, log, own_vae=own_vae)
    corpus = Corpus.load(corpus_dir)
    if cfg.text.respell is None:  # prompts will be respelled into these captions' spelling
        from umf.train.datasets import preferred_spellings

        respell = preferred_spellings(corpus_captions(corpus))
        cfg = dataclasses.replace(cfg, text=dataclasses.replace(cfg.text, respell=respell))
    t = _train_cfg(cfg, stage, max_steps)
    check_train_config(t)
    if t.labels or t.label_repeats:  # before anything is written: a typo must not stay
        check_labels(corpus, [*t.labels, *key_times(t.label_repeats, "label_repeats")])
    if stage == "vae" and t.decoder_only and init is None and not resuming:
        raise UMFError("train_vae.decoder_only fine-tunes a trained VAE: pass --init MODEL_DIR")
    if stage == "vae" and init is not None and not t.decoder_only and not own_vae:
        log(f"vae: the encoder trains too, so the latents change; the flows of {init} know "
            "the old ones: retrain them (or set train_vae.decoder_only=true)")  # fmt: skip
    torch.manual_seed(t.seed)
    normalizer = stage_normalizer(stage, corpus, run_dir, init)
    if stage == "vae":
        from umf.train.datasets import PLACEMENT_RADIUS

        body = body_normalizer(corpus, PLACEMENT_RADIUS) if cfg.vae.target == "body" else None
        st: Any = VAEStage(cfg, normalizer, body_normalizer=body)
    else:
        vae = MotionVAE(cfg.vae)
        _load_frozen(run_dir / "vae", "vae", vae, log)
        cache = text_cache(cfg, corpus, launch.progress)
        if stage == "pflow":
            st = PFlowStage(cfg, vae, cache, seed=t.seed)
        else:
            backbone = None
            if cfg.sflow.shared_backbone:  # ablation: reuse the trained P-Flow transformer
                p, r = vae.latent_shape
                pflow = PFlow(cfg.pflow, p, r, cache.encoder.dim)
                _load_frozen(run_dir / "pflow", "pflow", pflow, log)
                backbone = pflow.net
            st = SFlowStage(cfg, vae, cache, backbone=backbone, seed=t.seed, normalizer=normalizer)
    # only a config that built its stage is saved: a failed start never poisons the run
    run_dir.mkdir(parents=True, exist_ok=True)
    cfg.save_yaml(run_dir / "config.yaml")
    bank_vae = st.vae if stage != "vae" and t.latent_passes > 0 else None
    stats_vae = st.vae if stage != "vae" else None
    train_loader, val_loader, latents = _loaders(stage, corpus, cfg, t, bank_vae, launch.progress,
                                                 stats_vae, bank_device(launch),
                                                 normalizer)  # fmt: skip
    if latents is not None:  # a resumed run restores the same statistics from its checkpoint
        st.trainable().latent_norm.fit(latents)
    if init is not None:  # the latent statistics too: the weights were trained with them
        from umf.checkpoint import checked_weights
        from umf.train.growth import grown_keys, grown_names, grows

        module = st.trainable()
        own = module.state_dict()
        weights = checked_weights(init, stage, module, may_lack=grows)
        # a model without detail gains (trained before pflow.detail_norm) keeps the ones
        # just fitted, refitted under its own latent mean and std; one without per-person
        # prompts gets the zero projection (it computes what it did before)
        grown = grown_keys(own, weights)
        weights.update({k: own[k] for k in grown})
        module.load_state_dict({k: v.to(own[k].dtype) for k, v in weights.items()})
        fresh = [k for k in grown if k.endswith("detail_gain")]
        if grown:
            log(f"{stage}: new in this run, not in {init}: {', '.join(grown_names(grown))}")
        if fresh and latents is not None:
            module.latent_norm.fit_detail(latents)
        log(f"{stage}: starting from the weights of {init}")
        if stage == "vae" and t.refit_body and cfg.vae.target == "body":
            from umf.train.datasets import PLACEMENT_RADIUS

            st.vae.restate_body(body_normalizer(corpus, PLACEMENT_RADIUS, balance=t.balance_labels))
            log(
                "vae: body-frame statistics refitted on this corpus (the weights restated "
                "to compute the same function: umf.models.vae.MotionVAE.restate_body)"
            )
    log(f"training {stage}: {sum(p.numel() for p in st.trainable().parameters()):,} parameters")
    return train(
        st, train_loader, val_loader, t, run_dir / stage,
        config=cfg.to_dict(), normalizer=normalizer,
        accelerator=launch.accelerator, devices=launch.devices, num_nodes=launch.num_nodes,
        strategy=launch.strategy, precision=launch.precision, resume=resume,
        progress=launch.progress, tensorboard=launch.tensorboard, log=log,
    )  # fmt: skip


def export_model(
    run_dir: Path,
    out: Path,
    fp16: bool = True,
    log: Callable[[str], None] = print,
    base: Path | None = None,
) -> Path:
    """One model directory from a run's best checkpoints (what from_pretrained loads).

    ``base``: a model directory that supplies the stages the run did not train (a run
    that fine-tuned one flow with ``--init``); the run's config is the model's.
    """
    cfg = UMFConfig.load_yaml(run_dir / "config.yaml")
    weights = {}
    trained = {s: best_or_last(run_dir / s) is not None for s in STAGES}
    if base is not None and all(trained.values()):
        log(f"every stage was trained in {run_dir}: --base {base} is not used")
    for s in STAGES:
        if not trained[s] and base is not None:
            weights[s] = read_weights(base, s)
            log(f"{s}: from {base}")
            continue
        if not trained[s]:
            raise UMFError(f"{run_dir / s}: no checkpoint; train this stage first (or "
                           "pass --base MODEL_DIR for the stages not trained here)")  # fmt: skip
        weights[s] = load_first_good(checkpoint_candidates(run_dir / s),
                                     lambda p, s=s: read_weights(p, s), log)  # fmt: skip
    ck = load_first_good(checkpoint_candidates(run_dir / "vae"), load_checkpoint, log)
    return save_checkpoint(
        out, weights, config=cfg.to_dict(), normalizer=ck.normalizer,
        dtype=torch.float16 if fp16 else None,
    )  # fmt: skip


# Fine-tuning a released model on a new corpus (`umf train finetune`): what each stage changes
# from the model's own training options. The corpus should hold the model's own data beside
# the new library (replay: `umf data prepare --bandai ... --mocap MYLIB`); label balancing then
# sets how much of each batch is new (docs/training.md measures it), and every real take
# repeats in the scene batches. Sized for a 2-core CPU: about an hour for a few hundred clips.
FINETUNE: tuple[str, ...] = (
    "train_vae.decoder_only=false", "train_vae.lr=0.0001", "train_vae.warmup_steps=20",
    "train_vae.max_steps=300", "train_vae.balance_labels=0.5", "train_vae.real_repeats=40",
    "train_vae.val_every=100", "train_vae.ckpt_every=50", "train_vae.refit_body=true",
    "train_pflow.lr=0.0001", "train_pflow.max_steps=500", "train_pflow.balance_labels=0.5",
    "train_pflow.real_repeats=40", "train_pflow.latent_passes=2", "train_pflow.val_every=250",
    "train_pflow.ckpt_every=50",
    "train_sflow.lr=0.0001", "train_sflow.max_steps=500", "train_sflow.real_repeats=40",
    "train_sflow.latent_passes=2", "train_sflow.val_every=250", "train_sflow.ckpt_every=50",
)  # fmt: skip


def finetune(
    model: Path,
    corpus_dir: Path,
    run_dir: Path,
    overrides: Sequence[str],
    launch: Launch,
    *,
    resume: bool = False,
    stages: Sequence[str] = STAGES,
    log: Callable[[str], None] = print,
) -> Path:
    """Fine-tune every stage of ``model`` on ``corpus_dir`` into ``run_dir``; export
    ``run_dir/model``. The VAE is fine-tuned whole (encoder too: a model that never saw a
    backflip cannot encode one), so each flow starts from the model's weights and follows
    the new latents; stages not in ``stages`` are taken from the model unchanged."""
    model = Path(model)
    if not (model / "config.json").exists():
        raise UMFError(f"{model}: not a model directory (no config.json)")
    unknown = [s for s in stages if s not in STAGES]
    if unknown or not stages:
        raise UMFError(f"--stages: choose from {', '.join(STAGES)}, got {', '.join(stages)}")
    if "vae" not in stages and (set(stages) & {"pflow", "sflow"}):
        log("the VAE is not fine-tuned: the flows train on the model's own latents")
    fresh = not (run_dir / "config.yaml").exists()
    # the fine-tune defaults of the stages trained here only: a stage taken from the model
    # keeps the training options it was trained with in the exported config
    defaults = [o for o in FINETUNE if o.split(".", 1)[0].removeprefix("train_") in stages]
    cfg = resolve_config(run_dir, None, model / "config.json" if fresh else None,
                         [*defaults, *overrides] if fresh else list(overrides))  # fmt: skip
    base = UMFConfig.from_dict(json.loads((model / "config.json").read_text()))
    for flow in ("pflow", "sflow"):
        for option in ("person_head", "person_text"):  # weights a flow must be trained to have
            want, had = (getattr(getattr(c, flow).denoiser, option) for c in (cfg, base))
            if want and not had and flow not in stages:
                raise UMFError(f"{flow}.denoiser.{option}=true needs {flow} in --stages: the "
                               f"{flow} of {model} has no such weights to keep")  # fmt: skip
    own_vae = "vae" in stages
    for stage in STAGES:
        if stage not in stages:
            continue
        done = run_dir / stage / "done.json"
        if resume and done.exists():
            log(f"{stage}: already fine-tuned in {run_dir}")
            continue
        summary = train_stage(stage, corpus_dir, run_dir, cfg, launch, resume=resume,
                              init=model, own_vae=own_vae, log=log)  # fmt: skip
        write_json_atomic(done, {k: v for k, v in summary.items()
                                 if isinstance(v, int | float | str | None)})  # fmt: skip
        log(f"{stage}: {summary.get('steps')} steps in {summary.get('seconds', 0):.0f} s")
    out = export_model(run_dir, run_dir / "model", base=model, log=log)
    write_vocabulary(out, corpus_dir)
    if cfg.sflow.warm_start and cfg.sflow.warm_proposal == "retrieved":
        give_reactions(out, corpus_dir, model, own_vae, launch.progress, log)
    return out


def give_reactions(out: Path, corpus_dir: Path, base: Path, own_vae: bool, progress: bool,
                   log: Callable[[str], None]) -> None:  # fmt: skip
    """The bank of real reactions a fine-tuned model's warm start retrieves from: its
    corpus's. A corpus without multi-person train scenes (a library of solo clips) keeps
    the base model's bank where the VAE was not fine-tuned (its latents still fit), and
    otherwise turns the warm start off in the exported config, so the model still loads."""
    import shutil

    from umf.reaction_bank import REACTIONS
    from umf.train.reactions import NoReactions, write_reactions

    try:
        write_reactions(out, corpus_dir, progress=progress, log=log)
        return
    except NoReactions as exc:
        log(f"reactions: {exc}")
    if not own_vae and (base / REACTIONS).exists():
        with atomic_path(out / REACTIONS) as tmp:
            shutil.copyfile(base / REACTIONS, tmp)
        log(f"reactions: the model keeps the bank of {base}")
        return
    config = json.loads((out / "config.json").read_text())
    config["sflow"]["warm_start"] = 0.0
    write_json_atomic(out / "config.json", config)
    log("reactions: none to retrieve, so the exported model samples without the warm start "
        "(sflow.warm_start=0)")  # fmt: skip


def write_vocabulary(model: Path, corpus_dir: Path, threshold: float | None = None):
    """Give a model directory the vocabulary of the corpus it was trained on
    (:mod:`umf.coverage`), embedded by the model's own text encoder."""
    from umf.coverage import THRESHOLD, build_vocabulary
    from umf.text import build_text_encoder

    cfg = UMFConfig.from_dict(json.loads((Path(model) / "config.json").read_text()))
    enc = build_text_encoder(cfg.text.encoder, cfg.text.path, max_length=cfg.text.max_length)
    vocab = build_vocabulary(Corpus.load(corpus_dir), enc, cfg.text.encoder,
                             THRESHOLD if threshold is None else threshold)  # fmt: skip
    vocab.save(model)
    return vocab
