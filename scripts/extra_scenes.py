"""A corpus with more composed training scenes of one relation: a copy of CORPUS whose train
split gains N scenes of RELATION, composed from its train clips with a seed of their own.

    python scripts/extra_scenes.py CORPUS OUT --relation stand_facing --scenes 3000 [--seed 99]

Why: ``relation_repeats`` serves the same scenes again (new crops and mirrors, the same
pairs of clips); the per-person prompts of results/umf-small-bandai-20261204c needed more
pairs of different actions than a corpus's share of ``stand_facing`` scenes (462 of 6,000).
The copy links the clips, normaliser and caches of CORPUS (nothing else changes: the
normaliser stays the one the model was trained with) and writes its own scenes.json and
manifest.json (which records the addition under ``extra_scenes``).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("corpus", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--relation", default="stand_facing")
    ap.add_argument("--scenes", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=99)
    args = ap.parse_args()
    from umf.data.composer import compose_corpus
    from umf.data.corpus import Corpus, _actor
    from umf.data.scene_relations import RELATIONS

    if args.relation not in RELATIONS:
        raise SystemExit(f"error: no relation {args.relation!r}; relations: {', '.join(RELATIONS)}")
    if args.out.exists():
        raise SystemExit(f"error: {args.out} exists")
    corpus = Corpus.load(args.corpus)
    actors = [_actor(c) for c in corpus.split_clips("train") if c.num_people == 1]
    sizes = RELATIONS[args.relation].sizes
    sizes = (2,) if 2 in sizes else sizes[:1]  # pairs where the relation has them
    extra = compose_corpus(actors, args.scenes, sizes, seed=args.seed, relations=[args.relation])
    for r in extra:
        r["id"] = f"train-extra-{r['id']}"
    scenes = json.loads((args.corpus / "scenes.json").read_text())
    scenes["train"] = scenes["train"] + extra
    args.out.mkdir(parents=True)
    for name in ("clips.npz", "clips.json", "normalizer.safetensors", "cache", "text-cache"):
        if (args.corpus / name).exists():
            os.symlink((args.corpus / name).resolve(), args.out / name)
    (args.out / "scenes.json").write_text(json.dumps(scenes))
    manifest = json.loads((args.corpus / "manifest.json").read_text())
    manifest["extra_scenes"] = {"from": str(args.corpus.resolve()), "relation": args.relation,
                                "scenes": len(extra), "seed": args.seed}  # fmt: skip
    (args.out / "manifest.json").write_text(json.dumps(manifest, indent=2))
    print(f"{args.out}: {len(extra)} more {args.relation} train scenes "
          f"({len(scenes['train'])} in all)")  # fmt: skip


if __name__ == "__main__":
    main()
