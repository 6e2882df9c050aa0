"""The mutation score of `make mutation`: per module, from mutmut's results, with every
surviving mutant listed and either explained as equivalent or left to be killed.

    python scripts/mutation_report.py [--mutants mutants] [--out results/mutation]
        [--previous results/mutation/mutation.json]   # a rerun of that report's survivors
        [--sample umf.pipeline [--count 24 --seed 0]]  # a seeded sample of one module

Reads the ``*.meta`` files mutmut 3 leaves under ``mutants/`` (one exit code per mutant:
1 the tests failed, the mutant is killed; 0 they passed, it survived; 33 no test covers
it; 36, 24 or -24 it ran out of time, counted as killed as mutmut does; none, not run) and
each survivor's changed line, read off the mutated copies. The score is
killed / (run - equivalent).
Writes ``README.md`` and ``mutation.json`` under ``--out``.

``--previous``: the mutants/ hold a rerun of only the survivors (and equivalents) of an
earlier report of the same source (``make mutation-rerun``: a full run takes hours here,
a rerun of the few hundred survivors minutes); every mutant that run killed keeps its
outcome, every survivor takes the rerun's.

``--sample MODULE``: a module too slow to run whole (``umf.pipeline``: each mutant runs the
end-to-end tests, a few minutes, 821 mutants) is scored on a seeded random sample of
``--count`` of its mutants (``make mutation-sample``); with ``--names`` the sample is
printed (mutmut's own generator numbers the mutants, so the names are the run's), and the
report gives the sampled module's score with a 95 % interval (Wilson), every other module
carried from ``--previous``.
"""

from __future__ import annotations

import argparse
import ast
import difflib
import json
import math
import random
import re
import sys
from pathlib import Path

TIMEOUT_CODES = {36, 24, -24, 152}

# Mutants that cannot change behaviour here, and why. Keyed by the function a mutant lives in
# and its changed line (as `mutmut show` prints it), not by mutmut's numbering, which shifts
# whenever a function gains a line. Device arguments are None on a CPU-only machine anyway; a
# GPU run of the tests would tell them apart.
CPU = "the default device is the CPU's"
EQUIVALENT: dict[tuple[str, str], str] = {
    ("umf.flows.paths.x_expand_time",
     "t = torch.as_tensor(t, dtype=like.dtype, device=None)"): f"device=None: {CPU}",
    ("umf.flows.paths.x_expand_time",
     "t = torch.as_tensor(t, dtype=like.dtype, )"): f"device dropped: {CPU}",
    ("umf.flows.paths.x_sample_time",
     "return torch.rand(batch, generator=generator, device=None, dtype=dtype)"):
        f"device=None: {CPU}",
    ("umf.flows.paths.x_sample_time",
     "return torch.rand(batch, generator=generator, dtype=dtype)"): f"device dropped: {CPU}",
    ("umf.flows.paths.x_sample_time",
     "z = torch.randn(batch, generator=generator, device=None, dtype=dtype)"):
        f"device=None: {CPU}",
    ("umf.flows.paths.x_sample_time",
     "z = torch.randn(batch, generator=generator, dtype=dtype)"): f"device dropped: {CPU}",
    ("umf.flows.paths.x_flow_matching_loss", "m = mask.to(None)"):
        "mask.to(None) keeps the bool mask: bool x float multiplies and sums the same",
    # glTF export
    ("umf.exports.gltf.x__box",
     "if sign <= 0:  # keep t1 x t2 = n so the winding faces outwards"):
        "sign is 1.0 or -1.0: <= 0 picks the same faces as < 0",
    ("umf.exports.gltf.x__box",
     "if sign < 1:  # keep t1 x t2 = n so the winding faces outwards"):
        "sign is 1.0 or -1.0: < 1 picks the same faces as < 0",
    ("umf.exports.gltf.x__as_bodies",
     "if joints.ndim != 4 or joints.shape[2:] != (NUM_JOINTS, 3) or 0 in joints.shape[:3]:"):
        "shape[2] is 22 by the clause before it",
    ("umf.exports.gltf.x__bone_axes",
     "ref = np.array([0.0, 0.0, 2.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])"):
        "u is normalised: a longer reference along the same axis gives the same u",
    ("umf.exports.gltf.x__bone_axes",
     "ref = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([2.0, 0.0, 0.0])"):
        "u is normalised: a longer reference along the same axis gives the same u",
    ("umf.exports.gltf.x__bone_axes",
     "ref = np.array([0.0, 0.0, 1.0]) if abs(a[2]) <= 0.9 else np.array([1.0, 0.0, 0.0])"):
        "differs only for a bone exactly 0.9 along z, where both references work",
    ("umf.exports.gltf.x\u01c1_Packer\u01c1add",
     "flat = np.ascontiguousarray(array).reshape(len(array), -2)"):
        "numpy reads any negative size as 'the rest', like -1",
    ("umf.exports.gltf.x_scene_to_gltf",
     "gl.AnimationSampler(input=time_accessor, output=out, interpolation=None)"):
        "glTF's default interpolation is LINEAR, which pygltflib then writes",
    ("umf.exports.gltf.x_scene_to_gltf",
     "gl.AnimationSampler(input=time_accessor, output=out, )"):
        "glTF's default interpolation is LINEAR, which pygltflib then writes",
    ("umf.exports.gltf.x_continuous_quaternions",
     "sign = np.concatenate([np.ones_like(q[:1, ..., 0]), 1.0 - 2.0 * parity], )"):
        "axis 0 is numpy's default",
    ("umf.exports.gltf.x_continuous_quaternions",
     "sign = np.concatenate([np.ones_like(q[:1, ..., 1]), 1.0 - 2.0 * parity], axis=0)"):
        "ones_like of any component is the same ones",
    ("umf.exports.gltf.x_continuous_quaternions", "return q / sign[..., None]"):
        "sign is +1 or -1: dividing is multiplying",
    ("umf.exports.gltf.x_continuous_quaternions",
     "negative = np.sum(q[1:] * q[:-1], axis=-1) <= 0"):
        "differs only for consecutive keys exactly 180 degrees apart, either sign is right",
    ("umf.exports.gltf.x_person_colour",
     "linear = np.where(srgb < 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)"):
        "no palette channel, nor a darker round of one, is exactly 0.04045",
    # kinematics
    ("umf.kinematics.x__ancestry", "while a >= 1 and a != j:"):
        "at the pelvis (0) the walk up has met j or never will: stopping there answers alike",
    ("umf.kinematics.x__ancestry", "while a > 0 and a != j:"):
        "at the pelvis (0) the walk up has met j or never will: stopping there answers alike",
    # representation and body frame (session 27)
    ("umf.representation.x_assemble_features",
     "return torch.cat([pos, vel, rot, foot_contacts(joints)], dim=+1)"):
        "_check_joints forces (T, 22, 3): every piece is 2-D, so dim 1 is dim -1",
    ("umf.representation.x_fuse_positions", "vel = features[..., VEL].to(None)"):
        "only its last frame is used, cast back to the features' dtype: a float64 round trip "
        "is exact and torch.cat promotes",
    ("umf.representation.x_place_features",
     "rot = yaw_matrix(torch.as_tensor(yaw, dtype=features.dtype)).to(None)"):
        f"rot already has the features' dtype; .to(None) only drops the device move: {CPU}",
    ("umf.representation.x_transform_features",
     "rot = yaw_matrix(torch.tensor(tf.yaw, dtype=features.dtype)).to(None)"):
        f"rot already has the features' dtype; .to(None) only drops the device move: {CPU}",
    ("umf.representation.xǁRigidTransformǁapply",
     "rot = yaw_matrix(torch.tensor(self.yaw, dtype=joints.dtype)).to(None)"):
        f"rot already has the joints' dtype; .to(None) only drops the device move: {CPU}",
    ("umf.representation.xǁRigidTransformǁinvert",
     "rot = yaw_matrix(torch.tensor(self.yaw, dtype=joints.dtype)).to(None)"):
        f"rot already has the joints' dtype; .to(None) only drops the device move: {CPU}",
    ("umf.body_frame.x_fit_body_normalizer", "spread = body[:, ROOT].pow(2).sum(+1).mean() / 2"):
        "body[:, ROOT] is 2-D (N, 2): dim 1 is dim -1",
    ("umf.body_frame.x_from_body_frame", "zero = torch.zeros_like(body[..., 1])"):
        "body[..., 1] has the same shape, dtype and device as body[..., 0]",
    # flows and validation (session 27)
    ("umf.flows.pyramid.x_pyramid_training_sample",
     "stages = _stage_tensor(stage, config, b, generator, None)"): f"device=None: {CPU}",
    ("umf.flows.pyramid.x_pyramid_training_sample", "(removed: device=z1.device,)"):
        f"sample_time's device argument: {CPU}",
    ("umf.flows.pyramid.x_sample_pyramid",
     "for i, (w, n_steps) in enumerate(zip(windows, steps, strict=None)):"):
        "len(steps) == len(windows) is checked before the loop: strict never fires",
    ("umf.flows.pyramid.x_sample_pyramid",
     "for i, (w, n_steps) in enumerate(zip(windows, steps, )):"):
        "len(steps) == len(windows) is checked before the loop: strict never fires",
    ("umf.flows.pyramid.x_sample_pyramid",
     "for i, (w, n_steps) in enumerate(zip(windows, steps, strict=False)):"):
        "len(steps) == len(windows) is checked before the loop: strict never fires",
    ("umf.flows.pyramid.x_sample_pyramid",
     "stage = torch.full((x.shape[0],), w.stage, dtype=None, device=x.device)"):
        "torch.full infers int64 (torch.long) from the Python int w.stage",
    ("umf.flows.pyramid.x_sample_pyramid",
     "stage = torch.full((x.shape[0],), w.stage, device=x.device)"):
        "torch.full infers int64 (torch.long) from the Python int w.stage",
    ("umf.flows.solvers.x__repeat", "return torch.cat([value] * times, )"):
        "dim 0 is torch.cat's default",
    ("umf.flows.solvers.x__stack_pair", "return torch.cat([a, b], )"):
        "dim 0 is torch.cat's default",
    ("umf.flows.solvers.x_classifier_free_guidance",
     "out = velocity(torch.cat([x, x], ), torch.cat([t, t], 0), **dup, **both)"):
        "dim 0 is torch.cat's default",
    ("umf.flows.solvers.x_classifier_free_guidance",
     "out = velocity(torch.cat([x, x], 0), torch.cat([t, t], ), **dup, **both)"):
        "dim 0 is torch.cat's default",
    ("umf.flows.semi_noise.x_semi_noise_training_sample", "(removed: device=context.device,)"):
        f"sample_time's device argument: {CPU}",
    ("umf.validation.x_check_prompts", 'p.encode("UTF-8")'):
        "Python codec names are case-insensitive: 'UTF-8' is 'utf-8'",
    # exports (session 27)
    ("umf.exports.smpl.x_person_arrays",
     "body = matrix_to_axis_angle(torch.from_numpy(rot)).numpy().reshape(len(rot), -2)"):
        "numpy reads any negative size as 'the rest', like -1",
    ("umf.exports.smpl.x_smpl_directions", "norm = np.linalg.norm(smpl, axis=+1, keepdims=True)"):
        "smpl is (22, 3): axis 1 is axis -1",
    ("umf.exports.smpl.x_smpl_directions",
     "return unit * np.linalg.norm(offsets, axis=+1, keepdims=True)"):
        "offsets is one person's (22, 3): axis 1 is axis -1",
    ("umf.exports.smpl.x_smpl_directions",
     "unit = np.divide(smpl, norm, out=None, where=norm > 0)"):
        "only the pelvis row (norm 0) is left unwritten, and nothing reads row 0",
    ("umf.exports.gltf.x__add_person",
     "inverseBindMatrices=packer.add(ibm.reshape(-2, 16).astype(np.float32)),"):
        "numpy reads any negative size as 'the rest', like -1",
    ("umf.exports.gltf.x__as_bodies", "return fit_bodies(joints, )"):
        "without contacts or a floor, clean changes nothing: clean_targets returns the joints",
    ("umf.exports.gltf.x__as_bodies", "return fit_bodies(joints, clean=True)"):
        "without contacts or a floor, clean changes nothing: clean_targets returns the joints",
    ("umf.exports.gltf.x__body_boxes",
     "direction = offsets[j] if length > 1e-6 else np.asarray(REST_DIRECTIONS[j], None)"):
        "REST_DIRECTIONS are int tuples and _bone_axes divides by the norm: the same floats",
    ("umf.exports.gltf.x__body_boxes",
     "direction = offsets[j] if length > 1e-6 else np.asarray(REST_DIRECTIONS[j], )"):
        "REST_DIRECTIONS are int tuples and _bone_axes divides by the norm: the same floats",
    ("umf.exports.gltf.x__body_boxes", "axes = _bone_axes(np.asarray(REST_DIRECTIONS[w], None))"):
        "REST_DIRECTIONS are int tuples and _bone_axes divides by the norm: the same floats",
    ("umf.exports.gltf.x__body_boxes", "axes = _bone_axes(np.asarray(REST_DIRECTIONS[w], ))"):
        "REST_DIRECTIONS are int tuples and _bone_axes divides by the norm: the same floats",
    ("umf.exports.gltf.x_scene_to_gltf", '(removed: version="2.0",)'):
        "pygltflib's Asset() defaults to version 2.0",
    ("umf.representation.x_facing_direction", "up[..., 1] = 2.0"):
        "up is only crossed with the body's across vector and the result normalised: twice "
        "as long gives the same unit vector (bar a body without hip or shoulder width)",
    # pipeline (session 29, a sample)
    ("umf.clean_up.x_place_people", "if separate and decoded.shape[0] >= 1:"):  # was pipeline
        "one person has nobody to keep apart from: separate_people shifts nobody",
    # kinematics (session 27)
    ("umf.kinematics.x__lm_step",
     "eye = torch.eye(normal.shape[+1], device=normal.device)"):
        "normal is (B, n, n): shape[1] is shape[-1]",
    ("umf.kinematics.x__lm_step",  # the same line before session 29
     "normal = normal + damping.float()[:, None, None] * torch.eye(normal.shape[+1])"):
        "normal is (B, n, n): shape[1] is shape[-1]",
    ("umf.kinematics.x__lm_step",
     "eye = torch.eye(normal.shape[-2], device=normal.device)"):
        "normal is square: shape[-2] is shape[-1]",
    ("umf.kinematics.x__lm_step",  # the same line before session 29
     "normal = normal + damping.float()[:, None, None] * torch.eye(normal.shape[-2])"):
        "normal is square: shape[-2] is shape[-1]",
    ("umf.kinematics.x__lm_step",
     "total = torch.einsum(\"AD,BAC->BDC\", torch.from_numpy(_UPTO).to(local), omega)"):
        "torch.einsum accepts upper-case subscripts: the same contraction",
    ("umf.kinematics.x__lm_step",
     "for j in range(NUM_JOINTS):  # leaves keep their local rotation"):
        "joint 0 is a driver, which the loop skips anyway",
    ("umf.kinematics.x__lm_step",
     "for j in range(2, NUM_JOINTS):  # leaves keep their local rotation"):
        "joint 1 is a driver, which the loop skips anyway",
    ("umf.kinematics.x__lm_step",
     "new_local = parents.transpose(-1, +2) @ new_glob"):
        "parents is 4-D (B, 22, 3, 3): dims (-1, +2) are (-1, -2)",
    ("umf.kinematics.x_clean_targets",
     "target = joints.astype(None).copy()"):
        "numpy's astype(None) is float64 too",
    ("umf.kinematics.x_fit_bodies",
     "if joints.ndim != 4 or joints.shape[+2:] != (NUM_JOINTS, 3) or joints.shape[1] < 1:"):
        "ndim is checked to be 4 first: shape[2:] is shape[-2:]",
    ("umf.kinematics.x_fit_bodies",
     "local = torch.stack([inverse_kinematics(p, None) for p, o in zip(data, offsets, strict=True)])"):  # noqa: E501
        "IK uses only the offsets' directions, the same canonical ones for fitted and "
        "default offsets (FK differs by 1e-18)",
    ("umf.kinematics.x_fit_bodies",
     "local = torch.stack([inverse_kinematics(p, ) for p, o in zip(data, offsets, strict=True)])"):
        "IK uses only the offsets' directions, the same canonical ones for fitted and "
        "default offsets (FK differs by 1e-18)",
    ("umf.kinematics.x_fit_bodies",
     "local = torch.stack([inverse_kinematics(p, o) for p, o in zip(data, offsets, strict=None)])"):
        "offsets is built from data: the zipped lengths always match",
    ("umf.kinematics.x_fit_bodies",
     "local = torch.stack([inverse_kinematics(p, o) for p, o in zip(data, offsets, )])"):
        "offsets is built from data: the zipped lengths always match",
    ("umf.kinematics.x_fit_bodies",
     "local = torch.stack([inverse_kinematics(p, o) for p, o in zip(data, offsets, strict=False)])"):  # noqa: E501
        "offsets is built from data: the zipped lengths always match",
    ("umf.kinematics.x_fit_bodies",
     "c = None if contacts is None or not use else np.asarray(contacts[i], dtype=None)"):
        "contacts are only compared with CONTACT_THRESHOLD: their dtype does not matter",
    ("umf.kinematics.x_fit_bodies",
     "c = None if contacts is None or not use else np.asarray(contacts[i], )"):
        "contacts are only compared with CONTACT_THRESHOLD: their dtype does not matter",
    ("umf.kinematics.x_fit_bodies",
     "if iterations >= 0:"):
        "refine with 0 iterations returns its input unchanged",
    ("umf.kinematics.x_fit_bodies",
     "lift = np.maximum(floor - lowest, 0.0) * np.array(flags, dtype=None)[:, None]"):
        "a bool mask multiplies a float array alike",
    ("umf.kinematics.x_fit_bodies",
     "lift = np.maximum(floor - lowest, 0.0) * np.array(flags, )[:, None]"):
        "a bool mask multiplies a float array alike",
    ("umf.kinematics.x_normal_equations",
     "below = torch.from_numpy(_BELOW).to(None)"):
        "a 0/1 float64 mask times float32 levers, then .float(): the same values",
    ("umf.kinematics.x_normal_equations",
     "w = weight.float().repeat_interleave(3, dim=+1)[..., None]  # (B, 66, 1)"):
        "weight is (B, 22): dim +1 is dim -1",
    ("umf.kinematics.x_pin_targets",
     "fade = 1.0 - np.arange(1, blend + 2) / (blend + 1)"):
        "k <= blend, so fade[:k] never reaches the extra last entry",
    ("umf.kinematics.x_pin_targets",
     "k = min(blend, hi + lo)"):
        "in the fade-in branch lo == 0 or hi - lo > 2 * blend, so min() is the same "
        "(mutant 96 has the same text and is killed)",
    ("umf.kinematics.x_refine",
     "for s in range(0, flat[2].shape[0], BLOCK):"):
        "flat[2] (offsets) has as many rows as flat[1] (roots)",
    ("umf.kinematics.x_refine",
     "lam = torch.full(rt.shape[:1], damping, dtype=None)"):
        "not exact: a float32 damping schedule, cast to float32 for the solve anyway, "
        "differs by float32 rounding only",
    ("umf.kinematics.x_refine",
     "lam = torch.full(rt.shape[:1], damping, )"):
        "not exact: a float32 damping schedule, cast to float32 for the solve anyway, "
        "differs by float32 rounding only",
}  # fmt: skip


def function_of(mutant: str) -> str:
    """``umf.flows.paths.x_expand_time__mutmut_4`` -> ``umf.flows.paths.x_expand_time``."""
    return mutant.rsplit("__mutmut_", 1)[0]


def classify(code: int | None) -> str:
    if code is None:
        return "not run"
    if code == 0:
        return "survived"
    if code == 33:
        return "no tests"
    if code in TIMEOUT_CODES:
        return "timeout"
    return "killed"


def module_of(mutant: str) -> str:
    """``umf.flows.paths.x_expand_time__mutmut_4`` -> ``umf.flows.paths``."""
    parts = mutant.split(".")
    while parts and (parts[-1].startswith("x_") or "__mutmut_" in parts[-1]):
        parts.pop()
    return ".".join(parts)


def read_results(mutants: Path) -> dict[str, int | None]:
    codes: dict[str, int | None] = {}
    for meta in sorted(mutants.rglob("*.meta")):
        codes.update(json.loads(meta.read_text()).get("exit_code_by_key", {}))
    return codes


def rerun_names(previous: dict) -> list[str]:
    """The mutants a rerun of ``previous`` (a mutation.json) checks again: every survivor,
    every mutant no test covered and every equivalent (their reasons are judged again).
    A sampled module is left to ``make mutation-sample``."""
    names = []
    for m in previous["modules"].values():
        if "population" not in m:
            names += m["survivors"] + list(m.get("equivalents", {}))
    return sorted(names)


def carry_over(codes: dict[str, int | None], previous: dict) -> tuple[dict, dict]:
    """(codes, carried): the rerun's ``codes`` with every mutant of ``previous`` it left out
    as a survivor (0), and per module the killed and timeout
    counts of that run, which the rerun does not repeat. A rerun must not have run a mutant
    that the previous run killed: it would count twice."""
    rerun = {k: v for k, v in codes.items() if v is not None}
    checked = set(rerun_names(previous))
    if extra := sorted(set(rerun) - checked):
        raise ValueError(f"{extra[0]} was rerun but is no survivor of the previous report")
    merged, carried = dict(rerun), {}
    for module, m in previous["modules"].items():
        if "population" in m:  # a sample: main() keeps it as it was
            continue
        carried[module] = {"killed": m["killed"], "timeout": m["timeout"]}
        for name in [*m["survivors"], *m.get("equivalents", {})]:
            merged.setdefault(name, 0)
    return merged, carried


def module_names(module: str, root: Path = Path("src")) -> list[str]:
    """Every mutant mutmut makes of ``module`` (``umf.pipeline``), named as its run names
    them: its own generator applied to the module's source."""
    import io

    import mutmut.__main__ as mm

    path = root.joinpath(*module.split(".")).with_suffix(".py")
    if not path.is_file():
        sys.exit(f"error: no module {module} ({path} not found)")
    made = mm.write_all_mutants_to_file(out=io.StringIO(), source=path.read_text(),
                                        filename=path)  # fmt: skip
    return sorted(mm.get_mutant_name(path, n) for n in made.mutant_names)


def sample_names(names: list[str], count: int, seed: int) -> list[str]:
    """A seeded uniform sample of ``count`` of ``names`` (all of them if fewer), sorted."""
    return sorted(random.Random(seed).sample(sorted(names), min(count, len(names))))


def wilson(caught: int, judged: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion: a sampled module's score, which a
    normal interval would push past 100 % when few mutants survive."""
    if judged == 0:
        return 0.0, 1.0
    p = caught / judged
    centre = (p + z * z / (2 * judged)) / (1 + z * z / judged)
    spread = math.sqrt(p * (1 - p) / judged + z * z / (4 * judged * judged))
    half = z * spread / (1 + z * z / judged)
    return max(0.0, centre - half), min(1.0, centre + half)


def carry_sample(
    codes: dict[str, int | None], previous: dict, module: str, population: int
) -> tuple[dict, dict, dict]:
    """(codes, kept, sample): a sampled run of ``module`` beside ``previous``. ``codes``
    keeps the sample's outcomes alone; ``kept`` is every other module of ``previous`` as
    that report judged it (its survivors and equivalents were read off the source it ran
    on, which may have changed since); ``sample`` the sample's size and population."""
    run = {k: v for k, v in codes.items() if v is not None}
    if not run:
        raise ValueError(f"no mutant of {module} ran (an interrupted run?)")
    if stray := sorted(k for k in run if module_of(k) != module):
        raise ValueError(f"{stray[0]} was run but is not a mutant of the sampled {module}")
    kept = {name: m for name, m in previous["modules"].items() if name != module}
    return run, kept, {module: {"sampled": len(run), "population": population}}


def score(
    codes: dict[str, int | None],
    diffs: dict[str, str] | None = None,
    equivalent: dict = EQUIVALENT,
    originals: dict[str, str] | None = None,
    carried: dict | None = None,
) -> dict:
    """Per module: counts by outcome, equivalents among the survivors (matched on their
    function and changed line, ``diffs``), and the score; ``carried`` adds per module the
    killed and timeout counts of an earlier run (:func:`carry_over`)."""
    diffs = diffs or {}
    modules: dict[str, dict] = {}
    for module, c in (carried or {}).items():
        modules[module] = {"killed": c["killed"], "survived": 0, "timeout": c["timeout"],
                           "no tests": 0, "not run": 0, "equivalent": 0,
                           "survivors": []}  # fmt: skip
    for name, code in sorted(codes.items()):
        m = modules.setdefault(module_of(name), {"killed": 0, "survived": 0, "timeout": 0,
                                                 "no tests": 0, "not run": 0,
                                                 "equivalent": 0, "survivors": []})  # fmt: skip
        kind = classify(code)
        reason = None
        if kind == "survived":
            reason = equivalent.get((function_of(name), diffs.get(name, "")))
            if reason is None and device_only((originals or {}).get(name, ""),
                                              diffs.get(name, "")):  # fmt: skip
                reason = f"a device argument: {CPU}"
        if reason is not None:
            m["equivalent"] += 1
            m.setdefault("equivalents", {})[name] = reason
        else:
            m[kind] += 1
            if kind in ("survived", "no tests"):
                m["survivors"].append(name)
    for m in modules.values():
        caught = m["killed"] + m["timeout"]
        judged = caught + m["survived"] + m["no tests"]
        m["score"] = round(caught / judged, 4) if judged else None
    return modules


def mutant_sources(mutants: Path) -> dict[str, str]:
    """Every mutant's function source and every original's (``..__mutmut_orig``), read off
    the mutated copies under ``mutants/src`` (faster than one ``mutmut show`` per mutant)."""
    sources: dict[str, str] = {}
    root = mutants / "src"
    for path in sorted(root.rglob("*.py")):
        text = path.read_text()
        if "__mutmut_" not in text:
            continue
        module = ".".join(path.relative_to(root).with_suffix("").parts)
        lines = text.splitlines()  # sliced by line numbers: get_source_segment rescans the
        for node in ast.walk(ast.parse(text)):  # file per call, minutes on 800 mutants
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and (
                    "__mutmut_" in node.name):  # fmt: skip
                body = lines[node.lineno - 1 : node.end_lineno]
                sources[f"{module}.{node.name}"] = "\n".join(body)
    return sources


_DEVICE_ARG = re.compile(r"device=[^,()]*(\([^()]*\))?")


def device_only(original: str, mutated: str) -> bool:
    """True when two lines differ only in a ``device=`` argument (set to None or dropped):
    on a CPU-only machine every tensor is on the default device anyway."""
    if "device=" not in original:
        return False

    def plain(line: str) -> str:
        line = _DEVICE_ARG.sub("", line).replace(" ", "")
        return re.sub(r",+", ",", line).replace(",)", ")").replace("(,", "(")

    return plain(original) == plain(mutated)


def changed_pair(mutant: str, sources: dict[str, str]) -> tuple[str, str]:
    """(original, mutated) first differing line of a mutant's function, stripped; '' for
    what cannot be told (the mutated copies are gone), "(removed: LINE)" as the mutated
    side of a deletion."""
    mine = sources.get(mutant, "").splitlines()[1:]
    orig = sources.get(function_of(mutant) + "__mutmut_orig", "").splitlines()[1:]
    if not mine or not orig:
        return "", ""
    old = ""
    for line in difflib.ndiff(orig, mine):
        if line.startswith("- ") and not old:
            old = line[2:].strip()
        elif line.startswith("+ "):
            return old, line[2:].strip()
    return old, f"(removed: {old})" if len(mine) < len(orig) else ""


def changed_line(mutant: str, sources: dict[str, str]) -> str:
    """The first line of a mutant's function that differs from the original's, stripped."""
    return changed_pair(mutant, sources)[1]


def markdown(modules: dict, diffs: dict[str, str]) -> str:
    lines = ["# Mutation score (`make mutation`)", "",
             "mutmut 3 over the modules of `[tool.mutmut]` in `pyproject.toml`, each mutant "
             "run against the tests that cover it. The end-to-end tests (`test_pipeline`, "
             "`test_reroll`, `test_exports_agree`: 8-60 s a run) run only for mutants of "
             "`umf.pipeline` (`END_TO_END` in `tests/conftest.py`), so elsewhere a score is "
             "a lower bound on what `make test` catches. Score: killed (timeouts included) "
             "over the mutants run, equivalent ones left out.", "",
             "| module | mutants run | killed | timeout | survived | no tests | equivalent "
             "| score |", "|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for name, m in modules.items():
        run = m["killed"] + m["timeout"] + m["survived"] + m["no tests"] + m["equivalent"]
        pct = "—" if m["score"] is None else f"{100 * m['score']:.1f} %"
        if "population" in m:  # a sample: its size, the population, the interval
            lo, hi = m["interval"]
            run = f"{run} of {m['population']} (a sample)"
            pct += f" (95 %: {100 * lo:.0f}-{100 * hi:.0f} %)"
        lines.append(f"| `{name}` | {run} | {m['killed']} | {m['timeout']} | {m['survived']} "
                     f"| {m['no tests']} | {m['equivalent']} | {pct} |")  # fmt: skip
    whole = [m for m in modules.values() if "population" not in m]
    caught = sum(m["killed"] + m["timeout"] for m in whole)
    judged = caught + sum(m["survived"] + m["no tests"] for m in whole)
    if judged:
        label = "**all**" if len(whole) == len(modules) else "**all run whole**"
        lines.append(f"| {label} | | | | | | | **{100 * caught / judged:.1f} %** |")
    survivors = [s for m in modules.values() for s in m["survivors"]]
    lines += ["", f"## Surviving mutants ({len(survivors)})", ""]
    lines += [f"- `{s}`: `{diffs.get(s, '')}`" for s in survivors] or ["None."]
    equivalents = {k: v for m in modules.values() for k, v in m.get("equivalents", {}).items()}
    lines += ["", f"## Equivalent mutants ({len(equivalents)})", ""]
    lines += [f"- `{k}`: `{diffs.get(k, '')}`: {v}" for k, v in equivalents.items()]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mutants", type=Path, default=Path("mutants"))
    ap.add_argument("--out", type=Path, default=Path("results/mutation"))
    ap.add_argument(
        "--previous",
        type=Path,
        default=None,
        help="the mutation.json whose survivors the mutants/ rerun",
    )
    ap.add_argument(
        "--names",
        action="store_true",
        help="print the mutants a rerun of --previous (or --sample) checks, and exit",
    )
    ap.add_argument("--sample", default=None, help="score one module on a seeded sample")
    ap.add_argument("--count", type=int, default=24, help="mutants in the sample")
    ap.add_argument("--seed", type=int, default=0, help="the sample's seed")
    args = ap.parse_args()
    previous = json.loads(args.previous.read_text()) if args.previous else None
    if args.sample and args.names:
        print("\n".join(sample_names(module_names(args.sample), args.count, args.seed)))
        return
    if args.names:
        if previous is None:
            sys.exit("error: --names needs --previous")
        print("\n".join(rerun_names(previous)))
        return
    codes = read_results(args.mutants)
    if not codes:
        sys.exit(f"error: no mutmut results under {args.mutants} (run `make mutation`)")
    carried, kept, sample = None, {}, {}
    if args.sample and previous is None:
        sys.exit("error: --sample needs --previous (the report its other modules come from)")
    try:
        if args.sample:
            # the run's own mutants of the module (the source may have changed since)
            population = sum(module_of(k) == args.sample for k in codes)
            codes, kept, sample = carry_sample(codes, previous, args.sample, population)
        elif previous is not None:
            codes, carried = carry_over(codes, previous)
    except ValueError as e:
        sys.exit(f"error: {e}")
    sources = mutant_sources(args.mutants)
    pairs = {name: changed_pair(name, sources) for name, code in codes.items()
             if classify(code) in ("survived", "no tests")}  # fmt: skip
    diffs = {name: new for name, (_, new) in pairs.items()}
    if previous is not None:  # a survivor not rerun keeps the line the earlier run read
        diffs = {name: new or previous["diffs"].get(name, "") for name, new in diffs.items()}
    if kept:  # the modules a sample left alone keep their lines and their judgement
        diffs |= {k: v for k, v in previous["diffs"].items() if module_of(k) in kept}
    originals = {name: old for name, (old, _) in pairs.items()}
    modules = score(codes, diffs, originals=originals, carried=carried)
    if previous is not None and not args.sample:  # a sample in the earlier report stays
        for name, m in previous["modules"].items():
            if "population" in m:
                modules[name] = m
                diffs |= {k: v for k, v in previous["diffs"].items() if module_of(k) == name}
    if kept:  # in the earlier report's order
        order = list(previous["modules"]) + [m for m in modules if m not in previous["modules"]]
        modules = {name: modules.get(name) or kept.get(name) or previous["modules"][name]
                   for name in order}  # fmt: skip
    for name, extra in sample.items():
        m = modules.setdefault(name, {"killed": 0, "survived": 0, "timeout": 0, "no tests": 0,
                                      "not run": 0, "equivalent": 0, "survivors": [],
                                      "score": None})  # fmt: skip
        caught = m["killed"] + m["timeout"]
        lo, hi = wilson(caught, caught + m["survived"] + m["no tests"])
        m.update(extra, interval=[round(lo, 4), round(hi, 4)])
        m["not run"] = extra["population"] - extra["sampled"]
    args.out.mkdir(parents=True, exist_ok=True)
    report = {"modules": modules, "diffs": diffs}
    (args.out / "mutation.json").write_text(json.dumps(report, indent=1) + "\n")
    (args.out / "README.md").write_text(markdown(modules, diffs))
    for name, m in modules.items():
        print(f"{name}: score {m['score']}, {len(m['survivors'])} surviving")


if __name__ == "__main__":
    main()
