import numpy as np
import pytest

from umf.data import composer as C
from umf.data import scenes as S
from umf.data.relations import check, check_record, facing_angle, min_interperson_distance
from umf.skeleton import FOOT_LEFT, FOOT_RIGHT


@pytest.fixture(scope="module")
def actors(bandai_clips):
    return [
        S.Actor.from_joints(c.id, c.joints[0], c.meta["content"], c.meta["style"])
        for c in bandai_clips
    ]


def test_actor_is_canonical(actors):
    for a in actors:
        assert np.allclose(a.joints[0, 0, [0, 2]], 0.0, atol=1e-5)
        assert abs(a.joints[..., 1].min()) < 1e-5


def test_composer_is_deterministic_and_valid(actors):
    a = C.compose_corpus(actors, 30, (2,), seed=5)
    b = C.compose_corpus(list(reversed(actors)), 30, (2,), seed=5)
    assert a == b
    assert len(a) == 30
    by_id = {x.id: x for x in actors}
    relations = {r["relation"] for r in a}
    assert len(relations) >= 8
    for r in a:
        j = S.build_scene(r, by_id)
        assert j.shape == (2, r["num_frames"], 22, 3)
        assert S.MIN_FRAMES <= r["num_frames"] <= S.MAX_FRAMES
        results = check_record(j, r)
        assert all(x.passed for x in results), (r["id"], [x.detail for x in results])
        assert any(x.type == "no_contact" for x in results)
        assert len(r["captions"]) >= 3
        assert all(c[0].isupper() for c in r["captions"])
    assert C.compose_corpus(actors, 30, (2,), seed=6) != a


def test_groups(actors):
    groups = C.compose_corpus(actors, 12, (3, 4, 5, 6), seed=1)
    assert len(groups) == 12
    assert {r["num_people"] for r in groups} <= {3, 4, 5, 6}
    by_id = {x.id: x for x in actors}
    for r in groups:
        j = S.build_scene(r, by_id)
        assert j.shape[0] == r["num_people"]
        assert min_interperson_distance(j)[0] >= 0.25
        words = {3: "three", 4: "four", 5: "five", 6: "six"}
        assert any(
            words[r["num_people"]] in c or words.get(r["num_people"] - 1, "") in c
            for c in r["captions"]
        )


def test_captions_match_relation(actors):
    by_id = {x.id: x for x in actors}
    recipes = C.compose_corpus(actors, 40, (2,), seed=2)
    for r in recipes:
        j = S.build_scene(r, by_id)
        if r["relation"] in ("greet", "bow_back", "mirror", "spar"):
            assert facing_angle(j, 0, 1) < 45 and facing_angle(j, 1, 0) < 45
        if r["relation"] == "bow_back":
            assert check(j, {"type": "starts_after", "a": 0, "b": 1, "min_frames": 5}).passed
            assert not check(j, {"type": "starts_after", "a": 1, "b": 0, "min_frames": 5}).passed
        if r["relation"] == "mirror":
            assert r["people"][0]["clip"] == r["people"][1]["clip"]
            assert r["people"][1]["mirrored"]


def test_checks_catch_violations(actors):
    by_id = {x.id: x for x in actors}
    recipe = next(r for r in C.compose_corpus(actors, 20, (2,), seed=3) if r["relation"] == "greet")
    j = S.build_scene(recipe, by_id)
    # turning person 2 around breaks "faces"
    bad = dict(recipe, people=[recipe["people"][0], dict(recipe["people"][1], yaw=0.0)])
    jb = S.build_scene(bad, by_id)
    assert not check(jb, {"type": "faces", "a": 1, "b": 0}).passed
    # putting both on the same spot is caught as contact
    same = dict(recipe, people=[recipe["people"][0], dict(recipe["people"][1], xz=[0.1, 0.0])])
    assert not check(S.build_scene(same, by_id), {"type": "no_contact"}).passed
    assert check(j, {"type": "distance", "a": 0, "b": 1, "min": 1.2, "max": 3.2}).passed
    # side: moving the partner of a side-by-side walk to the other side flips the check
    walk = next(
        r
        for r in C.compose_corpus(actors, 20, (2,), seed=3)
        if r["relation"] == "walk_side_by_side"
    )
    side = next(c for c in walk["constraints"] if c["type"] == "side")
    assert check(S.build_scene(walk, by_id), side).passed
    p2 = walk["people"][1]
    moved = dict(walk, people=[walk["people"][0], dict(p2, xz=[-p2["xz"][0], p2["xz"][1]])])
    assert not check(S.build_scene(moved, by_id), side).passed


def test_time_layout():
    j = np.arange(10, dtype=np.float32)[:, None, None] * np.ones((1, 22, 3), np.float32)
    out = S.time_layout(j, delay=3, start=2, length=12)
    assert out.shape[0] == 12
    assert np.all(out[:4, 0, 0] == 2) and out[4, 0, 0] == 3 and out[-1, 0, 0] == 9


def _walker(id: str, speed: float, frames: int = 90) -> S.Actor:
    """A stick walker moving forward (+Z) at ``speed`` m per frame."""
    j = np.zeros((frames, 22, 3), np.float32)
    j[:, :, 1] = np.linspace(0.0, 1.6, 22)
    j[:, :, 2] = speed * np.arange(frames)[:, None]
    return S.Actor(id, j, "walk", "normal", 0)


def test_paced_relations_pair_walkers_of_the_same_pace():
    # two pace classes: a partner is always drawn from the leader's, never the leader itself
    slow = [_walker("s1", 0.030), _walker("s2", 0.032)]
    fast = [_walker("f1", 0.045), _walker("f2", 0.047)]
    pools = {"walk": slow + fast}
    rng = np.random.default_rng(0)
    for name in ("walk_side_by_side", "group_line"):
        rel = C.RELATIONS[name]
        for _ in range(50):
            n = 2 if name == "walk_side_by_side" else 4
            people = C._pick_actors(rng, rel, n, pools)
            assert people is not None and len(people) == n
            group = slow if people[0] in slow else fast
            assert all(p in group for p in people), [p.id for p in people]
            assert all(p is not people[0] for p in people[1:])
    # a leader with no partner at its pace walks beside its own clip
    a, b = _walker("a", 0.03), _walker("b", 0.05)
    for _ in range(10):
        lead, partner = C._pick_actors(rng, C.RELATIONS["walk_side_by_side"], 2, {"walk": [a, b]})
        assert partner is lead


def test_a_repeated_clip_starts_a_stride_later_and_keeps_its_course(actors):
    """The leader's own clip as its partner (no other at its pace) starts at its next left
    stride, unmirrored: not a copy, and on a parallel course (a mirrored copy of these
    curving walks, placed 0.8 m apart, ends 2.2-2.4 m away: research/paced_scenes.py)."""
    from umf.data.pace import left_strides

    walk = next(a for a in actors if a.id == "dataset-1_walk_normal_001")
    rng = np.random.default_rng(0)
    for name, n in (("walk_side_by_side", 2), ("group_line", 3)):
        layout = C.RELATIONS[name].layout(rng, [walk] * n)
        strides = left_strides(walk.joints)
        assert [p["start"] for p in layout["people"]] == strides[:n].tolist()
        assert not any(p["mirrored"] for p in layout["people"])
        recipe = {"num_frames": layout["num_frames"], "people": layout["people"]}
        j = S.build_scene(recipe, {walk.id: walk})
        gap = np.linalg.norm(j[1:, :, 0, [0, 2]] - j[:1, :, 0, [0, 2]], axis=-1)
        assert np.ptp(gap, axis=1).max() < 0.5, np.ptp(gap, axis=1)  # the gap holds


def test_paced_scenes_keep_pace_to_the_end(actors):
    by_id = {x.id: x for x in actors}
    paced = ("walk_side_by_side", "run_side_by_side", "group_line")
    recipes = C.compose_corpus(actors, 12, (2, 3, 4), seed=2, relations=paced)
    assert recipes
    for r in recipes:
        j = S.build_scene(r, by_id)
        # everybody moves until the last frame: no clip ends early and holds its last pose
        assert all(
            len(by_id[p["clip"]].joints) - p["start"] >= r["num_frames"] for p in r["people"]
        )
        travel = np.linalg.norm(j[:, -1, 0, [0, 2]] - j[:, 0, 0, [0, 2]], axis=-1)
        assert np.all(np.abs(travel / travel[0] - 1.0) <= 0.2), (r["id"], travel)
        # everybody starts on the line across the leader's heading (a clip cut at a stride
        # is moved back by what it travelled before), and in step: the left foot ahead
        assert np.all(np.abs(j[:, 0, 0, 2]) <= 0.2 + 1e-5), (r["id"], j[:, 0, 0, 2])
        for k, p in enumerate(r["people"]):
            if p["start"] > 0:
                ahead = j[k, 0, FOOT_LEFT[1], 2] - j[k, 0, FOOT_RIGHT[1], 2]
                assert ahead > 0.1, (r["id"], k, ahead)
    assert any(p["start"] > 0 for r in recipes for p in r["people"])


def test_left_strides_find_the_left_foot_forward():
    """A synthetic gait whose left foot leads the right by 0.3 sin(2 pi f / 30) m: the
    strides are the sine's crests, one per 30 frames, and a still body has none."""
    from umf.data.pace import left_strides, stride_start
    from umf.skeleton import FACE_JOINTS

    frames = 100
    j = np.zeros((frames, 22, 3), np.float32)
    r_hip, l_hip, r_sh, l_sh = FACE_JOINTS  # facing +Z: left is +X
    for k, x in ((l_hip, 0.1), (r_hip, -0.1), (l_sh, 0.2), (r_sh, -0.2)):
        j[:, k, 0] = x
    lead = 0.3 * np.sin(2 * np.pi * np.arange(frames) / 30)
    j[:, FOOT_LEFT[1], 2], j[:, FOOT_RIGHT[1], 2] = lead / 2, -lead / 2
    # crests at 7.5, 37.5 ...: frames 7 and 8 tie, and the later one is the local maximum
    assert left_strides(j).tolist() == [8, 38, 68, 98]
    assert stride_start(j) == left_strides(j)[0]
    assert left_strides(np.zeros_like(j)).size == 0 and stride_start(np.zeros_like(j)) == 0
    # mirrored (left and right swapped), the crests move half a cycle
    swapped = j.copy()
    swapped[:, [FOOT_LEFT[1], FOOT_RIGHT[1]]] = j[:, [FOOT_RIGHT[1], FOOT_LEFT[1]]]
    assert left_strides(swapped).tolist() == [23, 53, 83]


def test_side_by_side_captions_name_the_side_the_check_asks_for(actors):
    # the relation checks read a scene's first caption: for a side-by-side pair it must say
    # which side the second person keeps, or the "side" check asks for a coin flip
    recipes = [r for r in C.compose_corpus(actors, 60, (2,), seed=11)
               if r["relation"] in ("walk_side_by_side", "run_side_by_side")]  # fmt: skip
    sides = set()
    for r in recipes:
        side = next(c["side"] for c in r["constraints"] if c["type"] == "side")
        other = "right" if side == "left" else "left"
        named = [c for c in r["captions"] if side in c or other in c]
        assert r["captions"][0] in named and len(named) == 3
        assert all(side in c and other not in c for c in named)
        assert len(r["captions"]) - len(named) == 2  # and two wordings leave it open
        sides.add(side)
    assert sides == {"left", "right"}  # both sides occur, each named as itself


def test_stand_facing_pairs_two_different_actions_the_captions_leave_open(actors):
    """The per-person prompts' training scenes: two people face each other doing
    different in-place actions, each action as likely as any other, and no scene caption
    names an action (only each person's own captions do)."""
    from umf.data.scene_relations import IN_PLACE, RELATIONS

    rel = RELATIONS["stand_facing"]
    pools: dict[str, list] = {}
    for a in actors:
        pools.setdefault(a.content, []).append(a)
    kinds = {c for c in IN_PLACE if pools.get(c)}
    assert len(kinds) >= 2, "the fixture has in-place actions"
    rng = np.random.default_rng(0)
    seen = []
    for _ in range(200):
        pair = C._pick_actors(rng, rel, 2, pools)
        assert pair is not None and pair[0].content != pair[1].content
        assert {p.content for p in pair} <= kinds
        seen += [p.content for p in pair]
    counts = np.array([seen.count(k) for k in sorted(kinds)])
    assert counts.min() > 0.4 * counts.mean()  # uniform over actions, not over clips
    by_id = {x.id: x for x in actors}
    out = C.compose_scene(np.random.default_rng(1), rel, 2, pools, by_id)
    assert out is not None
    recipe, joints = out
    assert all(r.passed for r in check_record(joints, recipe))
    assert facing_angle(joints, 0, 1) < 45 and facing_angle(joints, 1, 0) < 45
    actions = ("wave", "bow", "raise", "hand", "kick", "punch", "slash", "call")
    for caption in recipe["captions"]:
        assert not any(w in caption.lower() for w in actions), caption


def test_starts_after_reads_the_action_not_the_shimmer(bandai_clips):
    """Decoded motion shimmers a few mm per joint per frame. Read frame to frame, a second of
    shimmering stillness weighs as much as a bow, so a person who waits 40 frames seems to
    bow at once; the check averages positions over ``ONSET_SMOOTHING`` frames first and
    reads the wait."""
    from umf.data.relations import ONSET_SMOOTHING, action_onset, moving_average

    bow = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001").joints[0]
    rng = np.random.default_rng(0)

    def waits(frames: int) -> np.ndarray:
        still, after = np.repeat(bow[:1], frames, 0), np.repeat(bow[-1:], 40 - frames, 0)
        j = np.concatenate([still, bow, after])
        return j + rng.normal(0.0, 0.001, j.shape)  # 1 mm per coordinate and frame

    clean = np.concatenate([np.repeat(bow[:1], 40, 0), bow])
    early, late = waits(0), waits(40)
    want = action_onset(clean, smooth=ONSET_SMOOTHING)  # the wait, read without shimmer
    assert abs(want - (action_onset(bow) + 40)) <= 3
    assert abs(action_onset(late, smooth=ONSET_SMOOTHING) - want) <= 3
    assert action_onset(late) < want - 15  # frame to frame: the shimmer reads as the bow
    scene = np.stack([early, late])
    assert check(scene, {"type": "starts_after", "a": 0, "b": 1, "min_frames": 30}).passed
    assert not check(scene, {"type": "starts_after", "a": 1, "b": 0, "min_frames": 5}).passed
    x = np.arange(12.0)[:, None]  # the average over a centred window, the ends repeated
    np.testing.assert_allclose(moving_average(x, 3)[[0, 5, 11], 0], [1 / 3, 5.0, 32 / 3])
    assert moving_average(x, 1) is x
