"""SMPL body poses (SMPL-H / AMASS-style ``.npz``), one file per person.

What a file holds (T frames, float32 unless said):

- ``poses`` (T, 156): axis-angle rotations of SMPL-H's 52 joints, SMPL's joint order: the
  22 body joints (joint 0, the pelvis, is the global orientation) then 30 hand joints,
  all zero (flat hands). SMPL's 24 joints are ``poses[:, :66]`` plus 6 zeros (its two
  hand joints); ``root_orient`` / ``pose_body`` / ``pose_hand`` hold the same numbers split
  the way AMASS' SMPL-X files do;
- ``trans`` (T, 3): SMPL's translation; ``betas`` (16,) zeros; ``gender`` "neutral";
  ``mocap_framerate`` (and AMASS' other spelling ``mocap_frame_rate``);
- ``joints`` (T, 22, 3): the scene's joints of this person, for checking.

Axes are SMPL's own (and umf's): Y up, the body faces +Z in the rest pose, its left is +X;
metres. (AMASS' released files live in a Z-up world: rotate by +90 degrees about X to
get there. In the SMPL-X Blender add-on, import with format "SMPL-X", not "AMASS".)

Rest pose. SMPL's rotations are relative to SMPL's template pose, not to umf's T-pose
(:mod:`umf.skeleton`), so each joint j gets a fixed rest correction C_j (a rotation taking
SMPL's rest bone directions onto ours) and SMPL's local rotation is
``C_parent^T @ R_local @ C_j`` (root: ``R_root @ C_0``). For a joint with one child C_j is
exact; the two branching joints (pelvis: hips and spine; spine3: neck and collars) get the
best rotation for their three children (Kabsch), and what it cannot match is the residual
of the mapping: the hips (and collars) sit a little differently around the pelvis (spine3)
in SMPL's template than in ours, and everything below them moves with them.
:func:`mapping_residual` measures it with SMPL's kinematic tree and our bone lengths.

``trans`` places SMPL's pelvis on ours: SMPL puts the pelvis at ``J_0 + trans`` with J_0
its template pelvis (betas 0), ``SMPL_PELVIS`` here; for another body (other betas, SMPL-X)
add ``SMPL_PELVIS - J_0(body)`` to ``trans``. Our bone lengths are not SMPL's, so an SMPL
mesh driven by these poses has SMPL's proportions (and its feet a few centimetres off the
floor or in it, as the heights differ); the rotations are the motion.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from umf.io import save_npz_atomic
from umf.kinematics import Bodies
from umf.rotations import matrix_to_axis_angle, quat_between, quat_to_matrix
from umf.skeleton import CHILDREN, NUM_JOINTS, PARENTS, global_rotations

__all__ = [
    "SMPL_OFFSETS",
    "SMPL_PELVIS",
    "mapping_residual",
    "rest_corrections",
    "smpl_pose",
    "smpl_tree_joints",
    "write",
]

NUM_SMPLH_JOINTS = 52
# Rest offsets (m) of SMPL's template (betas 0) from each joint's parent, SMPL's 24 joints
# (0-21 are umf's 22; 22, 23 the hands), Y up, facing +Z, the body's left +X: the SMPL
# model's joint regressor on its template, as published with many SMPL tools, to 0.1 mm.
SMPL_OFFSETS = np.array([
    [0.0, 0.0, 0.0],
    [0.0586, -0.0823, -0.0177], [-0.0603, -0.0905, -0.0135], [0.0044, 0.1244, -0.0384],
    [0.0435, -0.3865, 0.0080], [-0.0433, -0.3837, -0.0048], [0.0045, 0.1380, 0.0268],
    [-0.0148, -0.4269, -0.0374], [0.0191, -0.4200, -0.0346], [-0.0023, 0.0560, 0.0029],
    [0.0411, -0.0603, 0.1220], [-0.0348, -0.0621, 0.1303], [-0.0134, 0.2116, -0.0335],
    [0.0717, 0.1140, -0.0189], [-0.0830, 0.1125, -0.0237], [0.0101, 0.0889, 0.0504],
    [0.1229, 0.0452, -0.0190], [-0.1132, 0.0469, -0.0085], [0.2553, -0.0156, -0.0229],
    [-0.2601, -0.0144, -0.0313], [0.2657, 0.0127, -0.0074], [-0.2691, 0.0068, -0.0060],
    [0.0867, -0.0106, -0.0156], [-0.0888, -0.0087, -0.0101],
])  # fmt: skip
SMPL_PELVIS = np.array([-0.0018, -0.2233, 0.0282])  # J_0: SMPL's template pelvis (betas 0)


def _kabsch(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Rotation R (3, 3) minimising sum |R @ source_i - target_i|^2 over rows (K, 3)."""
    u, _, vt = np.linalg.svd(source.T @ target)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def smpl_directions(offsets: np.ndarray) -> np.ndarray:
    """SMPL's rest offsets (22, 3) with our bone lengths (``offsets`` (22, 3))."""
    smpl = SMPL_OFFSETS[:NUM_JOINTS]
    norm = np.linalg.norm(smpl, axis=-1, keepdims=True)
    unit = np.divide(smpl, norm, out=np.zeros_like(smpl), where=norm > 0)
    return unit * np.linalg.norm(offsets, axis=-1, keepdims=True)


def rest_corrections(offsets: np.ndarray) -> np.ndarray:
    """C_j (22, 3, 3): rotations taking SMPL's rest bone directions onto ours (``offsets``,
    (22, 3), one person), so that G_j @ C_j is joint j's global rotation in SMPL's terms.

    One child: the shortest arc between the two directions (exact). Several children: the
    best rotation for all of them (Kabsch). Leaves take their parent's, so a leaf that
    does not turn against its parent in umf does not in SMPL either.
    """
    smpl = smpl_directions(offsets)
    out = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
    for j in range(NUM_JOINTS):
        kids = CHILDREN[j]
        if len(kids) == 1:
            q = quat_between(torch.from_numpy(smpl[kids[0]]), torch.from_numpy(offsets[kids[0]]))
            out[j] = quat_to_matrix(q).numpy()
        elif kids:
            out[j] = _kabsch(smpl[list(kids)], offsets[list(kids)])
        else:
            out[j] = out[PARENTS[j]]
    return out


def smpl_pose(bodies: Bodies, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Person ``i`` as SMPL parameters: local rotation matrices (T, 22, 3, 3) relative to
    SMPL's rest pose, and ``trans`` (T, 3) (float64)."""
    corr = rest_corrections(bodies.offsets[i])
    local = bodies.rotations[i]
    parent = corr[[max(p, 0) for p in PARENTS]]
    smpl = parent.transpose(0, 2, 1)[None] @ local @ corr[None]
    smpl[:, 0] = local[:, 0] @ corr[0]
    return smpl, bodies.root[i] - SMPL_PELVIS


def smpl_tree_joints(rotations: np.ndarray, trans: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Joints (T, 22, 3) of SMPL's kinematic tree: local rotations (T, 22, 3, 3) relative
    to SMPL's rest pose, ``trans`` (T, 3) and rest offsets ``rest`` (22, 3) (pelvis at
    SMPL_PELVIS + trans)."""
    glob = global_rotations(torch.from_numpy(rotations)).numpy()
    pos = np.zeros((*rotations.shape[:-3], NUM_JOINTS, 3))
    pos[..., 0, :] = SMPL_PELVIS + trans
    for j in range(1, NUM_JOINTS):
        p = PARENTS[j]
        pos[..., j, :] = pos[..., p, :] + glob[..., p, :, :] @ rest[j]
    return pos


def mapping_residual(bodies: Bodies, i: int) -> np.ndarray:
    """Per frame and joint, the distance (T, 22) between SMPL's kinematic tree posed by
    person ``i``'s SMPL parameters, with our bone lengths on SMPL's rest directions, and
    that person's joints: what the rotation mapping cannot express."""
    rot, trans = smpl_pose(bodies, i)
    ours = bodies.person(i).joints()[0]
    tree = smpl_tree_joints(rot, trans, smpl_directions(bodies.offsets[i]))
    return np.linalg.norm(tree - ours, axis=-1)


def person_arrays(bodies: Bodies, i: int, fps: float) -> dict[str, np.ndarray]:
    """Every array of person ``i``'s SMPL file."""
    rot, trans = smpl_pose(bodies, i)
    body = matrix_to_axis_angle(torch.from_numpy(rot)).numpy().reshape(len(rot), -1)
    poses = np.zeros((len(rot), 3 * NUM_SMPLH_JOINTS))
    poses[:, : body.shape[1]] = body
    return {
        "poses": poses.astype(np.float32),
        "root_orient": poses[:, :3].astype(np.float32),
        "pose_body": poses[:, 3:66].astype(np.float32),
        "pose_hand": poses[:, 66:].astype(np.float32),
        "trans": trans.astype(np.float32),
        "betas": np.zeros(16, np.float32),
        "gender": np.array("neutral"),
        "surface_model_type": np.array("smplh"),
        "mocap_framerate": np.array(float(fps)),
        "mocap_frame_rate": np.array(float(fps)),
        "joints": bodies.person(i).joints()[0].astype(np.float32),
    }


def write(scene: Any, pattern: Path) -> list[Path]:
    """One SMPL ``.npz`` per person; ``{i}`` in the file name is the person number."""
    from umf.exports.bvh import person_path

    bodies = scene.rigid().bodies
    out = []
    for i in range(bodies.num_people):
        path = person_path(Path(pattern), i + 1)
        arrays = person_arrays(bodies, i, scene.fps)
        arrays["text"] = np.array(scene.text)
        save_npz_atomic(path, **arrays)
        out.append(path)
    return out
