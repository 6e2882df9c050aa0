"""Calibrate the coverage threshold: paraphrases of trained actions against unseen actions.

    python research/calibrate_coverage.py --corpus out/corpus [--model DIR] [--out results/coverage]
    python research/calibrate_coverage.py --test results/coverage/fresh [--model DIR]

Builds the vocabulary of the corpus's training captions in the model's text encoder, scores
``results/coverage/paraphrases.txt`` (should be known) and ``unseen.txt`` (should not), picks
the threshold on the even lines of each list (the highest that flags at most 10 % of the
paraphrases) and reports precision and recall of "unknown" on the odd lines, held out. Writes
``calibration.json`` and a histogram ``calibration.png``. ``--variants`` also prints the
ranking quality (AUC, paraphrases above unseen actions) of other scores built from the same
cosines: the mean of the k nearest captions, and the nearest one less its own crowding
(as in cross-domain similarity local scaling), each with its threshold chosen as above.

``--test DIR`` chooses nothing: it scores ``DIR/paraphrases.txt`` and ``DIR/unseen.txt`` (lists
written after the threshold was fixed) with the model as a user gets it (``pipe.coverage``: the
vocabulary and threshold the model carries) and writes ``DIR/test.json``, with each rate's 95 %
Wilson interval, since a list of a few dozen lines moves a rate by several points per line.
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


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a rate of k in n."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    mid = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (round(float(mid - half), 4), round(float(mid + half), 4))


def test_report(known: list[dict], unseen: list[dict]) -> dict:
    """Rates of the model's own verdicts (``known``) on paraphrases and unseen actions."""
    if not known or not unseen:
        raise SystemExit("both lists need at least one line")
    fk = sum(not c["known"] for c in known)
    fu = sum(not c["known"] for c in unseen)
    return {
        "paraphrases": len(known),
        "unseen": len(unseen),
        "paraphrases_flagged": round(fk / len(known), 4),
        "paraphrases_flagged_95": wilson(fk, len(known)),
        "unseen_flagged": round(fu / len(unseen), 4),
        "unseen_flagged_95": wilson(fu, len(unseen)),
        "precision": round(fu / (fu + fk), 4) if fu + fk else 1.0,
    }


def run_test(lists: Path, model: Path | None) -> None:
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(model)
    if pipe.vocabulary is None:
        raise SystemExit("this model carries no vocabulary")
    known_p, unseen_p = read_list(lists / "paraphrases.txt"), read_list(lists / "unseen.txt")
    known, unseen = pipe.coverage(known_p), pipe.coverage(unseen_p)
    report = {
        "model": pipe.name,
        "threshold": pipe.vocabulary.threshold,
        "vocabulary_phrases": len(pipe.vocabulary.phrases),
        **test_report(known, unseen),
        "paraphrases_scores": {p: c["score"] for p, c in zip(known_p, known, strict=True)},
        "unseen_scores": {p: c["score"] for p, c in zip(unseen_p, unseen, strict=True)},
    }
    (lists / "test.json").write_text(json.dumps(report, indent=1) + "\n")
    print({k: v for k, v in report.items() if not k.endswith("_scores")})
    for p, c in sorted(zip(known_p, known, strict=True), key=lambda x: x[1]["score"]):
        if not c["known"]:
            print(f"  flagged paraphrase {c['score']:.3f} {p}  (nearest: {c['nearest'][0]})")
    for p, c in sorted(zip(unseen_p, unseen, strict=True), key=lambda x: -x[1]["score"]):
        if c["known"]:
            print(f"  passed unseen      {c['score']:.3f} {p}  (nearest: {c['nearest'][0]})")


def auc(known: np.ndarray, unseen: np.ndarray) -> float:
    """Chance that a paraphrase scores above an unseen action (ties count half)."""
    diff = known[:, None] - unseen[None, :]
    return float((diff > 0).mean() + 0.5 * (diff == 0).mean())


def choose(cal_k: np.ndarray, cal_u: np.ndarray) -> float:
    """The highest threshold that flags at most 10 % of the calibration paraphrases."""
    cands = np.unique(np.round(np.concatenate([cal_k, cal_u]), 4))
    ok = [t for t in cands if (cal_k < t).mean() <= 0.10]
    return float(max(ok)) if ok else float(cands.min())


def variant_scores(sims: np.ndarray, crowd: np.ndarray) -> dict[str, np.ndarray]:
    """Scores of each query from its cosines ``sims`` (Q, V) to the vocabulary, whose
    phrases' mean cosine to their own nearest phrases is ``crowd`` (V,)."""
    top = -np.sort(-sims, axis=1)
    out = {"nearest (shipped)": top[:, 0]}
    for k in (2, 3, 5, 10):
        out[f"mean of {k} nearest"] = top[:, :k].mean(axis=1)
    out["nearest less its crowding / 2"] = top[:, 0] - 0.5 * crowd[sims.argmax(axis=1)]
    out["local scaling (CSLS, k 10)"] = (
        2 * top[:, 0] - top[:, :10].mean(axis=1) - crowd[sims.argmax(axis=1)]
    )
    return out


def print_variants(vocab, encoder, known_p: list[str], unseen_p: list[str]) -> None:
    from umf.coverage import embed

    emb = vocab.embeddings.float()
    sims = (embed(encoder, known_p + unseen_p) @ emb.T).numpy()
    own = (emb @ emb.T).numpy()
    np.fill_diagonal(own, -1.0)
    crowd = -np.sort(-own, axis=1)[:, :10].mean(axis=1)
    n = len(known_p)
    print(f"{'score':32s} AUC even  odd  | flagged on odd lines: paraphrases  unseen")
    for name, s in variant_scores(sims, crowd).items():
        k, u = s[:n], s[n:]
        t = choose(k[0::2], u[0::2])
        print(f"{name:32s} {auc(k[0::2], u[0::2]):8.3f} {auc(k[1::2], u[1::2]):5.3f} |"
              f" {(k[1::2] < t).mean():33.3f} {(u[1::2] < t).mean():7.3f}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", type=Path, default=None)
    ap.add_argument("--model", type=Path, default=None)
    ap.add_argument("--lists", type=Path, default=Path("results/coverage"))
    ap.add_argument("--out", type=Path, default=Path("results/coverage"))
    ap.add_argument("--variants", action="store_true", help="compare other scores too")
    ap.add_argument("--test", type=Path, default=None, help="score fresh lists, choose nothing")
    args = ap.parse_args()
    if args.test is not None:
        run_test(args.test, args.model)
        return
    if args.corpus is None:
        ap.error("--corpus is needed to calibrate")

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
    t = choose(cal_k, cal_u)
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
    if args.variants:
        print_variants(vocab, pipe.text_encoder, known_p, unseen_p)


if __name__ == "__main__":
    main()
