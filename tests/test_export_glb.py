"""GLB export, read back independently: pygltflib parses the file, numpy decodes the
accessors, scipy's quaternions (x, y, z, w like glTF) drive a forward kinematics written
here, and the Khronos glTF-Validator checks the file when node and the npm package exist."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from scipy.spatial.transform import Rotation

from conftest import MODULE
from umf.errors import UMFError
from umf.exports.gltf import write_glb
from umf.pipeline import Scene
from umf.skeleton import DEFAULT_OFFSETS, JOINT_NAMES

REPO = Path(__file__).resolve().parents[1]
VALIDATOR_ENV = "UMF_GLTF_VALIDATOR"
DEFAULT_VALIDATOR = REPO / ".venv" / "node" / "node_modules" / "gltf-validator"
FPS = 30.0

_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
           5126: np.float32}  # fmt: skip
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


# ----------------------------------------------------------------- an independent reader
def accessor(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    """Accessor ``index`` as (count, width) numpy, honouring offsets and byteStride."""
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    dtype = np.dtype(_DTYPES[acc.componentType]).newbyteorder("<")
    width = _WIDTH[acc.type]
    start = (view.byteOffset or 0) + (acc.byteOffset or 0)
    stride = view.byteStride or dtype.itemsize * width
    blob = gltf.binary_blob()
    rows = [np.frombuffer(blob, dtype, width, start + k * stride) for k in range(acc.count)]
    return np.array(rows).reshape(acc.count, width)


def node_parents(gltf: pygltflib.GLTF2) -> dict[int, int]:
    return {c: p for p, node in enumerate(gltf.nodes) for c in node.children or []}


def world_matrices(gltf: pygltflib.GLTF2, animate: bool = True) -> np.ndarray:
    """(T, nodes, 4, 4) world matrices of every node at every key of animation 0, or
    (1, nodes, 4, 4) of the rest pose (the nodes' own transforms) without ``animate``."""
    anim = gltf.animations[0]
    times = accessor(gltf, anim.samplers[0].input)[:, 0] if animate else np.zeros(1)
    num_frames, num_nodes = len(times), len(gltf.nodes)
    trans = np.zeros((num_frames, num_nodes, 3))
    quat = np.zeros((num_frames, num_nodes, 4))
    quat[..., 3] = 1.0
    for n, node in enumerate(gltf.nodes):
        assert node.matrix is None and node.scale is None
        if node.translation is not None:
            trans[:, n] = node.translation
        if node.rotation is not None:
            quat[:, n] = node.rotation
    for channel in anim.channels if animate else []:
        sampler = anim.samplers[channel.sampler]
        assert np.array_equal(accessor(gltf, sampler.input)[:, 0], times)
        values = accessor(gltf, sampler.output)
        target = channel.target
        if target.path == "translation":
            trans[:, target.node] = values
        else:
            assert target.path == "rotation"
            quat[:, target.node] = values
    local = np.tile(np.eye(4), (num_frames, num_nodes, 1, 1))
    local[..., :3, :3] = (
        Rotation.from_quat(quat.reshape(-1, 4)).as_matrix().reshape(num_frames, num_nodes, 3, 3)
    )
    local[..., :3, 3] = trans
    parents = node_parents(gltf)
    world = np.zeros_like(local)
    done: set[int] = set()

    def visit(n: int) -> None:
        if n in done:
            return
        if n in parents:
            visit(parents[n])
            world[:, n] = world[:, parents[n]] @ local[:, n]
        else:
            world[:, n] = local[:, n]
        done.add(n)

    for n in range(num_nodes):
        visit(n)
    return world


def skin_joint_positions(gltf: pygltflib.GLTF2) -> np.ndarray:
    """(N, T, 22, 3) world positions of every skin's joints at every key."""
    world = world_matrices(gltf)
    return np.stack([world[:, skin.joints][..., :3, 3] for skin in gltf.skins])


# ----------------------------------------------------------------- real scenes
def _yaw(joints: np.ndarray, degrees: float) -> np.ndarray:
    return joints @ Rotation.from_euler("y", degrees, degrees=True).as_matrix().T


def real_scene(real_joints, bandai_clips, people: int) -> np.ndarray:
    """(people, 100, 22, 3): a real walk and other real clips, metres apart, turned."""
    clips = {c.id: c.joints[0] for c in bandai_clips}
    motions = [
        real_joints.numpy()[:100],
        _yaw(clips["dataset-1_kick_normal_001"][:100], 90.0) + np.array([6.0, 0.0, 0.0]),
        _yaw(clips["dataset-2_wave-right-hand_normal_001"][:100], -135.0)
        + np.array([-5.0, 0.0, 8.0]),
    ]
    return np.stack(motions[:people])


@pytest.fixture(scope=MODULE)
def scene3(real_joints, bandai_clips) -> Scene:
    joints = real_scene(real_joints, bandai_clips, 3).astype(np.float32)
    return Scene(joints, np.zeros((3, 100, 262), np.float32), "three people: walk, kick, wave",
                 FPS, seed=7, model="test-model")  # fmt: skip


@pytest.fixture(scope=MODULE)
def glb3(scene3, tmp_path_factory) -> Path:
    return scene3.save_glb(tmp_path_factory.mktemp("glb") / "three.glb")


@pytest.mark.parametrize("people", [2, 3])
def test_forward_kinematics_reproduces_real_joints(real_joints, bandai_clips, tmp_path, people):
    joints = real_scene(real_joints, bandai_clips, people)
    path = write_glb(tmp_path / "scene.glb", joints, FPS, text="people far apart")
    gltf = pygltflib.GLTF2().load_binary(path)
    got = skin_joint_positions(gltf)
    assert got.shape == joints.shape
    err = np.linalg.norm(got - joints, axis=-1)
    assert err.max() < 5e-6, err.max()  # the plain fit and float32 storage: 0.0003-0.0005 mm


def test_structure(glb3, scene3):
    gltf = pygltflib.GLTF2().load_binary(glb3)
    n, t = scene3.num_people, scene3.num_frames
    assert gltf.asset.version == "2.0"
    assert gltf.asset.generator.startswith("umf ")
    assert gltf.asset.extras["text"] == scene3.text
    assert gltf.asset.extras["seed"] == 7 and gltf.asset.extras["people"] == [
        f"person{i + 1}" for i in range(n)
    ]
    assert len(gltf.skins) == len(gltf.meshes) == n == 3
    for i, skin in enumerate(gltf.skins):
        names = [gltf.nodes[j].name for j in skin.joints]
        assert names == [f"person{i + 1}_{name}" for name in JOINT_NAMES]
        assert gltf.nodes[skin.skeleton].name == f"person{i + 1}"
    roots = set(gltf.scenes[gltf.scene].nodes)
    assert {gltf.nodes[r].name for r in roots} == {
        f"person{i + 1}{suffix}" for i in range(n) for suffix in ("", "_body")
    }
    assert set(node_parents(gltf)).isdisjoint(roots)
    assert len(gltf.animations) == 1
    anim = gltf.animations[0]
    assert anim.name == "umf"
    assert len(anim.channels) == n * 23  # pelvis translation + 22 rotations per person
    assert {s.interpolation for s in anim.samplers} == {"LINEAR"}
    time_acc = gltf.accessors[anim.samplers[0].input]
    times = accessor(gltf, anim.samplers[0].input)[:, 0]
    np.testing.assert_allclose(times, np.arange(t) / FPS, rtol=0, atol=1e-6)
    assert time_acc.min == [float(times[0])] and time_acc.max == [float(times[-1])]
    for sampler in anim.samplers:
        out = accessor(gltf, sampler.output)
        assert len(out) == t
        if out.shape[1] == 4:  # unit quaternions, consecutive keys in one hemisphere
            np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0, atol=1e-6)
            assert (np.sum(out[1:] * out[:-1], axis=1) >= 0).all()
    colours = {tuple(m.pbrMetallicRoughness.baseColorFactor) for m in gltf.materials}
    assert len(colours) == n


def test_skin_follows_the_skeleton(glb3, scene3):
    """Inverse bind matrices undo the rest pose, so the skinned body stays on its own
    person's joints at every frame (a wrong or missing bind matrix moves it metres away)."""
    gltf = pygltflib.GLTF2().load_binary(glb3)
    world = world_matrices(gltf)
    rest = world_matrices(gltf, animate=False)[0]
    for i, skin in enumerate(gltf.skins):
        ibm = accessor(gltf, skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1)
        np.testing.assert_allclose(ibm @ rest[skin.joints], np.tile(np.eye(4), (22, 1, 1)),
                                   atol=1e-6)  # fmt: skip
        node = next(nd for nd in gltf.nodes if nd.skin == i)
        prim = gltf.meshes[node.mesh].primitives[0]
        pos = accessor(gltf, prim.attributes.POSITION)
        acc = gltf.accessors[prim.attributes.POSITION]
        np.testing.assert_array_equal(acc.min, pos.min(0))
        np.testing.assert_array_equal(acc.max, pos.max(0))
        tri = accessor(gltf, prim.indices)[:, 0].reshape(-1, 3)
        a, b, c = pos[tri[:, 0]], pos[tri[:, 1]], pos[tri[:, 2]]
        facing = np.einsum(
            "ij,ij->i", np.cross(b - a, c - a), accessor(gltf, prim.attributes.NORMAL)[tri[:, 0]]
        )
        assert (facing > 0).all()  # counter-clockwise seen from outside: front faces
        joints = accessor(gltf, prim.attributes.JOINTS_0)
        weights = accessor(gltf, prim.attributes.WEIGHTS_0)
        np.testing.assert_allclose(weights.sum(1), 1.0)
        skin_mats = world[:, skin.joints] @ ibm  # (T, 22, 4, 4)
        homog = np.concatenate([pos, np.ones((len(pos), 1))], axis=1)
        blend = np.einsum("vk,tvkab->tvab", weights, skin_mats[:, joints])
        verts = np.einsum("tvab,vb->tva", blend, homog)[..., :3]
        target = scene3.joints[i]  # (T, 22, 3)
        nearest = np.linalg.norm(verts[:, :, None] - target[:, None], axis=-1).min(-1)
        assert nearest.max() < 0.25, nearest.max()


def _validator_package() -> Path | None:
    """The gltf-validator npm package: $UMF_GLTF_VALIDATOR (the package folder or an npm
    prefix holding node_modules/gltf-validator), else .venv/node from the Makefile."""
    root = Path(os.environ.get(VALIDATOR_ENV, DEFAULT_VALIDATOR))
    for candidate in (root, root / "node_modules" / "gltf-validator"):
        manifest = candidate / "package.json"
        if manifest.is_file() and json.loads(manifest.read_text()).get("name") == "gltf-validator":
            return candidate
    return None


_VALIDATE_JS = """
const fs = require("fs");
const validator = require(process.argv[2]);
validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[3])), {maxIssues: 0})
  .then((report) => console.log(JSON.stringify(report)))
  .catch((error) => { console.error(String(error)); process.exit(2); });
"""


def test_khronos_validator(glb3, tmp_path):
    node = shutil.which("node")
    package = _validator_package()
    if node is None or package is None:
        pytest.skip(
            f"Khronos glTF-Validator not available (node: {node}, package: {package}); "
            f"install it with `npm install --prefix .venv/node gltf-validator` "
            f"or point {VALIDATOR_ENV} at it"
        )
    script = tmp_path / "validate.js"
    script.write_text(_VALIDATE_JS)
    run = subprocess.run(
        [node, str(script), str(package.resolve()), str(glb3)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    issues = report["issues"]
    summary = [(m["code"], m["severity"], m.get("pointer")) for m in issues["messages"]]
    print(f"gltf-validator {report['validatorVersion']}: {issues['numErrors']} errors, "
          f"{issues['numWarnings']} warnings, {issues['numInfos']} infos")  # fmt: skip
    assert issues["numErrors"] == 0, summary
    assert issues["numWarnings"] == 0, summary
    assert report["info"]["animationCount"] == 1 and report["info"]["hasSkins"]


def test_failed_write_leaves_no_file(real_joints, tmp_path, monkeypatch):
    joints = real_joints.numpy()[None, :40]
    dest = tmp_path / "out.glb"

    def half_then_fail(self):
        return [b"glTF", b"\x02\x00\x00\x00", None]  # writing None raises mid-file

    monkeypatch.setattr(pygltflib.GLTF2, "save_to_bytes", half_then_fail)
    with pytest.raises(TypeError):
        write_glb(dest, joints, FPS)
    assert list(tmp_path.iterdir()) == []
    dest.write_bytes(b"old")
    with pytest.raises(TypeError):
        write_glb(dest, joints, FPS)
    assert dest.read_bytes() == b"old" and list(tmp_path.iterdir()) == [dest]


@pytest.mark.parametrize(
    ("shape", "fps", "names", "message"),
    [((2, 10, 21, 3), 30.0, None, r"needs joints \(N, T, 22, 3\), got \(2, 10, 21, 3\)"),
     ((0, 10, 22, 3), 30.0, None, r"needs joints \(N, T, 22, 3\), got \(0, 10, 22, 3\)"),
     ((1, 0, 22, 3), 30.0, None, r"needs joints \(N, T, 22, 3\), got \(1, 0, 22, 3\)"),
     ((1, 10, 22, 3), 0.0, None, "fps must be positive, got 0.0"),
     ((1, 10, 22, 3), float("nan"), None, "fps must be positive, got nan"),
     ((2, 10, 22, 3), 30.0, ["a", "a"], "needs 2 distinct, non-empty person names"),
     ((2, 10, 22, 3), 30.0, ["a"], "needs 2 distinct, non-empty person names"),
     ((1, 10, 22, 3), 30.0, "nan", "NaN or infinite values")],
)  # fmt: skip
def test_bad_inputs_are_one_line_errors(tmp_path, shape, fps, names, message):
    joints = np.zeros(shape)
    if names == "nan":
        joints[0, 3, 5, 1], names = np.nan, None
    with pytest.raises(UMFError, match=message) as err:
        write_glb(tmp_path / "bad.glb", joints, fps, names=names)
    assert "\n" not in str(err.value) and str(err.value).startswith("glTF export")
    assert not (tmp_path / "bad.glb").exists()


# ----------------------------------------------------------------- the body mesh
def _person_mesh(gltf: pygltflib.GLTF2, i: int):
    """Person ``i``'s body: positions, normals, joint of each vertex, triangles, and the
    rest-pose world positions of its 22 joints."""
    node = next(nd for nd in gltf.nodes if nd.skin == i)
    prim = gltf.meshes[node.mesh].primitives[0]
    attr = prim.attributes
    joints, weights = accessor(gltf, attr.JOINTS_0), accessor(gltf, attr.WEIGHTS_0)
    np.testing.assert_array_equal(weights[:, 0], 1.0)  # rigid: one joint, weight 1
    np.testing.assert_array_equal(weights[:, 1:], 0.0)
    np.testing.assert_array_equal(joints[:, 1:], 0)
    rest = world_matrices(gltf, animate=False)[0][gltf.skins[i].joints][:, :3, 3]
    tri = accessor(gltf, prim.indices)[:, 0].reshape(-1, 3)
    return (accessor(gltf, attr.POSITION).astype(np.float64), accessor(gltf, attr.NORMAL),
            joints[:, 0], tri, rest)  # fmt: skip


def _boxes(pos, nrm, jnt, tri):
    """Split the mesh into its boxes (24 vertices, 12 triangles each) and measure each one
    from its vertices alone: (joint, centre, axes (3, 3), lengths (3,)). Checks on the way
    that each is a closed, outward-wound box."""
    assert len(pos) % 24 == 0 and len(tri) == len(pos) // 2
    out = []
    for b in range(len(pos) // 24):
        v, t = slice(24 * b, 24 * b + 24), tri[12 * b : 12 * b + 12]
        assert ((t >= 24 * b) & (t < 24 * b + 24)).all()
        assert len(set(jnt[v])) == 1  # a box moves with one joint
        normals = np.unique(np.round(nrm[v].astype(np.float64), 4), axis=0)
        assert len(normals) == 6
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-4)
        axes = _three_axes(normals / np.linalg.norm(normals, axis=1, keepdims=True))
        np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-4)  # a rectangular box
        proj = pos[v] @ axes.T
        lo, hi = proj.min(0), proj.max(0)
        assert np.all(np.isclose(proj, lo, atol=1e-5) | np.isclose(proj, hi, atol=1e-5))
        corners = np.unique(np.round(pos[v], 5), axis=0)
        assert len(corners) == 8
        keys = [tuple(np.round(p, 5)) for p in pos]  # faces share positions, not vertices
        edges = [(keys[a], keys[c]) for x in t for a, c in ((x[0], x[1]), (x[1], x[2]),
                                                             (x[2], x[0]))]  # fmt: skip
        assert sorted(edges) == sorted((c, a) for a, c in edges)  # closed: each edge twice,
        assert len(set(edges)) == len(edges)  # once each way
        a, c, d = pos[t[:, 0]], pos[t[:, 1]], pos[t[:, 2]]
        volume = np.einsum("ij,ij->i", a, np.cross(c, d)).sum() / 6  # divergence theorem
        np.testing.assert_allclose(volume, np.prod(hi - lo), rtol=1e-3)  # > 0: outward
        out.append((int(jnt[24 * b]), pos[v].mean(0), axes, hi - lo))  # 3 faces per corner
    return out


def _three_axes(normals: np.ndarray) -> np.ndarray:
    """One normal of each opposite pair."""
    axes: list[np.ndarray] = []
    for n in normals:
        if not any(np.allclose(n, -m, atol=1e-3) for m in axes):
            axes.append(n)
    assert len(axes) == 3
    return np.array(axes)


def test_body_is_a_box_per_bone_head_and_hand(glb3):
    """Each bone's box runs from its parent joint to its child and moves with the parent;
    the head box sits above the head joint, each hand box beyond its wrist, and every box
    is a closed, outward-wound box of human size."""
    gltf = pygltflib.GLTF2().load_binary(glb3)
    parents = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
    for i in range(len(gltf.skins)):
        pos, nrm, jnt, tri, rest = _person_mesh(gltf, i)
        boxes = _boxes(pos, nrm, jnt, tri)
        assert len(boxes) == 21 + 1 + 2
        for j in range(1, 22):  # one box per bone, found by where it is
            bone = rest[j] - rest[parents[j]]
            mid = (rest[j] + rest[parents[j]]) / 2
            found = [b for b in boxes if np.linalg.norm(b[1] - mid) < 1e-4]
            assert len(found) == 1, (i, j)
            joint, _, axes, lengths = found[0]
            assert joint == parents[j]
            along = np.argmax(np.abs(axes @ bone))
            np.testing.assert_allclose(abs(axes[along] @ bone), np.linalg.norm(bone), atol=1e-5)
            np.testing.assert_allclose(lengths[along], np.linalg.norm(bone), atol=1e-4)
            across = np.delete(lengths, along)
            assert ((across > 0.05) & (across < 0.3)).all(), (j, across)  # 5-30 cm thick
        head = [b for b in boxes if b[0] == 15]
        assert len(head) == 1
        _, centre, axes, lengths = head[0]
        np.testing.assert_allclose(np.abs(axes), np.eye(3)[np.argmax(np.abs(axes), 1)],
                                   atol=1e-6)  # fmt: skip
        lift = centre - rest[15]
        np.testing.assert_allclose(lift[[0, 2]], 0.0, atol=1e-5)
        assert 0.03 < lift[1] < 0.12  # above the head joint, which it contains
        size = lengths[np.argmax(np.abs(axes), 1).argsort()]  # x, y, z
        assert ((size > 0.12) & (size < 0.3)).all() and size[1] == size.max()  # tallest
        for w, side in ((20, 1.0), (21, -1.0)):  # l_wrist on +x in the T-pose
            hand = [b for b in boxes if b[0] == w]
            assert len(hand) == 1
            _, centre, axes, lengths = hand[0]
            along = np.argmax(np.abs(axes[:, 0]))
            np.testing.assert_allclose(abs(axes[along, 0]), 1.0, atol=1e-6)
            np.testing.assert_allclose(lengths[along], 0.09, atol=1e-5)  # 9 cm long
            np.testing.assert_allclose(centre - rest[w], [side * 0.045, 0, 0], atol=1e-5)
            assert 0.01 < np.delete(lengths, along).min() < 0.05  # flat: a palm, not a cube


def _mesh_boxes(offsets: np.ndarray):
    """The boxes (``_boxes``) of body_mesh for bone offsets (22, 3), pelvis at the origin,
    and the rest positions of the joints."""
    from umf.exports.gltf import body_mesh, rest_positions

    rest = rest_positions(offsets, np.zeros(3))
    mesh = body_mesh(offsets, rest)
    for key in ("POSITION", "NORMAL"):
        assert mesh[key].dtype == np.float32 and np.isfinite(mesh[key]).all()
    boxes = _boxes(mesh["POSITION"].astype(np.float64), mesh["NORMAL"], mesh["JOINTS_0"][:, 0],
                   mesh["indices"].reshape(-1, 3))  # fmt: skip
    return boxes, rest


def _bone_box(boxes, rest, offsets, j):
    """(centre, axes, lengths) of bone j's box, found by where it is (the bone's middle)."""
    parents = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
    mid = rest[parents[j]] + offsets[j] / 2
    found = [b for b in boxes if np.linalg.norm(b[1] - mid) < 1e-5]
    assert len(found) == 1 and found[0][0] == parents[j], j
    return found[0][1:]


def _extent(axes: np.ndarray, lengths: np.ndarray, direction) -> float:
    """The box's size along ``direction``, which must be one of its axes."""
    k = np.argmax(np.abs(axes @ direction))
    np.testing.assert_allclose(abs(axes[k] @ direction), np.linalg.norm(direction), atol=1e-6)
    return float(lengths[k])


def test_boxes_are_shaped_and_turned_like_a_body():
    """Across a vertical bone the box is deep front to back and wide sideways (the chest
    18 x 28 cm, the lower spine 16 x 24), limbs are 7 cm thick; a foot pointing forwards
    and down is square to the body, 9 cm wide sideways."""
    offsets = np.array(DEFAULT_OFFSETS, dtype=np.float64)
    offsets[10] = [0.0, -0.04, 0.11]  # the left foot: forwards and down
    boxes, rest = _mesh_boxes(offsets)
    x, y, z = np.eye(3)
    for j, deep, wide in ((9, 0.18, 0.28), (3, 0.16, 0.24), (20, 0.07, 0.07)):
        _, axes, lengths = _bone_box(boxes, rest, offsets, j)
        along = y if j != 20 else x  # the chest and spine stand up, the forearm points out
        np.testing.assert_allclose(_extent(axes, lengths, along), np.linalg.norm(offsets[j]),
                                   atol=1e-5)  # fmt: skip
        np.testing.assert_allclose(_extent(axes, lengths, z), deep, atol=1e-5)
        np.testing.assert_allclose(_extent(axes, lengths, np.cross(along, z)), wide, atol=1e-5)
    _, axes, lengths = _bone_box(boxes, rest, offsets, 10)
    foot = np.linalg.norm(offsets[10])
    np.testing.assert_allclose(_extent(axes, lengths, offsets[10] / foot), foot, atol=1e-5)
    np.testing.assert_allclose(_extent(axes, lengths, x), 0.09, atol=1e-5)


@pytest.mark.parametrize("length", [0.0, 1e-6])
def test_a_bone_without_length_gets_a_box_along_its_rest_direction(length):
    """A bone of a micrometre or less has no direction of its own: its box lies along the
    T-pose's (the thigh's: down), 1 cm long and as thick as a thigh."""
    offsets = np.array(DEFAULT_OFFSETS, dtype=np.float64)
    offsets[4] = [length, 0.0, 0.0]  # the left thigh (hip -> knee), squashed sideways
    boxes, rest = _mesh_boxes(offsets)
    _, axes, lengths = _bone_box(boxes, rest, offsets, 4)
    np.testing.assert_allclose(_extent(axes, lengths, [0.0, -1.0, 0.0]), 0.01, atol=1e-6)
    np.testing.assert_allclose(np.sort(lengths)[1:], [0.12, 0.12], atol=1e-6)


def test_packer_aligns_every_view_whatever_the_array_size():
    """The one buffer's views start 4-byte aligned, each right after the one before, the
    gaps zero bytes; the buffer's length is the blob's; min/max only where asked for, and
    integers for integer arrays."""
    from umf.exports.gltf import _Packer

    gltf = pygltflib.GLTF2()
    packer = _Packer(gltf)
    arrays = [np.array([[1], [7], [3]], np.uint8),  # 3 bytes: 1 of padding
              np.array([[0.5, -2.0, 4.0]], np.float32),
              np.arange(5, dtype=np.uint16)[:, None],  # 10 bytes: 2 of padding
              np.array([[1.0, 2.0, 3.0, 4.0]], np.float32)]  # fmt: skip
    bounds = [True, False, True, False]
    index = [packer.add(a, bounds=b) for a, b in zip(arrays, bounds, strict=True)]
    packer.finish()
    blob = gltf.binary_blob()
    views = [(v.byteOffset, v.byteLength) for v in gltf.bufferViews]
    assert views == [(0, 3), (4, 12), (16, 10), (28, 16)]
    assert gltf.buffers[0].byteLength == len(blob) == 44
    assert blob[3:4] == b"\0" and blob[26:28] == b"\0\0"
    for k, array, bounded in zip(index, arrays, bounds, strict=True):
        np.testing.assert_array_equal(accessor(gltf, k), array)
        acc = gltf.accessors[k]
        if bounded:
            assert acc.min == array.min(0).tolist() and acc.max == array.max(0).tolist()
            assert all(isinstance(v, int) for v in acc.min + acc.max)
        else:
            assert not acc.min and not acc.max


def test_rotation_keys_are_renormalised_in_float32():
    from umf.exports.gltf import _float32_unit

    out = _float32_unit(np.array([[0.0, 0.0, 0.6, 0.8], [1.0, 1.0, 1.0, 1.0]]) * 3.0)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out, [[0.0, 0.0, 0.6, 0.8], [0.5, 0.5, 0.5, 0.5]], atol=1e-7)


def test_joints_as_nested_lists_with_a_gap_are_the_nan_error(tmp_path):
    """Joints may come as nested lists (as JSON gives them): a missing value (None, JSON's
    null) is refused like NaN, in one line."""
    joints = np.zeros((1, 3, 22, 3)).tolist()
    joints[0][1][4][2] = None
    with pytest.raises(UMFError, match="NaN or infinite values"):
        write_glb(tmp_path / "gap.glb", joints, FPS)
    assert not (tmp_path / "gap.glb").exists()


def test_materials_are_matte_in_the_renders_colours(real_joints, tmp_path):
    """Person k's material is matte in the GIF's colour k; past the 12-colour palette the
    colours come round again, 30 % darker per round (never black)."""
    import matplotlib.colors as mcolors

    from umf.render import PALETTE

    people = 16  # past the palette, darker: #ff7f0e's blue channel takes the linear branch
    joints = np.stack([real_joints.numpy()[:4] + np.array([3.0 * k, 0, 0]) for k in range(people)])
    gltf = pygltflib.GLTF2().load_binary(write_glb(tmp_path / "crowd.glb", joints, FPS))
    assert len(gltf.materials) == people
    for k in range(people):
        node = next(nd for nd in gltf.nodes if nd.skin == k)
        material = gltf.materials[gltf.meshes[node.mesh].primitives[0].material]
        pbr = material.pbrMetallicRoughness
        assert pbr.metallicFactor == 0.0 and pbr.roughnessFactor == 0.7
        *linear, alpha = pbr.baseColorFactor
        assert alpha == 1.0
        linear = np.array(linear)
        srgb = np.where(linear <= 0.0031308, linear * 12.92,
                        1.055 * linear ** (1 / 2.4) - 0.055)  # fmt: skip
        want = np.array(mcolors.to_rgb(PALETTE[k % 12])) * (0.7 if k >= 12 else 1.0)
        np.testing.assert_allclose(srgb, want, atol=2e-5)
    # written to 6 decimals: the palette's first colour, #1f77b4, in linear RGB
    first = next(nd for nd in gltf.nodes if nd.skin == 0)
    material = gltf.materials[gltf.meshes[first.mesh].primitives[0].material]
    assert material.pbrMetallicRoughness.baseColorFactor == [0.013702, 0.184475, 0.456411, 1.0]


def test_document_names_links_views_and_defaults(real_joints, tmp_path):
    """What players and validators read besides the motion: names, the node tree, buffer
    view targets, the bind matrices' layout, the rest pose where the motion starts, and the
    defaults when no prompt or names are given."""
    from umf.exports.gltf import glb_bytes, scene_to_gltf

    joints = np.stack([real_joints.numpy()[:12], real_joints.numpy()[:12] + 2.0])
    path = write_glb(tmp_path / "plain.glb", joints, 0.5, names=["ann", "bo"])  # any fps > 0
    assert path.read_bytes() == glb_bytes(scene_to_gltf(joints, 0.5, names=["ann", "bo"]))
    gltf = pygltflib.GLTF2().load_binary(path)
    assert gltf.asset.extras.get("text", "") == "" and gltf.asset.extras["fps"] == 0.5
    assert gltf.asset.extras["people"] == ["ann", "bo"] and gltf.scenes[0].name == "umf"
    parents = node_parents(gltf)
    rest = world_matrices(gltf, animate=False)[0]
    for i, name in enumerate(["ann", "bo"]):
        skin = gltf.skins[i]
        assert skin.name == name and gltf.nodes[skin.skeleton].name == name
        assert [gltf.nodes[j].name for j in skin.joints] == [f"{name}_{n}" for n in JOINT_NAMES]
        assert parents[skin.joints[0]] == skin.skeleton  # the pelvis hangs from the person
        tree = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
        for j in range(1, 22):
            assert parents[skin.joints[j]] == skin.joints[tree[j]]
        np.testing.assert_allclose(rest[skin.joints[0]][:3, 3], joints[i, 0, 0], atol=1e-5)
        ibm = gltf.accessors[skin.inverseBindMatrices]
        assert (ibm.type, ibm.count) == ("MAT4", 22)
        body = next(nd for nd in gltf.nodes if nd.skin == i)
        mesh = gltf.meshes[body.mesh]
        assert body.name == mesh.name == f"{name}_body"
        prim = mesh.primitives[0]
        assert gltf.materials[prim.material].name == f"{name}_material"
        attrs = [prim.attributes.POSITION, prim.attributes.NORMAL, prim.attributes.JOINTS_0,
                 prim.attributes.WEIGHTS_0]  # fmt: skip
        for a in attrs:
            assert gltf.bufferViews[gltf.accessors[a].bufferView].target == pygltflib.ARRAY_BUFFER
        view = gltf.bufferViews[gltf.accessors[prim.indices].bufferView]
        assert view.target == pygltflib.ELEMENT_ARRAY_BUFFER
        assert gltf.bufferViews[ibm.bufferView].target is None
    views = gltf.bufferViews
    assert all(v.byteOffset % 4 == 0 for v in views)  # 4-byte aligned, tightly packed
    assert gltf.buffers[0].byteLength == len(gltf.binary_blob())
    assert views[-1].byteOffset + views[-1].byteLength <= gltf.buffers[0].byteLength
    for acc in gltf.accessors:
        has_bounds = bool(acc.min)
        assert has_bounds == (
            acc is gltf.accessors[0]
            or any(acc is gltf.accessors[m.primitives[0].attributes.POSITION] for m in gltf.meshes)
        )
        if acc.componentType != 5126:
            assert all(isinstance(v, int) for v in acc.min or [])
    long = write_glb(tmp_path / "long.glb", joints[:1], FPS, text="w" * 100)
    assert pygltflib.GLTF2().load_binary(long).scenes[0].name == "w" * 80


def test_quaternions_are_unit_and_sign_continuous():
    """q and -q are one rotation: the writer flips signs so consecutive keys share a
    hemisphere (any number of flips), and normalises what it is given."""
    from umf.exports.gltf import continuous_quaternions

    rng = np.random.default_rng(3)
    q = rng.normal(size=(1, 3, 4)) + np.array([0.0, 0.0, 0.0, 3.0])  # near identity
    steps = np.repeat(q, 9, axis=0) + rng.normal(0, 0.01, (9, 3, 4))
    flips = np.array([1, -1, -1, 1, -1, 1, 1, -1, -1.0])[:, None, None]
    out = continuous_quaternions(steps * flips * 2.5)  # not unit, signs flipped 6 times
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-12)
    assert (np.sum(out[1:] * out[:-1], axis=-1) > 0).all()
    unit = steps / np.linalg.norm(steps, axis=-1, keepdims=True)
    np.testing.assert_allclose(out, unit, atol=1e-12)  # first key's sign kept: +, so no flips


def test_document_records_the_model_of_a_scene(glb3, scene3):
    extras = pygltflib.GLTF2().load_binary(glb3).asset.extras
    assert extras["model"] == "test-model" and extras["fps"] == FPS
