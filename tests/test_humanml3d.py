"""HumanML3D adapter: 263-d encode/decode round trip, 20 -> 30 fps, loader on a tiny fixture."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import MODULE
from umf.data.humanml3d import Caption, SkippedItemWarning, load_humanml3d, parse_caption_line
from umf.errors import UMFError
from umf.humanml3d import (
    canonicalize_first_frame,
    encode_joints,
    recover_joints,
    resample,
    resampled_length,
)
from umf.representation import heading_angle, mirror_joints
from umf.rotations import axis_angle_to_matrix, yaw_matrix
from umf.skeleton import default_offsets, forward_kinematics

F64 = torch.float64


def _integrated_path(num_frames: int, fps: float, turn_rate: float) -> torch.Tensor:
    """Root XZ displacement (T, 3): speed along the heading, integrated on a 600 Hz grid."""
    sub = round(600 / fps)
    t = torch.arange((num_frames - 1) * sub + 1, dtype=F64) / 600.0
    yaw = 0.4 + turn_rate * t + 0.2 * torch.sin(0.9 * t)
    speed = 1.2 + 0.1 * torch.sin(2 * math.pi * 1.8 * t)
    vel = torch.stack([torch.sin(yaw), torch.zeros_like(yaw), torch.cos(yaw)], -1) * speed[:, None]
    steps = 0.5 * (vel[1:] + vel[:-1]) / 600.0  # trapezoid rule
    return torch.cat([torch.zeros(1, 3, dtype=F64), steps.cumsum(0)])[::sub]


def walking_motion(
    num_frames: int = 120, fps: float = 20.0, turn_rate: float = 1.1
) -> torch.Tensor:
    """FK of the default body: legs/arms swinging, root walking forward while turning.

    All curves are analytic in time, so a clip at another fps samples the same motion.
    """
    t = torch.arange(num_frames, dtype=F64) / fps
    yaw = 0.4 + turn_rate * t + 0.2 * torch.sin(0.9 * t)
    phase = 2 * math.pi * 1.8 * t
    s = torch.sin(phase)
    aa = torch.zeros(num_frames, 22, 3, dtype=F64)
    aa[:, 1, 0], aa[:, 2, 0] = 0.45 * s, -0.45 * s  # hips
    aa[:, 4, 0] = 0.3 + 0.3 * torch.sin(phase + 1)  # knees
    aa[:, 5, 0] = 0.3 - 0.3 * torch.sin(phase + 1)
    aa[:, 7, 0], aa[:, 8, 0] = 0.2 * s, -0.2 * s  # ankles
    aa[:, 3, 1], aa[:, 6, 0], aa[:, 9, 2] = 0.15 * s, 0.05, 0.05 * s  # spine
    aa[:, 12, 0] = 0.1 * torch.sin(0.5 * phase)  # neck
    aa[:, 16, 2], aa[:, 17, 2] = -1.2 + 0.1 * s, 1.2 + 0.1 * s  # arms down from T-pose
    aa[:, 16, 0], aa[:, 17, 0] = 0.4 * s, -0.4 * s
    aa[:, 18, 1], aa[:, 19, 1] = 0.3 + 0.2 * s, -0.3 - 0.2 * s  # elbows
    local = axis_angle_to_matrix(aa)
    tilt = torch.zeros(num_frames, 3, dtype=F64)
    tilt[:, 0] = 0.05 * s
    local[:, 0] = yaw_matrix(yaw) @ axis_angle_to_matrix(tilt)
    root = torch.tensor([1.5, 0.0, -2.0], dtype=F64) + _integrated_path(num_frames, fps, turn_rate)
    root[:, 1] = 0.93 + 0.03 * torch.cos(2 * phase)
    return forward_kinematics(local, root, default_offsets(F64))


def canonical(joints: torch.Tensor) -> torch.Tensor:
    """Independent reference of HumanML3D's first-frame canonicalisation (yaw + XZ)."""
    ground = joints[0, 0] * torch.tensor([1.0, 0.0, 1.0], dtype=joints.dtype)
    return (joints - ground) @ yaw_matrix(-heading_angle(joints[0])).T


@pytest.fixture(scope=MODULE)
def walk() -> torch.Tensor:
    return walking_motion()


# --------------------------------------------------------------------- encode / decode
def test_round_trip_turning_walk(walk: torch.Tensor) -> None:
    turn = heading_angle(walk)
    unwrapped = torch.atan2(torch.sin(turn.diff()), torch.cos(turn.diff())).sum()
    assert unwrapped > 2 * math.pi  # more than a full turn: crosses +-180 degrees
    vecs = encode_joints(walk)
    assert vecs.shape == (walk.shape[0] - 1, 263)
    truth = canonical(walk)[:-1]
    assert (recover_joints(vecs) - truth).abs().max() < 1e-4
    vecs32 = encode_joints(walk.float())
    assert vecs32.dtype == torch.float32
    assert (recover_joints(vecs32).double() - truth).abs().max() < 1e-4
    assert vecs[:, 0].abs().max() < math.pi / 2  # half-angles, as in the released files
    smooth = encode_joints(walk, heading_sigma=20.0)  # HumanML3D's smoothed heading
    ref = canonicalize_first_frame(walk, 20.0)[:-1]
    assert (recover_joints(smooth) - ref).abs().max() < 1e-4
    # the first frame is canonical: root over the origin, facing +Z
    assert recover_joints(vecs)[0, 0, [0, 2]].abs().max() < 1e-12
    assert heading_angle(recover_joints(vecs)[0]).abs() < 1e-9


def test_recovered_path_matches_truth_and_sign_errors_are_caught(walk: torch.Tensor) -> None:
    vecs = encode_joints(walk)
    truth = canonical(walk)[:-1, 0]
    assert (recover_joints(vecs)[:, 0] - truth).norm(dim=-1).max() < 1e-4
    flipped = vecs.clone()
    flipped[:, 0] = -flipped[:, 0]  # a yaw sign bug
    assert (recover_joints(flipped)[:, 0] - truth).norm(dim=-1).max() > 0.5
    transposed = vecs.clone()
    transposed[:, 2] = -transposed[:, 2]  # R instead of R^T on the root velocity (x <-> z mix)
    assert (recover_joints(transposed)[:, 0] - truth).norm(dim=-1).max() > 0.5


def test_recover_constant_turn_is_the_documented_circle() -> None:
    """theta_vel > 0 with forward speed: heading psi_t = -2 c t, a turn to the right."""
    n, c, v = 60, 0.02, 0.05
    vecs = torch.zeros(n, 263, dtype=F64)
    vecs[:, 0], vecs[:, 2], vecs[:, 3] = c, v, 0.9
    root = recover_joints(vecs)[:, 0]
    psi = -2 * c * torch.arange(n, dtype=F64)
    step = v * torch.stack([torch.sin(psi), torch.zeros_like(psi), torch.cos(psi)], -1)
    expected = torch.cat([torch.zeros(1, 3, dtype=F64), step[1:]]).cumsum(0)
    expected[:, 1] = 0.9
    assert torch.allclose(root, expected, atol=1e-12)
    assert root[-1, 0] < -0.5  # facing +Z with the left at +X: a right turn goes to -X


def test_encoder_contacts_and_layout(walk: torch.Tensor) -> None:
    vecs = encode_joints(walk)
    contacts = vecs[:, 259:]
    assert set(contacts.unique().tolist()) <= {0.0, 1.0}
    assert torch.allclose(vecs[:, 3], walk[:-1, 0, 1])  # root height untouched
    # batch decoding matches per-clip decoding
    batch = recover_joints(torch.stack([vecs, vecs.flip(0)]))
    assert torch.allclose(batch[0], recover_joints(vecs))


# --------------------------------------------------------------------- resampling
@pytest.mark.parametrize("num", [41, 40])
def test_resample_linear_path_exact_and_duration(num: int) -> None:
    t = torch.arange(num, dtype=F64) / 20.0
    path = torch.stack([0.3 + 1.1 * t, 0.9 + 0 * t, -2.0 * t], -1)[:, None, :]
    out = resample(path, 20.0, 30.0)
    assert out.shape[0] == resampled_length(num, 20.0, 30.0) == math.floor(1.5 * (num - 1)) + 1
    t30 = torch.arange(out.shape[0], dtype=F64) / 30.0
    expected = torch.stack([0.3 + 1.1 * t30, 0.9 + 0 * t30, -2.0 * t30], -1)[:, None, :]
    assert torch.allclose(out, expected, atol=1e-12)
    src_duration, dst_duration = (num - 1) / 20.0, (out.shape[0] - 1) / 30.0
    assert 0.0 <= src_duration - dst_duration < 1.0 / 60.0 + 1e-12
    assert (src_duration == pytest.approx(dst_duration)) == (num % 2 == 1)


def test_resample_walk_matches_motion_sampled_at_30fps() -> None:
    at20 = walking_motion(121, fps=20.0)
    at30 = walking_motion(181, fps=30.0)
    out = resample(at20, 20.0, 30.0)
    assert out.shape == at30.shape
    err = (out - at30).norm(dim=-1)
    assert err[::3].max() < 1e-12  # every third 30 fps frame is a 20 fps frame
    assert err[:, 0].max() < 0.005 and err.mean() < 0.005  # chord error of linear interp
    lagged = (out[1:] - at30[:-1]).norm(dim=-1)  # what a one-frame time shift would cost
    assert lagged.mean() > 10 * err.mean()


def test_parse_caption_line() -> None:
    line = "a man walks.#a/DET man/NOUN walk/VERB#0.0#0.0"
    assert parse_caption_line(line) == Caption("a man walks.", 0.0, 0.0)
    assert parse_caption_line("he waves.#he/PRON#nan#nan").whole
    assert parse_caption_line("he waves.#he/PRON#1.5#3.0") == Caption("he waves.", 1.5, 3.0)
    assert parse_caption_line("   #x#0#0") is None


# --------------------------------------------------------------------- loader
def _tokens(text: str) -> str:
    return " ".join(f"{w}/X" for w in text.strip(".").split())


def _write_text(path: Path, lines: list[tuple[str, str, str]]) -> None:
    path.write_text("".join(f"{c}#{_tokens(c)}#{s}#{e}\n" for c, s, e in lines))


@pytest.fixture
def humanml_root(tmp_path: Path, walk: torch.Tensor) -> Path:
    root = tmp_path / "HumanML3D"
    for sub in ("new_joint_vecs", "new_joints", "texts"):
        (root / sub).mkdir(parents=True)
    clips = {"000001": walk, "M000001": mirror_joints(walk), "000004": walk[:30]}
    for item, joints in clips.items():
        vecs = encode_joints(joints).float()
        np.save(root / "new_joint_vecs" / f"{item}.npy", vecs.numpy())
        np.save(root / "new_joints" / f"{item}.npy", recover_joints(vecs).numpy())
    _write_text(
        root / "texts" / "000001.txt",
        [
            ("a person walks forward and turns to the left.", "0.0", "0.0"),
            ("someone walks in a circle.", "nan", "nan"),
            ("the person keeps turning.", "1.0", "3.0"),
            ("a person turns while walking.", "1.0", "3.0"),
        ],
    )
    _write_text(root / "texts" / "M000001.txt", [("a person walks and turns right.", "0", "0")])
    _write_text(root / "texts" / "000002.txt", [("broken.", "0.0", "0.0")])
    _write_text(root / "texts" / "000003.txt", [("wrong shape.", "0.0", "0.0")])
    _write_text(root / "texts" / "000005.txt", [("not finite.", "0.0", "0.0")])
    # 000004 has no caption file
    (root / "new_joint_vecs" / "000002.npy").write_bytes(b"\x93NUMPY\x01\x00garbage")
    np.save(root / "new_joint_vecs" / "000003.npy", np.zeros((30, 250), np.float32))
    nan = np.zeros((30, 263), np.float32)
    nan[3, 7] = np.nan
    np.save(root / "new_joint_vecs" / "000005.npy", nan)
    (root / "train.txt").write_text("000001\nM000001\n000002\n000003\n")
    (root / "val.txt").write_text("000004\n")
    (root / "test.txt").write_text("000005\n")
    return root


def test_loader_clips_ids_captions_splits_frames(humanml_root: Path, walk: torch.Tensor) -> None:
    problems: list[tuple[Path, str]] = []
    with pytest.warns(SkippedItemWarning):
        clips = {c.id: c for c in load_humanml3d(humanml_root, problems=problems)}
    assert sorted(clips) == ["000001", "000001#0", "M000001"]
    whole, seg, mirror = clips["000001"], clips["000001#0"], clips["M000001"]
    assert whole.captions == [
        "a person walks forward and turns to the left.",
        "someone walks in a circle.",
    ]
    assert seg.captions == ["the person keeps turning.", "a person turns while walking."]
    assert {c.split for c in clips.values()} == {"train"}
    assert all(
        c.source == "humanml3d" and c.fps == 30.0 and c.rotations is None for c in clips.values()
    )
    assert mirror.meta["mirrored"] and not whole.meta["mirrored"]
    assert seg.meta["parent"] == "000001" and seg.meta["segment"] == (1.0, 3.0)
    rows = walk.shape[0] - 1
    assert whole.joints.shape == (1, math.floor(1.5 * (rows - 1)) + 1, 22, 3)
    assert whole.joints.dtype == np.float32
    assert seg.num_frames == math.floor(1.5 * (40 - 1)) + 1  # rows 20:60 at 20 fps
    truth = resample(canonical(walk)[:-1], 20.0, 30.0)
    assert np.abs(whole.joints[0] - truth.numpy()).max() < 1e-4
    truth_seg = resample(canonical(walk)[20:60], 20.0, 30.0)
    assert np.abs(seg.joints[0] - truth_seg.numpy()).max() < 1e-4
    assert (
        np.abs(
            mirror.joints[0] - resample(canonical(mirror_joints(walk))[:-1], 20, 30).numpy()
        ).max()
        < 1e-4
    )
    named = {p.name: reason for p, reason in problems}
    assert set(named) == {"000002.npy", "000003.npy", "000004.txt", "000005.npy"}
    assert "shape" in named["000003.npy"] and "NaN" in named["000005.npy"]
    assert "missing" in named["000004.txt"]


def test_loader_warning_names_the_file(humanml_root: Path) -> None:
    with pytest.warns(SkippedItemWarning) as record:
        list(load_humanml3d(humanml_root, split="train"))
    messages = [str(w.message) for w in record]
    assert any("000002.npy" in m and "cannot read" in m for m in messages)
    assert all("\n" not in m for m in messages)


def test_loader_joints_folder_matches_vectors(humanml_root: Path) -> None:
    with pytest.warns(SkippedItemWarning):
        a = {c.id: c.joints for c in load_humanml3d(humanml_root, "train")}
    with pytest.warns(SkippedItemWarning):
        b = {c.id: c.joints for c in load_humanml3d(humanml_root, "train", positions="joints")}
    assert sorted(a) == sorted(b) == ["000001", "000001#0", "M000001"]
    for key in a:
        assert np.abs(a[key] - b[key]).max() < 1e-5


def test_loader_split_selection(humanml_root: Path) -> None:
    problems: list[tuple[Path, str]] = []
    with pytest.warns(SkippedItemWarning):
        assert list(load_humanml3d(humanml_root, "val", problems=problems)) == []
    assert [p.name for p, _ in problems] == ["000004.txt"]


def test_loader_bad_roots(tmp_path: Path, humanml_root: Path) -> None:
    with pytest.raises(UMFError, match="not found"):
        load_humanml3d(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(UMFError, match="new_joint_vecs"):
        load_humanml3d(tmp_path / "empty")
    (humanml_root / "test.txt").unlink()
    with pytest.raises(UMFError, match=r"test\.txt"):
        load_humanml3d(humanml_root, "test")
    with pytest.raises(UMFError, match="unknown split"):
        load_humanml3d(humanml_root, "dev")


def test_round_trip_real_capture(real_joints: torch.Tensor) -> None:
    """Real mocap (a Bandai walk, bundled fixture): same exactness as the synthetic walk."""
    vecs = encode_joints(real_joints)
    err = (recover_joints(vecs) - canonical(real_joints)[:-1]).abs().max()
    assert err < 1e-4
    err32 = (
        recover_joints(encode_joints(real_joints.float())).double() - canonical(real_joints)[:-1]
    )
    assert err32.abs().max() < 1e-4


def test_caption_times_that_are_no_segment_are_refused_per_line(humanml_root: Path) -> None:
    """A negative start or end would count frames from the clip's end; inf is no time."""
    _write_text(humanml_root / "texts" / "000001.txt", [
        ("a person walks forward.", "0.0", "0.0"), ("from the end.", "-2.0", "-1.0"),
        ("forever.", "0", "inf"), ("backwards in time.", "3.0", "1.0"),
    ])  # fmt: skip
    problems: list[tuple[Path, str]] = []
    with pytest.warns(SkippedItemWarning):
        clips = {c.id: c for c in load_humanml3d(humanml_root, problems=problems)}
    assert clips["000001"].captions == ["a person walks forward."]
    assert "000001#0" not in clips
    reasons = [r for p, r in problems if p.name == "000001.txt"]
    assert len(reasons) == 3 and all("not a segment" in r for r in reasons)


@pytest.mark.parametrize("entry", ["../../outside", "/etc/passwd", "a/b"])
def test_split_ids_stay_inside_the_dataset(humanml_root: Path, entry: str) -> None:
    (humanml_root / "train.txt").write_text(f"000001\n{entry}\n")
    with pytest.raises(UMFError, match="plain names"):
        list(load_humanml3d(humanml_root, problems=[]))
    (humanml_root / "train.txt").write_bytes(b"\xff\xfe000001\n")
    with pytest.raises(UMFError, match="UTF-8"):
        list(load_humanml3d(humanml_root, problems=[]))


def test_export_writes_each_person_at_20_fps_on_the_scenes_floor(real_joints, tmp_path):
    """One file per person (``{i}`` counts from 1), the prompt beside the vectors, the
    scene's floor (``meta["floor"]``) at y = 0, else each person's lowest joint."""
    from umf.exports.humanml3d import person_arrays, write
    from umf.pipeline import Scene

    walk = real_joints.numpy()[:90]  # 3 s at 30 fps
    joints = np.stack([walk, walk + np.array([2.0, 0.25, 0.0])]).astype(np.float32)
    scene = Scene(joints, None, "two walkers", 30.0, meta={"floor": -0.1}, fit=False)
    paths = write(scene, tmp_path / "walk-p{i}.npz")
    assert [p.name for p in paths] == ["walk-p1.npz", "walk-p2.npz"]
    lowest = joints[..., 1].min(axis=(1, 2))
    for person, path in enumerate(paths):
        data = np.load(path)
        assert set(data.files) == {"new_joint_vecs", "new_joints", "text", "fps"}
        assert str(data["text"]) == "two walkers" and float(data["fps"]) == 20.0
        vecs, canon = data["new_joint_vecs"], data["new_joints"]
        assert canon.shape == (60, 22, 3) and vecs.shape == (59, 263)  # 3 s at 20 fps
        np.testing.assert_allclose(canon[..., 1].min(), lowest[person] + 0.1, atol=2e-3)
        back = recover_joints(torch.from_numpy(vecs).double()).numpy()
        np.testing.assert_allclose(back, canon[:-1], atol=1e-3)
    own = person_arrays(joints[1], 30.0, floor=None)["new_joints"]
    assert abs(own[..., 1].min()) < 2e-3  # no floor given: the person's lowest joint
    with pytest.raises(ValueError, match="at least 2 frames at 20 fps"):
        person_arrays(joints[0, :1], 30.0, floor=None)


def test_export_arrays_are_float32_from_two_frames_on() -> None:
    """The vectors, joints and fps are float32 whatever the input's dtype (float32 joints
    are computed in float64, as float64 ones are); two frames at 20 fps, one vector, are
    enough, one frame is refused."""
    from umf.exports.humanml3d import person_arrays

    walk = walking_motion(num_frames=40).numpy()
    two = person_arrays(walk[:2], 20.0, floor=None)
    assert two["new_joint_vecs"].shape == (1, 263) and two["new_joints"].shape == (2, 22, 3)
    for key in ("new_joint_vecs", "new_joints", "fps"):
        assert two[key].dtype == np.float32, key
    assert two["fps"].shape == () and float(two["fps"]) == 20.0
    single = walk[:32].astype(np.float32)
    got = person_arrays(single, 20.0, floor=0.0)
    want = person_arrays(single.astype(np.float64), 20.0, floor=0.0)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key])
    with pytest.raises(ValueError, match=r"^HumanML3D export needs at least 2 frames at 20 fps$"):
        person_arrays(walk[:1], 20.0, floor=None)
