"""Coverage: a model's vocabulary, the score of a prompt, where it shows, touching takes."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from conftest import FakeText, prepare_fixture_corpus, save_tiny_model
from umf.coverage import Vocabulary, build_vocabulary, embed, take_contacts


class WordText(FakeText):
    """Bag of words: prompts sharing words have similar pooled states (a stand-in for a
    sentence encoder whose similarity means something)."""

    def encode(self, texts):
        import zlib

        from umf.text import TextFeatures

        pooled = torch.zeros(len(texts), self.dim)
        for i, t in enumerate(texts):
            for w in t.lower().replace(".", " ").split():
                g = torch.Generator().manual_seed(zlib.crc32(w.encode()))
                pooled[i] += torch.randn(self.dim, generator=g)
        return TextFeatures(pooled[:, None], torch.ones(len(texts), 1, dtype=torch.bool), pooled)


def _vocab(phrases, threshold=0.8, contact=None) -> Vocabulary:
    enc = WordText()
    return Vocabulary(list(phrases), embed(enc, phrases), "fake", threshold, contact=contact or {})


def test_trained_captions_are_known_and_new_ones_are_not():
    v = _vocab(["a person walks forward", "a person bows politely", "two people dance salsa"])
    enc = WordText()
    same, near, new = v.score(["a person bows politely", "a person walks forward slowly",
                               "swim butterfly"], enc)  # fmt: skip
    assert same["score"] == pytest.approx(1.0, abs=1e-4) and same["known"]
    assert same["nearest"][0] == "a person bows politely"
    assert near["nearest"][0] == "a person walks forward" and near["known"]
    assert not new["known"] and new["score"] < 0.5
    assert len(new["nearest"]) == 3


def test_contact_comes_with_a_known_prompt_worded_like_a_touching_take():
    touch = {"two people dance salsa": {"closest_m": 0.07, "pelvis_m": 0.29}}
    v = _vocab(["a person walks forward", "two people dance salsa"], contact=touch)
    salsa, walk, new = v.score(["two people dance salsa", "a person walks forward",
                                "juggle balls"], WordText())  # fmt: skip
    assert salsa["contact"] == touch["two people dance salsa"]
    assert "contact" not in walk and "contact" not in new


def test_vocabulary_round_trips_and_a_broken_one_is_one_line(tmp_path):
    from umf.errors import UMFError

    v = _vocab(
        ["a person walks", "someone bows"],
        contact={"someone bows": {"closest_m": 0.1, "pelvis_m": 0.3}},
    )
    v.actions, v.styles, v.relations = ["walk", "bow"], ["normal"], ["greet"]
    v.groups = ["single_file"]
    v.save(tmp_path)
    w = Vocabulary.load(tmp_path)
    assert w.phrases == v.phrases and w.actions == ["walk", "bow"] and w.contact == v.contact
    assert w.groups == ["single_file"]
    doc = json.loads((tmp_path / "vocabulary.json").read_text())
    del doc["groups"]  # a vocabulary written before group relations
    (tmp_path / "vocabulary.json").write_text(json.dumps(doc))
    assert Vocabulary.load(tmp_path).groups == []
    for key in ("groups", "actions"):  # a list field that is no list: one line, not a traceback
        broken = {**doc, key: None}
        (tmp_path / "vocabulary.json").write_text(json.dumps(broken))
        with pytest.raises(UMFError, match=f"corrupt vocabulary \\({key}\\)"):
            Vocabulary.load(tmp_path)
    assert torch.allclose(w.embeddings, v.embeddings, atol=1e-3)  # stored in fp16
    assert Vocabulary.load(tmp_path / "nothing") is None
    doc = json.loads((tmp_path / "vocabulary.json").read_text())
    doc["phrases"] = doc["phrases"][:1]
    (tmp_path / "vocabulary.json").write_text(json.dumps(doc))
    with pytest.raises(UMFError, match="do not match"):
        Vocabulary.load(tmp_path)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    from umf.data.corpus import Corpus

    root = prepare_fixture_corpus(tmp_path_factory.mktemp("cov") / "c", train_scenes=20,
                                  val_scenes=4, test_scenes=4, test_groups=2)  # fmt: skip
    return Corpus.load(root)


def test_a_corpus_vocabulary_holds_its_train_captions_and_labels(corpus):
    v = build_vocabulary(corpus, WordText(), "fake")
    train = corpus.split_clips("train")
    assert set(train[0].captions) <= set(v.phrases)
    assert {c.meta["content"] for c in train} == set(v.actions)
    assert set(v.relations) == {r["relation"] for r in corpus.scenes["train"]}
    held_out = {t for c in corpus.split_clips("test") for t in c.captions} - {
        t for c in train for t in c.captions
    }
    assert not held_out & set(v.phrases)  # only what training saw


def test_a_vocabulary_knows_the_groups_composed_from_its_train_clips(corpus):
    """Groups are composed at sampling, never trained: their captions join the vocabulary as
    groups composed from the training clips (never from a held-out clip) would be worded."""
    from umf.coverage import train_groups
    from umf.data.scene_relations import RELATIONS

    groups = train_groups(corpus, count=40)
    assert groups and all(r["num_people"] >= 3 for r in groups)
    train = {c.id for c in corpus.split_clips("train")}
    assert all(a["clip"] in train for r in groups for a in r["people"])
    assert train_groups(corpus, count=40) == groups  # deterministic
    v = build_vocabulary(corpus, WordText(), "fake")
    assert {t for r in train_groups(corpus) for t in r["captions"]} <= set(v.phrases)
    assert v.groups == sorted({r["relation"] for r in train_groups(corpus)})
    assert all(max(RELATIONS[g].sizes) > 2 for g in v.groups)
    assert not set(v.groups) & set(v.relations)  # pairs are trained scenes, groups are not


def test_touching_takes_give_their_closeness(real_joints):
    from umf.data.clip import MotionClip

    a = real_joints.numpy()[:60].astype(np.float32)
    b = a.copy()
    b[..., 0] += 0.4  # side by side, hands near
    far = a.copy()
    far[..., 0] += 3.0
    clips = [
        MotionClip("t", "mocap", np.stack([a, b]), ["two people hold hands"]),
        MotionClip("f", "mocap", np.stack([a, far]), ["two people stand apart"]),
    ]
    got = take_contacts(clips)
    assert list(got) == ["two people hold hands"]
    assert got["two people hold hands"]["pelvis_m"] == pytest.approx(0.4, abs=1e-4)
    assert 0.0 < got["two people hold hands"]["closest_m"] < 0.4


def test_touching_prompts_are_separated_less_but_never_through_each_other(real_joints):
    from umf.pipeline import touching_distances
    from umf.separation import FIT_MARGIN, TOUCH_FLOOR, separate_people

    a = real_joints.numpy()[:40].astype(np.float32)
    b = a.copy()
    b[..., 0] += 0.6  # side by side, arms' joints 10-20 cm apart: a couple, not strangers
    scene = np.stack([a, b])
    from umf.data.relations import closest_joints

    assert 0.05 + FIT_MARGIN < closest_joints(a, b)[0] < 0.25
    _, default = separate_people(scene)
    _, close = separate_people(scene, **touching_distances({"closest_m": 0.05, "pelvis_m": 0.25}))
    assert np.linalg.norm(default[1]) > 0.1 and np.abs(close).max() < 1e-6
    d = touching_distances({"closest_m": 0.0, "pelvis_m": 0.0})
    assert d["contact_distance"] == pytest.approx(TOUCH_FLOOR)
    _, through = separate_people(np.stack([a, a]), **d)  # one body inside the other
    assert np.linalg.norm(through[1]) > 0.1
    assert touching_distances(None) == {}


def test_touching_people_may_come_as_close_as_real_partners_ever_do(real_joints):
    """A couple whose joints come within 5 cm at two frames (closer than the take's 5th
    percentile, 8 cm, as real partners do) stays where it is; the rule before, that
    percentile at every frame, pushed it away, as it pushed real salsa takes
    (research/touch_shifts.py). Joints 1 cm apart at a frame, or pelvises 15 cm apart,
    still move it: a centimetre or a few, not metres."""
    from umf.data.relations import closest_joints
    from umf.separation import TOUCH_FLOOR, TOUCH_PELVIS, separate_people, touching_distances

    a = real_joints.numpy()[:40].astype(np.float64)

    def beside(gaps):
        """a's double, moved along x frame by frame until its closest joints to a are
        ``gaps`` (40,) m apart (bisection: the gap grows with the offset)."""
        b = a.copy()
        for t, gap in enumerate(gaps):
            lo, hi = 0.0, 2.0
            for _ in range(40):
                mid = (lo + hi) / 2
                d = closest_joints(a[t : t + 1], a[t : t + 1] + np.array([mid, 0, 0]))[0]
                lo, hi = (mid, hi) if d < gap else (lo, mid)
            b[t, :, 0] += hi
        return b

    gaps = np.full(40, 0.14)  # closest joints 14 cm apart ...
    gaps[[10, 30]] = 0.05  # ... and 5 cm at two frames (pelvises 0.24 m apart there)
    near = touching_distances({"closest_m": 0.08, "pelvis_m": 0.25})
    _, kept = separate_people(np.stack([a, beside(gaps)]), **near)
    assert np.abs(kept).max() < 1e-9
    before = {"min_distance": 0.25, "contact_distance": 0.08 + 0.03, "smallest": True}
    _, pushed = separate_people(np.stack([a, beside(gaps)]), **before)
    assert np.linalg.norm(pushed[1]) > 0.05
    for frame_gap, least in ((0.01, 0.005), (0.0, 0.03)):  # joints 1 cm; pelvises 0.15 m
        g = gaps.copy()
        g[20] = frame_gap
        b = beside(g)
        if frame_gap == 0.0:
            b[20, :, 0] = a[20, :, 0] + 0.15
        _, moved = separate_people(np.stack([a, b]), **near)
        b = b + moved[1]
        assert least < np.linalg.norm(moved[1]) < 0.1
        assert closest_joints(a, b)[0] >= TOUCH_FLOOR - 1e-6
        assert (
            np.linalg.norm(b[:, 0, [0, 2]] - a[:, 0, [0, 2]], axis=-1).min() >= TOUCH_PELVIS - 1e-6
        )


@pytest.fixture
def covered_model(tmp_path, monkeypatch):
    import umf.text

    monkeypatch.setattr(umf.text, "build_text_encoder", lambda *a, **k: WordText())
    model = save_tiny_model(tmp_path / "m")
    _vocab(["a person walks forward", "a person bows politely"], threshold=0.8).save(model)
    return model


def test_scenes_npz_and_cli_carry_coverage(covered_model, tmp_path, one_thread):
    from umf.cli.main import app
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(covered_model)
    known, new = pipe(["a person walks forward", "juggle three balls"], num_people=1,
                      seconds=1.0, fit=False)  # fmt: skip
    assert known.meta["coverage"]["known"] and not new.meta["coverage"]["known"]
    new.save_npz(tmp_path / "s.npz")
    with np.load(tmp_path / "s.npz") as z:
        assert json.loads(str(z["coverage"]))["nearest"] == new.meta["coverage"]["nearest"]
    runner = CliRunner()
    out = runner.invoke(app, ["generate", "juggle three balls", "--people", "1", "--seconds",
                              "1", "--model", str(covered_model), "--out", str(tmp_path / "g"),
                              "--format", "npz"])  # fmt: skip
    assert out.exit_code == 0, out.output
    assert out.stderr.count("umf: warning:") == 1 and "nearest known" in out.stderr
    out = runner.invoke(app, ["generate", "a person walks forward", "--people", "1",
                              "--seconds", "1", "--model", str(covered_model), "--out",
                              str(tmp_path / "g2"), "--format", "npz"])  # fmt: skip
    assert out.exit_code == 0 and "warning" not in out.stderr
    info = runner.invoke(app, ["info", str(covered_model), "--prompt", "juggle three balls"])
    assert info.exit_code == 0 and "NOT known" in info.stdout


def test_a_model_without_vocabulary_still_generates(tmp_path, fake_text, one_thread):
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(save_tiny_model(tmp_path / "m"))
    (scene,) = pipe("anything", num_people=1, seconds=1.0, fit=False)
    assert "coverage" not in scene.meta
