"""InterHuman adapter on a tiny fixture written in the dataset's processed format."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from umf.data.humanml3d import SkippedItemWarning
from umf.data.interhuman import ZUP_TO_YUP, load_interhuman, to_y_up
from umf.errors import UMFError
from umf.rotations import axis_angle_to_matrix, matrix_to_6d, yaw_matrix
from umf.skeleton import default_offsets, forward_kinematics

F64 = torch.float64
CAPTIONS = [
    "two people walk side by side and turn together.",
    "the first person walks in a curve while the second follows.",
    "two persons stroll and turn.",
]


def walking_person(num_frames: int, yaw0: float, turn: float, start: tuple[float, float]):
    """(joints (T, 22, 3), local rotations (T, 22, 3, 3)): a turning walk of the default body."""
    t = torch.arange(num_frames, dtype=F64) / 30.0
    yaw = yaw0 + turn * t
    s = torch.sin(2 * math.pi * 1.6 * t)
    aa = torch.zeros(num_frames, 22, 3, dtype=F64)
    aa[:, 1, 0], aa[:, 2, 0] = 0.4 * s, -0.4 * s
    aa[:, 4, 0], aa[:, 5, 0] = 0.3 + 0.3 * s, 0.3 - 0.3 * s
    aa[:, 3, 1], aa[:, 9, 2], aa[:, 12, 0] = 0.1 * s, 0.05 * s, 0.1
    aa[:, 16, 2], aa[:, 17, 2] = -1.2 + 0.1 * s, 1.2 - 0.1 * s
    aa[:, 18, 1], aa[:, 19, 1] = 0.3, -0.3
    local = axis_angle_to_matrix(aa)
    tilt = torch.zeros(num_frames, 3, dtype=F64)
    tilt[:, 2] = 0.04 * s
    local[:, 0] = yaw_matrix(yaw) @ axis_angle_to_matrix(tilt)
    step = torch.stack([torch.sin(yaw), 0 * yaw, torch.cos(yaw)], -1) * 0.04
    root = torch.cat([torch.zeros(1, 3, dtype=F64), step[:-1]]).cumsum(0)
    root += torch.tensor([start[0], 0.92, start[1]], dtype=F64)
    return forward_kinematics(local, root, default_offsets(F64)), local


def to_rows(joints: torch.Tensor, local: torch.Tensor, up: str = "z") -> np.ndarray:
    """One person's (T, 492) row block: 62 positions then 51 6-D rotations."""
    num = joints.shape[0]
    pos = joints.numpy()
    if up == "z":  # inverse of InterGen's conversion: (x, y, z)_yup -> (x, -z, y)_zup
        pos = np.stack([pos[..., 0], -pos[..., 2], pos[..., 1]], axis=-1)
    rng = np.random.default_rng(0)
    extra_pos = rng.normal(size=(num, 40 * 3))  # hand joints, unused
    rot = matrix_to_6d(local[:, 1:]).reshape(num, 126).numpy()
    extra_rot = np.tile([1.0, 0.0, 0.0, 0.0, 1.0, 0.0], (num, 30))
    rows = np.concatenate([pos.reshape(num, 66), extra_pos, rot, extra_rot], axis=1)
    assert rows.shape == (num, 492)
    return rows.astype(np.float32)


@functools.cache
def scene(num_frames: int):
    p1 = walking_person(num_frames, 0.3, 0.9, (0.5, -1.0))
    p2 = walking_person(num_frames, 2.0, -0.7, (-0.8, 1.5))
    return p1, p2


def write_scene(root: Path, item: str, num_frames: int, up: str = "z") -> tuple:
    people = scene(num_frames)
    for name, (joints, local) in zip(("person1", "person2"), people, strict=True):
        np.save(root / "motions_processed" / name / f"{item}.npy", to_rows(joints, local, up))
    return people


def make_root(root: Path) -> Path:
    for sub in ("motions_processed/person1", "motions_processed/person2", "annots"):
        (root / sub).mkdir(parents=True)
    return root


@pytest.fixture
def interhuman(tmp_path: Path) -> tuple[Path, dict]:
    root = make_root(tmp_path / "InterHuman")
    truth = {"1": write_scene(root, "1", 90), "5": write_scene(root, "5", 60)}
    write_scene(root, "2", 40)  # ignored
    write_scene(root, "3", 40)
    (root / "motions_processed/person2/3.npy").write_bytes(b"not a numpy file")
    write_scene(root, "4", 40)  # no annotation file
    write_scene(root, "6", 40)
    p1, _ = scene(35)
    np.save(root / "motions_processed/person2/6.npy", to_rows(*p1))  # length mismatch
    for item in ("1", "2", "3", "5", "6"):
        (root / "annots" / f"{item}.txt").write_text("\n".join(CAPTIONS) + "\n")
    (root / "train.txt").write_text("1\n2\n3\n4\n6\n")
    (root / "val.txt").write_text("")
    (root / "test.txt").write_text("5\n")
    (root / "ignore_list.txt").write_text("2\n")
    return root, truth


def test_loader_ids_captions_splits_and_problems(interhuman) -> None:
    root, _ = interhuman
    problems: list[tuple[Path, str]] = []
    with pytest.warns(SkippedItemWarning) as record:
        clips = {c.id: c for c in load_interhuman(root, problems=problems)}
    assert sorted(clips) == ["1", "5"]
    assert clips["1"].split == "train" and clips["5"].split == "test"
    assert clips["1"].captions == CAPTIONS
    assert clips["1"].joints.shape == (2, 90, 22, 3) and clips["5"].num_frames == 60
    assert clips["1"].rotations.shape == (2, 90, 22, 3, 3)
    assert clips["1"].joints.dtype == np.float32 and clips["1"].fps == 30.0
    assert clips["1"].source == "interhuman" and clips["1"].num_people == 2
    named = {"/".join(p.parts[-2:]): reason for p, reason in problems}
    assert set(named) == {"person2/3.npy", "annots/4.txt", "person2/6.npy"}
    assert "frame count" in named["person2/6.npy"]
    assert all("ignore" not in str(w.message) and "/2." not in str(w.message) for w in record)
    assert any("3.npy" in str(w.message) for w in record)


def test_loader_positions_and_rotations_match_truth(interhuman) -> None:
    root, truth = interhuman
    clip = next(iter(load_interhuman(root, "train")))  # lazy: stops before the bad items
    assert clip.id == "1"
    for person, (joints, local) in enumerate(truth["1"]):
        got = torch.from_numpy(clip.joints[person]).double()
        rot = torch.from_numpy(clip.rotations[person]).double()
        assert (got - joints).abs().max() < 1e-5  # Z-up file -> Y-up, same world placement
        assert (rot[:, 1:] - local[:, 1:]).abs().max() < 1e-5  # file's 6-D, joints 1..21
        assert (rot[:, 0] - local[:, 0]).abs().max() < 1e-4  # root recovered by IK
        det = torch.linalg.det(rot)
        assert torch.allclose(det, torch.ones_like(det), atol=1e-5)
        fk = forward_kinematics(rot, got[:, 0], default_offsets(F64))
        assert (fk - joints).abs().max() < 1e-4


def test_up_axis_option(tmp_path: Path, interhuman) -> None:
    m = ZUP_TO_YUP
    assert np.isclose(np.linalg.det(m), 1.0) and np.allclose(m @ [0, 0, 1], [0, 1, 0])
    root_z, _ = interhuman
    root_y = make_root(tmp_path / "yup")
    write_scene(root_y, "1", 90, up="y")
    (root_y / "annots" / "1.txt").write_text("\n".join(CAPTIONS))
    from_y = next(iter(load_interhuman(root_y, up_axis="y")))
    from_z = next(iter(load_interhuman(root_z, "train")))
    assert np.abs(from_y.joints - from_z.joints).max() < 1e-5
    assert np.abs(from_y.rotations - from_z.rotations).max() < 1e-4
    # reading the Z-up files as Y-up puts the people on their backs: head not above pelvis
    wrong = next(iter(load_interhuman(root_z, "train", up_axis="y")))
    up = wrong.joints[:, :, 15, 1] - wrong.joints[:, :, 0, 1]
    assert np.abs(up).max() < 0.1
    assert (from_z.joints[:, :, 15, 1] - from_z.joints[:, :, 0, 1] > 0.4).all()
    assert np.allclose(to_y_up(np.array([1.0, 2.0, 3.0]), "z"), [1.0, 3.0, -2.0])


def test_split_and_bad_roots(tmp_path: Path, interhuman) -> None:
    root, _ = interhuman
    assert [c.id for c in load_interhuman(root, "test")] == ["5"]
    assert list(load_interhuman(root, "val")) == []
    with pytest.raises(UMFError, match="not found"):
        load_interhuman(tmp_path / "missing")
    with pytest.raises(UMFError, match="up_axis"):
        load_interhuman(root, up_axis="x")
    (root / "test.txt").unlink()
    with pytest.raises(UMFError, match=r"test\.txt"):
        load_interhuman(root, "test")
    partial = tmp_path / "partial"
    (partial / "motions_processed" / "person1").mkdir(parents=True)
    with pytest.raises(UMFError, match="person2"):
        load_interhuman(partial)
