"""How a short single-person clip is extended to a full training crop, truthfully.

A flow trained on the latents of clips shorter than its crops never sees the latent tokens
past a clip's end stand for anything, and what it makes past the usual length of a label
follows no data: a 4 s "raise both hands" (real clips: 2.4 s) glides off after 2 s, a 4 s
run (real clips: 3.2 s) slows to a glide. Three options extend a clip shorter than the
shortest crop where that can be done truthfully, as the scene composer already holds people
whose clips end early (:func:`umf.data.scenes.time_layout`):

* ``hold_rest`` holds the last pose of a clip that ends with the body at rest
  (:func:`ends_at_rest`);
* ``repeat_gait`` repeats the last cycle of one that ends in a steady, straight gait
  (:func:`gait_period`), carried on along the path it travelled;
* ``settle`` eases to a stop, then holds, one that ends slowly but not yet at rest (a getup
  cut while the pelvis still rises: :func:`settle_times`).

Other clips are served as they are. :func:`extension_period` chooses, per person; the
datasets (:mod:`umf.train.datasets`) serve the extended frames.

``repeat_gait`` extends a composed scene too (:func:`scene_gait_periods`), where every person
ends in a steady, straight gait and the scene's relation checks still hold on the extended
scene: Bandai's runs are short, so the composed runs side by side long enough for a 4 s crop
were the slow jogs (1.6 m/s at the median against 2.7 m/s for 2 s), and the S-Flow's
4-second runners lagged their leader.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from umf.data.clip import FPS
from umf.data.relations import check_record
from umf.representation import heading_angle
from umf.rotations import matrix_to_6d, sixd_to_matrix
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT

REST_FRAMES = 10  # the last frames of a clip that decide whether it ends at rest
REST_SPEED = 0.15  # m/s: pelvis and feet slower than this over them (a body not travelling)


REST_JOINTS = (0, *FOOT_LEFT, *FOOT_RIGHT)  # pelvis, left ankle and toe, right ankle and toe


def end_speeds(joints: np.ndarray, fps: float = FPS, frames: int = REST_FRAMES) -> np.ndarray:
    """Mean speeds (m/s) of the :data:`REST_JOINTS` of one person's joints (T, 22, 3) over
    its last ``frames`` frames; empty when the clip has fewer than two frames."""
    j = np.asarray(joints, dtype=np.float64)[-(frames + 1) :, list(REST_JOINTS)]
    if len(j) < 2:
        return np.zeros(0)
    return np.linalg.norm(np.diff(j, axis=0), axis=-1).mean(axis=0) * fps


def ends_at_rest(
    joints: np.ndarray, fps: float = FPS, frames: int = REST_FRAMES, speed: float = REST_SPEED
) -> bool:
    """Whether one person's joints (T, 22, 3) end standing: the pelvis and both feet (ankles,
    toes) move slower than ``speed`` on average over the last ``frames`` frames
    (:func:`end_speeds`). The arms may still move (the Bandai gestures are cut while the
    hands come down)."""
    v = end_speeds(joints, fps, frames)
    return bool(v.size and v.max() < speed)


GAIT_FRAMES = (15, 45)  # a gait cycle: 0.5 to 1.5 s at 30 fps
GAIT_MATCH = 0.05  # m: mean joint distance of the last pose to the pose one cycle earlier
GAIT_TURN = math.radians(15)  # most heading change over the cycle (turns are not repeated)
GAIT_SPEED = 0.3  # m/s: least travel over the cycle (a gait goes somewhere; gestures do not)


def last_cycle(
    joints: np.ndarray, frames: tuple[int, int] = GAIT_FRAMES, fps: float = FPS
) -> tuple[int, float, float, float]:
    """The last cycle of one person's joints (T, 22, 3): (lag, seam m, turn rad, travel m/s).
    The lag in ``frames`` is the one at which the pelvis-relative pose best matches the last
    pose (a step to the other foot does not: left and right differ); the seam is that mean
    joint distance, the turn the heading change and the travel the pelvis's floor speed over
    the lag. Lag 0 (and the rest 0) when the clip is shorter than the shortest lag."""
    j = np.asarray(joints, dtype=np.float64)
    rel = j - j[:, :1]
    lags = range(frames[0], min(frames[1], len(j) - 1) + 1)
    if not lags:
        return 0, 0.0, 0.0, 0.0
    err = [float(np.linalg.norm(rel[-1] - rel[-1 - lag], axis=-1).mean()) for lag in lags]
    lag = lags[int(np.argmin(err))]
    yaw = heading_angle(torch.from_numpy(j[[-1 - lag, -1]])).numpy()
    turned = abs((yaw[1] - yaw[0] + math.pi) % (2 * math.pi) - math.pi)
    travel = float(np.linalg.norm(j[-1, 0, [0, 2]] - j[-1 - lag, 0, [0, 2]])) * fps / lag
    return lag, min(err), float(turned), travel


def gait_period(
    joints: np.ndarray,
    frames: tuple[int, int] = GAIT_FRAMES,
    match: float = GAIT_MATCH,
    turn: float = GAIT_TURN,
    speed: float = GAIT_SPEED,
    fps: float = FPS,
) -> int:
    """Frames in the last cycle of one person's joints (T, 22, 3); 0 where the clip does not
    end in a steady, straight cycle: the :func:`last_cycle` counts when its seam is at most
    ``match`` metres, its turn under ``turn`` radians and its travel ``speed`` m/s or more."""
    lag, seam, turned, travel = last_cycle(joints, frames, fps)
    return lag if lag and seam <= match and turned < turn and travel >= speed else 0


SETTLE = -1  # extension "period" of a clip whose end is eased to a stop, then held
SETTLE_FRAMES = 10  # the last frames replayed at a pace falling to zero, over twice as many
SETTLE_SPEED = 1.0  # m/s: the most end speed (:func:`end_speeds`) of a clip eased to a stop


def extension_period(
    joints: np.ndarray, min_frames: int, hold_rest: bool, repeat_gait: bool, settle: bool = False
) -> int | None:
    """How one person's clip (T, 22, 3) is extended to a crop of ``min_frames`` feature
    frames: None (long enough, or no option fits: served as it is), 0 (its last pose
    held: ``hold_rest`` and :func:`ends_at_rest`), P (its last P frames repeated:
    ``repeat_gait`` and :func:`gait_period`) or :data:`SETTLE` (its end eased to a stop,
    then held: ``settle`` and every end speed under :data:`SETTLE_SPEED`; a clip cut while
    the body still settles, e.g. DeepMimic's getups, which end with the pelvis rising)."""
    if len(joints) - 1 >= min_frames:
        return None
    if hold_rest and ends_at_rest(joints):
        return 0
    if repeat_gait and (period := gait_period(joints)):
        return period
    if settle and (v := end_speeds(joints)).size and v.max() < SETTLE_SPEED:
        return SETTLE
    return None


def settle_times(num_frames: int, start: int, stop: int, frames: int = SETTLE_FRAMES) -> np.ndarray:
    """Source times (fractional frames) of frames ``start .. stop - 1`` of a clip of
    ``num_frames`` frames eased to a stop: played as it is up to its last ``frames`` frames,
    which then take twice as many frames at a pace falling linearly from 1 to 0 (the
    velocity is continuous and ends at zero), then its last frame held. Only real poses and
    poses between neighbouring real frames are served; nothing is extrapolated."""
    t = np.arange(start, stop, dtype=np.float64)
    k = min(frames, num_frames - 1)
    if k <= 0:
        return np.minimum(t, num_frames - 1)
    ease = num_frames - 1 - k  # the frame where the pace starts to fall
    u = np.clip(t - ease, 0.0, 2.0 * k)
    return np.where(t <= ease, t, ease + u - u * u / (4.0 * k))


def interpolate_frames(x: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``x`` (T, ...) at fractional frame ``times``: linear between the neighbouring frames."""
    x = np.asarray(x)
    lo = np.clip(np.floor(times).astype(np.int64), 0, len(x) - 1)
    hi = np.minimum(lo + 1, len(x) - 1)
    w = (np.asarray(times) - lo).reshape(-1, *([1] * (x.ndim - 1)))
    return (x[lo] * (1.0 - w) + x[hi] * w).astype(x.dtype)


def extended_frames(
    num_frames: int, start: int, stop: int, period: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Frames ``start .. stop - 1`` of a clip of ``num_frames`` frames, extended past its
    end: (source frame, cycles added) per frame. ``period`` 0 holds the last frame (cycles
    0); ``period`` P repeats the last P frames, the k-th repeat moved by k times the travel
    of one cycle."""
    if not 0 <= period < num_frames:
        raise ValueError(f"period {period} must be in [0, {num_frames - 1}] ({num_frames} frames)")
    t = np.arange(start, stop)
    past = np.maximum(t - (num_frames - 1), 0)  # frames past the last one
    if not period:
        return np.minimum(t, num_frames - 1), np.zeros(len(t))
    src = np.where(past > 0, num_frames - 1 - period + (past - 1) % period + 1, t)
    return src, np.where(past > 0, (past - 1) // period + 1, 0).astype(np.float64)


def extend_joints(joints: np.ndarray, start: int, stop: int, period: int = 0) -> np.ndarray:
    """Joints (stop - start, 22, 3) of frames ``start .. stop - 1`` of one person's joints
    (T, 22, 3) extended past the end (:func:`extended_frames`): held, or repeating the last
    ``period`` frames, each repeat carried on by the pelvis's floor travel over the cycle."""
    j = np.asarray(joints)
    src, cycles = extended_frames(len(j), start, stop, period)
    if not period:
        return j[src]
    travel = (j[-1, 0] - j[-1 - period, 0]) * np.array([1.0, 0.0, 1.0])
    return (j[src] + cycles[:, None, None] * travel).astype(j.dtype)


def extend_person(
    joints: np.ndarray, rot6d: np.ndarray, start: int, stop: int, period: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Joints (stop - start, 22, 3) and local 6-D rotations (stop - start, 21, 6) of frames
    ``start .. stop - 1`` of one person, extended past the end as :func:`extension_period`
    chose: held (0), repeating the last ``period`` frames (:func:`extend_joints`), or eased
    to a stop (:data:`SETTLE`: :func:`settle_times`; rotations between two frames go back
    to rotations through Gram-Schmidt)."""
    if period == SETTLE:
        times = settle_times(len(joints), start, stop)
        rot = torch.from_numpy(interpolate_frames(rot6d, times))
        return interpolate_frames(joints, times), matrix_to_6d(sixd_to_matrix(rot)).numpy()
    frames, _ = extended_frames(len(joints), start, stop, period)
    return extend_joints(joints, start, stop, period), rot6d[frames]


def scene_gait_periods(joints: np.ndarray, record: dict, frames: int) -> list[int] | None:
    """Each person's gait period where a composed scene's joints (P, T, 22, 3) can be
    extended to ``frames`` joint frames truthfully: its people travel together (its
    relation ``record`` checks a ``same_heading``: side by side, one following another),
    every person ends in a steady, straight gait (:func:`gait_period`) and every check of
    the record holds on the extended scene. None otherwise, or when long enough.

    People walking towards each other are not carried on: their scene ends where they meet,
    and a walker carried past that point is no longer what the caption says (with them in
    the bank of reactions, partners asked to part ways faced away in 0.57 of the val scenes
    instead of 0.86)."""
    if len(joints) == 0 or joints.shape[1] >= frames:
        return None
    if not any(c["type"] == "same_heading" for c in record.get("constraints", [])):
        return None
    periods = [gait_period(j) for j in joints]
    if not all(periods):
        return None
    extended = np.stack([extend_joints(j, 0, frames, p)
                         for j, p in zip(joints, periods, strict=True)])  # fmt: skip
    if not all(c.passed for c in check_record(extended, record)):
        return None
    return periods


def extend_scene(
    joints: np.ndarray, rot6d: np.ndarray, periods: list[int], start: int, stop: int
) -> tuple[np.ndarray, np.ndarray]:
    """Joints (P, stop - start, 22, 3) and rotations (P, stop - start, 21, 6) of frames
    ``start .. stop - 1`` of a scene's people, each extended as :func:`extend_person` with
    its period (:func:`scene_gait_periods`)."""
    out = [extend_person(j, r, start, stop, p)
           for j, r, p in zip(joints, rot6d, periods, strict=True)]  # fmt: skip
    return np.stack([j for j, _ in out]), np.stack([r for _, r in out])


# a gait played at most this much faster or slower still looks like a gait (cadence and stride
# together): a runner's pace in the training crops spans 1.9-3.1 m/s
PLAY_FASTEST = 1.25
PLAY_SLOWEST = 0.8


def played_at(joints: np.ndarray, rate: float, frames: int) -> np.ndarray:
    """``frames`` frames of one person's joints (T, 22, 3) played ``rate`` times as fast
    (clamped to [:data:`PLAY_SLOWEST`, :data:`PLAY_FASTEST`]): resampled in time from the
    first frame, and where that needs frames past the end, its last cycle repeated on along
    its path (:func:`extend_joints`; the cycle :func:`last_cycle` finds, steady or not).
    A partner who walks beside a leader faster than every real partner on record."""
    j = np.asarray(joints, dtype=np.float64)
    rate = float(np.clip(rate, PLAY_SLOWEST, PLAY_FASTEST))
    times = np.arange(frames) * rate
    need = int(np.ceil(times[-1])) + 2 if frames else 0
    if need > len(j):
        j = extend_joints(j, 0, need, last_cycle(j)[0] or 0)
    return interpolate_frames(j, times).astype(np.asarray(joints).dtype)
