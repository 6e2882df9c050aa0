"""How generated people move second by second: does the motion hold up past a label's usual length?

Each prompt gives ``--samples`` people (``--seconds`` long, seed 0, raw decoded motion: the
draws of ``research/motion_stats_report.py``). Per model and prompt, one row of medians over
the people of each second's mean pelvis floor speed and mean root-relative ankle speed
(m/s). A standing gesture should stay near the real clips' pelvis speed (hand-raisers:
0.03) in every second, a run should keep running; with ``--corpus`` a last column gives
the median length of the real clips of the prompt's label (``umf.eval.motion_stats.LABELS``).
Cells read "pelvis / ankles".

    python research/speed_over_time.py MODEL_DIR [MODEL_DIR ...]
        [--prompt "A person raises both hands." ...] [--seconds 4] [--corpus out/corpus]
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import numpy as np
import torch

from umf.eval import motion_stats as MS

PROMPTS = (
    "A person raises both hands.",
    "A person runs forward.",
    "A person walks backward.",
    "Someone bows politely.",
    "Someone waves with the right hand.",
)


def per_second(
    people: Sequence[np.ndarray], fps: float = 30.0, seconds: int | None = None
) -> tuple[list[float], list[float]]:
    """Medians over people (each (T, 22, 3)) of each second's ``pelvis_speed`` and
    ``ankle_energy`` (``umf.eval.motion_stats``: mean pelvis floor speed, mean root-relative
    ankle speed, m/s), for ``seconds`` seconds (default round(T / fps); T frames have T - 1
    steps, so the last second may be a step short)."""
    sec = round(fps)
    n = seconds if seconds is not None else max(round(len(people[0]) / fps), 1)
    rows = [MS.median_statistics([j[i * sec : (i + 1) * sec + 1] for j in people],
                                 ("pelvis_speed", "ankle_energy"), fps)
            for i in range(n)]  # fmt: skip
    return [r[0] for r in rows], [r[1] for r in rows]


def label_of(prompt: str) -> str | None:
    return next((label for label, (p, _) in MS.LABELS.items() if p == prompt), None)


def format_row(name: str, prompt: str, pelvis: list[float], ankles: list[float],
               real: str | None = None) -> str:  # fmt: skip
    """One table row: "pelvis / ankles" per second, then ``real`` (a last column) if given."""
    cells = " | ".join(f"{p:.2f} / {a:.2f}" for p, a in zip(pelvis, ankles, strict=True))
    return f"| {name} | {prompt} | {cells}" + ("" if real is None else f" | {real}") + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--prompt", action="append", help="a prompt (repeat); default: five labels")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--seconds", type=int, default=4, help="whole seconds, 1-10")
    ap.add_argument("--corpus", help="prepared corpus: add the real clips' median length")
    args = ap.parse_args()
    if args.samples < 1 or args.seconds not in range(1, 11):
        ap.error("need --samples >= 1 and --seconds a whole number from 1 to 10")
    torch.set_num_threads(2)
    from umf.pipeline import UMFPipeline

    prompts = args.prompt or list(PROMPTS)
    lengths: dict[str, float] = {}
    if args.corpus:
        from umf.data.corpus import Corpus

        real = MS.real_joints_by_label(Corpus.load(args.corpus))
        lengths = {k: float(np.median([len(j) for j in v])) for k, v in real.items()}
    secs = args.seconds
    head = "| model | prompt | " + " | ".join(f"second {i + 1}" for i in range(secs))
    print(head + (" | real clips (median) |" if args.corpus else " |"))
    print("|---|---|" + "---:|" * (secs + bool(args.corpus)))
    for path in args.models:
        pipe = UMFPipeline.from_pretrained(path)
        for prompt in prompts:
            scenes = pipe([prompt] * args.samples, num_people=1, seconds=float(secs), seed=0,
                          fit=False)  # fmt: skip
            pelvis, ankles = per_second([s.raw_joints[0] for s in scenes], pipe.config.fps,
                                        secs)  # fmt: skip
            real = None
            if args.corpus:
                frames = lengths.get(label_of(prompt) or "")
                real = "—" if frames is None else f"{frames / pipe.config.fps:.1f} s"
            print(format_row(path, prompt, pelvis, ankles, real), flush=True)


if __name__ == "__main__":
    main()
