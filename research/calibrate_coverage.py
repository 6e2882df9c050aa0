"""Calibrate the coverage threshold: paraphrases of trained actions against unseen actions.

    python research/calibrate_coverage.py --corpus out/corpus [--model DIR] [--out results/coverage]

Builds the vocabulary of the corpus's training captions in the model's text encoder, scores
``results/coverage/paraphrases.txt`` (should be known) and ``unseen.txt`` (should not), picks
the threshold on the even lines of each list (the highest that flags at most 10 % of the
paraphrases) and reports precision and recall of "unknown" on the odd lines, held out. Writes
``calibration.json`` and a histogram ``calibration.png``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def read_list(path: Path) -> list[str]:
    return [
        ln.strip() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")
    ]


def rates(known: np.ndarray, unseen: np.ndarray, t: float) -> dict[str, float]:
    flagged_unseen = int((unseen < t).sum())
    flagged_known = int((known < t).sum())
    flagged = flagged_unseen + flagged_known
    return {
        "threshold": round(float(t), 4),
        "unseen_flagged": round(flagged_unseen / len(unseen), 4),  # recall of "unknown"
        "paraphrases_flagged": round(flagged_known / len(known), 4),
        "precision": round(flagged_unseen / flagged, 4) if flagged else 1.0,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--lists", type=Path, default=Path("results/coverage"))
    ap.add_argument("--out", type=Path, default=Path("results/coverage"))
    args = ap.parse_args()

    from umf.coverage import build_vocabulary
    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    corpus = Corpus.load(args.corpus)
    vocab = build_vocabulary(corpus, pipe.text_encoder, pipe.config.text.encoder)
    known_p, unseen_p = (
        read_list(args.lists / "paraphrases.txt"),
        read_list(args.lists / "unseen.txt"),
    )
    known = np.array([c["score"] for c in vocab.score(known_p, pipe.text_encoder)])
    unseen = np.array([c["score"] for c in vocab.score(unseen_p, pipe.text_encoder)])
    # choose on the even lines: the highest threshold that flags at most 10 % of paraphrases
    cal_k, cal_u = known[0::2], unseen[0::2]
    cands = np.unique(np.round(np.concatenate([cal_k, cal_u]), 4))
    ok = [t for t in cands if (cal_k < t).mean() <= 0.10]
    t = float(max(ok)) if ok else float(cands.min())
    report = {
        "vocabulary_phrases": len(vocab.phrases),
        "chosen_on_even_lines": rates(cal_k, cal_u, t),
        "held_out_odd_lines": rates(known[1::2], unseen[1::2], t),
        "all_lines": rates(known, unseen, t),
        "paraphrases": {p: float(s) for p, s in zip(known_p, known, strict=True)},
        "unseen": {p: float(s) for p, s in zip(unseen_p, unseen, strict=True)},
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "calibration.json").write_text(json.dumps(report, indent=1) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3))
    bins = np.linspace(min(known.min(), unseen.min()) - 0.02, 1.0, 30)
    ax.hist(known, bins, alpha=0.6, label=f"paraphrases of trained actions ({len(known)})")
    ax.hist(unseen, bins, alpha=0.6, label=f"unseen actions ({len(unseen)})")
    ax.axvline(t, color="k", ls="--", label=f"threshold {t:.3f}")
    ax.set_xlabel("coverage score (cosine to the nearest trained caption)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out / "calibration.png", dpi=120)
    for k in ("chosen_on_even_lines", "held_out_odd_lines", "all_lines"):
        print(k, report[k])
    for p, s in sorted(report["paraphrases"].items(), key=lambda x: x[1])[:6]:
        print(f"  lowest paraphrase {s:.3f} {p}")
    for p, s in sorted(report["unseen"].items(), key=lambda x: -x[1])[:6]:
        print(f"  highest unseen    {s:.3f} {p}")


if __name__ == "__main__":
    main()
