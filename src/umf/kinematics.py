"""One rigid body per person: the motion every export writes.

Decoded joints stretch their bones over time (by 6-26 cm within one generated person),
while BVH, glTF and SMPL carry a rigid skeleton. A scene is therefore fitted once: each
person gets one set of bone lengths, and its joints become the forward kinematics (FK) of a
root path and local rotations, kept close to the decoded positions. NPZ, BVH, GLB, video,
SMPL and HumanML3D files then all hold this one motion.

:func:`fit_bodies` does, for every person at once (all frames batched):

1. bone lengths: :func:`umf.skeleton.fit_offsets` (each bone's mean decoded length; the
   branching joints' children their mean offset in the joint's frame), or the default body;
2. rotations: :func:`umf.skeleton.inverse_kinematics`: every bone points where the decoded
   one does, so the errors are only the bone-length differences, summed along a chain;
3. refinement: a few damped Gauss-Newton (Levenberg-Marquardt) steps on the pelvis height
   and every joint's rotation toward target positions, so those length errors no longer
   add up along chains (the pelvis keeps its decoded horizontal path, so where people
   stand, and :mod:`umf.separation`'s spacing, do not change). Targets are the decoded
   positions, except where a foot's contact label says it is planted (and it is low
   enough): there the ankle / toe is pinned to one spot (the mean of the run, while the
   decoded foot stays within PIN_REACH of where it landed; blended in and out over a few
   frames), and no target is below the floor;
4. floor: a frame whose lowest joint is still under the floor is lifted onto it.

Clean-up (pins and floor) applies to generated people; a user's own motion (``clean``
False) is only fitted, so a rigid input (any BVH) comes back unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import torch

from umf.representation import CONTACT_HEIGHT_THRESHOLDS
from umf.rotations import axis_angle_to_matrix
from umf.skeleton import (
    CHILDREN,
    FOOT_LEFT,
    FOOT_RIGHT,
    NUM_JOINTS,
    PARENTS,
    default_offsets,
    fit_offsets,
    forward_kinematics,
    global_rotations,
    inverse_kinematics,
)

Tensor = torch.Tensor

FOOT_JOINTS = (FOOT_LEFT[0], FOOT_LEFT[1], FOOT_RIGHT[0], FOOT_RIGHT[1])  # contact slot order
CONTACT_THRESHOLD = 0.5  # decoded contact labels are soft: planted above this
PIN_WEIGHT = 4.0  # a planted foot joint counts this many times a free joint
PIN_BLEND = 4  # frames over which a pin fades in before / out after its contact run
PIN_REACH = 0.08  # m: a pin lets go where the decoded foot slides further than this
PIN_GAP = 4  # frames between a let-go pin and the next one (2 makes the feet jitter)
ITERATIONS = 4  # Levenberg-Marquardt steps; the error stops falling after 2 to 4
DAMPING = 1e-3  # m^2 per rad^2: keeps unobservable twists where inverse kinematics put them
PINNED_DAMPING = 1e9  # on the pelvis' horizontal shift: where people stand stays decoded
BLOCK = 4096  # person-frames per batched solve (bounds the memory of the normal equations)

# Joints whose rotation moves something (the others are leaves: feet, head, wrists).
DRIVERS = tuple(j for j in range(NUM_JOINTS) if CHILDREN[j])


def _ancestry() -> tuple[np.ndarray, np.ndarray]:
    """(22, D) mask: joint k lies strictly below driver j; (D, D): driver a is j or above it."""
    below = np.zeros((NUM_JOINTS, len(DRIVERS)))
    upto = np.zeros((len(DRIVERS), len(DRIVERS)))
    for col, j in enumerate(DRIVERS):
        for k in range(NUM_JOINTS):
            a = PARENTS[k]
            while a >= 0 and a != j:
                a = PARENTS[a]
            below[k, col] = float(a == j)
        a = j
        while a >= 0:
            upto[DRIVERS.index(a), col] = 1.0
            a = PARENTS[a]
    return below, upto


_BELOW, _UPTO = _ancestry()


@dataclass
class Bodies:
    """N people as rigid skeletons (float64, metres, the scene's frame).

    ``offsets`` (N, 22, 3): each person's rest offsets (the T-pose of :mod:`umf.skeleton`,
    facing +Z); ``rotations`` (N, T, 22, 3, 3): local rotations (joint 0: the global root
    orientation); ``root`` (N, T, 3): the pelvis path. :meth:`joints` is their FK.
    """

    offsets: np.ndarray
    rotations: np.ndarray
    root: np.ndarray

    def __post_init__(self) -> None:
        n, t = self.root.shape[:2]
        if self.offsets.shape != (n, NUM_JOINTS, 3) or self.rotations.shape != (
            n, t, NUM_JOINTS, 3, 3,
        ):  # fmt: skip
            raise ValueError(
                f"inconsistent bodies: offsets {self.offsets.shape}, rotations "
                f"{self.rotations.shape}, root {self.root.shape}"
            )

    @property
    def num_people(self) -> int:
        return int(self.root.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.root.shape[1])

    def joints(self) -> np.ndarray:
        """(N, T, 22, 3) forward kinematics of every person."""
        rot = torch.from_numpy(self.rotations)
        off = torch.from_numpy(self.offsets)[:, None]
        return forward_kinematics(rot, torch.from_numpy(self.root), off).numpy()

    def frames(self, stop: int, start: int = 0) -> Bodies:
        """Frames ``start:stop`` (a copy)."""
        return Bodies(self.offsets.copy(), self.rotations[:, start:stop].copy(),
                      self.root[:, start:stop].copy())  # fmt: skip

    def person(self, i: int) -> Bodies:
        return Bodies(self.offsets[i : i + 1], self.rotations[i : i + 1], self.root[i : i + 1])


# --------------------------------------------------------------------- targets
def pin_runs(
    path: np.ndarray, planted: np.ndarray, reach: float = PIN_REACH, gap: int = PIN_GAP
) -> list[tuple[int, int]]:
    """[start, stop) frame ranges during which one foot joint (path (T, 3)) stays pinned.

    A run starts at a planted frame and lasts while the joint is planted and its decoded
    position (XZ) stays within ``reach`` of where the run began: a foot the decoder slides
    further than that (the body walks on) is let go for ``gap`` frames and pinned again,
    so no pin pulls a foot far from its decoded place (which the leg could not reach).
    """
    runs: list[tuple[int, int]] = []
    t, n = 0, len(path)
    while t < n:
        if not planted[t]:
            t += 1
            continue
        start = t
        while t < n and planted[t] and np.hypot(*(path[t, [0, 2]] - path[start, [0, 2]])) <= reach:
            t += 1
        runs.append((start, t))
        if t < n and planted[t]:
            t += gap
    return runs


def pin_targets(
    path: np.ndarray, planted: np.ndarray, blend: int = PIN_BLEND
) -> tuple[np.ndarray, np.ndarray]:
    """Targets (T, 3) and pin strength (T,) in [0, 1] for one foot joint's path (T, 3).

    Inside each run of :func:`pin_runs` the target is the run's mean position (strength 1).
    Between runs the displacement from the decoded path is interpolated linearly when the
    gap is at most ``2 * blend`` frames, else faded to zero over ``blend`` frames on each
    side, so the target never jumps.
    """
    n = len(path)
    disp = np.zeros_like(path, dtype=np.float64)
    strength = np.zeros(n)
    runs = pin_runs(path, planted)
    for start, stop in runs:
        disp[start:stop] = path[start:stop].mean(axis=0) - path[start:stop]
        strength[start:stop] = 1.0
    edges = [(None, runs[0][0])] if runs else []
    edges += [(a[1], b[0]) for a, b in pairwise(runs)]
    edges += [(runs[-1][1], None)] if runs else []
    for after, before in edges:  # gap frames [after, before) between runs
        lo = 0 if after is None else after
        hi = n if before is None else before
        if after is not None and before is not None and hi - lo <= 2 * blend:
            s = (np.arange(lo, hi) - lo + 1) / (hi - lo + 1)
            disp[lo:hi] = (1 - s)[:, None] * disp[after - 1] + s[:, None] * disp[before]
            strength[lo:hi] = 1.0
            continue
        fade = 1.0 - np.arange(1, blend + 1) / (blend + 1)
        if after is not None:
            k = min(blend, hi - lo)
            disp[lo : lo + k] = fade[:k, None] * disp[after - 1]
            strength[lo : lo + k] = fade[:k]
        if before is not None:
            k = min(blend, hi - lo)
            disp[hi - k : hi] = fade[:k][::-1, None] * disp[before]
            strength[hi - k : hi] = np.maximum(strength[hi - k : hi], fade[:k][::-1])
    return path + disp, strength


def planted_feet(joints: np.ndarray, contacts: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """(T, 4) bool, in contact slot order (l_ankle, l_foot, r_ankle, r_foot): the joint's
    contact label is on and it is low enough to touch the ``floor`` (InterGen's contact
    heights above it). One person's ``joints`` (T, 22, 3), ``contacts`` (T, 4)."""
    heights = floor + np.array(CONTACT_HEIGHT_THRESHOLDS * 2)  # ankle, toe, ankle, toe
    return (contacts > CONTACT_THRESHOLD) & (joints[:, list(FOOT_JOINTS), 1] < heights)


def clean_targets(
    joints: np.ndarray, contacts: np.ndarray | None, floor: float | None
) -> tuple[np.ndarray, np.ndarray]:
    """Target positions (T, 22, 3) and weights (T, 22) for one person's refinement.

    A foot joint (ankle or toe) is planted where its contact label (``contacts`` (T, 4):
    l_ankle, l_foot, r_ankle, r_foot) says so and it is low enough to touch the floor
    (InterGen's contact heights above ``floor``); planted frames pin it
    (:func:`pin_targets`). ``floor`` keeps every target on or above it. Without either,
    the targets are the joints themselves.
    """
    target = joints.astype(np.float64).copy()
    weight = np.ones(joints.shape[:2])
    if contacts is not None:
        planted = planted_feet(joints, contacts, 0.0 if floor is None else floor)
        for slot, j in enumerate(FOOT_JOINTS):
            target[:, j], s = pin_targets(target[:, j], planted[:, slot])
            weight[:, j] += (PIN_WEIGHT - 1.0) * s
    if floor is not None:
        target[..., 1] = np.maximum(target[..., 1], floor)
    return target, weight


# --------------------------------------------------------------------- refinement
def _skew(v: Tensor) -> Tensor:
    """Cross-product matrices [v]x (..., 3, 3): [v]x @ w = v x w."""
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], dim=-1).reshape(*v.shape, 3)


def normal_equations(pos: Tensor, res: Tensor, weight: Tensor) -> tuple[Tensor, Tensor]:
    """J^T W J (B, 3 + 3D, 3 + 3D) and J^T W r (B, 3 + 3D) of one Gauss-Newton step.

    ``pos`` (B, 22, 3) joints, ``res`` (B, 22, 3) target - joints, ``weight`` (B, 22).
    Unknowns: the root shift t and a world rotation vector w_j per driver j (turning j's
    subtree about joint j), so dp_k = t + sum over drivers j above k of w_j x (p_k - p_j):
    the Jacobian's (k, j) block is -[p_k - p_j]x. In float32: a step needs no more, and
    batched float32 matrix products are the fastest way through (poses stay float64).
    """
    b = pos.shape[0]
    below = torch.from_numpy(_BELOW).to(pos)
    lever = (pos[:, :, None, :] - pos[:, None, list(DRIVERS), :]) * below[None, :, :, None]
    j_rot = -_skew(lever.float()).permute(0, 1, 3, 2, 4).reshape(b, 66, 3 * len(DRIVERS))
    j_root = torch.eye(3, device=pos.device).repeat(NUM_JOINTS, 1).expand(b, -1, -1)
    jac = torch.cat([j_root, j_rot], dim=-1)  # (B, 66, 3 + 3D)
    w = weight.float().repeat_interleave(3, dim=-1)[..., None]  # (B, 66, 1)
    jtw = jac.transpose(1, 2) * w.transpose(1, 2)
    return jtw @ jac, (jtw @ res.float().reshape(b, -1, 1))[..., 0]


def _cost(local: Tensor, root: Tensor, offsets: Tensor, target: Tensor, weight: Tensor) -> Tensor:
    """Weighted squared distance (B,) of each pose's FK to its targets."""
    pos = forward_kinematics(local, root, offsets)
    return (weight * ((pos - target) ** 2).sum(-1)).sum(-1)


def _steady(normal: Tensor, grad: Tensor, bad: Tensor, chol: Tensor) -> tuple[Tensor, Tensor]:
    """The Cholesky factors (B, n, n) and gradients (B, n) of one step, where the ``bad``
    rows' normal matrices (B, n, n) did not factor: damped again by 1e-4 of their largest
    diagonal entry, and a row that still does not factor takes no step (the fit must never
    stop a command; poses it cannot fit stay where they were)."""
    eye = torch.eye(normal.shape[-1], device=normal.device)
    scale = normal.diagonal(dim1=-2, dim2=-1).amax(-1).clamp_min(1.0)
    again, info = torch.linalg.cholesky_ex(normal + (1e-4 * scale)[:, None, None] * eye)
    chol = torch.where(bad[:, None, None], again, chol)
    stuck = bad & (info != 0)
    chol = torch.where(stuck[:, None, None], eye, chol)
    return chol, torch.where(stuck[:, None], torch.zeros_like(grad), grad)


def _lm_step(
    local: Tensor, root: Tensor, offsets: Tensor, target: Tensor, weight: Tensor, damping: Tensor
) -> tuple[Tensor, Tensor]:
    """One damped Gauss-Newton step for B poses: local (B, 22, 3, 3), root (B, 3),
    offsets (B, 22, 3), target (B, 22, 3), weight (B, 22), damping (B,)."""
    glob = global_rotations(local)
    pos = forward_kinematics(local, root, offsets)
    normal, grad = normal_equations(pos, target - pos, weight)
    eye = torch.eye(normal.shape[-1], device=normal.device)
    normal = normal + damping.float()[:, None, None] * eye
    normal[:, [0, 2], [0, 2]] += PINNED_DAMPING  # the pelvis keeps its horizontal path
    chol, info = torch.linalg.cholesky_ex(normal)
    if bool((info != 0).any()):  # float32 lost definiteness (a body 90 units tall, in a line)
        chol, grad = _steady(normal, grad, info != 0, chol)
    step = torch.cholesky_solve(grad[..., None], chol)[..., 0].to(local)
    omega = step[:, 3:].reshape(len(step), len(DRIVERS), 3)
    # a driver's new global rotation turns by everything at or above it (first order)
    total = torch.einsum("ad,bac->bdc", torch.from_numpy(_UPTO).to(local), omega)
    new_glob = glob.clone()
    new_glob[:, list(DRIVERS)] = axis_angle_to_matrix(total) @ glob[:, list(DRIVERS)]
    for j in range(1, NUM_JOINTS):  # leaves keep their local rotation
        if j not in DRIVERS:
            new_glob[:, j] = new_glob[:, PARENTS[j]] @ local[:, j]
    parents = new_glob[:, [max(p, 0) for p in PARENTS]]
    new_local = parents.transpose(-1, -2) @ new_glob
    new_local[:, 0] = new_glob[:, 0]
    return new_local, root + step[:, :3]


def refine(
    local: Tensor,
    root: Tensor,
    offsets: Tensor,
    target: Tensor,
    weight: Tensor,
    iterations: int = ITERATIONS,
    damping: float = DAMPING,
) -> tuple[Tensor, Tensor]:
    """Rotations and root (..., 22, 3, 3), (..., 3) moved towards ``target`` (..., 22, 3)
    (weights (..., 22)) by ``iterations`` Levenberg-Marquardt steps, bone lengths fixed.

    A step that does not lower a pose's error is rejected and that pose's damping raised
    tenfold (accepted: lowered threefold), so unreachable targets cannot make it diverge.
    Poses are independent, so they are solved in blocks of at most BLOCK.
    """
    lead = root.shape[:-1]
    flat = [local.reshape(-1, NUM_JOINTS, 3, 3), root.reshape(-1, 3),
            offsets.expand(*lead, NUM_JOINTS, 3).reshape(-1, NUM_JOINTS, 3),
            target.reshape(-1, NUM_JOINTS, 3), weight.reshape(-1, NUM_JOINTS)]  # fmt: skip
    out_local, out_root = [], []
    for s in range(0, flat[1].shape[0], BLOCK):
        loc, rt, off, tg, wt = (x[s : s + BLOCK] for x in flat)
        lam = torch.full(rt.shape[:1], damping, dtype=rt.dtype, device=rt.device)
        cost = _cost(loc, rt, off, tg, wt)
        for _ in range(iterations):
            new_loc, new_rt = _lm_step(loc, rt, off, tg, wt, lam)
            new_cost = _cost(new_loc, new_rt, off, tg, wt)
            better = new_cost < cost
            loc = torch.where(better[:, None, None, None], new_loc, loc)
            rt = torch.where(better[:, None], new_rt, rt)
            cost = torch.where(better, new_cost, cost)
            lam = torch.where(better, lam / 3.0, lam * 10.0)
        out_local.append(loc)
        out_root.append(rt)
    return torch.cat(out_local).reshape(local.shape), torch.cat(out_root).reshape(root.shape)


# --------------------------------------------------------------------- the fit
def fit_bodies(
    joints: np.ndarray,
    contacts: np.ndarray | None = None,
    floor: float | None = None,
    clean: Sequence[bool] | bool = True,
    bones: str = "fit",
    iterations: int = ITERATIONS,
    device: str | torch.device | None = None,
) -> Bodies:
    """Rigid bodies for N people's joints (N, T, 22, 3): see the module docstring.

    Args:
        joints: decoded (or given) positions, metres.
        contacts: (N, T, 4) contact labels (l_ankle, l_foot, r_ankle, r_foot); planted
            frames of people with ``clean`` pin that foot joint.
        floor: floor height for people with ``clean`` (None: no floor).
        clean: per person (or for all): pin planted feet and keep them off the floor.
        bones: ``"fit"`` (each person's mean decoded bone lengths) or ``"default"``.
        iterations: refinement steps (0: inverse kinematics only).
        device: where the inverse kinematics and refinement run (default the CPU). On a
            GPU, thousands of poses solve at once: fit many scenes' people in one call.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 4 or joints.shape[-2:] != (NUM_JOINTS, 3) or joints.shape[1] < 1:
        raise ValueError(f"expected joints (N, T, 22, 3), got {joints.shape}")
    if bones not in ("fit", "default"):
        raise ValueError(f"bones must be 'fit' or 'default', got {bones!r}")
    n = joints.shape[0]
    flags = [bool(clean)] * n if isinstance(clean, bool) else [bool(c) for c in clean]
    data = torch.from_numpy(joints).to(device or "cpu")
    if bones == "fit":
        offsets = torch.stack([fit_offsets(p) for p in data])
    else:
        offsets = default_offsets(torch.float64, data.device).expand(n, -1, -1).clone()
    local = inverse_kinematics(data, offsets[:, None])  # everybody at once
    root = data[:, :, 0].clone()
    targets, weights = [], []
    for i in range(n):
        use = flags[i]
        c = None if contacts is None or not use else np.asarray(contacts[i], dtype=np.float64)
        tg, wt = clean_targets(joints[i], c, floor if use else None)
        targets.append(tg)
        weights.append(wt)
    if iterations > 0:
        local, root = refine(local, root, offsets[:, None],
                             torch.from_numpy(np.stack(targets)).to(data.device),
                             torch.from_numpy(np.stack(weights)).to(data.device),
                             iterations)  # fmt: skip
    bodies = Bodies(offsets.cpu().numpy(), local.cpu().numpy(), root.cpu().numpy())
    if floor is not None and any(flags):
        lowest = bodies.joints()[..., 1].min(-1)  # (N, T)
        lift = np.maximum(floor - lowest, 0.0) * np.array(flags, dtype=np.float64)[:, None]
        bodies.root[..., 1] += lift
    return bodies
