"""Stick-figure rendering: files that play, fixed camera, no mirrored left/right."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import matplotlib.colors as mcolors
import numpy as np
import pytest
import torch
from PIL import Image

import umf.frame_files as frame_files
import umf.render as render
from umf import skeleton as sk
from umf.errors import UMFError
from umf.render import PALETTE, project, render_animation, render_frames, save_still

T = 20
SIZE = (320, 240)


def _people(num_frames: int = T) -> torch.Tensor:
    """Two T-posed people 2 m apart (x = -1, +1) facing +Z and walking towards +Z."""
    rot = torch.eye(3).expand(num_frames, sk.NUM_JOINTS, 3, 3)
    out = []
    for x in (-1.0, 1.0):
        t = torch.arange(num_frames, dtype=torch.float32)
        root = torch.stack([torch.full_like(t, x), torch.full_like(t, 0.93), 0.03 * t], -1)
        out.append(sk.forward_kinematics(rot, root, sk.default_offsets()))
    return torch.stack(out)  # (2, T, 22, 3)


def _mask(frames: np.ndarray, color: str, tol: float) -> np.ndarray:
    rgb = np.asarray(mcolors.to_rgb(color)) * 255
    return (np.abs(frames.astype(np.float32) - rgb) <= tol).all(-1)


def _assert_looks_right(frames: np.ndarray, tol: float) -> None:
    assert frames.shape[1:] == (SIZE[1], SIZE[0], 3)
    assert all(f.std() > 5 for f in frames), "a blank frame"
    for color in PALETTE[:2]:  # both people, in every frame
        assert all(m.sum() > 20 for m in _mask(frames, color, tol)), color


@pytest.fixture(scope="module")
def people() -> torch.Tensor:
    return _people()


def test_gif(people, tmp_path):
    out = render_animation(people, tmp_path / "a.gif", "two people", fps=20, size=SIZE)
    assert out == tmp_path / "a.gif" and sorted(tmp_path.iterdir()) == [out]
    frames = iio.imread(out, index=None)
    assert len(frames) == T
    _assert_looks_right(frames[..., :3], tol=25)
    assert (frames[:, 2, 2, :3] == 255).all()  # the palette keeps the background white
    with Image.open(out) as im:
        assert im.info["loop"] == 0
        durations = []
        for i in range(im.n_frames):
            im.seek(i)
            durations.append(im.info["duration"])
    assert sum(durations) == pytest.approx(1000 * T / 20, abs=10)


def test_mp4(people, tmp_path):
    out = render_animation(people.numpy(), tmp_path / "a.mp4", "two people", size=SIZE)
    meta = iio.immeta(out, plugin="FFMPEG")
    assert meta["codec"] == "h264" and meta["pix_fmt"].startswith("yuv420p")
    assert meta["fps"] == pytest.approx(30.0)
    frames = iio.imread(out, index=None, plugin="FFMPEG")
    assert len(frames) == T
    _assert_looks_right(frames, tol=60)


def test_mp4_odd_size_is_made_even(people, tmp_path):
    out = render_animation(people, tmp_path / "a.mp4", size=(201, 151), max_frames=2)
    assert iio.immeta(out, plugin="FFMPEG")["size"] == (202, 152)


def test_stride_and_max_frames(people, tmp_path):
    out = render_animation(people, tmp_path / "s.gif", size=SIZE, stride=3, progress=False)
    assert len(iio.imread(out, index=None)) == len(range(0, T, 3))
    with Image.open(out) as im:
        assert im.info["duration"] == 100  # each shown frame stands for 3 / 30 s
    out = render_animation(people, tmp_path / "m.mp4", size=SIZE, max_frames=5)
    assert iio.immeta(out, plugin="FFMPEG")["duration"] == pytest.approx(5 / 30, abs=0.02)
    assert len(iio.imread(out, index=None, plugin="FFMPEG")) == 5


def test_render_frames_inputs(people):
    frames = render_frames(people, "x", [0, 5, 19], size=SIZE)
    assert frames.shape == (3, SIZE[1], SIZE[0], 3) and frames.dtype == np.uint8
    single = render_frames(people[0].numpy(), size=SIZE, max_frames=2)  # (T, 22, 3)
    assert single.shape[0] == 2
    assert render_frames(people, size=SIZE, stride=7).shape[0] == 3
    # the camera is fixed: a still scene renders the same picture in every frame
    still = people[:, :1].expand(-1, 3, -1, -1)
    frames = render_frames(still, size=SIZE, labels=False)
    counter = slice(-20, None)  # bottom rows hold the frame counter, which changes
    assert (frames[0, : counter.start] == frames[2, : counter.start]).all()


@pytest.mark.parametrize(
    "bad",
    [np.zeros((T, 21, 3)), np.zeros((2, 0, 22, 3)), np.full((1, 3, 22, 3), np.nan)],
)
def test_bad_joints(bad, tmp_path):
    with pytest.raises(UMFError):
        render_animation(bad, tmp_path / "a.gif")
    assert list(tmp_path.iterdir()) == []


def test_bad_options(people):
    with pytest.raises(UMFError):
        render_frames(people, frame_indices=[99])
    with pytest.raises(UMFError):
        render_frames(people, colors=["red"])
    with pytest.raises(UMFError):
        render_frames(people, stride=0)


def test_unknown_extension(people, tmp_path):
    with pytest.raises(UMFError, match="gif"):
        render_animation(people, tmp_path / "a.avi")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".gif", ".mp4"])
def test_failure_mid_write_leaves_no_file(people, tmp_path, monkeypatch, suffix):
    target = tmp_path / f"a{suffix}"
    target.write_bytes(b"old")
    draw = render._Scene.draw
    calls = []

    def failing_draw(self, t):
        calls.append(t)
        if len(calls) == 4:
            raise RuntimeError("boom")
        return draw(self, t)

    monkeypatch.setattr(render._Scene, "draw", failing_draw)
    with pytest.raises(RuntimeError, match="boom"):
        render_animation(people, target, size=SIZE, progress=False)
    assert list(tmp_path.iterdir()) == [target] and target.read_bytes() == b"old"


def test_save_still(people, tmp_path):
    out = save_still(people, tmp_path / "still.png", (0, 10, 19), "two people", size=SIZE)
    assert sorted(tmp_path.iterdir()) == [out]
    img = iio.imread(out)
    assert img.shape[1] == 3 * SIZE[0] and img.shape[0] > SIZE[1]  # caption band on top
    assert iio.imread(save_still(people, tmp_path / "d.png", size=SIZE)).shape[1] == 4 * SIZE[0]


# ----------------------------------------------------------------- handedness
def test_project_left_hand_on_screen_right():
    """Seen from the front (default camera), a person's left hand is on screen right."""
    body = _people(1)[0, 0].numpy()  # facing +Z, left hand (20) at +X
    left, right = sk.JOINT_NAMES.index("l_wrist"), sk.JOINT_NAMES.index("r_wrist")
    assert body[left, 0] > body[right, 0]
    uv = project(body)
    assert uv[left, 0] > uv[right, 0]
    assert uv[15, 1] > uv[10, 1]  # head above feet
    behind = project(body, azim=180.0)
    assert behind[left, 0] < behind[right, 0]


@pytest.mark.parametrize("azim", [0.0, render.DEFAULT_AZIM, 120.0, 180.0, -90.0])
def test_pixels_match_project(azim):
    """Markers at +X, -X, +Z and +Y land on screen where :func:`project` says.

    Together with the test above this pins the full pipeline to a right-handed view
    with Y up: nothing mirrored, camera on the side the angles say.
    """
    spots = np.array([[1.0, 1.0, 0.0], [-1.0, 1.0, 0.0], [0.0, 1.0, 1.5], [0.0, 2.5, 0.0]])
    joints = np.repeat(spots[:, None, None, :], sk.NUM_JOINTS, axis=2).repeat(2, axis=1)
    colors = ["#ff0000", "#00b000", "#0000ff", "#ff00ff"]
    frame = render_frames(
        joints, frame_indices=[0], colors=colors, labels=False, size=(400, 300), azim=azim
    )[0]
    centres = []
    for c in colors:
        rows, cols = np.nonzero(_mask(frame, c, tol=40))
        assert len(rows) > 5, c
        centres.append((cols.mean(), -rows.mean()))  # screen right, screen up
    centres = np.array(centres)
    uv = project(spots, azim=azim)
    for i in range(4):
        for j in range(i + 1, 4):
            for axis in (0, 1):
                if abs(uv[i, axis] - uv[j, axis]) > 0.3:
                    assert np.sign(centres[i, axis] - centres[j, axis]) == np.sign(
                        uv[i, axis] - uv[j, axis]
                    ), (i, j, axis)


def test_left_side_drawn_lighter_on_screen_right(people):
    """The lighter (left) limbs of a person facing the camera appear on screen right."""
    frame = render_frames(people[:1], frame_indices=[0], labels=False, size=(400, 300), azim=0.0)[0]
    light = np.nonzero(_mask(frame, mcolors.to_hex(render._shade(PALETTE[0], 0.45)), 12))[1]
    dark = np.nonzero(_mask(frame, mcolors.to_hex(render._shade(PALETTE[0], -0.15)), 12))[1]
    assert len(light) > 20 and len(dark) > 20
    assert light.mean() > dark.mean()


def test_gif_durations_keep_real_time():
    d = frame_files.gif_durations(300, 1 / 30)
    assert sum(d) == 10_000 and set(d) == {30, 40}
    assert frame_files.gif_durations(3, 0.1) == [100, 100, 100]


def test_no_temp_files_left(people, tmp_path):
    render_animation(people, tmp_path / "x" / "a.gif", size=SIZE, max_frames=2)
    assert [p.name for p in (tmp_path / "x").iterdir()] == ["a.gif"]


def test_path_type(people, tmp_path):
    assert isinstance(render_animation(people, str(tmp_path / "a.gif"), max_frames=1), Path)
