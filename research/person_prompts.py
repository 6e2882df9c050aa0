"""Does each person do what their own prompt says? The per-person prompts issue's targets,
measured on a model.

    python research/person_prompts.py [--model DIR] [--corpus DIR] [--seeds 8] [--json FILE]

1. Gestures on command: "Two people stand facing each other." with person prompts "A person
   raises both hands." and "Someone bows politely.", seeds 0..N-1, 4 s, the delivered
   joints: person 1's lower wrist above the head (``both_wrists_above_head`` > 0) and
   person 2's head dropping more than 8 cm (``head_drop``); then the two prompts swapped.
   The same scene prompt without person prompts is the baseline (what each person does by
   chance).
2. Re-rolled on command: each seed's scene without person prompts, person 2 re-rolled
   (``pipe.reroll``, seed 100 + s) told to raise both hands, then to bow: person 1
   bit-identical, person 2 changed, doing what it was told, and the two bodies' capsules
   apart (``umf.eval.physics.interpenetration``).
3. Per-person text matching (``--corpus``, :mod:`umf.eval.person_matching`): every test
   scene of the corpus whose people play different actions, generated from its first caption
   and each person's own prompt (seed 0, raw), each person scored by the bundled
   single-person evaluator against their own prompt and the other's; also for the
   ``stand_facing`` scenes alone, whose scene captions name no action. Chance is 0.5.
"""

from __future__ import annotations

import argparse
from pathlib import Path

SCENE = "Two people stand facing each other."
HANDS, BOW = "A person raises both hands.", "Someone bows politely."
HEAD_DROP = 0.08  # metres


def gestures(pipe, seeds: int) -> dict:
    """Seeds where person 1 / person 2 do what each order of the two prompts asks."""
    from umf.eval.motion_stats import motion_statistics

    def stats(own):
        scenes = pipe([SCENE] * seeds, num_people=2, seed=0, sample_indices=range(seeds),
                      person_prompts=own)  # fmt: skip
        rows = [[motion_statistics(s.joints[k]) for k in range(2)] for s in scenes]
        return {
            "hands_p1": [round(r[0]["both_wrists_above_head"], 3) for r in rows],
            "hands_p2": [round(r[1]["both_wrists_above_head"], 3) for r in rows],
            "head_drop_p1": [round(r[0]["head_drop"], 3) for r in rows],
            "head_drop_p2": [round(r[1]["head_drop"], 3) for r in rows],
        }

    out = {"baseline": stats(None)}
    if pipe.person_prompts:
        out["hands, bow"] = stats([HANDS, BOW])
        out["bow, hands"] = stats([BOW, HANDS])
    for row in out.values():
        row["p1 hands"] = sum(x > 0 for x in row["hands_p1"])
        row["p2 bows"] = sum(x > HEAD_DROP for x in row["head_drop_p2"])
        row["p1 bows"] = sum(x > HEAD_DROP for x in row["head_drop_p1"])
        row["p2 hands"] = sum(x > 0 for x in row["hands_p2"])
    return out


def rerolled(pipe, seeds: int) -> dict:
    """Person 2 of each plain scene re-rolled with an own prompt (module notes, 2)."""
    import numpy as np

    from umf.eval.motion_stats import motion_statistics
    from umf.eval.physics import interpenetration

    scenes = pipe([SCENE] * seeds, num_people=2, seed=0, sample_indices=range(seeds))
    out = {}
    for name, own, did in (("hands", HANDS, lambda st: st["both_wrists_above_head"] > 0),
                           ("bow", BOW, lambda st: st["head_drop"] > HEAD_DROP)):  # fmt: skip
        rows = []
        for s, scene in enumerate(scenes):
            new = pipe.reroll(scene, 2, seed=100 + s, person_prompt=own)
            a, b = np.asarray(scene.joints), np.asarray(new.joints)
            pen = interpenetration(b[:2])[1]
            rows.append({"p1_same": bool(np.array_equal(a[0], b[0])),
                         "p2_new": not np.allclose(a[1], b[1]),
                         "did": bool(did(motion_statistics(b[1]))),
                         "penetration_cm": round(pen["penetration_max_cm"], 3)})  # fmt: skip
        out[name] = {k: sum(r[k] for r in rows) for k in ("p1_same", "p2_new", "did")}
        out[name]["max_penetration_cm"] = max(r["penetration_cm"] for r in rows)
    return out


def matching(pipe, corpus_dir: Path) -> dict:
    """Per-person top-1 of own prompt against the others' (:mod:`umf.eval.person_matching`)
    on the corpus's test scenes of different actions, and on its ``stand_facing`` ones."""
    from umf.data.corpus import Corpus
    from umf.eval.evaluator import load_evaluator
    from umf.eval.person_matching import person_items, person_matching
    from umf.eval.plan import default_evaluator_dir

    corpus = Corpus.load(corpus_dir)
    ev = load_evaluator(default_evaluator_dir() / "single", cache_dir=corpus.root / "text-cache")
    from umf.data.scene_relations import RELATIONS

    # the stand_facing relation's captions, as the composer writes them (capitalised)
    words = RELATIONS["stand_facing"].captions(None, [], 2, {})
    stand_facing = {c[0].upper() + c[1:] for c in words}
    items = person_items(corpus, "test")
    facing = [it for it in items if it[0] in stand_facing]
    return {"all": person_matching(pipe, ev, items),
            "stand_facing": person_matching(pipe, ev, facing)}  # fmt: skip


def report(m: dict) -> str:
    n = m["seeds"]
    lines = [f"model {m['model']}; {n} seeds, 4 s, delivered joints; scene: {SCENE!r}"]
    for name, row in m["gestures"].items():
        lines.append(f"  {name:10s} p1 raises hands {row['p1 hands']}/{n}, p2 bows "
                     f"{row['p2 bows']}/{n} | p1 bows {row['p1 bows']}/{n}, p2 raises hands "
                     f"{row['p2 hands']}/{n}")  # fmt: skip
    for name, r in m.get("reroll", {}).items():
        lines.append(f"  re-rolled p2 told {name}: p1 bit-identical {r['p1_same']}/{n}, p2 "
                     f"changed {r['p2_new']}/{n}, did it {r['did']}/{n}, deepest overlap "
                     f"{r['max_penetration_cm']} cm")  # fmt: skip
    for name, r in m.get("matching", {}).items():
        lines.append(f"  per-person matching, {name}: top-1 {r['top1']:.3f} +- {r['ci95']:.3f} "
                     f"over {r['people']} people of {r['scenes']} test scenes (chance "
                     f"{r['chance']:.2f})")  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--corpus", type=Path, default=None)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    m = {"model": pipe.name, "seeds": args.seeds, "gestures": gestures(pipe, args.seeds)}
    if pipe.person_prompts:
        m["reroll"] = rerolled(pipe, args.seeds)
    if args.corpus is not None and pipe.person_prompts:
        m["matching"] = matching(pipe, args.corpus)
    print(report(m))
    if args.json:
        from umf.io import write_json_atomic

        write_json_atomic(args.json, m)


if __name__ == "__main__":
    main()
