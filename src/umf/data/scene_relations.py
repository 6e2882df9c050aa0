"""The relations a composed scene can show (greet, bow back, walk side by side, follow,
call and approach, step back, spar, mirror, part ways, lines, circles, an audience,
gathering ...): for each, which clips play each role, where people stand and face, when
each starts, the captions that describe it and the checks that must hold."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from umf.data.pace import in_step
from umf.data.relations import CONTACT_DISTANCE
from umf.data.scenes import MAX_FRAMES, MIN_FRAMES, Actor, forward_travel, heading_to

NUMBER_WORDS = {2: "two", 3: "three", 4: "four", 5: "five", 6: "six", 7: "seven", 8: "eight"}


GREETINGS = ("bow", "bye", "byebye", "wave-both-hands", "wave-left-hand", "wave-right-hand")


WALKS = ("walk",)


RUNS = ("run", "dash")


ATTACKS = ("kick", "punch", "slash")


GESTURES = (
    "bow", "bye", "byebye", "wave-both-hands", "wave-left-hand", "wave-right-hand",
    "raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand", "guide",
)  # fmt: skip


@dataclass
class Relation:
    """A named way for people to relate; ``layout`` turns actors into a recipe."""

    name: str
    roles: Callable[[int], list[tuple[str, ...]]]  # per-person allowed contents for N people
    layout: Callable[..., dict[str, Any] | None]
    captions: Callable[..., list[str]]  # (rng, actors, n, layout): wordings, [0] checked
    sizes: tuple[int, ...]  # numbers of people it supports


def _person(
    actor: Actor, yaw: float, xz, delay: int = 0, start: int = 0, mirrored: bool = False
) -> dict:
    return {
        "clip": actor.id,
        "content": actor.content,
        "style": actor.style,
        "mirrored": mirrored,
        "start": int(start),
        "delay": int(delay),
        "yaw": float(yaw),
        "xz": [float(xz[0]), float(xz[1])],
    }


# Relations whose people move together: their partners are drawn at the leader's pace
# (the composer) and the scene ends with the shortest clip, so nobody stops while the
# others go on.
PACED = ("walk_side_by_side", "run_side_by_side", "group_line")


def _paced_people(
    actors: Sequence[Actor], xz: Sequence[tuple[float, float]]
) -> tuple[list[dict], int]:
    """People of a paced relation at ``xz`` (each first pelvis position), in step with the
    leader; and the frames they all keep moving."""
    starts = in_step(actors)
    people = []
    for a, (x, z), s in zip(actors, xz, starts, strict=True):
        at = a.joints[s, 0]  # a clip cut at frame s starts there: move it back to xz
        people.append(_person(a, 0.0, (x - float(at[0]), z - float(at[2])), start=s))
    n = min(len(a.joints) - s for a, s in zip(actors, starts, strict=True))
    return people, int(min(n, MAX_FRAMES))


def _length(
    actors: Sequence[Actor], delays: Sequence[int], starts: Sequence[int] | None = None
) -> int:
    starts = starts or [0] * len(actors)
    # the scene lasts while the longest-running person still acts, capped at MAX_FRAMES
    n = max(a.joints.shape[0] - s + d for a, d, s in zip(actors, delays, starts, strict=True))
    return int(min(n, MAX_FRAMES))


def _aligned_delay(leader: Actor, follower: Actor, lag: int) -> tuple[int, int]:
    """(delay, start) for the follower so its onset comes ``lag`` frames after the leader's."""
    shift = leader.onset + lag - follower.onset
    return (shift, 0) if shift >= 0 else (0, -shift)


def _frames_while(ok: np.ndarray) -> int:
    """Frames from the start for which ``ok`` holds (a scene is cut where it first fails)."""
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if len(bad) else len(ok)


def _facing_each_other() -> list[dict]:
    return [{"type": "faces", "a": 0, "b": 1}, {"type": "faces", "a": 1, "b": 0}]


def _no_contact() -> dict:
    return {"type": "no_contact", "min_distance": CONTACT_DISTANCE}


def _face_each_other(rng, actors, lag: int | None):
    a, b = actors
    d = float(rng.uniform(1.6, 2.6))
    delay, start = _aligned_delay(a, b, lag) if lag is not None else (0, 0)
    n = _length(actors, [0, delay], [0, start])
    people = [_person(a, 0.0, (0.0, 0.0)), _person(b, np.pi, (0.0, d), delay, start)]
    cons = [
        *_facing_each_other(),
        {"type": "distance", "a": 0, "b": 1, "min": 1.2, "max": 3.2},
        _no_contact(),
    ]
    if lag is not None:
        cons.append({"type": "starts_after", "a": 0, "b": 1, "min_frames": max(lag // 2, 5)})
    return {"num_frames": n, "people": people, "constraints": cons}


def _greet_captions(rng, actors, n, layout):
    words = {a.content for a in actors}
    if words == {"bow"}:
        core = [
            "two people face each other and bow.",
            "two people bow to each other.",
            "facing each other, two people exchange bows.",
        ]
    elif words <= {"bye", "byebye", "wave-both-hands", "wave-left-hand", "wave-right-hand"}:
        core = [
            "two people face each other and wave.",
            "two people wave at each other.",
            "two people greet each other with a wave.",
        ]
    else:
        core = [
            "two people face each other and greet each other.",
            "two people greet each other, one bows and the other waves.",
            "facing each other, two people say hello.",
        ]
    return core


# In-place actions of "stand_facing": each person does their own, which only their own
# prompt names (the per-person prompts; the scene's captions leave the actions open).
IN_PLACE = (*GESTURES, "call", "respond", "kick", "punch", "slash")


def _stand_facing_captions(rng, actors, n, layout):
    """Name no action: what each person does is in their own captions (the clip's)."""
    return [
        "two people stand facing each other.",
        "two people face each other.",
        "two people stand opposite each other.",
        "two people meet face to face.",
    ]


def _bow_back_captions(rng, actors, n, layout):
    return [
        "one person bows and the other bows back.",
        "a person bows to someone, who then returns the bow.",
        "two people face each other; the first bows and the second answers with a bow.",
    ]


def _side_by_side(rng, actors, spacing=(0.7, 1.1)):
    lat = float(rng.uniform(*spacing))
    side = "left" if rng.random() < 0.5 else "right"
    x = lat if side == "left" else -lat
    people, n = _paced_people(actors, [(0.0, 0.0), (x, float(rng.uniform(-0.2, 0.2)))])
    cons = [
        {"type": "same_heading", "a": 0, "b": 1},
        {"type": "side", "a": 0, "b": 1, "side": side},
        {"type": "distance", "a": 0, "b": 1, "min": 0.5, "max": 1.6},
        _no_contact(),
    ]
    return {"num_frames": n, "people": people, "constraints": cons, "side": side}


def _walk_together_captions(rng, actors, n, layout):
    """The first three name the side the second person keeps (the "side" check reads the
    first caption); the last two leave it open, as most users' prompts do."""
    verb = "run" if actors[0].content in RUNS else "walk"
    side = layout["side"]
    return [
        f"two people {verb} side by side, the second person on the first one's {side}.",
        f"a person {verb}s forward with another person at their {side} side.",
        f"two people {verb} next to each other, the second keeping to the {side} of the first.",
        f"two people {verb} side by side.",
        f"a pair of people {verb} forward together, shoulder to shoulder.",
    ]


def _follow(rng, actors):
    a, b = actors
    gap = float(rng.uniform(1.6, 2.6))
    # keep the follower from catching up: walk clips of different speeds end early
    ta, tb = forward_travel(a.joints), forward_travel(b.joints)
    n = min(len(ta), len(tb), MAX_FRAMES)
    closing = tb[:n] - ta[:n]
    n = _frames_while(gap - closing > 0.9)
    if n < MIN_FRAMES:
        return None
    people = [_person(a, 0.0, (0.0, 0.0)), _person(b, 0.0, (0.0, -gap))]
    cons = [
        {"type": "same_heading", "a": 0, "b": 1},
        {"type": "order", "a": 0, "b": 1},
        {"type": "distance", "a": 0, "b": 1, "min": 1.0, "max": 3.5},
        _no_contact(),
    ]
    return {"num_frames": n, "people": people, "constraints": cons}


def _follow_captions(rng, actors, n, layout):
    return [
        "one person follows another.",
        "a person walks behind another person, following them.",
        "two people walk in single file, one behind the other.",
    ]


def _walk_up_to(walker: Actor, dist: float, stop: float = 1.0) -> int:
    """Frames a walker can walk straight ahead before getting within ``stop`` m."""
    travel = forward_travel(walker.joints)
    return _frames_while(dist - travel > stop)


def _call_approach(rng, actors):
    caller, walker = actors
    d = float(rng.uniform(3.0, 4.5))
    delay, start = _aligned_delay(caller, walker, int(rng.integers(10, 25)))
    n = min(_walk_up_to(walker, d) + delay, MAX_FRAMES)
    if n - delay < MIN_FRAMES:
        return None
    people = [_person(caller, 0.0, (0.0, 0.0)), _person(walker, np.pi, (0.0, d), delay, start)]
    cons = [
        *_facing_each_other(),
        {"type": "approach", "a": 1, "b": 0, "min_change": 0.5},
        _no_contact(),
    ]
    return {"num_frames": n, "people": people, "constraints": cons}


def _call_approach_captions(rng, actors, n, layout):
    return [
        "one person calls out and the other walks over to them.",
        "a person beckons someone, who walks towards them.",
        "someone calls a person over and that person approaches.",
    ]


def _call_respond_captions(rng, actors, n, layout):
    return [
        "one person calls out to another, who responds.",
        "a person calls someone and the other answers.",
        "two people face each other; one calls and the other reacts to the call.",
    ]


def _step_back(rng, actors):
    attacker, defender = actors
    d = float(rng.uniform(1.5, 2.1))
    delay, start = _aligned_delay(attacker, defender, int(rng.integers(3, 12)))
    n = _length(actors, [0, delay], [0, start])
    people = [
        _person(attacker, 0.0, (0.0, 0.0)),
        _person(defender, np.pi, (0.0, d), delay, start),
    ]
    cons = [
        *_facing_each_other(),
        {"type": "retreat", "a": 1, "b": 0, "min_change": 0.4},
        _no_contact(),
    ]
    return {"num_frames": n, "people": people, "constraints": cons}


def _step_back_captions(rng, actors, n, layout):
    verb = {"kick": "kicks", "punch": "throws a punch", "slash": "slashes"}[actors[0].content]
    return [
        f"one person {verb} and the other steps back.",
        f"a person {verb} at someone, who backs away.",
        f"two people face each other; one {verb} and the other retreats.",
    ]


def _spar(rng, actors):
    return _face_each_other(rng, actors, lag=int(rng.integers(10, 30)))


def _spar_captions(rng, actors, n, layout):
    return [
        "two people face each other and fight.",
        "two people spar, attacking each other in turn.",
        "one person attacks and the other strikes back.",
    ]


def _mirror(rng, actors):
    (a,) = actors[:1]
    d = float(rng.uniform(1.6, 2.4))
    n = _length([a, a], [0, 0])
    people = [_person(a, 0.0, (0.0, 0.0)), _person(a, np.pi, (0.0, d), mirrored=True)]
    cons = [
        *_facing_each_other(),
        {"type": "distance", "a": 0, "b": 1, "min": 1.2, "max": 3.0},
        _no_contact(),
    ]
    return {"num_frames": n, "people": people, "constraints": cons}


def _mirror_captions(rng, actors, n, layout):
    return [
        "two people face each other and mirror each other's movements.",
        "facing each other, two people move like mirror images.",
        "one person copies the other like a mirror.",
    ]


def _part_ways(rng, actors):
    a, b = actors
    gap = float(rng.uniform(0.8, 1.2))
    n = _length(actors, [0, 0])
    people = [_person(a, 0.0, (0.0, gap / 2)), _person(b, np.pi, (0.0, -gap / 2))]
    cons = [
        {"type": "faces_away", "a": 0, "b": 1},
        {"type": "faces_away", "a": 1, "b": 0},
        {"type": "retreat", "a": 0, "b": 1, "min_change": 1.0},
        _no_contact(),
    ]
    return {"num_frames": n, "people": people, "constraints": cons}


def _part_captions(rng, actors, n, layout):
    return [
        "two people walk away from each other.",
        "two people part ways, walking in opposite directions.",
        "standing back to back, two people walk off in opposite directions.",
    ]


def _toward_each_other(rng, actors):
    a, b = actors
    d = float(rng.uniform(5.0, 7.0))
    lateral = float(rng.uniform(0.6, 0.9)) * (1 if rng.random() < 0.5 else -1)
    ta, tb = forward_travel(a.joints), forward_travel(b.joints)
    n = min(len(ta), len(tb), MAX_FRAMES)
    n = _frames_while(d - (ta[:n] + tb[:n]) > 1.2)
    if n < MIN_FRAMES:
        return None
    yaw_b = np.pi
    people = [_person(a, 0.0, (0.0, 0.0)), _person(b, yaw_b, (lateral, d))]
    cons = [
        *_facing_each_other(),
        {"type": "approach", "a": 0, "b": 1, "min_change": 0.8},
        _no_contact(),
    ]
    return {"num_frames": n, "people": people, "constraints": cons}


def _toward_captions(rng, actors, n, layout):
    return [
        "two people walk towards each other.",
        "two people approach each other from opposite sides.",
        "two people walk up to each other.",
    ]


# ---- groups of 3..6
def _line(rng, actors, spacing=(0.8, 1.1)):
    n_people = len(actors)
    gap = float(rng.uniform(*spacing))
    xs = (np.arange(n_people) - (n_people - 1) / 2) * gap
    people, n = _paced_people(actors, [(float(x), float(rng.uniform(-0.15, 0.15))) for x in xs])
    cons = [{"type": "same_heading", "a": 0, "b": i} for i in range(1, n_people)]
    # x grows to the left of people facing +Z: each next person is on the previous one's left
    cons += [{"type": "side", "a": i, "b": i + 1, "side": "left"} for i in range(n_people - 1)]
    cons.append(_no_contact())
    return {"num_frames": n, "people": people, "constraints": cons}


def _line_captions(rng, actors, n, layout):
    k = NUMBER_WORDS[n]
    verb = "run" if actors[0].content in RUNS else "walk"
    return [
        f"{k} people {verb} side by side.",
        f"a group of {k} people {verb} forward in a row.",
        f"{k} people {verb} together, shoulder to shoulder.",
    ]


def _single_file(rng, actors):
    n_people = len(actors)
    gap = float(rng.uniform(1.8, 2.4))
    travel = [forward_travel(a.joints) for a in actors]
    n = min(min(len(t) for t in travel), MAX_FRAMES)
    zs = [-i * gap for i in range(n_people)]
    # everyone must stay at least 0.9 m behind the person ahead
    margin = np.min(
        [(zs[i] + travel[i][:n]) - (zs[i + 1] + travel[i + 1][:n]) for i in range(n_people - 1)],
        axis=0,
    )
    n = _frames_while(margin > 0.9)
    if n < MIN_FRAMES:
        return None
    people = [_person(a, 0.0, (0.0, z)) for a, z in zip(actors, zs, strict=True)]
    cons = [{"type": "order", "a": i, "b": i + 1} for i in range(n_people - 1)]
    cons += [{"type": "same_heading", "a": 0, "b": i} for i in range(1, n_people)]
    cons.append(_no_contact())
    return {"num_frames": n, "people": people, "constraints": cons}


def _single_file_captions(rng, actors, n, layout):
    k = NUMBER_WORDS[n]
    return [
        f"{k} people walk in single file.",
        f"{k} people follow a leader, one behind the other.",
        f"a line of {k} people walks forward, each following the one in front.",
    ]


def _circle(rng, actors):
    n_people = len(actors)
    radius = float(rng.uniform(1.1, 1.5)) * max(1.0, n_people / 4)
    angles = np.arange(n_people) * 2 * np.pi / n_people + rng.uniform(0, 2 * np.pi)
    pos = np.stack([radius * np.sin(angles), radius * np.cos(angles)], -1)
    n = _length(actors, [0] * n_people)
    people = [_person(a, heading_to(p, (0.0, 0.0)), p) for a, p in zip(actors, pos, strict=True)]
    cons = [
        {"type": "distance", "a": i, "b": (i + 1) % n_people, "min": 0.6, "max": 3.5}
        for i in range(n_people)
    ]
    # each person faces the one across the circle (the centre lies in between)
    cons += [
        {"type": "faces", "a": i, "b": (i + n_people // 2) % n_people, "tolerance_deg": 60}
        for i in range(n_people)
    ]
    cons.append(_no_contact())
    return {"num_frames": n, "people": people, "constraints": cons}


def _circle_captions(rng, actors, n, layout):
    k = NUMBER_WORDS[n]
    what = "bow" if all(a.content == "bow" for a in actors) else "greet each other"
    return [
        f"{k} people stand in a circle and {what}.",
        f"{k} people face the centre of a circle and {what}.",
        f"a circle of {k} people {what}.",
    ]


def _audience(rng, actors):
    leader, *group = actors
    d = float(rng.uniform(2.2, 3.0))
    gap = float(rng.uniform(0.9, 1.2))
    xs = (np.arange(len(group)) - (len(group) - 1) / 2) * gap
    delays = []
    people = [_person(leader, 0.0, (0.0, 0.0))]
    lag = int(rng.integers(10, 25))
    for a, x in zip(group, xs, strict=True):
        delay, start = _aligned_delay(leader, a, lag)
        delays.append((delay, start))
        people.append(_person(a, heading_to((x, d), (0.0, 0.0)), (float(x), d), delay, start))
    n = _length(actors, [0] + [d_ for d_, _ in delays], [0] + [s for _, s in delays])
    cons = [{"type": "faces", "a": i, "b": 0} for i in range(1, len(actors))]
    cons += [
        {"type": "starts_after", "a": 0, "b": i, "min_frames": max(lag // 2, 5)}
        for i in range(1, len(actors))
    ]
    cons.append(_no_contact())
    return {"num_frames": n, "people": people, "constraints": cons}


def _audience_captions(rng, actors, n, layout):
    k = NUMBER_WORDS[n - 1]
    lead = actors[0].content
    if lead == "call":
        return [
            f"a person calls out to {k} people, who respond.",
            f"one person calls a group of {k}, and they answer.",
            f"{k} people react when a person in front of them calls out.",
        ]
    return [
        f"a person bows to {k} people, who bow back.",
        f"one person bows in front of a group of {k}, and they return the bow.",
        f"{k} people bow back to a person who bows to them.",
    ]


def _gather(rng, actors):
    caller, *walkers = actors
    n_w = len(walkers)
    spread = np.radians(rng.uniform(80, 140))
    angles = (np.arange(n_w) - (n_w - 1) / 2) * (spread / max(n_w - 1, 1))
    dist = float(rng.uniform(3.5, 4.5))
    lag = int(rng.integers(10, 25))
    people = [_person(caller, 0.0, (0.0, 0.0))]
    frames = []
    for a, ang in zip(walkers, angles, strict=True):
        pos = (dist * np.sin(ang), dist * np.cos(ang))
        delay, start = _aligned_delay(caller, a, lag)
        frames.append(_walk_up_to(a, dist, stop=1.6) + delay)
        people.append(_person(a, heading_to(pos, (0.0, 0.0)), pos, delay, start))
    n = min(min(frames), MAX_FRAMES)
    if n < MIN_FRAMES + lag:
        return None
    cons = [{"type": "approach", "a": i, "b": 0, "min_change": 0.4} for i in range(1, len(actors))]
    cons += [{"type": "faces", "a": i, "b": 0} for i in range(1, len(actors))]
    cons.append(_no_contact())
    return {"num_frames": n, "people": people, "constraints": cons}


def _gather_captions(rng, actors, n, layout):
    k = NUMBER_WORDS[n - 1]
    return [
        f"a person calls and {k} people walk over to them.",
        f"{k} people gather around someone who calls them.",
        f"one person beckons and a group of {k} approaches.",
    ]


def _two(first: tuple[str, ...], second: tuple[str, ...] | None = None):
    return lambda n: [first, second or first]


def _group(first: tuple[str, ...], rest: tuple[str, ...] | None = None):
    return lambda n: [first] + [rest or first] * (n - 1)


RELATIONS: dict[str, Relation] = {
    r.name: r
    for r in [
        Relation(
            "greet",
            _two(GREETINGS),
            lambda rng, a: _face_each_other(rng, a, None),
            _greet_captions,
            (2,),
        ),
        Relation(
            "bow_back",
            _two(("bow",)),
            lambda rng, a: _face_each_other(rng, a, int(rng.integers(15, 40))),
            _bow_back_captions,
            (2,),
        ),
        Relation(
            "call_respond",
            _two(("call",), ("respond",)),
            lambda rng, a: _face_each_other(rng, a, int(rng.integers(10, 30))),
            _call_respond_captions,
            (2,),
        ),
        Relation(
            "stand_facing",
            _two(IN_PLACE),
            lambda rng, a: _face_each_other(rng, a, None),
            _stand_facing_captions,
            (2,),
        ),
        Relation("walk_side_by_side", _two(WALKS), _side_by_side, _walk_together_captions, (2,)),
        Relation("run_side_by_side", _two(RUNS), _side_by_side, _walk_together_captions, (2,)),
        Relation("follow", _two(WALKS), _follow, _follow_captions, (2,)),
        Relation(
            "call_approach", _two(("call",), WALKS), _call_approach, _call_approach_captions, (2,)
        ),
        Relation("step_back", _two(ATTACKS, ("walk-back",)), _step_back, _step_back_captions, (2,)),
        Relation("spar", _two(("kick", "punch")), _spar, _spar_captions, (2,)),
        Relation("mirror", _two(GESTURES), _mirror, _mirror_captions, (2,)),
        Relation("part_ways", _two(WALKS), _part_ways, _part_captions, (2,)),
        Relation("walk_toward", _two(WALKS), _toward_each_other, _toward_captions, (2,)),
        Relation("group_line", _group(WALKS + RUNS), _line, _line_captions, (3, 4, 5, 6)),
        Relation("single_file", _group(WALKS), _single_file, _single_file_captions, (3, 4, 5, 6)),
        Relation(
            "circle_greet",
            _group(("bow", "bye", "wave-both-hands", "wave-right-hand")),
            _circle,
            _circle_captions,
            (3, 4, 5, 6),
        ),
        Relation(
            "audience",
            lambda n: [("call", "bow")] + [("respond", "bow")] * (n - 1),
            _audience,
            _audience_captions,
            (3, 4, 5, 6),
        ),
        Relation("gather", _group(("call",), WALKS), _gather, _gather_captions, (3, 4, 5, 6)),
    ]
}
