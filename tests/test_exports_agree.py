"""Every file of one scene holds the same motion: a 3-person scene and a reaction from the
bundled model, written in every format and read back by readers that share no code with
the writers (numpy, bvhio, pygltflib + the FK of test_export_glb, the Khronos validator,
SMPL's kinematic tree written out here with scipy's rotations, HumanML3D's decoding).

Agreement is measured against ``scene.joints``; the figures are printed (``-s``)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import bvhio
import numpy as np
import pygltflib
import pytest
import torch
from scipy.spatial.transform import Rotation

from conftest import BANDAI_FIXTURE, MODULE
from test_export_glb import _VALIDATE_JS, _validator_package, skin_joint_positions
from umf.exports import FORMATS
from umf.skeleton import JOINT_NAMES, PARENTS

ALL = [f for f in FORMATS if f != "mp4"]  # the MP4 writer is checked by spying (encoding costs)
MM = 1e-3
# the README's figure: every format agrees with scene.joints to 0.002 mm; a quarter more
# margin. A bone offset 0.08 % long (0.7 mm) or a BVH written at 4 decimals fails it
TOL = 0.0025 * MM
BOW = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001.bvh"
# SMPL's 24-joint tree (pelvis ... right hand), written out independently of umf
SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]


@pytest.fixture(scope=MODULE)
def pipe():
    from umf import UMFPipeline

    torch.set_num_threads(1)
    return UMFPipeline.from_pretrained()


@pytest.fixture(scope=MODULE)
def scenes(pipe):
    from umf.data.motion_file import load_motion

    three = pipe("Three people walk side by side.", num_people=3, seconds=2.0, seed=0)[0]
    actor = load_motion(BOW).joints[0][:61]
    react = pipe("One person bows and the other bows back.", num_people=2, seed=0, actor=actor)[0]
    return {"three": three, "react": react, "actor": actor}


@pytest.fixture(scope=MODULE, params=["three", "react"])
def written(request, scenes, tmp_path_factory):
    scene = scenes[request.param]
    out = tmp_path_factory.mktemp(request.param)
    paths = scene.save(out / request.param, ALL)
    return request.param, scene, {p.name: p for p in paths}


def _report(name: str, fmt: str, err: float) -> None:
    print(f"agreement {name} {fmt}: max {err / MM:.4f} mm")


def bvhio_joints(path: Path, frames: list[int]) -> np.ndarray:
    """(len(frames), 22, 3) world positions from bvhio, in umf's joint order."""
    root = bvhio.readAsHierarchy(str(path))
    layout = [joint for joint, _, _ in root.layout()]
    order = [[j.Name for j in layout].index(n) for n in JOINT_NAMES]
    out = []
    for f in frames:
        root.loadPose(f)
        out.append([tuple(layout[k].PositionWorld) for k in order])
    return np.array(out, dtype=np.float64)


def smpl_tree(poses: np.ndarray, trans: np.ndarray, rest: np.ndarray, pelvis: np.ndarray):
    """SMPL's joints (T, 24, 3): G_0 = [R_0 | pelvis], G_j = G_p [R_j | rest_j], + trans."""
    t = len(poses)
    rot = Rotation.from_rotvec(poses[:, :72].reshape(-1, 3)).as_matrix().reshape(t, 24, 3, 3)
    glob = np.zeros_like(rot)
    pos = np.zeros((t, 24, 3))
    for j, p in enumerate(SMPL_PARENTS):
        if p < 0:
            glob[:, j], pos[:, j] = rot[:, j], pelvis + trans
        else:
            glob[:, j] = glob[:, p] @ rot[:, j]
            pos[:, j] = pos[:, p] + glob[:, p] @ rest[j]
    return pos


# --------------------------------------------------------------------- the scenes
def test_scenes_are_one_rigid_motion(scenes):
    """One set of bone lengths per person; joints close to the decoded ones; nobody in the
    floor; the reaction's actor is the user's motion."""
    from umf.anchoring import anchor_people
    from umf.representation import CONTACT
    from umf.skeleton import bone_lengths

    for name in ("three", "react"):
        s = scenes[name]
        lengths = bone_lengths(torch.from_numpy(s.joints.astype(np.float64)))
        spread = (lengths.max(1).values - lengths.min(1).values).max()
        raw = bone_lengths(torch.from_numpy(s.raw_joints.astype(np.float64)))
        raw_spread = (raw.max(1).values - raw.min(1).values).max()
        print(f"{name}: bone length spread {raw_spread * 100:.1f} cm raw, {spread * 1e3:.4f} mm")
        assert spread < 1e-4
        # close to the decoded joints once planted feet are anchored (a floor translation)
        clean = [name != "react" or k > 0 for k in range(s.num_people)]
        start = anchor_people(s.raw_joints, s.features[..., CONTACT], s.meta["floor"], clean)
        gap = np.linalg.norm(s.joints - start, axis=-1)
        assert gap.mean() < 0.03, gap.mean()
        generated = s.joints[1:] if name == "react" else s.joints
        assert generated[..., 1].min() >= s.meta["floor"] - 1e-5
    react, actor = scenes["react"], scenes["actor"]
    assert np.abs(react.joints[0] - actor[:60]).max() < 1e-4


# --------------------------------------------------------------------- every format
def test_npz_agrees(written):
    name, scene, files = written
    with np.load(files[f"{name}.npz"]) as z:
        err = np.abs(z["joints"] - scene.joints).max()
        assert np.array_equal(z["raw_joints"], scene.raw_joints)
        assert z["rotations"].shape == (*scene.joints.shape[:3], 3, 3)
    _report(name, "npz", err)
    assert err < 1e-6


def test_bvh_agrees(written):
    """bvhio (every 6th frame and the last) and umf's own reader (every frame)."""
    from umf.bvh import forward_kinematics, read_bvh

    name, scene, files = written
    frames = [*range(0, scene.num_frames, 6), scene.num_frames - 1]
    worst = 0.0
    for i in range(scene.num_people):
        path = files[f"{name}-p{i + 1}.bvh"]
        worst = max(worst, np.abs(bvhio_joints(path, frames) - scene.joints[i, frames]).max())
        bvh = read_bvh(path)
        pos, _ = forward_kinematics(bvh)
        order = [bvh.names.index(n) for n in JOINT_NAMES]
        worst = max(worst, np.abs(pos[:, order] - scene.joints[i]).max())
    _report(name, "bvh", worst)
    assert worst < TOL


def test_glb_agrees(written, tmp_path):
    name, scene, files = written
    gltf = pygltflib.GLTF2().load(str(files[f"{name}.glb"]))
    err = np.abs(skin_joint_positions(gltf) - scene.joints).max()
    _report(name, "glb", err)
    assert err < TOL
    node, package = shutil.which("node"), _validator_package()
    if node is None or package is None:
        pytest.skip("Khronos glTF-Validator not available (see test_export_glb)")
    script = tmp_path / "validate.js"
    script.write_text(_VALIDATE_JS)
    run = subprocess.run([node, str(script), str(package.resolve()), str(files[f"{name}.glb"])],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    issues = json.loads(run.stdout)["issues"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0


def test_video_draws_the_scene_joints(written, monkeypatch, tmp_path):
    """The GIF/MP4 writer renders exactly ``scene.joints`` (pixels cannot be read back as
    joints), and the GIF has one frame per motion frame."""
    import imageio.v3 as iio

    import umf.render

    name, scene, files = written
    assert iio.imread(files[f"{name}.gif"], index=None).shape[0] == scene.num_frames
    seen = {}

    def spy(joints, path, **kwargs):
        seen["joints"] = np.asarray(joints)
        Path(path).write_bytes(b"")
        return Path(path)

    monkeypatch.setattr(umf.render, "render_animation", spy)
    err = 0.0
    for fmt in ("gif", "mp4"):
        scene.save(tmp_path / "v", fmt)
        err = max(err, np.abs(seen.pop("joints") - scene.joints).max())
    _report(name, "gif/mp4", err)
    assert err == 0.0


def test_smpl_agrees(written):
    """SMPL's own tree (scipy rotations) posed by the file: with our bones in SMPL's rest
    frame it gives the scene's joints (the rotation mapping loses nothing); with SMPL's
    template bone directions the residual is the mapping's documented error."""
    from umf.exports.smpl import SMPL_PELVIS, rest_corrections, smpl_directions

    name, scene, files = written
    worst, residual = 0.0, []
    for i in range(scene.num_people):
        with np.load(files[f"{name}-p{i + 1}.smpl.npz"]) as z:
            poses, trans = z["poses"].astype(np.float64), z["trans"].astype(np.float64)
            assert poses.shape == (scene.num_frames, 156) and not poses[:, 66:].any()
            assert str(z["gender"]) == "neutral" and not z["betas"].any()
            assert float(z["mocap_framerate"]) == scene.fps
        offsets = scene.bodies.offsets[i]
        corr = rest_corrections(offsets)
        ours = np.zeros((24, 3))
        for j in range(1, 22):  # our bone, seen from the parent's SMPL rest frame
            ours[j] = corr[PARENTS[j]].T @ offsets[j]
        tree = smpl_tree(poses, trans, ours, SMPL_PELVIS)[:, :22]
        worst = max(worst, np.abs(tree - scene.joints[i]).max())
        rest = np.zeros((24, 3))
        rest[:22] = smpl_directions(offsets)
        template = smpl_tree(poses, trans, rest, SMPL_PELVIS)[:, :22]
        residual.append(np.linalg.norm(template - scene.joints[i], axis=-1))
    res = np.concatenate(residual)
    _report(name, "smpl (our bones)", worst)
    print(f"smpl mapping residual {name}: mean {res.mean() / MM:.1f} mm, max {res.max() / MM:.1f}")
    assert worst < TOL
    assert res.mean() < 0.04 and res.max() < 0.08  # the hips' and collars' template offsets


def test_humanml3d_agrees(written):
    """HumanML3D's decoding of the vectors gives ``new_joints``, which are the scene's
    joints resampled to 20 fps and moved rigidly into HumanML3D's canonical frame."""
    from umf.humanml3d import recover_joints

    name, scene, files = written
    worst = 0.0
    for i in range(scene.num_people):
        with np.load(files[f"{name}-p{i + 1}.humanml3d.npz"]) as z:
            vecs, canon = z["new_joint_vecs"], z["new_joints"].astype(np.float64)
            assert float(z["fps"]) == 20.0 and vecs.shape == (len(canon) - 1, 263)
        decoded = recover_joints(torch.from_numpy(vecs.astype(np.float64))).numpy()
        worst = max(worst, np.abs(decoded - canon[:-1]).max())
        src = np.arange(len(canon)) * 1.5  # 20 fps frame k is 30 fps frame 1.5 k
        lo = np.minimum(np.floor(src).astype(int), scene.num_frames - 2)
        w = (src - lo)[:, None, None]
        ours = scene.joints[i, lo] * (1 - w) + scene.joints[i, lo + 1] * w
        a, b = ours.reshape(-1, 3), canon.reshape(-1, 3)
        u, _, vt = np.linalg.svd((a - a.mean(0)).T @ (b - b.mean(0)))
        rot = vt.T @ np.diag([1, 1, np.linalg.det(vt.T @ u.T)]) @ u.T
        fitted = (a - a.mean(0)) @ rot.T + b.mean(0)
        worst = max(worst, np.abs(fitted - b).max())
        assert abs(rot[1, 1] - 1) < 1e-6  # a turn about the vertical only
    _report(name, "humanml3d", worst)
    assert worst < TOL
