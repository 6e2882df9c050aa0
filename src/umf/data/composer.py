"""The composer: seeded scenes of a relation from the corpus's actors, kept only when every
check of the relation holds on the placed joints (:mod:`umf.data.scene_relations`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from umf.data.pace import partners_at_pace
from umf.data.relations import check_record
from umf.data.scene_relations import PACED, RELATIONS, Relation
from umf.data.scenes import MIN_FRAMES, Actor, build_scene

# Relations whose people each do a different action, named only in their own captions
# (the per-person prompts learn from them): contents drawn uniformly, all different.
DISTINCT = ("stand_facing",)


# --------------------------------------------------------------------- composer
def _draw(rng, pool: list[Actor]) -> Actor:
    return pool[int(rng.integers(len(pool)))]


def _pick_actors(
    rng,
    relation: Relation,
    n: int,
    pools: dict[str, list[Actor]],
    paces: dict[str, float] | None = None,
) -> list[Actor] | None:
    """The actors of one scene of ``relation``, or None when its roles cannot be filled;
    ``paces``: clip paces already measured in this composition (filled as needed)."""
    chosen: list[Actor] = []
    roles = relation.roles(n)
    if relation.name == "audience":  # the group answers in kind: call -> respond, bow -> bow
        answers = {"call": "respond", "bow": "bow"}
        lead = [a for c in roles[0] for a in pools.get(c, []) if pools.get(answers[c])]
        if not lead:
            return None
        leader = lead[int(rng.integers(len(lead)))]
        roles = [(leader.content,)] + [(answers[leader.content],)] * (n - 1)
    if relation.name in PACED:
        # one speed class for everybody, and each partner within PACE_TOLERANCE of the
        # leader's pace: partners of unequal pace drift apart, and a flow trained on them
        # learns followers that fall behind (results/reaction-pace-20261202)
        first = [a for c in roles[0] for a in pools.get(c, [])]
        if not first:
            return None
        leader = first[int(rng.integers(len(first)))]
        # no other clip at its pace: the leader's own clip, a stride later (the layout)
        partners = partners_at_pace(leader, pools[leader.content], {} if paces is None else paces)
        partners = partners or [leader]
        return [leader] + [partners[int(rng.integers(len(partners)))] for _ in range(n - 1)]
    if relation.name in DISTINCT:
        # two different actions, each action as likely as any other (not each clip: the
        # raised hands have 30 times the clips of a bow)
        kinds = sorted({c for c in roles[0] if pools.get(c)})
        if len(kinds) < n:
            return None
        picked = rng.choice(len(kinds), size=n, replace=False)
        return [_draw(rng, pools[kinds[int(i)]]) for i in picked]
    for contents in roles:
        cands = [a for c in contents for a in pools.get(c, [])]
        if not cands:
            return None
        chosen.append(cands[int(rng.integers(len(cands)))])
    if relation.name == "mirror":
        chosen[1] = chosen[0]
    return chosen


def compose_scene(
    rng: np.random.Generator,
    relation: Relation,
    n: int,
    pools: dict[str, list[Actor]],
    actors_by_id: dict[str, Actor],
    max_tries: int = 20,
    paces: dict[str, float] | None = None,
) -> tuple[dict[str, Any], np.ndarray] | None:
    """One valid scene (recipe, joints) of ``relation`` with ``n`` people, or None."""
    for _ in range(max_tries):
        actors = _pick_actors(rng, relation, n, pools, paces)
        if actors is None:
            return None
        layout = relation.layout(rng, actors)
        if layout is None or layout["num_frames"] < MIN_FRAMES:
            continue
        recipe = {
            "relation": relation.name,
            "num_people": n,
            "num_frames": int(layout["num_frames"]),
            "people": layout["people"],
            "constraints": layout["constraints"],
            "captions": [c[0].upper() + c[1:] for c in relation.captions(rng, actors, n, layout)],
        }
        joints = build_scene(recipe, actors_by_id)
        if all(r.passed for r in check_record(joints, recipe)):
            return recipe, joints
    return None


def compose_corpus(
    actors: Sequence[Actor],
    num_scenes: int,
    sizes: Sequence[int],
    seed: int,
    relations: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """``num_scenes`` valid recipes, spread evenly over relations that fit ``sizes``.

    Deterministic for a given seed and actor list (order-independent: actors are
    sorted by id first).
    """
    rng = np.random.default_rng(seed)
    actors = sorted(actors, key=lambda a: a.id)
    by_id = {a.id: a for a in actors}
    pools: dict[str, list[Actor]] = {}
    for a in actors:
        pools.setdefault(a.content, []).append(a)
    paces: dict[str, float] = {}  # measured once per clip for the paced relations
    names = [r for r in (relations or RELATIONS) if set(RELATIONS[r].sizes) & set(sizes)]
    recipes: list[dict[str, Any]] = []
    failures = attempt = 0
    while len(recipes) < num_scenes and names:
        rel = RELATIONS[names[attempt % len(names)]]
        attempt += 1
        n = int(rng.choice([s for s in sizes if s in rel.sizes]))
        out = compose_scene(rng, rel, n, pools, by_id, paces=paces)
        if out is None:
            failures += 1
            if failures > 50 * max(num_scenes, 1):
                break
            # a relation whose roles cannot be filled from this pool is dropped
            if _pick_actors(rng, rel, n, pools, paces) is None:
                names.remove(rel.name)
            continue
        recipe, _ = out
        recipe["id"] = f"{rel.name}-{len(recipes):05d}"
        recipes.append(recipe)
    return recipes
