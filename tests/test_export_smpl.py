"""SMPL export maths, checked with SMPL's kinematic tree written out independently
(test_exports_agree.smpl_tree: SMPL's 24-joint parents, scipy rotations, no umf code).

A body on SMPL's own template skeleton, posed with random SMPL parameters, must come back
through umf (fit -> export) as the same joints: that fixes the joint order of ``poses``,
the axis convention, the rest-pose corrections and ``trans``."""

from __future__ import annotations

import numpy as np
import pytest

from test_exports_agree import smpl_tree
from umf.exports.smpl import SMPL_OFFSETS, SMPL_PELVIS, mapping_residual
from umf.scene import Scene


def _smpl_motion(frames: int = 24, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random SMPL poses (T, 72) (smooth, moderate angles, hands still) and a walk (T, 3)."""
    rng = np.random.default_rng(seed)
    keys = rng.normal(0.0, 0.35, (2, 24, 3))
    s = np.linspace(0, 1, frames)[:, None, None]
    poses = keys[0] * (1 - s) + keys[1] * s
    poses[:, 0] = [0.2, 2.5, -0.1] + 0.3 * s[:, 0]  # turned far round, leaning
    poses[:, 22:] = 0.0
    trans = np.stack([np.linspace(0, 1.2, frames), 0.9 + 0.02 * np.sin(np.arange(frames)),
                      np.linspace(0, -0.4, frames)], axis=-1)  # fmt: skip
    return poses.reshape(frames, 72), trans


def test_smpl_round_trip_on_smpl_skeleton(tmp_path):
    poses, trans = _smpl_motion()
    joints = smpl_tree(poses, trans, SMPL_OFFSETS, SMPL_PELVIS)[:, :22]
    scene = Scene(joints[None].astype(np.float64), None, "an SMPL body", 30.0)
    assert np.abs(scene.joints[0] - joints).max() < 1e-5  # a rigid body is kept as it is
    (path,) = scene.save_smpl(tmp_path / "smpl-p{i}.smpl.npz")
    with np.load(path) as z:
        back_poses, back_trans = z["poses"].astype(np.float64), z["trans"].astype(np.float64)
        assert np.abs(z["joints"] - scene.joints[0]).max() < 1e-6
    assert back_poses.shape == (len(poses), 156) and not back_poses[:, 66:].any()
    back = smpl_tree(back_poses[:, :72], back_trans, SMPL_OFFSETS, SMPL_PELVIS)[:, :22]
    assert np.abs(back - joints).max() < 1e-4
    # the pelvis is SMPL's J_0 + trans, and the global orientation is the pelvis rotation
    assert np.allclose(back_trans + SMPL_PELVIS, joints[:, 0], atol=1e-5)


def test_residual_is_zero_on_smpl_proportions_and_bounded_on_ours(real_joints):
    """The mapping's residual comes only from where SMPL's template puts the hips and
    collars: none for an SMPL-shaped body, centimetres for umf's (measured, documented)."""
    poses, trans = _smpl_motion(frames=10, seed=1)
    smpl_body = Scene(smpl_tree(poses, trans, SMPL_OFFSETS, SMPL_PELVIS)[None, :, :22], None,
                      "", 30.0)  # fmt: skip
    assert mapping_residual(smpl_body.bodies, 0).max() < 1e-6
    ours = Scene(real_joints.numpy()[None], None, "", 30.0)
    res = mapping_residual(ours.bodies, 0)
    assert 0.005 < res.mean() < 0.04 and res.max() < 0.08
    assert res[:, 0].max() == pytest.approx(0.0, abs=1e-9)  # the pelvis is placed exactly


def test_rest_corrections_turn_smpls_bones_onto_ours():
    """C_j takes SMPL's rest direction of each child bone onto ours: exactly for one child,
    best-fit for several (pelvis, chest), the parent's for leaves; all proper rotations;
    the identity on SMPL's own proportions."""
    from umf.exports.smpl import rest_corrections, smpl_directions
    from umf.skeleton import DEFAULT_OFFSETS

    ours = np.asarray(DEFAULT_OFFSETS, dtype=np.float64)
    parents = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
    children = {j: [k for k in range(22) if parents[k] == j] for j in range(22)}
    smpl = smpl_directions(ours)
    np.testing.assert_allclose(np.linalg.norm(smpl, axis=1), np.linalg.norm(ours, axis=1))
    template = SMPL_OFFSETS[:22]
    for k in range(1, 22):  # SMPL's direction, our length
        unit = template[k] / np.linalg.norm(template[k])
        np.testing.assert_allclose(smpl[k], unit * np.linalg.norm(ours[k]), atol=1e-12)
    corr = rest_corrections(ours)
    assert corr.shape == (22, 3, 3)
    np.testing.assert_allclose(corr @ corr.transpose(0, 2, 1), np.tile(np.eye(3), (22, 1, 1)),
                               atol=1e-9)  # fmt: skip
    np.testing.assert_allclose(np.linalg.det(corr), 1.0, atol=1e-9)
    for j in range(22):
        kids = children[j]
        if len(kids) == 1:
            np.testing.assert_allclose(corr[j] @ smpl[kids[0]], ours[kids[0]], atol=1e-9)
        elif kids:  # no other rotation brings the children closer
            fit = np.linalg.norm(smpl[kids] @ corr[j].T - ours[kids])
            for angle in (0.02, -0.02):
                for axis in np.eye(3):
                    c, s = np.cos(angle), np.sin(angle)
                    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]],
                                  [-axis[1], axis[0], 0]])  # fmt: skip
                    turn = np.eye(3) + s * k + (1 - c) * k @ k
                    assert fit <= np.linalg.norm(smpl[kids] @ (turn @ corr[j]).T - ours[kids])
        else:
            np.testing.assert_array_equal(corr[j], corr[parents[j]])
    np.testing.assert_allclose(rest_corrections(template.copy()),
                               np.tile(np.eye(3), (22, 1, 1)), atol=1e-9)  # fmt: skip


@pytest.mark.filterwarnings("error")  # and it warns of nothing on the way
def test_smpl_file_holds_every_documented_array(tmp_path):
    """The keys, dtypes, shapes and values smpl.py documents, one file per person (``{i}``
    from 1): AMASS' split of ``poses``, flat hands, zero betas, the neutral SMPL-H body,
    both spellings of the frame rate, the prompt; no pickled objects."""
    poses, trans = _smpl_motion(frames=8, seed=2)
    one = smpl_tree(poses, trans, SMPL_OFFSETS, SMPL_PELVIS)[:, :22]
    scene = Scene(np.stack([one, one + np.array([1.5, 0.0, 0.0])]), None, "two SMPL bodies",
                  24.0)  # fmt: skip
    paths = scene.save_smpl(tmp_path / "body-p{i}.smpl.npz")
    assert paths == [tmp_path / "body-p1.smpl.npz", tmp_path / "body-p2.smpl.npz"]
    shapes = {"poses": (8, 156), "root_orient": (8, 3), "pose_body": (8, 63),
              "pose_hand": (8, 90), "trans": (8, 3), "betas": (16,),
              "joints": (8, 22, 3)}  # fmt: skip
    for i, path in enumerate(paths):
        with np.load(path, allow_pickle=False) as z:
            assert set(z.files) == {*shapes, "gender", "surface_model_type", "mocap_framerate",
                                    "mocap_frame_rate", "text"}  # fmt: skip
            for key, shape in shapes.items():
                assert (z[key].dtype, z[key].shape) == (np.float32, shape), key
            body = z["poses"]
            assert body[:, :66].any() and not body[:, 66:].any()
            np.testing.assert_array_equal(z["root_orient"], body[:, :3])
            np.testing.assert_array_equal(z["pose_body"], body[:, 3:66])
            np.testing.assert_array_equal(z["pose_hand"], body[:, 66:])
            assert not z["betas"].any()
            np.testing.assert_allclose(z["joints"], scene.joints[i], atol=1e-6)
            assert str(z["gender"]) == "neutral" and str(z["surface_model_type"]) == "smplh"
            assert float(z["mocap_framerate"]) == float(z["mocap_frame_rate"]) == 24.0
            assert str(z["text"]) == "two SMPL bodies"
