"""Stick-figure pictures of SMPL-22 motion: GIF / MP4 animations and PNG strips.

One fixed 3-D perspective camera per clip (everyone in view for every frame, the same
metres per pixel on all axes), a floor grid under the whole trajectory and one colour
per person, the left side of each body lighter than the right so a mirrored motion is
visible at a glance. The figure and its artists are built once and only their data
change per frame, which keeps a 300-frame clip at a few seconds.

Data are in the umf frame (Y up, metres, a person in the rest pose faces +Z, their left
is +X). Matplotlib's 3-D axes have Z up, so a data point (x, y, z) is drawn at plot
(x, -z, y): a rotation, not a reflection, so left and right are not mirrored on screen.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import matplotlib.colors as mcolors
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d import proj3d
from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection
from tqdm import tqdm

from umf.errors import UMFError
from umf.frame_files import gif_durations, write_gif, write_mp4
from umf.io import atomic_path
from umf.skeleton import CHAINS, NUM_JOINTS

__all__ = [
    "DEFAULT_AZIM",
    "DEFAULT_ELEV",
    "PALETTE",
    "project",
    "render_animation",
    "render_frames",
    "save_still",
]

# Camera: elevation above the floor and heading around the vertical axis, in degrees.
# azim=0 looks straight at the front of someone facing +Z; positive azim swings the
# camera towards +X (that person's left). The default is a front three-quarter view.
DEFAULT_ELEV = 20.0
DEFAULT_AZIM = 30.0

# One colour per person: distinct hues first, readable on white, none grey (the floor).
PALETTE: tuple[str, ...] = (
    "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#17becf",
    "#e377c2", "#8c564b", "#bcbd22", "#393b79", "#7b4173", "#006d5b",
)  # fmt: skip
# Shade of each chain in CHAINS (right leg, left leg, spine, right arm, left arm):
# > 0 blends towards white (left side), < 0 towards black (right side).
_CHAIN_SHADES = (-0.15, 0.45, 0.0, -0.15, 0.45)
_CHAIN_LISTS = [list(chain) for chain in CHAINS]
_HEAD = 15
_PELVIS = 0
_DPI = 100
_SUFFIXES = (".gif", ".mp4")


# ----------------------------------------------------------------- geometry
def _view_basis(elev: float, azim: float) -> np.ndarray:
    """Rows: screen right, screen up, towards the camera, as unit vectors in data axes."""
    e, a = math.radians(elev), math.radians(azim)
    toward = np.array([math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)])
    right = np.cross([0.0, 1.0, 0.0], toward)
    right /= np.linalg.norm(right)
    up = np.cross(toward, right)
    return np.stack([right, up, toward])


def project(
    points: np.ndarray, elev: float = DEFAULT_ELEV, azim: float = DEFAULT_AZIM
) -> np.ndarray:
    """Screen coordinates (..., 2) (right, up; metres, orthographic) of data points (..., 3).

    The same camera convention as the renderer (whose perspective only rescales these),
    so tests and callers can reason about where something lands on screen.
    """
    return np.asarray(points, dtype=np.float64) @ _view_basis(elev, azim)[:2].T


def _to_plot(points: np.ndarray) -> np.ndarray:
    """Data (x, y, z), Y up -> matplotlib (x, -z, y), Z up; a proper rotation."""
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def _as_people(joints: Any) -> np.ndarray:
    """(P, T, 22, 3) float64 array from numpy / torch, (T, 22, 3) meaning one person."""
    if hasattr(joints, "detach"):
        joints = joints.detach().cpu().numpy()
    arr = np.asarray(joints, dtype=np.float64)
    if arr.ndim == 3:
        arr = arr[None]
    if arr.ndim != 4 or arr.shape[2:] != (NUM_JOINTS, 3) or arr.shape[0] < 1:
        raise UMFError(f"joints must be (P, T, 22, 3) or (T, 22, 3), got {tuple(arr.shape)}")
    if arr.shape[1] < 1:
        raise UMFError("joints have no frames")
    if not np.isfinite(arr).all():
        raise UMFError("joints contain NaN or infinite values")
    return arr


def _frame_indices(
    num_frames: int,
    frame_indices: Sequence[int] | None = None,
    stride: int = 1,
    max_frames: int | None = None,
) -> list[int]:
    if stride < 1:
        raise UMFError(f"stride must be >= 1, got {stride}")
    if max_frames is not None and max_frames < 1:
        raise UMFError(f"max_frames must be >= 1, got {max_frames}")
    if frame_indices is None:
        frames = list(range(0, num_frames, stride))
    else:
        frames = [int(t) for t in frame_indices]
        bad = [t for t in frames if not 0 <= t < num_frames]
        if bad or not frames:
            raise UMFError(f"frame indices must lie in [0, {num_frames}), got {bad or 'none'}")
    return frames[:max_frames] if max_frames is not None else frames


def _shade(color: Any, amount: float) -> tuple[float, float, float]:
    rgb = np.asarray(mcolors.to_rgb(color))
    target = 1.0 if amount > 0 else 0.0
    return tuple(rgb + (target - rgb) * abs(amount))  # type: ignore[return-value]


def _person_colors(num_people: int, colors: Sequence[Any] | None) -> list[Any]:
    if colors is None:
        # past the palette, repeat it darker so people stay distinguishable
        return [
            _shade(PALETTE[i % len(PALETTE)], -0.35 * min(i // len(PALETTE), 2) / 2)
            for i in range(num_people)
        ]
    colors = list(colors)
    if len(colors) < num_people:
        raise UMFError(f"{len(colors)} colours given for {num_people} people")
    for c in colors:
        if not mcolors.is_color_like(c):
            raise UMFError(f"not a colour: {c!r}")
    return colors[:num_people]


def _person_labels(num_people: int, labels: Sequence[str] | bool | None) -> list[str]:
    if labels is None:
        labels = num_people > 1
    if labels is True:
        return [f"P{i + 1}" for i in range(num_people)]
    if labels is False:
        return []
    labels = [str(s) for s in labels]
    if len(labels) < num_people:
        raise UMFError(f"{len(labels)} labels given for {num_people} people")
    return labels[:num_people]


def _multiples(lo: float, hi: float, step: float) -> list[float]:
    """Multiples of ``step`` strictly inside (lo, hi), keeping clear of the ends."""
    first, last = math.floor(lo / step) + 1, math.ceil(hi / step) - 1
    return [k * step for k in range(first, last + 1) if lo + 0.05 < k * step < hi - 0.05]


# ----------------------------------------------------------------- the scene
class _Scene:
    """One figure with every artist of the clip; :meth:`draw` poses it at a frame."""

    def __init__(
        self,
        joints: np.ndarray,
        *,
        caption: str = "",
        fps: float = 30.0,
        colors: Sequence[Any] | None = None,
        labels: Sequence[str] | bool | None = None,
        size: tuple[int, int] = (640, 480),
        elev: float = DEFAULT_ELEV,
        azim: float = DEFAULT_AZIM,
    ) -> None:
        width, height = (int(s) for s in size)
        if width < 64 or height < 64:
            raise UMFError(f"frame size must be at least 64x64 pixels, got {width}x{height}")
        if not fps > 0:
            raise UMFError(f"fps must be positive, got {fps}")
        self.fps = float(fps)
        self.num_frames = joints.shape[1]
        self.size = (width, height)
        self.toward = _view_basis(elev, azim)[2]
        self.joints = joints
        self.pts = _to_plot(joints)  # (P, T, 22, 3) plot coordinates
        num_people = joints.shape[0]
        person_colors = _person_colors(num_people, colors)
        person_labels = _person_labels(num_people, labels)

        self.fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")
        self.canvas = FigureCanvasAgg(self.fig)
        scale = min(width, height) / 480.0  # line widths and fonts follow the frame size

        # caption on top, wrapped to the frame width; the 3-D view gets what is left
        font = float(np.clip(width / 52.0, 8.0, 15.0))
        top = 4.0
        if caption:
            chars = max(20, int(width / (0.55 * font * _DPI / 72.0)))
            lines = textwrap.wrap(caption, chars)
            if len(lines) > 3:
                lines = [*lines[:2], textwrap.shorten(" ".join(lines[2:]), chars, placeholder=" …")]
            self.fig.text(
                0.5,
                1 - 4 / height,
                "\n".join(lines),
                ha="center",
                va="top",
                fontsize=font,
                color="#222222",
                linespacing=1.25,
                wrap=False,
            )
            top += len(lines) * font * 1.25 * _DPI / 72.0 + 6
        self.view = (0.0, 0.0, float(width), max(height - top, height * 0.4))  # x0, y0, w, h

        ax = self.fig.add_axes((0.0, 0.0, 1.0, 1.0), projection="3d", computed_zorder=False)
        self.ax = ax
        ax.set_axis_off()
        ax.set_proj_type("persp", focal_length=0.6)
        ax.view_init(elev=elev, azim=azim - 90.0, roll=0.0)  # see _view_basis

        # fixed limits from the whole clip: floor grid under every trajectory
        flat = self.pts.reshape(-1, 3)
        lo, hi = flat.min(0), flat.max(0)
        floor = lo[2]
        extent = float(max(hi[0] - lo[0], hi[1] - lo[1]))
        step = 0.5 if extent <= 6.0 else 1.0
        lo_xy, hi_xy = lo[:2] - 0.4, hi[:2] + 0.4
        top_z = max(hi[2], floor + 1.0) + 0.15
        self.floor = floor
        ax.set_xlim(lo_xy[0], hi_xy[0])
        ax.set_ylim(lo_xy[1], hi_xy[1])
        ax.set_zlim(floor, top_z)
        self.aspect = np.array([hi_xy[0] - lo_xy[0], hi_xy[1] - lo_xy[1], top_z - floor])

        corners = [
            (lo_xy[0], lo_xy[1], floor),
            (hi_xy[0], lo_xy[1], floor),
            (hi_xy[0], hi_xy[1], floor),
            (lo_xy[0], hi_xy[1], floor),
        ]
        # what must stay in view: the floor and every joint of every frame, plus room
        # above the heads for the labels
        heads = self.pts[:, :, _HEAD].reshape(-1, 3) + np.array([0.0, 0.0, 0.3])
        self.keep = np.concatenate([np.array(corners), flat, heads])
        ax.add_collection3d(
            Poly3DCollection([corners], facecolor="#f3f4f6", edgecolor="none", zorder=0)
        )
        # grid lines on world multiples of the step (distances can be read off), plus
        # the floor's border
        xs = [lo_xy[0], *_multiples(lo_xy[0], hi_xy[0], step), hi_xy[0]]
        ys = [lo_xy[1], *_multiples(lo_xy[1], hi_xy[1], step), hi_xy[1]]
        grid = [[(x, ys[0], floor), (x, ys[-1], floor)] for x in xs]
        grid += [[(xs[0], y, floor), (xs[-1], y, floor)] for y in ys]
        ax.add_collection3d(
            Line3DCollection(grid, colors="#c9ccd1", linewidths=0.8 * max(scale, 0.6), zorder=0.5)
        )

        lw = 2.6 * max(scale, 0.5)
        self.chains: list[list[Any]] = []
        self.heads: list[Any] = []
        self.trails: list[Any] = []
        self.labels: list[Any] = []
        for p in range(num_people):
            color = person_colors[p]
            (trail,) = ax.plot([], [], [], color=color, alpha=0.45, lw=lw * 0.5, zorder=1)
            self.trails.append(trail)
            self.chains.append(
                [
                    ax.plot([], [], [], color=_shade(color, s), lw=lw, solid_capstyle="round")[0]
                    for s in _CHAIN_SHADES
                ]
            )
            (head,) = ax.plot([], [], [], "o", color=color, ms=lw * 2.4, mec="white", mew=0.8)
            self.heads.append(head)
            if person_labels:
                self.labels.append(
                    ax.text(
                        0,
                        0,
                        0,
                        person_labels[p],
                        color=color,
                        ha="center",
                        va="bottom",
                        fontsize=font * 0.9,
                        fontweight="bold",
                        zorder=100,
                    )
                )
        self.counter = self.fig.text(
            1 - 6 / width,
            5 / height,
            "",
            ha="right",
            va="bottom",
            fontsize=font * 0.8,
            color="#666666",
            family="monospace",
        )
        for artist in ax.get_children():
            artist.set_clip_on(False)  # the axes square may be larger than the frame
        self._fit_camera()

    def _fit_camera(self) -> None:
        """Zoom and shift the view so the floor and everyone, in every frame, fill the frame.

        Matplotlib keeps a 3-D axes square and centred on the box; instead the square is
        sized and moved (it may stick out of the figure) until the projection of
        everything that must stay in view touches the free area's edges.
        """
        width, height = self.size
        x0, y0, vw, vh = self.view
        zoom, side = 1.0, float(max(vw, vh))
        cx, cy = x0 + vw / 2, y0 + vh / 2
        margin = 0.96
        for _ in range(5):
            self.ax.set_box_aspect(self.aspect, zoom=zoom)
            self.ax.set_position(
                (
                    (cx - side / 2) / width,
                    (cy - side / 2) / height,
                    side / width,
                    side / height,
                )
            )
            xs, ys, _ = proj3d.proj_transform(*self.keep.T, self.ax.get_proj())
            px = self.ax.transData.transform(np.column_stack([xs, ys]))
            (left, bottom), (right, top) = px.min(0), px.max(0)
            fit = min(vw / (right - left), vh / (top - bottom)) * margin
            zoom *= fit
            # move the square so the projected box is centred in the free area
            cx += (x0 + vw / 2) - (left + right) / 2
            cy += (y0 + vh / 2) - (bottom + top) / 2
            if abs(fit - 1) < 0.005:
                break

    def draw(self, t: int) -> np.ndarray:
        """The frame ``t`` as an (H, W, 3) uint8 image."""
        pts = self.pts[:, t]
        depth = self.joints[:, t, _PELVIS] @ self.toward  # larger: nearer the camera
        for rank, p in enumerate(np.argsort(depth, kind="stable")):
            z = 2.0 + rank
            for line, chain in zip(self.chains[p], _CHAIN_LISTS, strict=True):
                seg = pts[p, chain]
                line.set_data_3d(seg[:, 0], seg[:, 1], seg[:, 2])
                line.set_zorder(z)
            head = pts[p, _HEAD]
            self.heads[p].set_data_3d([head[0]], [head[1]], [head[2]])
            self.heads[p].set_zorder(z + 0.5)
            path = self.pts[p, : t + 1, _PELVIS]
            self.trails[p].set_data_3d(path[:, 0], path[:, 1], np.full(len(path), self.floor))
            if self.labels:
                self.labels[p].set_position_3d((head[0], head[1], head[2] + 0.12))
        self.counter.set_text(f"{t + 1}/{self.num_frames}  {t / self.fps:6.2f} s")
        self.canvas.draw()
        rgba = np.asarray(self.canvas.buffer_rgba())
        return np.ascontiguousarray(rgba[..., :3])

    def close(self) -> None:
        self.fig.clear()
        del self.canvas, self.fig, self.ax

    def __enter__(self) -> _Scene:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _frames(
    scene: _Scene,
    indices: Sequence[int],
    progress: bool,
    desc: str,
    on_frame: Callable[[int, int], None] | None = None,
) -> Iterator[Any]:
    for done, t in enumerate(tqdm(indices, desc=desc, unit="frame", disable=not progress,
                                  leave=False), start=1):  # fmt: skip
        yield scene.draw(t)
        if on_frame is not None:
            on_frame(done, len(indices))


# ----------------------------------------------------------------- public API
def render_frames(
    joints: Any,
    caption: str = "",
    frame_indices: Sequence[int] | None = None,
    *,
    fps: float = 30.0,
    colors: Sequence[Any] | None = None,
    labels: Sequence[str] | bool | None = None,
    size: tuple[int, int] = (640, 480),
    elev: float = DEFAULT_ELEV,
    azim: float = DEFAULT_AZIM,
    progress: bool = False,
    max_frames: int | None = None,
    stride: int = 1,
) -> np.ndarray:
    """Rendered frames (K, H, W, 3) uint8 of ``joints`` (P, T, 22, 3) or (T, 22, 3).

    ``frame_indices`` picks frames (default every ``stride``-th, at most ``max_frames``);
    the camera is fixed by the whole clip either way. ``labels``: None names people
    "P1", "P2"... when there are several, True / False force that, or give the names.
    """
    people = _as_people(joints)
    indices = _frame_indices(people.shape[1], frame_indices, stride, max_frames)
    with _Scene(
        people,
        caption=caption,
        fps=fps,
        colors=colors,
        labels=labels,
        size=size,
        elev=elev,
        azim=azim,
    ) as scene:
        return np.stack(list(_frames(scene, indices, progress, "render")))


def render_animation(
    joints: Any,
    path: str | Path,
    caption: str = "",
    fps: float = 30.0,
    *,
    colors: Sequence[Any] | None = None,
    labels: Sequence[str] | bool | None = None,
    size: tuple[int, int] = (640, 480),
    elev: float = DEFAULT_ELEV,
    azim: float = DEFAULT_AZIM,
    progress: bool = True,
    max_frames: int | None = None,
    stride: int = 1,
    on_frame: Callable[[int, int], None] | None = None,
) -> Path:
    """Write an animation of ``joints`` (P, T, 22, 3) or (T, 22, 3) to ``path``; return it.

    ``.gif`` loops forever, ``.mp4`` is H.264 / yuv420p (plays in browsers; an odd
    frame size is rounded up to even). Playback is real time: with ``stride`` k every
    k-th frame is shown for k / ``fps`` seconds. Written atomically. ``on_frame(done,
    total)`` is called after each drawn frame, so a caller (``umf serve``) can show progress.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in _SUFFIXES:
        raise UMFError(f"cannot write {path.name}: use one of {', '.join(_SUFFIXES)}")
    people = _as_people(joints)
    indices = _frame_indices(people.shape[1], None, stride, max_frames)
    if suffix == ".mp4":
        size = (int(size[0]) + int(size[0]) % 2, int(size[1]) + int(size[1]) % 2)
    with (
        _Scene(
            people,
            caption=caption,
            fps=fps,
            colors=colors,
            labels=labels,
            size=size,
            elev=elev,
            azim=azim,
        ) as scene,
        atomic_path(path) as tmp,
    ):
        frames = _frames(scene, indices, progress, f"render {path.name}", on_frame)
        if suffix == ".gif":
            write_gif(frames, tmp, gif_durations(len(indices), stride / scene.fps))
        else:
            write_mp4(frames, tmp, scene.size, scene.fps / stride)
    return path


def save_still(
    joints: Any,
    path_png: str | Path,
    frame_indices: Sequence[int] | None = None,
    caption: str = "",
    *,
    size: tuple[int, int] = (480, 360),
    **options: Any,
) -> Path:
    """Write a PNG strip of frames side by side (default: 4 spread over the clip).

    Every panel is ``size`` pixels and shares one camera, so the strip reads as motion;
    the caption sits once above the strip. Other options as for :func:`render_frames`.
    """
    from PIL import Image

    people = _as_people(joints)
    num_frames = people.shape[1]
    if frame_indices is None:
        frame_indices = np.unique(np.linspace(0, num_frames - 1, min(4, num_frames)).round())
    panels = render_frames(people, "", frame_indices, size=size, **options)
    strip = np.concatenate(list(panels), axis=1)
    if caption:
        strip = np.concatenate([_caption_band(caption, strip.shape[1]), strip], axis=0)
    path_png = Path(path_png)
    with atomic_path(path_png) as tmp:
        Image.fromarray(strip).save(tmp, format="PNG", optimize=True)
    return path_png


def _caption_band(caption: str, width: int) -> np.ndarray:
    """The caption rendered as a white (h, width, 3) band to put above a strip."""
    font = 13.0
    chars = max(20, int(width / (0.55 * font * _DPI / 72.0)))
    lines = textwrap.wrap(caption, chars)[:4]
    height = int(len(lines) * font * 1.3 * _DPI / 72.0 + 14)
    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    fig.text(0.5, 0.5, "\n".join(lines), ha="center", va="center", fontsize=font, color="#222222")
    canvas.draw()
    band = np.array(canvas.buffer_rgba())[..., :3]
    fig.clear()
    return band
