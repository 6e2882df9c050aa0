"""Does a generated motion do what its label says? Simple body statistics vs real clips.

Distribution scores (FID, R-precision) come from a learned evaluator and can move with no
visible change. These statistics are what a person looking at the motion checks: how
fast the pelvis travels, how far the head drops (a bow), how high the wrists get
relative to the head (raised hands, a wave), how much the wrists and ankles move
(gestures, kicks) and how often the right hand swings from side to side by at least
10 cm (a wave). A mean pose carried along a path fails them: its head never drops and
its wrists never rise or move. A hand that is raised and wobbles also fails the wave:
it moves (wrist speed) but does not swing.

For each label, generated motions from the label's prompt are compared with the real
clips of that label: a statistic passes when the generated median lies within the real
clips' interquartile range widened by ``slack`` of that range on each side.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from umf.representation import facing_direction

Array = np.ndarray

FEW_REAL = 5  # fewer real clips than this: the range is one or two motions, not a spread
SWING = 0.10  # m: the least side-to-side travel of a hand between turns that is a swing

HEAD, PELVIS, L_WRIST, R_WRIST, L_ANKLE, R_ANKLE = 15, 0, 20, 21, 7, 8

# label (Bandai content) -> the prompt a user would type; the statistics each label must
# match (the ones that tell it apart from standing still or from the other labels)
LABELS: dict[str, tuple[str, tuple[str, ...]]] = {
    "walk": ("A person walks forward.", ("pelvis_speed", "ankle_energy")),
    "run": ("A person runs forward.", ("pelvis_speed", "ankle_energy")),
    "walk-back": ("A person walks backward.", ("pelvis_speed", "backward_speed")),
    "bow": ("Someone bows politely.", ("head_drop", "pelvis_speed")),
    "wave-right-hand": ("Someone waves with the right hand.",
                        ("right_wrist_above_head", "right_wrist_energy", "right_wrist_swings")),
    "raise-up-both-hands": ("A person raises both hands.",
                            ("both_wrists_above_head", "pelvis_speed")),
    "kick": ("A person kicks.", ("ankle_energy", "ankle_height")),
    "punch": ("A person punches.", ("wrist_energy", "pelvis_speed")),
}  # fmt: skip


def start_facing(joints: Array) -> Array:
    """(2,) unit floor direction (X, Z) a person (T, 22, 3) faces at frame 0."""
    return facing_direction(torch.from_numpy(np.asarray(joints[:1]))).numpy()[0, [0, 2]]


def sideways(joints: Array, joint: int = R_WRIST, facing: Array | None = None) -> Array:
    """(T,) offset (m) of ``joint`` from the pelvis along the person's left-right axis at
    frame 0 (the floor direction perpendicular to its facing, :func:`start_facing` unless
    given), for joints (T, 22, 3)."""
    j = np.asarray(joints, dtype=np.float64)
    fwd = start_facing(j) if facing is None else facing
    side = np.array([fwd[1], -fwd[0]])  # the facing turned 90 degrees on the floor
    return (j[:, joint, [0, 2]] - j[:, PELVIS, [0, 2]]) @ side


def swings_per_second(trace: Array, least: float = SWING, fps: float = 30.0) -> float:
    """Turns per second of a 1-D trace that has moved at least ``least`` since its last
    turn (a zig-zag filter). A waving hand going left-right-left counts every turn; a
    tremor, a wobble of a few centimetres or a slow one-way drift counts none."""
    y = np.asarray(trace, dtype=np.float64)
    turns, going = 0, 0  # going: +1 up, -1 down, 0 not yet moved by ``least``
    hi = lo = float(y[0])
    for v in y[1:]:
        hi, lo = max(hi, v), min(lo, v)
        if going >= 0 and hi - v >= least:
            turns, going, hi, lo = turns + (going == 1), -1, v, v
        elif going <= 0 and v - lo >= least:
            turns, going, hi, lo = turns + (going == -1), 1, v, v
    return turns / max((len(y) - 1) / fps, 1e-9)


def motion_statistics(joints: Array, fps: float = 30.0) -> dict[str, float]:
    """Statistics of one person's joints (T, 22, 3), metres, Y up."""
    j = np.asarray(joints, dtype=np.float64)
    pelvis = j[:, PELVIS, [0, 2]]
    dur = max(len(j) - 1, 1) / fps
    path = np.linalg.norm(np.diff(pelvis, axis=0), axis=-1).sum()
    head = j[:, HEAD, 1]
    rel = j - j[:, PELVIS : PELVIS + 1]  # root-relative: gestures, not travel

    def energy(idx: Sequence[int]) -> float:
        return float(np.linalg.norm(np.diff(rel[:, list(idx)], axis=0), axis=-1).mean() * fps)

    # facing at the start: travel along it is forward, against it backward
    fwd = start_facing(j)
    disp = pelvis[-1] - pelvis[0]
    return {
        "pelvis_speed": float(path / dur),
        "backward_speed": float(-(disp @ fwd) / dur),
        "head_drop": float(head[: min(5, len(head))].mean() - head.min()),
        "right_wrist_above_head": float((j[:, R_WRIST, 1] - head).max()),
        "both_wrists_above_head": float(
            (np.minimum(j[:, L_WRIST, 1], j[:, R_WRIST, 1]) - head).max()
        ),
        "right_wrist_energy": energy([R_WRIST]),
        "right_wrist_swings": swings_per_second(sideways(j, R_WRIST, fwd), fps=fps),
        "wrist_energy": energy([L_WRIST, R_WRIST]),
        "ankle_energy": energy([L_ANKLE, R_ANKLE]),
        "ankle_height": float(
            j[:, [L_ANKLE, R_ANKLE], 1].max() - j[:, [L_ANKLE, R_ANKLE], 1].min()
        ),
    }


@dataclass
class LabelCheck:
    label: str
    prompt: str
    stat: str
    real_q: tuple[float, float, float]  # 25th, 50th, 75th percentile of the real clips
    generated_median: float
    passed: bool
    real_count: int = 0  # real clips behind the range (0: not recorded, older reports)


def compare_label(
    label: str,
    real: Sequence[Array],
    generated: Sequence[Array],
    fps: float = 30.0,
    slack: float = 0.25,
) -> list[LabelCheck]:
    """Check the label's statistics of generated joints against real joints (each (T, 22, 3))."""
    prompt, stats = LABELS[label]
    rs = [motion_statistics(j, fps) for j in real]
    medians = median_statistics(generated, stats, fps)
    out = []
    for s, g in zip(stats, medians, strict=True):
        q = np.percentile([r[s] for r in rs], [25, 50, 75])
        pad = slack * (q[2] - q[0])
        out.append(LabelCheck(label, prompt, s, (float(q[0]), float(q[1]), float(q[2])), g,
                              bool(q[0] - pad <= g <= q[2] + pad), len(rs)))  # fmt: skip
    return out


def check_labels(
    real_by_label: dict[str, Sequence[Array]],
    generate: Callable[[str, int], Sequence[Array]],
    samples: int = 8,
    fps: float = 30.0,
) -> list[LabelCheck]:
    """Every label with real clips: ``generate(prompt, samples)`` -> joints (T, 22, 3) each."""
    rows: list[LabelCheck] = []
    for label in LABELS:
        real = real_by_label.get(label)
        if real:
            rows.extend(compare_label(label, real, generate(LABELS[label][0], samples), fps))
    return rows


def label_passes(rows: Sequence[LabelCheck]) -> dict[str, bool]:
    """A label passes when all of its statistics do."""
    out: dict[str, bool] = {}
    for r in rows:
        out[r.label] = out.get(r.label, True) and r.passed
    return out


def format_checks(rows: Sequence[LabelCheck]) -> str:
    """Markdown table of the checks."""
    head = "| label | prompt | statistic | real clips | real 25/50/75 % | generated median | ok |"
    lines = [head, "|---|---|---|---:|---|---:|:-:|"]
    for r in rows:
        q = " / ".join(f"{v:.2f}" for v in r.real_q)
        n = str(r.real_count) if r.real_count else "?"
        lines.append(f"| {r.label} | {r.prompt} | {r.stat} | {n} | {q} | "
                     f"{r.generated_median:.2f} | {'yes' if r.passed else 'no'} |")  # fmt: skip
    return "\n".join(lines)


def few_real_clips(rows: Sequence[LabelCheck], least: int = FEW_REAL) -> dict[str, int]:
    """Labels whose real range rests on fewer than ``least`` clips (label -> count).

    With one clip the "interquartile range" has zero width and nothing but that clip's
    exact value passes; the report names such labels instead of hiding them."""
    return {r.label: r.real_count for r in rows if 0 < r.real_count < least}


def median_statistics(people: Sequence[Array], stats: Sequence[str],
                      fps: float = 30.0) -> list[float]:  # fmt: skip
    """Median over people (each (T, 22, 3) joints) of each named statistic."""
    return medians([motion_statistics(j, fps) for j in people], stats)


def medians(rows: Sequence[dict[str, float]], stats: Sequence[str]) -> list[float]:
    """Median over rows of :func:`motion_statistics` of each named statistic (for callers
    that also need the rows themselves)."""
    return [float(np.median([row[s] for row in rows])) for s in stats]


def real_clips_by_label(corpus, splits: Sequence[str] = ("train", "val", "test"),
                        labels: Collection[str] = LABELS) -> dict:  # fmt: skip
    """The corpus's single-person clips of each content label in ``labels`` (any labels
    of the corpus, not only the checked ones), in corpus order."""
    out: dict[str, list] = {}
    for split in splits:
        for clip in corpus.split_clips(split):
            label = clip.meta.get("content")
            if clip.num_people == 1 and label in labels:
                out.setdefault(label, []).append(clip)
    return out


def real_joints_by_label(
    corpus,
    splits: Sequence[str] = ("train", "val", "test"),
    max_frames: int = 300,
    labels: Collection[str] = LABELS,
) -> dict[str, list[Array]]:
    """Joints (T, 22, 3) of the corpus's single-person clips of each label in ``labels``
    (at most ``max_frames`` frames each, the longest motion the pipeline makes)."""
    return {label: [np.asarray(c.joints[0][:max_frames]) for c in clips]
            for label, clips in real_clips_by_label(corpus, splits, labels).items()}  # fmt: skip
