"""BVH reader, FK and writer.

Real Bandai clips are checked against an independent reader (bvhio), synthetic files
against hand-computed FK, the writer by round trips, and bad input by its error message.
"""

from __future__ import annotations

import io
import re
import time
from pathlib import Path

import bvhio
import numpy as np
import pytest
import torch

from conftest import BANDAI_FIXTURE
from umf import skeleton
from umf.bvh import (
    forward_kinematics,
    local_transforms,
    parse_bvh,
    read_bvh,
    write_bvh,
    write_smpl22_bvh,
)
from umf.errors import UMFError
from umf.rotations import axis_angle_to_matrix, euler_to_matrix

FIXTURES = sorted(BANDAI_FIXTURE.glob("*/data/*.bvh"))
BANDAI_CHANNELS = ["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]
# bvhio composes glm transforms in float32, so it agrees with float64 FK only to a few
# float32 ulps of the distance from the origin (one ulp at 5 m is 6e-5 cm). Over the whole
# corpus (3,076 clips, every 10th frame) the largest gap is 2.7e-4 cm (a clip 5.3 m from
# the origin), 20% of the clips exceed 1e-4 cm; the mean gap stays ~1e-5 cm.
BVHIO_TOL_CM = 3e-4
BVHIO_MEAN_TOL_CM = 3e-5


def bvhio_positions(path: str | Path, frames: list[int]) -> tuple[list[str], np.ndarray]:
    """World joint positions (len(frames), J, 3) per bvhio, joints in file order."""
    root = bvhio.readAsHierarchy(str(path))
    joints = [joint for joint, _, _ in root.layout()]
    out = []
    for f in frames:
        root.loadPose(f)
        out.append([tuple(joint.PositionWorld) for joint in joints])
    return [joint.Name for joint in joints], np.array(out, dtype=np.float64)


# --------------------------------------------------------------------- real clips
def test_fixtures_present() -> None:
    assert len(FIXTURES) >= 10


@pytest.mark.parametrize("path", FIXTURES, ids=[p.stem for p in FIXTURES])
def test_bandai_fk_matches_bvhio(path: Path) -> None:
    bvh = read_bvh(path)
    assert bvh.num_joints == 22 and bvh.names[:2] == ["joint_Root", "Hips"]
    assert all(chans == BANDAI_CHANNELS for chans in bvh.channels)
    assert bvh.motion.shape == (bvh.num_frames, 22 * 6)
    assert bvh.fps == pytest.approx(30.0, rel=1e-5)
    assert len(bvh.end_sites) == 5

    positions, global_rot = forward_kinematics(bvh)
    frames = list(range(0, bvh.num_frames, 10))
    names, ref = bvhio_positions(path, frames)
    assert names == bvh.names
    err = np.abs(positions[frames] - ref)
    assert err.max() < BVHIO_TOL_CM
    assert err.mean() < BVHIO_MEAN_TOL_CM
    # proper rotations
    eye = np.broadcast_to(np.eye(3), global_rot.shape)
    np.testing.assert_allclose(global_rot @ global_rot.swapaxes(-1, -2), eye, atol=1e-12)


def test_bandai_position_channels() -> None:
    """Hips carry the trajectory; other joints' position channels repeat their OFFSET."""
    bvh = read_bvh(FIXTURES[0])
    _, trans = local_transforms(bvh)
    np.testing.assert_allclose(
        trans[:, 2:], np.broadcast_to(bvh.offsets[2:], trans[:, 2:].shape), atol=1e-4
    )
    np.testing.assert_array_equal(trans[:, 1], bvh.motion[:, 6:9])
    assert np.ptp(trans[:, 1], axis=0).max() > 1.0  # the hips move


def test_read_sources_agree() -> None:
    path = FIXTURES[0]
    ref = read_bvh(path)
    with open(path, "rb") as fh:
        from_binary = read_bvh(fh)
    with open(path, encoding="utf-8") as fh:
        from_text = read_bvh(fh)
    from_string = read_bvh(path.read_text())
    for other in (from_binary, from_text, from_string, read_bvh(str(path))):
        assert other.names == ref.names and other.parents == ref.parents
        np.testing.assert_array_equal(other.motion, ref.motion)
    assert ref.index("Hips") == 1
    with pytest.raises(UMFError, match=re.escape(path.name)):
        ref.index("pelvis")


def test_largest_fixture_is_fast() -> None:
    path = max(FIXTURES, key=lambda p: p.stat().st_size)
    start = time.perf_counter()
    forward_kinematics(read_bvh(path))
    assert time.perf_counter() - start < 0.5  # ~10 ms; a per-value Python parser is far slower


# --------------------------------------------------------------------- synthetic files
# root: rotations before positions, YXZ order, positions as Z X Y; a: XYZ; b: ZXY;
# d: YXZ; c: a single position channel (replaces OFFSET y) and a single rotation.
SYNTHETIC = """HIERARCHY
ROOT root
{
\tOFFSET 5 5 5
\tCHANNELS 6 Yrotation Xrotation Zrotation Zposition Xposition Yposition
\tJOINT a
\t{
\t\tOFFSET 0 10 0
\t\tCHANNELS 3 Xrotation Yrotation Zrotation
\t\tJOINT b
\t\t{
\t\t\tOFFSET 0 0 4
\t\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\t\tJOINT d
\t\t\t{
\t\t\t\tOFFSET 0 3 0
\t\t\t\tCHANNELS 3 Yrotation Xrotation Zrotation
\t\t\t\tEnd Site
\t\t\t\t{
\t\t\t\t\tOFFSET 0 1 0
\t\t\t\t}
\t\t\t}
\t\t}
\t}
    JOINT c
    {
        OFFSET 2 0 0
        CHANNELS 2 Yposition Zrotation
        End Site
        {
            OFFSET 1 0 0
        }
    }
}
MOTION
Frames: 2
Frame Time: 0.008333
0 0 0 3 1 2  0 0 0  0 0 0  0 0 0  7 0
90 0 0 0 10 0\t90 0 0\t90 90 0\t0 0 30\t1 90
"""
RX90 = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=float)
RY90 = np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], dtype=float)
RZ90 = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1]], dtype=float)


def test_synthetic_structure() -> None:
    bvh = read_bvh(SYNTHETIC.replace("\n", "\r\n"))
    assert bvh.names == ["root", "a", "b", "d", "c"]
    assert bvh.parents == [-1, 0, 1, 2, 0]
    assert [len(c) for c in bvh.channels] == [6, 3, 3, 3, 2]
    assert bvh.frame_time == 0.008333 and bvh.fps == pytest.approx(120.0, rel=1e-4)
    assert sorted(bvh.end_sites) == [3, 4]
    np.testing.assert_array_equal(bvh.end_sites[3], [0, 1, 0])
    np.testing.assert_array_equal(bvh.end_sites[4], [1, 0, 0])
    np.testing.assert_array_equal(bvh.offsets[0], [5, 5, 5])


def test_synthetic_fk_by_hand() -> None:
    positions, global_rot = forward_kinematics(read_bvh(SYNTHETIC.replace("\n", "\r\n")))
    # frame 0: no rotation; root position from channels (OFFSET ignored), c's y from its channel
    np.testing.assert_allclose(
        positions[0], [[1, 2, 3], [1, 12, 3], [1, 12, 7], [1, 15, 7], [3, 9, 3]], atol=1e-12
    )
    # frame 1: root Ry90 at (10,0,0); a Rx90; b Rz90 @ Rx90 (ZXY); c Rz90, y channel 1
    g_a = RY90 @ RX90
    g_b = g_a @ RZ90 @ RX90
    np.testing.assert_allclose(
        positions[1], [[10, 0, 0], [10, 10, 0], [10, 6, 0], [10, 3, 0], [10, 1, -2]], atol=1e-12
    )
    np.testing.assert_allclose(global_rot[1, 0], RY90, atol=1e-12)
    np.testing.assert_allclose(global_rot[1, 2], g_b, atol=1e-12)
    np.testing.assert_allclose(global_rot[1, 2], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(global_rot[1, 4], RY90 @ RZ90, atol=1e-12)


def test_synthetic_matches_bvhio(tmp_path: Path) -> None:
    path = tmp_path / "synthetic.bvh"
    path.write_bytes(SYNTHETIC.replace("\n", "\r\n").encode())
    positions, _ = forward_kinematics(read_bvh(path))
    names, ref = bvhio_positions(path, [0, 1])
    assert names == ["root", "a", "b", "d", "c"]
    np.testing.assert_allclose(positions, ref, atol=1e-5)


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_rotation_orders_match_umf_convention(order: str) -> None:
    angles = np.random.default_rng(0).uniform(-180, 180, size=(4, 3))
    chans = " ".join(f"{axis}rotation" for axis in order)
    text = (
        f"HIERARCHY\nROOT r\n{{\n OFFSET 0 0 0\n CHANNELS 3 {chans}\n"
        " End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 4\nFrame Time: 0.1\n"
        + "\n".join(" ".join(f"{v:.10f}" for v in row) for row in angles)
    )
    rot, trans = local_transforms(read_bvh(text))
    expected = euler_to_matrix(torch.from_numpy(angles), order).numpy()
    np.testing.assert_allclose(rot[:, 0], expected, atol=1e-12)
    np.testing.assert_array_equal(trans, 0.0)


def test_brace_layout_and_spaces_in_names() -> None:
    text = (
        "HIERARCHY ROOT my root { OFFSET 0 0 0 CHANNELS 3 Xposition Yposition Zposition "
        "JOINT child { OFFSET 1 0 0 CHANNELS 0 End Site { OFFSET 0 1 0 } } }\n"
        "MOTION\nFrames: 1\nFrame Time: 0\n1 2 3\n"
    )
    bvh = read_bvh(text)
    assert bvh.names == ["my root", "child"] and np.isnan(bvh.fps)
    np.testing.assert_allclose(forward_kinematics(bvh)[0][0], [[1, 2, 3], [2, 2, 3]])


# --------------------------------------------------------------------- writer
def random_motion(frames: int, joints: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(seed)
    aa = torch.randn(frames, joints, 3, generator=gen, dtype=torch.float64)
    return axis_angle_to_matrix(aa), torch.randn(frames, 3, generator=gen, dtype=torch.float64)


def test_smpl22_round_trip(tmp_path: Path) -> None:
    local_rot, root_pos = random_motion(12, 22, seed=1)
    offsets = skeleton.default_offsets(torch.float64)
    path = tmp_path / "smpl.bvh"
    write_smpl22_bvh(path, local_rot, root_pos, offsets, fps=20.0)

    bvh = read_bvh(path)
    assert sorted(bvh.names) == sorted(skeleton.JOINT_NAMES)
    assert bvh.channels[0] == ["Xposition", "Yposition", "Zposition", *BANDAI_CHANNELS[3:]]
    assert all(c == BANDAI_CHANNELS[3:] for c in bvh.channels[1:])
    assert bvh.fps == pytest.approx(20.0)
    idx = [bvh.index(name) for name in skeleton.JOINT_NAMES]
    leaves = [j for j in range(22) if not skeleton.CHILDREN[j]]
    assert sorted(bvh.end_sites) == sorted(idx[j] for j in leaves)
    for j in leaves:  # default End Site: half the bone into the leaf
        np.testing.assert_allclose(bvh.end_sites[idx[j]], 0.5 * offsets[j].numpy(), atol=1e-6)

    expected = skeleton.forward_kinematics(local_rot, root_pos, offsets).numpy()
    positions, global_rot = forward_kinematics(bvh)
    assert np.abs(positions[:, idx] - expected).max() < 1e-5
    expected_rot = skeleton.global_rotations(local_rot).numpy()
    assert np.abs(global_rot[:, idx] - expected_rot).max() < 1e-6

    names, ref = bvhio_positions(path, list(range(12)))
    assert names == bvh.names
    assert np.abs(ref[:, idx] - expected).max() < 1e-5


def test_scene_export_writes_each_person_at_the_scenes_fps(tmp_path: Path) -> None:
    """umf.exports.bvh: one file per person (``{i}`` from 1), returned in order, each at the
    scene's frame rate, its forward kinematics that person's joints."""
    from umf.exports.bvh import write
    from umf.scene import Scene

    offsets = skeleton.default_offsets(torch.float64)
    people = []
    for seed in (3, 4):
        local_rot, root_pos = random_motion(6, 22, seed=seed)
        people.append(skeleton.forward_kinematics(local_rot, root_pos, offsets).numpy())
    scene = Scene(np.stack(people), None, "two people", 24.0)
    paths = write(scene, tmp_path / "pair-p{i}.bvh")
    assert paths == [tmp_path / "pair-p1.bvh", tmp_path / "pair-p2.bvh"]
    for i, path in enumerate(paths):
        bvh = read_bvh(path)
        assert bvh.fps == pytest.approx(24.0)
        idx = [bvh.index(name) for name in skeleton.JOINT_NAMES]
        positions, _ = forward_kinematics(bvh)
        np.testing.assert_allclose(positions[:, idx], scene.joints[i], atol=1e-5)


def test_write_generic_skeleton(tmp_path: Path) -> None:
    """Parents not in depth-first order, XYZ channels, numpy inputs, given End Sites."""
    names = ["hip", "tail", "spine", "tip", "head"]
    parents = [-1, 0, 0, 1, 2]  # written depth-first: hip, tail, tip, spine, head
    offsets = np.array([[0, 0, 0], [0, -1, 0], [0, 1, 0], [0.5, 0, 0], [0, 0.3, 0]])
    local_rot, root_pos = random_motion(5, 5, seed=2)
    path = tmp_path / "generic.bvh"
    write_bvh(
        path,
        names,
        parents,
        offsets,
        local_rot.numpy(),
        root_pos.numpy(),
        0.05,
        "xyz",
        {4: [0, 0, 2]},
    )
    bvh = read_bvh(path)
    assert bvh.names == ["hip", "tail", "tip", "spine", "head"]
    assert bvh.channels[1] == ["Xrotation", "Yrotation", "Zrotation"]
    np.testing.assert_allclose(bvh.end_sites[bvh.index("head")], [0, 0, 2])
    np.testing.assert_allclose(bvh.end_sites[bvh.index("tip")], [0.25, 0, 0])

    rot, trans = local_transforms(bvh)
    order = [names.index(n) for n in bvh.names]
    np.testing.assert_allclose(rot, local_rot.numpy()[:, order], atol=1e-7)
    np.testing.assert_allclose(trans[:, 0], root_pos.numpy(), atol=1e-6)
    np.testing.assert_allclose(
        trans[:, 1:], np.broadcast_to(offsets[order][1:], trans[:, 1:].shape)
    )


@pytest.mark.parametrize(
    "change",
    [
        {"root_pos": np.zeros((3, 3))},
        {"offsets": np.zeros((21, 3))},
        {"local_rot": np.zeros((4, 21, 3, 3))},
        {"root_pos": np.full((4, 3), np.nan)},
    ],
    ids=["root_pos-frames", "offsets-joints", "rot-joints", "nan"],
)
def test_writer_failure_leaves_no_file(tmp_path: Path, change: dict) -> None:
    local_rot, root_pos = random_motion(4, 22, seed=3)
    args = {"local_rot": local_rot, "root_pos": root_pos, "offsets": skeleton.default_offsets()}
    path = tmp_path / "out.bvh"
    with pytest.raises(UMFError, match=re.escape("out.bvh")):
        write_smpl22_bvh(path, **(args | change))
    assert list(tmp_path.iterdir()) == []

    write_smpl22_bvh(path, **args)  # a failed rewrite keeps the old file intact
    before = path.read_bytes()
    with pytest.raises(UMFError):
        write_smpl22_bvh(path, **(args | change))
    assert path.read_bytes() == before and list(tmp_path.iterdir()) == [path]


def test_writer_rejects_bad_skeleton(tmp_path: Path) -> None:
    local_rot, root_pos = random_motion(2, 3, seed=4)
    offsets = np.zeros((3, 3))
    bad = [
        (["a", "b", "c"], [-1, 0, -1]),  # two roots
        (["a", "b", "b"], [-1, 0, 1]),  # duplicate name
        (["a", "b c", "d"], [-1, 0, 1]),  # whitespace in a name
        (["a", "b", "c"], [-1, 2, 1]),  # cycle: b and c unreachable from the root
    ]
    for names, parents in bad:
        with pytest.raises(UMFError):
            write_bvh(tmp_path / "x.bvh", names, parents, offsets, local_rot, root_pos, 0.1)
    with pytest.raises(UMFError, match="End Site 1"):  # joint 1 is not a leaf
        args = (["a", "b", "c"], [-1, 0, 1], offsets, local_rot, root_pos, 0.1)
        write_bvh(tmp_path / "x.bvh", *args, end_sites={1: [0, 1, 0]})
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------- malformed input
MALFORMED = {
    "no-motion": lambda t: t[: t.index("MOTION")],
    "short-frame": lambda t: t.replace("0 0 30\t1 90", "0 0 30\t1"),
    "long-frame": lambda t: t.replace("7 0\n", "7 0 0\n"),
    "unknown-channel": lambda t: t.replace("3 Xrotation Yrotation", "3 Wrotation Yrotation"),
    "fewer-frames": lambda t: t.replace("Frames: 2", "Frames: 3"),
    "more-frames": lambda t: t.replace("Frames: 2", "Frames: 1"),
    "non-numeric": lambda t: t.replace("90 90 0", "90 abc 0"),
    "truncated-hierarchy": lambda t: (
        t[: t.index("JOINT c")] + "MOTION\nFrames: 0\nFrame Time: 0.1\n"
    ),
    "no-frame-time": lambda t: t.replace("Frame Time: 0.008333\n", ""),
    "bad-offset": lambda t: t.replace("OFFSET 0 10 0", "OFFSET 0 10"),
    "channel-count": lambda t: t.replace("CHANNELS 2 Yposition", "CHANNELS 3 Yposition"),
    "not-bvh": lambda t: "hello\nworld\n",
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_raises_one_line_error(tmp_path: Path, case: str) -> None:
    path = tmp_path / f"broken-{case}.bvh"
    path.write_text(MALFORMED[case](SYNTHETIC))
    with pytest.raises(UMFError, match=re.escape(path.name)) as info:
        read_bvh(path)
    assert "\n" not in str(info.value)


def test_malformed_messages_locate_the_problem() -> None:
    with pytest.raises(UMFError, match=r"frame 2 \(line 39\) has 16 values, expected 17"):
        parse_bvh(MALFORMED["short-frame"](SYNTHETIC), "x.bvh")
    with pytest.raises(UMFError, match=r"has 2 frames but the header declares 3"):
        parse_bvh(MALFORMED["fewer-frames"](SYNTHETIC), "x.bvh")
    with pytest.raises(UMFError, match=r"line 9: unknown channel 'Wrotation' on joint a"):
        parse_bvh(MALFORMED["unknown-channel"](SYNTHETIC), "x.bvh")


def test_missing_file_and_stream_names(tmp_path: Path) -> None:
    with pytest.raises(UMFError, match=re.escape("nowhere.bvh")):
        read_bvh(tmp_path / "nowhere.bvh")
    stream = io.StringIO(SYNTHETIC[: SYNTHETIC.index("MOTION")])
    stream.name = "upload.bvh"
    with pytest.raises(UMFError, match=re.escape("upload.bvh")):
        read_bvh(stream)


def test_a_tiny_file_cannot_make_the_reader_allocate_much():
    """Frames: N with no channels held no motion but cost N frames of work downstream; a
    frame count past the cap is refused before anything is read."""
    from umf.bvh import MAX_FRAMES, parse_bvh
    from umf.errors import UMFError

    head = "HIERARCHY\nROOT a\n{\n  OFFSET 0 0 0\n"
    with pytest.raises(UMFError, match="no CHANNELS"):
        parse_bvh(head + "}\nMOTION\nFrames: 100000\nFrame Time: 0.03\n")
    chans = "  CHANNELS 3 Xposition Yposition Zposition\n}\n"
    with pytest.raises(UMFError, match="at most"):
        parse_bvh(head + chans + f"MOTION\nFrames: {MAX_FRAMES + 1}\nFrame Time: 0.03\n0 0 0\n")
