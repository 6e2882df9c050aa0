import json

import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE
from umf.data import corpus as C
from umf.data.relations import check_record
from umf.errors import UMFError
from umf.representation import FEATURE_DIM, features_to_joints


@pytest.fixture(scope="module")
def small_corpus(tmp_path_factory):
    out = tmp_path_factory.mktemp("corpus")
    cfg = C.PrepareConfig(train_scenes=24, val_scenes=6, test_scenes=6, test_groups=4)
    manifest = C.prepare_corpus(
        out, {"bandai": BANDAI_FIXTURE}, cfg, progress=False, log=lambda s: None
    )
    return out, manifest


def test_manifest_and_files(small_corpus):
    out, manifest = small_corpus
    assert manifest["format"] == C.FORMAT and manifest["version"] == C.FORMAT_VERSION
    for name in (
        "manifest.json",
        "clips.json",
        "clips.npz",
        "scenes.json",
        "normalizer.safetensors",
    ):
        assert (out / name).exists()
    assert manifest["total"]["clips"] == 11
    assert sum(s["clips"] for k, s in manifest["splits"].items() if k in C.SPLITS) == 11
    assert manifest["splits"]["train"]["scenes"] == 24
    assert manifest["splits"]["test_groups"]["scenes"] == 4
    assert "CC BY-NC 4.0" in manifest["license"]
    assert not list(out.glob("*.tmp")) and not list(out.glob(".*.tmp"))


def test_splits_are_by_clip_and_scenes_stay_inside(small_corpus):
    out, _ = small_corpus
    corpus = C.Corpus.load(out)
    split_of = {c.id: c.split for c in corpus.clips}
    for split, recipes in corpus.scenes.items():
        want = "test" if split == "test_groups" else split
        for r in recipes:
            assert {split_of[p["clip"]] for p in r["people"]} == {want}, r["id"]


def test_assign_splits_stratified_and_stable():
    clips = [{"id": f"c{i}", "source": "bandai", "dataset": 1, "content": k}
             for k in ("walk", "bow") for i in range(20)]  # fmt: skip
    a = C.assign_splits(clips, 0.1, 0.1)
    assert a == C.assign_splits(list(reversed(clips)), 0.1, 0.1)
    for k in ("walk", "bow"):
        got = [a[c["id"]] for c in clips if c["content"] == k]
        assert got.count("test") == 2 and got.count("val") == 2
    # a dataset's own split wins
    clips.append({"id": "x", "source": "humanml3d", "split": "val"})
    assert C.assign_splits(clips, 0.1, 0.1)["x"] == "val"


def test_scene_features_match_joints(small_corpus):
    out, _ = small_corpus
    corpus = C.Corpus.load(out)
    recipe = corpus.scenes["train"][0]
    f = corpus.scene_features(recipe)
    j = corpus.scene_joints(recipe)
    assert f.shape == (recipe["num_people"], recipe["num_frames"] - 1, FEATURE_DIM)
    assert np.allclose(features_to_joints(torch.from_numpy(f)).numpy(), j[:, :-1], atol=1e-6)
    assert all(r.passed for r in check_record(j, recipe))
    clip = corpus.clips[0]
    cf = corpus.clip_features(clip)
    assert cf.shape == (1, clip.num_frames - 1, FEATURE_DIM)
    # canonical: first-frame pelvis over the origin
    assert np.allclose(cf[0, 0, [0, 2]], 0.0, atol=1e-5)


def test_normalizer_is_sane(small_corpus):
    out, _ = small_corpus
    norm = C.Corpus.load(out).normalizer
    assert norm.mean.shape == (FEATURE_DIM,) and (norm.std > 0).all()
    # mean pelvis height about 0.9 m
    assert 0.7 < float(norm.mean[1]) < 1.1


def test_second_run_reuses_cache(small_corpus, tmp_path):
    out, first = small_corpus
    cfg = C.PrepareConfig(train_scenes=24, val_scenes=6, test_scenes=6, test_groups=4)
    again = C.prepare_corpus(
        out, {"bandai": BANDAI_FIXTURE}, cfg, progress=False, log=lambda s: None
    )
    assert again["sources"][0]["reused_cache"] is True
    assert again["splits"] == first["splits"]
    assert json.loads((out / "scenes.json").read_text())["train"][0]["id"].startswith("train-")


def test_corrupt_input_is_reported_and_skipped(tmp_path):
    src = tmp_path / "bandai" / "data"
    src.mkdir(parents=True)
    good = (
        BANDAI_FIXTURE
        / "Bandai-Namco-Research-Motiondataset-1"
        / "data"
        / "dataset-1_bow_normal_001.bvh"
    )
    (src / good.name).write_bytes(good.read_bytes())
    text = good.read_text()
    (src / "dataset-1_bye_normal_001.bvh").write_text(text[: len(text) // 2])  # truncated
    logs: list[str] = []
    cfg = C.PrepareConfig(train_scenes=2, val_scenes=0, test_scenes=0, test_groups=0)
    m = C.prepare_corpus(
        tmp_path / "out", {"bandai": tmp_path / "bandai"}, cfg, progress=False, log=logs.append
    )
    assert m["total"]["clips"] == 1
    assert len(m["skipped"]) == 1 and "dataset-1_bye_normal_001" in m["skipped"][0]["file"]
    assert any("skipped" in line and "dataset-1_bye_normal_001" in line for line in logs)


def test_bad_inputs():
    with pytest.raises(UMFError, match="no data source"):
        C.prepare_corpus("/tmp/x", {}, progress=False)
    with pytest.raises(UMFError, match="not found"):
        C.prepare_corpus("/tmp/x", {"bandai": "/nonexistent"}, progress=False)
    with pytest.raises(UMFError, match="not a umf corpus"):
        C.Corpus.load("/nonexistent")


def test_prepare_with_humanml3d_and_interhuman(tmp_path, bandai_clips):
    """All three adapters feed one corpus; dataset splits are kept, bad items reported."""
    from test_interhuman import make_root, write_scene
    from umf.humanml3d import encode_joints

    ih = make_root(tmp_path / "InterHuman")
    for item in ("1", "2"):
        write_scene(ih, item, 60)
        (ih / "annots" / f"{item}.txt").write_text("two people walk past each other.\n")
    (ih / "train.txt").write_text("1\n")
    (ih / "test.txt").write_text("2\n")

    hm = tmp_path / "HumanML3D"
    for sub in ("new_joint_vecs", "texts"):
        (hm / sub).mkdir(parents=True)
    walk = next(c for c in bandai_clips if c.id == "dataset-1_walk_normal_001").joints[0]
    from umf.data.bandai import resample

    at20 = resample(walk[None], 30.0, 20.0)[0]  # HumanML3D runs at 20 fps
    vec = encode_joints(torch.from_numpy(at20).double()).float().numpy()
    np.save(hm / "new_joint_vecs" / "000001.npy", vec)
    (hm / "texts" / "000001.txt").write_text("a person walks forward.#a/DET#0.0#0.0\n")
    (hm / "new_joint_vecs" / "000002.npy").write_bytes(b"garbage")
    (hm / "texts" / "000002.txt").write_text("a person jumps.#a/DET#0.0#0.0\n")
    (hm / "train.txt").write_text("000001\n000002\n")

    cfg = C.PrepareConfig(train_scenes=4, val_scenes=0, test_scenes=0, test_groups=0)
    m = C.prepare_corpus(
        tmp_path / "out",
        {"bandai": BANDAI_FIXTURE, "humanml3d": hm, "interhuman": ih},
        cfg,
        progress=False,
        log=lambda s: None,
    )
    assert [s["name"] for s in m["sources"]] == ["bandai", "humanml3d", "interhuman"]
    assert [s["clips"] for s in m["sources"]] == [11, 1, 2]
    assert any("000002" in s["file"] for s in m["skipped"])
    corpus = C.Corpus.load(tmp_path / "out")
    by_id = {c.id: c for c in corpus.clips}
    two = [c for c in corpus.clips if c.source == "interhuman"]
    assert {c.split for c in two} == {"train", "test"} and all(c.num_people == 2 for c in two)
    feats = corpus.clip_features(two[0])
    assert feats.shape == (2, two[0].num_frames - 1, 262)
    h = by_id["000001"]
    # 20 -> 30 fps: about the original number of frames of the walk again
    assert abs(h.num_frames - walk.shape[0]) <= 3 and h.fps == 30.0
    travel = np.linalg.norm(h.joints[0, -1, 0, [0, 2]] - h.joints[0, 0, 0, [0, 2]])
    assert travel > 5.0
