import tarfile
import zipfile

import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE, SHARED_BANDAI
from umf.data import bandai
from umf.errors import UMFError
from umf.representation import heading_angle


def test_all_fixture_clips_load(bandai_clips):
    assert len(bandai_clips) == 11
    for c in bandai_clips:
        assert c.joints.shape[0] == 1 and c.joints.shape[2:] == (22, 3)
        assert c.joints.dtype == np.float32 and np.isfinite(c.joints).all()
        assert c.fps == 30.0 and c.source == "bandai"
        assert len(c.captions) >= 3 and len(set(c.captions)) == len(c.captions)
        assert c.meta["content"] in bandai.CONTENT_PHRASES


def test_retarget_is_metric_and_upright(bandai_clips):
    for c in bandai_clips:
        j = c.joints[0]
        floor = j[..., 1].min()
        head = j[:, 15, 1] - floor
        # adult actors: head joint 1.1-1.6 m above the floor, pelvis 0.8-1.1 m
        assert 1.1 < np.median(head) < 1.6, c.id
        assert 0.75 < np.median(j[:, 0, 1] - floor) < 1.15, c.id
        # spine3 is the midpoint between spine2 (Chest) and neck
        assert np.allclose(j[:, 9], 0.5 * (j[:, 6] + j[:, 12]), atol=1e-6)
        # femur about 35-50 cm
        femur = np.linalg.norm(j[:, 4] - j[:, 1], axis=-1)
        assert 0.33 < femur.mean() < 0.5


def test_labels_match_motion(bandai_clips):
    by_id = {c.id: c for c in bandai_clips}
    walk = by_id["dataset-1_walk_normal_001"].joints[0]
    travel = np.linalg.norm(walk[-1, 0, [0, 2]] - walk[0, 0, [0, 2]])
    assert travel > 5.0
    bow = by_id["dataset-1_bow_normal_001"].joints[0]
    assert np.linalg.norm(bow[-1, 0, [0, 2]] - bow[0, 0, [0, 2]]) < 0.3
    # the bow tilts the head forward and down, then back up
    head_h = bow[:, 15, 1]
    assert head_h.min() < head_h[0] - 0.08 and head_h[-1] > head_h.min() + 0.08
    # waving the right hand lifts the right wrist above the head, not the left one
    wave = by_id["dataset-2_wave-right-hand_normal_001"].joints[0]
    assert (wave[:, 21, 1] > wave[:, 15, 1]).any()
    assert not (wave[:, 20, 1] > wave[:, 15, 1]).any()
    # a left turn turns the heading counter-clockwise seen from above (+yaw)
    turn = torch.from_numpy(by_id["dataset-2_walk-turn-left_active_001"].joints[0])
    dyaw = float(heading_angle(turn[-1]) - heading_angle(turn[0]))
    dyaw = (dyaw + np.pi) % (2 * np.pi) - np.pi
    assert dyaw > np.radians(45)


def test_captions_are_natural_and_deterministic():
    a = bandai.captions_for("bow", "happy", 4, seed="x")
    assert a == bandai.captions_for("bow", "happy", 4, seed="x")
    assert all(s[0].isupper() and s.endswith(".") for s in a)
    assert all("bow" in s for s in a)
    assert any(w in " ".join(a) for w in ("happ", "cheerful"))
    assert all("normal" not in s for s in bandai.captions_for("walk", "normal", 4))
    with pytest.raises(UMFError):
        bandai.captions_for("juggle", "normal")


def test_reads_archives_and_reports_bad_files(tmp_path):
    src = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1"
    names = ["dataset-1_bow_normal_001", "dataset-1_walk_normal_002"]
    tar_path = tmp_path / "dataset-1.tar.xz"
    with tarfile.open(tar_path, "w:xz") as tar:
        for n in names:
            for ext in ("bvh", "json"):
                tar.add(src / "data" / f"{n}.{ext}", arcname=f"ds/data/{n}.{ext}")
    zip_path = tmp_path / "data.zip"
    with zipfile.ZipFile(zip_path, "w") as zf:
        zf.write(src / "data" / f"{names[0]}.bvh", arcname=f"data/{names[0]}.bvh")
        zf.writestr("data/dataset-1_kick_normal_009.bvh", "HIERARCHY\nROOT joint_Root\n{")
    from_tar = list(bandai.load_bandai(tar_path))
    assert [c.id for c in from_tar] == names
    direct = {c.id: c for c in bandai.load_bandai(src)}
    assert np.array_equal(from_tar[0].joints, direct[names[0]].joints)
    problems: list = []
    from_zip = list(bandai.load_bandai(zip_path, problems))
    assert [c.id for c in from_zip] == [names[0]]
    assert len(problems) == 1 and "dataset-1_kick_normal_009" in problems[0][0]
    with pytest.raises(UMFError):
        list(bandai.load_bandai(zip_path))  # without a problems list the error surfaces
    with pytest.raises(UMFError, match="not found"):
        list(bandai.load_bandai(tmp_path / "nope"))


def test_resample_keeps_duration_and_linear_paths():
    t = np.arange(61, dtype=np.float32) / 60.0  # 1 s at 60 fps
    j = np.zeros((1, 61, 22, 3), np.float32)
    j[..., 0] = (3.0 * t)[None, :, None]
    out = bandai.resample(j, 60.0, 30.0)
    assert out.shape[1] == 31
    assert np.allclose(out[0, :, 0, 0], 3.0 * np.arange(31) / 30.0, atol=1e-6)
    assert bandai.resample(j, 30.0, 30.0) is j


@pytest.mark.shared
@pytest.mark.slow
def test_full_bandai_corpus_loads():
    if not SHARED_BANDAI.exists():
        pytest.skip("../shared/data/bandai not present")
    problems: list = []
    n = sum(1 for _ in bandai.load_bandai(SHARED_BANDAI, problems))
    assert problems == [] and n == 3076


def test_a_label_that_is_not_an_object_and_a_corrupt_inner_zip(tmp_path):
    """A label file holding `5` reads as no label (the name carries the labels); a corrupt
    zip inside a tar is one line naming it."""
    import io
    import shutil
    import tarfile

    from conftest import BANDAI_FIXTURE
    from umf.data.bandai import load_bandai
    from umf.errors import UMFError

    src = tmp_path / "b"
    shutil.copytree(BANDAI_FIXTURE, src)
    label = next(src.rglob("dataset-1_bow_normal_001.json"))
    label.write_text("5")
    problems: list = []
    clips = {c.id: c for c in load_bandai(src, problems)}
    assert clips["dataset-1_bow_normal_001"].meta["content"] == "bow"
    tar = tmp_path / "x.tar"
    with tarfile.open(tar, "w") as tf:
        data = b"PK\x03\x04 not a zip"
        info = tarfile.TarInfo("inner/data.zip")
        info.size = len(data)
        tf.addfile(info, io.BytesIO(data))
    with pytest.raises(UMFError, match="unreadable zip inside the archive"):
        list(load_bandai(tar, []))
