"""A partner carried along the leader's path: motion path editing for people side by side.

Every real partner in the training scenes runs or walks straight (``research/runner_turns.py``:
no training crop turns more than 20 degrees), and so does every reaction in the bank. The
P-Flow's runner curves now and then (52-56 degrees in seed 7 of "Two people run side by
side.") and changes pace within a scene (3.8 m/s over its first 1.3 s, 2.7 over its last);
a straight proposal at the leader's mean pace then ends a metre or more behind it.

:func:`follow_path` moves such a proposal onto the leader's own path, as motion path editing
does: the leader's smoothed floor path and heading define a frame that rides along it; the
proposal keeps its start offset in that frame (beside, ahead or behind), turns as the leader
turns, and is played along its new path at the speed the path asks for, each frame taken
from where the proposal's own stride has covered as much ground (a time warp by arc length),
so its feet step as far as its pelvis travels.
"""

from __future__ import annotations

import numpy as np

from umf.data.extension import interpolate_frames, played_at

# frames (30 fps) of the centred moving average that takes the sway of a stride cycle
# (a walk's left and right steps take about a second) out of a path
SMOOTHING = 31
# the proposal is played at most this many times its own length to cover the new path
LONGEST = 4


def centred_mean(x: np.ndarray, window: int = SMOOTHING) -> np.ndarray:
    """``x`` (T, ...) under a centred moving average of ``window`` frames (for a floor path:
    without the sway of a stride cycle), the window
    narrowing towards each end so that it stays centred: a path bending away at an end
    biases neither its position nor its direction there, as a padded one does."""
    x = np.asarray(x, dtype=np.float64)
    t = len(x)
    half = np.minimum(np.minimum(np.arange(t), t - 1 - np.arange(t)), window // 2)
    total = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, axis=0)])
    lo, hi = np.arange(t) - half, np.arange(t) + half + 1
    return (total[hi] - total[lo]) / (hi - lo).reshape(-1, *([1] * (x.ndim - 1)))


def path_yaw(path: np.ndarray, window: int = 1) -> np.ndarray:
    """(T,) the heading (rad, 0 along +Z, positive towards +X, unwrapped) of a floor path's
    (T, 2) tangent, its velocity averaged over ``window`` frames: within half a window of an
    end, where a narrowed window would let the sway back in, the heading goes on turning at
    the rate of the half window next to it."""
    d = centred_mean(np.gradient(np.asarray(path, dtype=np.float64), axis=0), window)
    yaw = np.unwrap(np.arctan2(d[:, 0], d[:, 1]))
    h, t = window // 2, len(yaw)
    if h < 1 or t < 4 * h + 1:
        return yaw
    frames = np.arange(t, dtype=np.float64)
    start = (yaw[2 * h] - yaw[h]) / h
    end = (yaw[t - 1 - h] - yaw[t - 1 - 2 * h]) / h
    yaw[:h] = yaw[h] + (frames[:h] - h) * start
    yaw[t - h :] = yaw[t - 1 - h] + (frames[t - h :] - (t - 1 - h)) * end
    return yaw


def arc_length(path: np.ndarray) -> np.ndarray:
    """(T,) the distance (m) travelled along a floor path (T, 2) up to each frame."""
    steps = np.linalg.norm(np.diff(np.asarray(path, dtype=np.float64), axis=0), axis=-1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def turn(vectors: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Floor vectors (..., 2) as (x, z) turned by ``yaw`` (rad, broadcast over the leading
    axes; +Z turns towards +X)."""
    c, s = np.cos(yaw), np.sin(yaw)
    x, z = vectors[..., 0], vectors[..., 1]
    return np.stack([x * c + z * s, z * c - x * s], axis=-1)


def path_turn(joints: np.ndarray, window: int = SMOOTHING) -> float:
    """How far (degrees, either way) one person's (T, 22, 3) smoothed path turns from its
    first frame's heading to its last's."""
    yaw = path_yaw(np.asarray(joints, dtype=np.float64)[:, 0, [0, 2]], window)
    return float(abs(np.degrees(yaw[-1] - yaw[0])))


def follow_path(joints: np.ndarray, leader: np.ndarray, window: int = SMOOTHING) -> np.ndarray:
    """One person's joints (T, 22, 3) carried along the path of ``leader`` (T, 22, 3), both
    in the same floor frame: the smoothed pelvis path of ``joints`` starts where it did and
    keeps its first-frame offset from the leader's in the leader's turning frame; each frame's
    pose is the person's own at the point where their stride has covered the new path's
    distance so far (past their end, their last gait cycle carried on), turned from their own
    path's heading to the leader's. A person who barely travels, or beside a leader who
    barely does, is returned as is."""
    j = np.asarray(joints, dtype=np.float64)
    t = len(j)
    if len(leader) != t:
        raise ValueError(f"follow_path: {t} frames against the leader's {len(leader)}")
    lead_floor = np.asarray(leader, dtype=np.float64)[:, 0, [0, 2]]
    own, lead = centred_mean(j[:, 0, [0, 2]], window), centred_mean(lead_floor, window)
    own_length = arc_length(own)[-1]
    if t < 3 or min(own_length, arc_length(lead)[-1]) < 1e-3 * t:
        return np.asarray(joints).copy()  # no path to follow, or nobody to carry
    lead_yaw = path_yaw(lead_floor, window)
    new = lead + turn(own[0] - lead[0], lead_yaw - lead_yaw[0])
    need = arc_length(new)
    # the person's motion, carried on past its end until it covers the new path
    frames = t
    if need[-1] > own_length:
        per_frame = own_length / (t - 1)
        frames = int(np.clip(np.ceil(need[-1] / per_frame) + 2, t, LONGEST * t))
    longer = played_at(j, 1.0, frames) if frames > t else j
    path = centred_mean(longer[:, 0, [0, 2]], window)
    covered = arc_length(path) + 1e-9 * np.arange(len(path))  # strictly increasing
    times = np.interp(need, covered, np.arange(len(path), dtype=np.float64))
    pose = interpolate_frames(longer, times)
    base = interpolate_frames(path, times)
    own_yaw = path_yaw(longer[:, 0, [0, 2]], window)
    yaw = lead_yaw - interpolate_frames(own_yaw, times)  # facing the leader's way
    out = pose.copy()
    out[..., [0, 2]] = new[:, None] + turn(pose[..., [0, 2]] - base[:, None], yaw[:, None])
    return out.astype(np.asarray(joints).dtype)
