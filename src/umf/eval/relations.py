"""Relation accuracy: do generated scenes obey the relation records of the test scenes?

Every composed test scene carries a machine-readable record (who faces whom, distance
band, side, order, approach / retreat, timing, no contact; see
:mod:`umf.data.relations`). A model prompted with the scene's caption and number of
people should produce a scene that passes the same checks; the real scene itself is the
reference (it passes all of them by construction).

The checks only use differences of root positions on the floor, horizontal facing
directions and distances, so they are invariant to any turn about +Y and any
translation: a generated scene in person 1's canonical frame and a corpus scene in
another frame are compared as they are, provided people come in the record's order.
Mirroring is *not* an invariance (left and right swap), and neither is a change of
people order: the strict reading wants people in the record's order. A group caption
("three people walk side by side.") does not say who stands where, while the record was
composed in one order (each next person on the previous one's left). So groups are also
read in any order of the people their caption does not tell apart
(:data:`INTERCHANGEABLE`, :func:`any_order_checks`), beside the strict reading.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import Any

import numpy as np

from umf.data.clip import FPS
from umf.data.relations import CheckResult, check
from umf.data.scenes import Actor, build_scene
from umf.eval.physics import as_numpy

# constraint entries that count frames at the corpus frame rate
_FRAME_KEYS = ("frame", "min_frames")


def _at_fps(constraint: dict[str, Any], fps: float, num_frames: int) -> dict[str, Any]:
    """The constraint with frame counts converted from the corpus rate to ``fps``."""
    c = dict(constraint)
    if fps != FPS:
        for key in _FRAME_KEYS:
            if key in c:
                c[key] = round(c[key] * fps / FPS)
    if "frame" in c:  # a shorter generated scene is checked at its last frame
        c["frame"] = min(c["frame"], num_frames - 1)
    return c


def scene_checks(record: dict[str, Any], joints: Any, fps: float = FPS) -> list[CheckResult]:
    """Every constraint of ``record`` evaluated on ``joints`` (N, T, 22, 3) at ``fps``."""
    j = as_numpy(joints)
    if j.ndim != 4 or j.shape[0] != record["num_people"]:
        raise ValueError(
            f"{record.get('id', 'scene')}: record has {record['num_people']} people, "
            f"joints are {j.shape}"
        )
    return [check(j, _at_fps(c, fps, j.shape[1])) for c in record["constraints"]]


# relation -> the first person (0-based) from whom on its captions tell nobody apart: anyone
# in a row, a single file or a circle; everyone but the caller or the bower before an
# audience or a gathering (whose checks are the same for each of the others, so that any
# order reads as the recorded one: listed for completeness). Pairs name their roles ("the
# second person on the first one's left", "one person bows and the other bows back"): not
# listed, read in order only.
INTERCHANGEABLE = {"group_line": 0, "single_file": 0, "circle_greet": 0, "audience": 1,
                   "gather": 1}  # fmt: skip
MAX_PERMUTED = 6  # people whose every order is tried (720); more are read as recorded


def any_order_checks(
    record: dict[str, Any],
    joints: Any,
    fps: float = FPS,
    strict: Sequence[CheckResult] | None = None,
) -> list[CheckResult]:
    """:func:`scene_checks` in the order of the people the caption leaves open
    (:data:`INTERCHANGEABLE`) that passes the most checks (the record's own order on a
    tie); people are renumbered back, so the results name the scene's people. A record of
    another relation, or with more than :data:`MAX_PERMUTED` such people (the protocol's
    groups have at most 6), is read in order. ``strict``: the results in the record's order,
    where the caller has them already."""
    j = as_numpy(joints)
    first = INTERCHANGEABLE.get(record.get("relation", ""))
    strict = scene_checks(record, j, fps) if strict is None else list(strict)
    n = j.shape[0]
    if first is None or not 2 <= n - first <= MAX_PERMUTED or all(r.passed for r in strict):
        return strict
    constraints = [_at_fps(c, fps, j.shape[1]) for c in record["constraints"]]
    cache: dict[tuple[int, int, int], CheckResult] = {}
    for i, (c, res) in enumerate(zip(constraints, strict, strict=True)):  # the recorded order
        pair = "a" in c or "b" in c
        cache[(i, c.get("a", 0), c.get("b", 1)) if pair else (i, -1, -1)] = res

    def result(i: int, c: dict[str, Any], order: tuple[int, ...]) -> CheckResult:
        if "a" not in c and "b" not in c:  # no_contact: the same in any order
            key = (i, -1, -1)
        else:
            key = (i, order[c.get("a", 0)], order[c.get("b", 1)])
        if key not in cache:
            moved = dict(c)
            if key[1] >= 0:
                moved["a"], moved["b"] = key[1], key[2]
            cache[key] = check(j, moved)
        return cache[key]

    best, best_passed = strict, sum(r.passed for r in strict)
    for tail in itertools.permutations(range(first, n)):
        order = (*range(first), *tail)
        res = [result(i, c, order) for i, c in enumerate(constraints)]
        passed = sum(r.passed for r in res)
        if passed > best_passed:
            best, best_passed = res, passed
            if passed == len(res):
                break
    return best


def _rate(flags: Sequence[bool]) -> float:
    return float(np.mean(flags)) if len(flags) else float("nan")


def accuracy_from_checks(
    records: Sequence[dict[str, Any]], results: Sequence[Sequence[CheckResult]]
) -> dict[str, Any]:
    """Aggregate per-scene check results (see :func:`relation_accuracy` for the keys)."""
    by_kind: dict[str, list[bool]] = {}
    by_relation: dict[str, list[bool]] = {}
    by_size: dict[str, list[bool]] = {}
    scene_ok, all_checks = [], []
    for record, res in zip(records, results, strict=True):
        ok = all(r.passed for r in res)
        scene_ok.append(ok)
        by_relation.setdefault(record.get("relation", "?"), []).append(ok)
        by_size.setdefault(str(record["num_people"]), []).append(ok)
        for r in res:
            by_kind.setdefault(r.type, []).append(r.passed)
            all_checks.append(r.passed)
    kinds = {k: {"accuracy": _rate(v), "count": len(v)} for k, v in sorted(by_kind.items())}
    return {
        "num_scenes": len(scene_ok),
        "num_checks": len(all_checks),
        "scene_accuracy": _rate(scene_ok),
        "check_accuracy": _rate(all_checks),
        "kind_accuracy": _rate([k["accuracy"] for k in kinds.values()]) if kinds else 0.0,
        "by_kind": kinds,
        "by_relation": {k: _rate(v) for k, v in sorted(by_relation.items())},
        "by_num_people": {k: _rate(v) for k, v in sorted(by_size.items(), key=lambda x: int(x[0]))},
    }


def relation_accuracy(
    records: Sequence[dict[str, Any]],
    joints_list: Sequence[Any],
    fps: float = FPS,
    reference: Sequence[Any] | None = None,
) -> dict[str, Any]:
    """Relation accuracy of generated scenes against their records.

    Args:
        records: relation records (scene recipes) with ``num_people`` and
            ``constraints``; frame counts in them are at the corpus rate (30 fps).
        joints_list: one generated scene (N, T, 22, 3) per record, people in the
            record's order, sampled at ``fps``.
        reference: optionally the real scenes (at 30 fps) of the same records; their
            accuracy is reported under ``"reference"``.
    Returns:
        ``scene_accuracy`` (fraction of scenes passing every check), ``check_accuracy``
        (fraction of all checks passed), ``kind_accuracy`` (mean of the per-kind
        accuracies), ``by_kind`` ({kind: {accuracy, count}} for faces, faces_away,
        distance, side, order, same_heading, approach, retreat, starts_after,
        no_contact), ``by_relation`` and ``by_num_people`` (scene accuracy), counts,
        ``any_order`` (``scene_accuracy``, ``by_relation``, ``by_kind`` of
        :func:`any_order_checks`) where a record has people its caption does not tell
        apart, and ``reference`` when given.
    """
    if len(records) != len(joints_list):
        raise ValueError(f"{len(records)} records but {len(joints_list)} scenes")
    results = [scene_checks(r, j, fps) for r, j in zip(records, joints_list, strict=True)]
    out = accuracy_from_checks(records, results)
    if any(r.get("relation") in INTERCHANGEABLE for r in records):
        loose = [any_order_checks(r, j, fps, res)
                 for r, j, res in zip(records, joints_list, results, strict=True)]  # fmt: skip
        acc = accuracy_from_checks(records, loose)
        out["any_order"] = {k: acc[k] for k in ("scene_accuracy", "by_relation", "by_kind")}
    if reference is not None:
        out["reference"] = relation_accuracy(records, reference, FPS)
    return out


def real_scene_joints(corpus: Any, recipes: Sequence[dict[str, Any]]) -> list[np.ndarray]:
    """Real joints (N, T, 22, 3) of corpus scene recipes, in person 1's canonical frame.

    Builds only the actors these recipes use (about a second for the test splits)
    rather than :meth:`Corpus.actors` (every clip, tens of seconds on the full corpus);
    the joints are identical to ``corpus.scene_joints``.
    """
    needed = {p["clip"] for r in recipes for p in r["people"]}
    actors = {
        c.id: Actor.from_joints(c.id, c.joints[0], c.meta.get("content", ""), "")
        for c in corpus.clips
        if c.id in needed and c.num_people == 1
    }
    return [build_scene(r, actors) for r in recipes]
