"""glTF 2.0 binary (GLB) export: the whole scene, one animated, skinned skeleton per person.

Layout (``person1`` stands for each person's name; default ``person1``, ``person2``, ...):

- per person a scene root ``person1`` (no transform) holding the SMPL-22 joint nodes
  ``person1_pelvis`` ... ``person1_r_wrist`` in the ``umf.skeleton`` hierarchy; their rest
  translations are that person's fitted bone offsets and their rest rotations the identity
  (the T-pose), so the bind pose is the rest pose;
- per person a scene root ``person1_body`` with a skinned mesh (a box along every bone,
  rigidly bound to the bone's parent joint, a head and two hands) in the person's colour;
  skinned-mesh nodes are roots because glTF ignores their parents' transforms anyway;
- one skin per person (its 22 joints, inverse bind matrices of the T-pose);
- one animation, ``umf``, holding everybody's channels so all people play in sync: the
  pelvis translation and every joint's rotation at every frame, LINEAR samplers.

Offsets, rotations and the pelvis path are the scene's rigid bodies
(:class:`umf.kinematics.Bodies`), the same as in the BVH files, so forward kinematics of the
node hierarchy is ``scene.joints``. Units are metres and Y is up: glTF's own convention,
nothing is converted.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib.colors as mcolors
import numpy as np
import pygltflib as gl
import torch

from umf.errors import UMFError
from umf.io import atomic_path
from umf.kinematics import Bodies, fit_bodies
from umf.render import PALETTE
from umf.rotations import matrix_to_quat
from umf.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS, REST_DIRECTIONS
from umf.version import __version__

__all__ = [
    "ANIMATION_NAME",
    "body_mesh",
    "continuous_quaternions",
    "glb_bytes",
    "inverse_bind_matrices",
    "person_colour",
    "person_motion",
    "rest_positions",
    "scene_to_gltf",
    "write",
    "write_glb",
]

ANIMATION_NAME = "umf"

# Half sizes (m) across each bone, keyed by the bone's child joint: (along u, along v) of
# the bone frame built by `_bone_axes` (u is front-back for vertical and sideways bones,
# sideways for the feet). Bones not listed are limbs of _LIMB.
_LIMB = (0.035, 0.035)
_BONE_HALF: dict[int, tuple[float, float]] = {
    1: (0.07, 0.06), 2: (0.07, 0.06),      # pelvis -> hips
    3: (0.08, 0.12), 6: (0.08, 0.12),      # lower spine
    9: (0.09, 0.14),                       # chest
    12: (0.04, 0.04),                      # neck
    13: (0.05, 0.04), 14: (0.05, 0.04),    # collars
    4: (0.06, 0.06), 5: (0.06, 0.06),      # thighs
    7: (0.045, 0.045), 8: (0.045, 0.045),  # shins
    10: (0.045, 0.035), 11: (0.045, 0.035),  # feet
    18: (0.045, 0.045), 19: (0.045, 0.045),  # upper arms
}  # fmt: skip
_HEAD, _WRISTS = 15, (20, 21)
_HEAD_HALF = (0.1, 0.09, 0.08)  # up, front-back, sideways
_HEAD_LIFT = 0.07  # the head box's centre above the head joint
_HAND_LENGTH, _HAND_HALF = 0.09, (0.045, 0.015)  # along the forearm; (front-back, thickness)
_Box = tuple[int, np.ndarray, np.ndarray, np.ndarray]  # bound joint, centre, axes, half
_DARKEN_PER_ROUND = 0.3  # people beyond the palette reuse it, this much darker per round


# ----------------------------------------------------------------- motion
def continuous_quaternions(q: np.ndarray) -> np.ndarray:
    """Unit quaternions with signs flipped along time (axis 0) so consecutive keys share a
    hemisphere: q and -q are one rotation, but a player interpolating components (Blender's
    curves) would swing the long way round between two keys of opposite sign."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    negative = np.sum(q[1:] * q[:-1], axis=-1) < 0
    parity = np.cumsum(negative, axis=0) % 2
    sign = np.concatenate([np.ones_like(q[:1, ..., 0]), 1.0 - 2.0 * parity], axis=0)
    return q * sign[..., None]


def person_motion(bodies: Bodies, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Person ``i`` of ``bodies`` -> bone offsets (22, 3), local rotations (T, 22, 4) as
    glTF quaternions (x, y, z, w), sign-continuous, and the pelvis path (T, 3); float64."""
    wxyz = matrix_to_quat(torch.from_numpy(bodies.rotations[i])).numpy()
    xyzw = np.concatenate([wxyz[..., 1:], wxyz[..., :1]], axis=-1)
    return bodies.offsets[i], continuous_quaternions(xyzw), bodies.root[i]


def rest_positions(offsets: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Joint positions (22, 3) of the T-pose (all rotations identity), pelvis at ``root``."""
    pos = np.zeros((NUM_JOINTS, 3))
    pos[0] = root
    for j in range(1, NUM_JOINTS):
        pos[j] = pos[PARENTS[j]] + offsets[j]
    return pos


def inverse_bind_matrices(rest: np.ndarray) -> np.ndarray:
    """(22, 4, 4) inverses of the joints' T-pose world matrices (pure translations)."""
    ibm = np.tile(np.eye(4), (NUM_JOINTS, 1, 1))
    ibm[:, :3, 3] = -rest
    return ibm


# ----------------------------------------------------------------- body mesh
def _box(center: np.ndarray, axes: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, ...]:
    """A box with flat-shaded faces: positions (24, 3), normals (24, 3), indices (36,).

    ``axes`` (3, 3) are right-handed unit rows; ``half`` the half extents along them.
    Triangles wind counter-clockwise seen from outside, as glTF's front faces do.
    """
    pos, nrm, idx = [], [], []
    for k in range(3):
        for sign in (1.0, -1.0):
            n = sign * axes[k]
            t1, t2 = axes[(k + 1) % 3], axes[(k + 2) % 3]
            h1, h2 = half[(k + 1) % 3], half[(k + 2) % 3]
            if sign < 0:  # keep t1 x t2 = n so the winding faces outwards
                t1, t2, h1, h2 = t2, t1, h2, h1
            face = center + n * half[k]
            base = len(pos)
            for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                pos.append(face + a * h1 * t1 + b * h2 * t2)
                nrm.append(n)
            idx += [base, base + 1, base + 2, base, base + 2, base + 3]
    return np.array(pos), np.array(nrm), np.array(idx)


def _bone_axes(direction: np.ndarray) -> np.ndarray:
    """Right-handed unit rows (along, u, v) for a box along ``direction``; u is the part
    of +Z (the facing direction) across the bone, or +X for bones that point forwards."""
    a = direction / np.linalg.norm(direction)
    ref = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = ref - np.dot(ref, a) * a
    u /= np.linalg.norm(u)
    return np.stack([a, u, np.cross(a, u)])


def _body_boxes(offsets: np.ndarray, rest: np.ndarray) -> list[_Box]:
    """(bound joint, centre, axes, half extents) of every box of the T-pose body."""
    boxes = []
    for j in range(1, NUM_JOINTS):
        length = float(np.linalg.norm(offsets[j]))
        direction = offsets[j] if length > 1e-6 else np.asarray(REST_DIRECTIONS[j], float)
        axes = _bone_axes(direction)
        half = np.array([max(length / 2, 0.005), *_BONE_HALF.get(j, _LIMB)])
        boxes.append((PARENTS[j], rest[PARENTS[j]] + axes[0] * length / 2, axes, half))
    up_axes = np.array([[0.0, 1, 0], [0, 0, 1], [1, 0, 0]])
    boxes.append((_HEAD, rest[_HEAD] + [0.0, _HEAD_LIFT, 0.0], up_axes, np.array(_HEAD_HALF)))
    for w in _WRISTS:
        axes = _bone_axes(np.asarray(REST_DIRECTIONS[w], float))
        half = np.array([_HAND_LENGTH / 2, *_HAND_HALF])
        boxes.append((w, rest[w] + axes[0] * _HAND_LENGTH / 2, axes, half))
    return boxes


def body_mesh(offsets: np.ndarray, rest: np.ndarray) -> dict[str, np.ndarray]:
    """The T-pose body as one rigidly skinned triangle mesh, glTF-ready dtypes:
    POSITION, NORMAL (V, 3) float32, JOINTS_0 (V, 4) uint8, WEIGHTS_0 (V, 4) float32 and
    indices (I,) uint16. Each vertex follows one joint with weight 1."""
    pos, nrm, jnt, idx = [], [], [], []
    for joint, center, axes, half in _body_boxes(offsets, rest):
        p, n, i = _box(center, axes, half)
        idx.append(i + sum(len(x) for x in pos))
        pos.append(p)
        nrm.append(n)
        jnt.append(np.full(len(p), joint))
    joints = np.zeros((sum(len(p) for p in pos), 4), np.uint8)
    joints[:, 0] = np.concatenate(jnt)
    weights = np.zeros(joints.shape, np.float32)
    weights[:, 0] = 1.0
    return {
        "POSITION": np.concatenate(pos).astype(np.float32),
        "NORMAL": np.concatenate(nrm).astype(np.float32),
        "JOINTS_0": joints,
        "WEIGHTS_0": weights,
        "indices": np.concatenate(idx).astype(np.uint16),
    }


def person_colour(index: int) -> list[float]:
    """Linear RGBA base colour of person ``index`` (0-based): the renderer's palette, so a
    GLB and a GIF of one scene agree; people beyond the palette get darker rounds of it."""
    srgb = np.array(mcolors.to_rgb(PALETTE[index % len(PALETTE)]))
    srgb = srgb * max(1.0 - _DARKEN_PER_ROUND * (index // len(PALETTE)), 0.1)
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return [*(round(float(c), 6) for c in linear), 1.0]


# ----------------------------------------------------------------- binary packing
_COMPONENT = {np.dtype(np.float32): gl.FLOAT, np.dtype(np.uint16): gl.UNSIGNED_SHORT,
              np.dtype(np.uint8): gl.UNSIGNED_BYTE}  # fmt: skip
_TYPE = {1: gl.SCALAR, 3: gl.VEC3, 4: gl.VEC4, 16: gl.MAT4}


class _Packer:
    """Appends arrays to the one GLB buffer: a buffer view per accessor, 4-byte aligned, so
    no view needs a byteStride and every accessor is tightly packed."""

    def __init__(self, gltf: gl.GLTF2) -> None:
        self.gltf = gltf
        self.chunks: list[bytes] = []
        self.size = 0

    def add(self, array: np.ndarray, target: int | None = None, bounds: bool = False) -> int:
        """Accessor index of ``array`` (count, ...) with min/max when ``bounds``."""
        flat = np.ascontiguousarray(array).reshape(len(array), -1)
        data = flat.astype(flat.dtype.newbyteorder("<")).tobytes()
        self.gltf.bufferViews.append(
            gl.BufferView(buffer=0, byteOffset=self.size, byteLength=len(data), target=target)
        )
        pad = -len(data) % 4
        self.chunks += [data, b"\0" * pad]
        self.size += len(data) + pad
        kind = float if flat.dtype.kind == "f" else int
        self.gltf.accessors.append(
            gl.Accessor(
                bufferView=len(self.gltf.bufferViews) - 1,
                componentType=_COMPONENT[flat.dtype],
                count=len(flat),
                type=_TYPE[flat.shape[1]],
                min=[kind(v) for v in flat.min(axis=0)] if bounds else [],
                max=[kind(v) for v in flat.max(axis=0)] if bounds else [],
            )
        )
        return len(self.gltf.accessors) - 1

    def finish(self) -> None:
        blob = b"".join(self.chunks)
        self.gltf.buffers = [gl.Buffer(byteLength=len(blob))]
        self.gltf.set_binary_blob(blob)


# ----------------------------------------------------------------- the document
def _as_bodies(motion: Bodies | np.ndarray) -> Bodies:
    """Bodies as given, or fitted (plainly, no clean-up) to joints (N, T, 22, 3)."""
    if isinstance(motion, Bodies):
        return motion
    joints = np.asarray(motion, dtype=np.float64)
    if joints.ndim != 4 or joints.shape[2:] != (NUM_JOINTS, 3) or 0 in joints.shape[:2]:
        raise UMFError(f"glTF export needs joints (N, T, 22, 3), got {joints.shape}")
    if not np.isfinite(joints).all():
        raise UMFError("glTF export: the joints contain NaN or infinite values")
    return fit_bodies(joints, clean=False)


def _check_inputs(bodies: Bodies, fps: float, names: Sequence[str] | None) -> list[str]:
    if not (np.isfinite(fps) and fps > 0):
        raise UMFError(f"glTF export: fps must be positive, got {fps}")
    n = bodies.num_people
    names = [f"person{i + 1}" for i in range(n)] if names is None else [str(s) for s in names]
    if len(names) != n or len(set(names)) != n or not all(names):
        raise UMFError(f"glTF export needs {n} distinct, non-empty person names, got {names}")
    return names


def _float32_unit(q: np.ndarray) -> np.ndarray:
    """float32 quaternions renormalised after rounding (validators check unit length)."""
    q = q.astype(np.float32)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _add_person(
    gltf: gl.GLTF2, packer: _Packer, index: int, name: str, bodies: Bodies
) -> tuple[list[int], list[tuple[int, str, int]]]:
    """Nodes, material, mesh and skin of person ``index``; returns their scene roots and
    the animated (node, path, output accessor) triples."""
    offsets, quats, root = person_motion(bodies, index)
    rest = rest_positions(offsets, root[0])
    first = len(gltf.nodes)  # the person root; joint j is node first + 1 + j
    children: list[list[int]] = [[] for _ in range(NUM_JOINTS)]
    for j in range(1, NUM_JOINTS):
        children[PARENTS[j]].append(first + 1 + j)
    gltf.nodes.append(gl.Node(name=name, children=[first + 1]))
    for j, joint_name in enumerate(JOINT_NAMES):
        t = rest[0] if j == 0 else offsets[j]
        gltf.nodes.append(
            gl.Node(name=f"{name}_{joint_name}", translation=[float(v) for v in t],
                    children=children[j])
        )  # fmt: skip
    joint_nodes = list(range(first + 1, first + 1 + NUM_JOINTS))

    mesh = body_mesh(offsets, rest)
    attrs = {
        key: packer.add(mesh[key], gl.ARRAY_BUFFER, bounds=key == "POSITION")
        for key in ("POSITION", "NORMAL", "JOINTS_0", "WEIGHTS_0")
    }
    indices = packer.add(mesh["indices"], gl.ELEMENT_ARRAY_BUFFER)
    gltf.materials.append(
        gl.Material(
            name=f"{name}_material",
            pbrMetallicRoughness=gl.PbrMetallicRoughness(
                baseColorFactor=person_colour(index), metallicFactor=0.0, roughnessFactor=0.7
            ),
        )
    )
    primitive = gl.Primitive(
        attributes=gl.Attributes(**attrs), indices=indices, material=len(gltf.materials) - 1
    )
    gltf.meshes.append(gl.Mesh(name=f"{name}_body", primitives=[primitive]))
    ibm = inverse_bind_matrices(rest).transpose(0, 2, 1)  # glTF matrices are column-major
    gltf.skins.append(
        gl.Skin(
            name=name,
            inverseBindMatrices=packer.add(ibm.reshape(-1, 16).astype(np.float32)),
            skeleton=first,
            joints=joint_nodes,
        )
    )
    body = len(gltf.nodes)
    gltf.nodes.append(
        gl.Node(name=f"{name}_body", mesh=len(gltf.meshes) - 1, skin=len(gltf.skins) - 1)
    )

    quats = _float32_unit(quats)
    channels = [(joint_nodes[0], "translation", packer.add(root.astype(np.float32)))]
    channels += [
        (node, "rotation", packer.add(np.ascontiguousarray(quats[:, j])))
        for j, node in enumerate(joint_nodes)
    ]
    return [first, body], channels


def scene_to_gltf(
    motion: Bodies | np.ndarray,
    fps: float,
    names: Sequence[str] | None = None,
    text: str = "",
    extras: dict[str, Any] | None = None,
) -> gl.GLTF2:
    """A glTF document (binary buffer attached) of N people: rigid ``Bodies``, or joints
    (N, T, 22, 3), which are fitted first (bone lengths and inverse kinematics).

    ``names`` name the people (default ``person1``...); ``text`` (the prompt), fps, the
    names and ``extras`` (e.g. seed, model) are stored in ``asset.extras``.
    """
    bodies = _as_bodies(motion)
    names = _check_inputs(bodies, float(fps), names)
    gltf = gl.GLTF2(
        asset=gl.Asset(
            version="2.0",
            generator=f"umf {__version__}",
            extras={"text": text, "fps": float(fps), "people": names, **(extras or {})},
        )
    )
    packer = _Packer(gltf)
    times = (np.arange(bodies.num_frames) / float(fps)).astype(np.float32)
    time_accessor = packer.add(times, bounds=True)  # samplers' input needs min/max
    roots, channels = [], []
    for i, name in enumerate(names):
        person_roots, person_channels = _add_person(gltf, packer, i, name, bodies)
        roots += person_roots
        channels += person_channels
    gltf.animations.append(
        gl.Animation(
            name=ANIMATION_NAME,
            samplers=[
                gl.AnimationSampler(input=time_accessor, output=out, interpolation=gl.ANIM_LINEAR)
                for _, _, out in channels
            ],
            channels=[
                gl.AnimationChannel(sampler=k, target=gl.AnimationChannelTarget(node=n, path=p))
                for k, (n, p, _) in enumerate(channels)
            ],
        )
    )
    gltf.scenes.append(gl.Scene(name=text[:80] or "umf", nodes=roots))
    gltf.scene = 0
    packer.finish()
    return gltf


def glb_bytes(gltf: gl.GLTF2) -> bytes:
    """The GLB file of a document whose buffer is its attached binary blob."""
    return b"".join(gltf.save_to_bytes())


def write_glb(
    path: str | os.PathLike,
    motion: Bodies | np.ndarray,
    fps: float,
    names: Sequence[str] | None = None,
    text: str = "",
    extras: dict[str, Any] | None = None,
) -> Path:
    """Write bodies (or joints, fitted first) as a GLB atomically: a failure leaves no (or
    the old) file at ``path``."""
    gltf = scene_to_gltf(motion, fps, names=names, text=text, extras=extras)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        for chunk in gltf.save_to_bytes():
            fh.write(chunk)
    return Path(path)


def write(scene: Any, path: Path) -> list[Path]:
    """The scene's GLB (its bodies; prompt, fps, seed and model in ``asset.extras``)."""
    scene = scene.rigid()
    extras = {"seed": scene.seed, "model": scene.model}
    return [write_glb(path, scene.bodies, scene.fps, text=scene.text, extras=extras)]
