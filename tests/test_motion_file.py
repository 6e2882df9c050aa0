"""Reading a user's motion file (what `umf react --actor` takes): units, frame rates, errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE
from umf.bvh import write_smpl22_bvh
from umf.data.motion_file import load_motion
from umf.errors import UMFError
from umf.skeleton import fit_offsets, inverse_kinematics
from umf.units import choose_unit

BOW = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001.bvh"


def _write(path, joints: np.ndarray, scale: float, fps: float) -> None:
    """SMPL-22 BVH of metre joints, written in units of ``scale`` metres."""
    j = torch.from_numpy(joints).double()
    offsets = fit_offsets(j)
    local = inverse_kinematics(j, offsets)
    write_smpl22_bvh(path, local.numpy(), j[:, 0].numpy() / scale, offsets.numpy() / scale, fps)


@pytest.mark.parametrize("unit", [1.0, 0.01, 0.001, 0.0254, 0.0254 / 0.45])
def test_units_are_recognised(real_joints, unit):
    joints = real_joints.numpy()
    assert choose_unit(joints / unit)[0] == unit


@pytest.mark.parametrize("unit", [1.0, 0.01, 0.0254])
def test_smpl22_bvh_in_any_unit_reads_back_in_metres(real_joints, tmp_path, unit):
    joints = real_joints.numpy()[:60].astype(np.float32)
    _write(tmp_path / "a.bvh", joints, unit, 30.0)
    m = load_motion(tmp_path / "a.bvh")
    assert m.joints.shape == (1, 60, 22, 3)
    assert np.abs(m.joints[0] - joints).max() < 1e-4


def test_frame_rate_is_resampled_to_30(real_joints, tmp_path):
    joints = real_joints.numpy()[:61].astype(np.float32)
    _write(tmp_path / "a.bvh", joints, 1.0, 60.0)  # the same frames, played twice as fast
    m = load_motion(tmp_path / "a.bvh")
    assert m.meta["source_fps"] == pytest.approx(60.0)
    assert m.joints.shape[1] == 31  # 1 s at 60 fps = 1 s at 30 fps
    assert np.abs(m.joints[0] - joints[::2]).max() < 1e-4


def test_bandai_bvh_in_centimetres(bandai_clips):
    m = load_motion(BOW)
    clip = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001")
    assert np.abs(m.joints - clip.joints).max() < 1e-5  # same as the corpus adapter
    height = m.joints[0, 0, :, 1].max() - m.joints[0, 0, :, 1].min()
    assert 1.2 < height < 2.0


def test_npz_scenes_and_bare_joints(real_joints, tmp_path):
    joints = real_joints.numpy()[:40].astype(np.float32)
    np.savez(tmp_path / "one.npz", joints=joints)
    np.savez(tmp_path / "two.npz", joints=np.stack([joints, joints + 1]), text=np.array("hi"))
    assert load_motion(tmp_path / "one.npz").joints.shape == (1, 40, 22, 3)
    two = load_motion(tmp_path / "two.npz")
    assert two.joints.shape == (2, 40, 22, 3) and two.text == "hi"


@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("x.fbx", b"", "unsupported"),
        ("x.npz", b"garbage", "not a readable"),
        ("x.bvh", b"HIERARCHY\nROOT a {\n", "x.bvh"),
    ],
)
def test_bad_files_are_one_clear_error(tmp_path, name, content, needle):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(UMFError, match=needle):
        load_motion(tmp_path / name)


def test_bad_arrays(tmp_path):
    np.savez(tmp_path / "shape.npz", joints=np.zeros((10, 21, 3)))
    with pytest.raises(UMFError, match="22, 3"):
        load_motion(tmp_path / "shape.npz")
    bad = np.ones((10, 22, 3)) * np.linspace(0, 1.7, 22)[:, None]
    bad[3, 4, 1] = np.nan
    np.savez(tmp_path / "nan.npz", joints=bad)
    with pytest.raises(UMFError, match="NaN"):
        load_motion(tmp_path / "nan.npz")
    np.savez(tmp_path / "none.npz", other=np.zeros(3))
    with pytest.raises(UMFError, match="joints"):
        load_motion(tmp_path / "none.npz")
    with pytest.raises(UMFError, match="not found"):
        load_motion(tmp_path / "missing.bvh")


def test_npz_in_centimetres_is_converted_and_empty_ones_refused(real_joints, tmp_path):
    joints = real_joints.numpy()[:40].astype(np.float32)
    np.savez(tmp_path / "cm.npz", joints=joints * 100)
    m = load_motion(tmp_path / "cm.npz")
    assert m.meta["converted_from"] == "cm" and np.abs(m.joints[0] - joints).max() < 1e-4
    np.savez(tmp_path / "none.npz", joints=np.zeros((0, 10, 22, 3), np.float32))
    with pytest.raises(UMFError, match="no motion"):
        load_motion(tmp_path / "none.npz")


def test_an_api_actor_in_centimetres_is_one_line(real_joints):
    from umf.validation import check_actor

    joints = real_joints.numpy()[:40]
    assert check_actor(joints, 30.0, 300) is joints
    with pytest.raises(UMFError, match="in cm, not metres"):
        check_actor(joints * 100, 30.0, 300)


def test_a_zip_bomb_and_an_endless_motion_are_refused_before_they_are_read(tmp_path):
    import zipfile

    import umf.data.motion_file as mf

    np.savez_compressed(tmp_path / "bomb.npz", joints=np.zeros((8, 150_000, 22, 3), np.float32))
    assert (tmp_path / "bomb.npz").stat().st_size < 1_000_000
    with zipfile.ZipFile(tmp_path / "bomb.npz") as z:
        assert z.getinfo("joints.npy").file_size > 300 * 10**6
    with pytest.raises(UMFError, match="unpacks to"):
        load_motion(tmp_path / "bomb.npz")
    np.savez(tmp_path / "slow.npz", joints=np.zeros((1, 2000, 22, 3), np.float32), fps=1.0)
    assert mf.MAX_SECONDS < 2000  # 2,000 frames at 1 fps: 60,000 frames once resampled
    with pytest.raises(UMFError, match="s of motion"):
        load_motion(tmp_path / "slow.npz")


@pytest.mark.parametrize("fps", [30.0, 24.0, 60.0, 7.3])
def test_a_resampled_window_is_the_window_of_the_resampled_motion(fps):
    """resample(first, count) gives exactly the cut of the whole resample (bit for bit)
    and reads only the input frames it needs: NaNs outside them stay out."""
    from umf.data.bandai import resample, resampled_length

    rng = np.random.default_rng(0)
    j = rng.normal(size=(2, 300, 22, 3)).astype(np.float32)
    full = resample(j, fps)
    assert full.shape[1] == resampled_length(300, fps)
    n = full.shape[1]
    for first, count in [(0, 5), (17, 40), (n - 3, 10), (n, 4), (3, 1), (5, None)]:
        end = None if count is None else first + count
        assert np.array_equal(resample(j, fps, first=first, count=count), full[:, first:end])
    lo, hi = int(17 * fps / 30), int(56 * fps / 30) + 2  # the input behind output 17..56
    poisoned = np.full_like(j, np.nan)
    poisoned[:, lo:hi] = j[:, lo:hi]
    assert np.array_equal(resample(poisoned, fps, first=17, count=40), full[:, 17:57])


def test_react_reads_a_window_of_a_long_file_as_the_whole_file_cut(tmp_path):
    """A window of a 60 fps file (MotionFile.scene) is the same motion as the whole file
    read and cut afterwards: the window costs only its frames."""
    from umf.data.motion_file import open_motion

    src = load_motion(BOW).joints[0]
    _write(tmp_path / "bow60.bvh", np.repeat(src, 2, axis=0)[:-1], 1.0, 60.0)  # each frame twice
    whole = load_motion(tmp_path / "bow60.bvh").joints
    motion = open_motion(tmp_path / "bow60.bvh")
    assert motion.frames == whole.shape[1] and motion.fps == pytest.approx(60.0)
    part = motion.scene(20, 50).joints
    assert part.shape == (1, 50, 22, 3)
    np.testing.assert_allclose(part, whole[:, 20:70], atol=2e-4)
    with pytest.raises(UMFError, match="no motion from frame"):
        motion.scene(whole.shape[1] - 1, 10)
