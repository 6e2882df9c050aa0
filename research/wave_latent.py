"""Where a generated wave loses its swing: the VAE's latent, its decoder, or the P-Flow?

    python research/wave_latent.py latents MODEL_DIR [--corpus out/corpus]
    python research/wave_latent.py decode MODEL_DIR [MODEL_DIR ...] [--corpus out/corpus]
    python research/wave_latent.py refine MODEL_DIR [--corpus out/corpus]
    python research/wave_latent.py finetune MODEL_DIR --out DIR [--steps 400] [--label ...]
    python research/wave_latent.py detail MODEL_DIR [--corpus out/corpus]
    python research/wave_latent.py perturb MODEL_DIR [--corpus out/corpus]
    python research/wave_latent.py overfit MODEL_DIR [--clips 16] [--steps 600] [--crops K]
        [--split train] [--cosine] [--captions own|shuffled] [--caption-mix Q] [--mirror]
        [--guidance G]
        [--fresh WIDTH,LAYERS] [--detail-norm] [--seed S] [--corpus ...]
    python research/wave_latent.py churn MODEL_DIR
    python research/wave_latent.py nyquist MODEL_DIR

``latents``: for waves, walks and raised hands, how much the latent changes along time,
for latents of real training clips (posterior means of their first 4 s) and for latents
the P-Flow generates from the label's prompt (32 people, 4 s, seed 0): the mean squared
difference of neighbouring tokens, and the variance of the tokens about their own mean
(the tokens that stand for those 4 s, either way). A latent that hardly changes along time decodes
to a held pose.

``decode``: how fast real waves swing (the strongest frequency of the wrist's sideways
trace, all real waves); then real val + test waves (their first 160 frames) encoded, decoded three
ways: as they are; with neighbouring token pairs averaged (what the pyramid's coarse stage
can hold); with every token replaced by the mean token (a latent constant in time). For
each, the median right-wrist speed and swings per second (``umf.eval.motion_stats``).

``refine``: can the P-Flow's fine stage make the swing when the coarse content is right?
Real val + test waves are encoded, put on the fine stage's path at local time t' (its
start: a quarter-way: ...; t' = 0 is exactly where the sampler hands over from the coarse
stage, the token-pair means of the real latent plus noise), and finished by the model with
its own guidance (10 Euler steps), then decoded: the swings per second that come back.

``finetune``: trains only the VAE's decoder (the encoder, so every latent, fixed) for
``--steps`` steps of 32 crops (140-160 frames) of one label's training clips and writes a
copy of the model with that decoder: if the decoder then reconstructs held-out waves, the
latent holds the swing and the decoder had not learnt to read it. An experiment, not a
model to ship (it forgets the other labels).

``detail``: how much of a real latent's fine detail (each token less the mean of its pair:
what only the finest pyramid stage adds) the P-Flow's fine stage recovers in one step.
Real val + test clips (first 160 frames, up to 48 per label) are put on the fine stage's
path at local time t' as in ``refine``, and the model's estimate of the endpoint
(x + (1 - t') v, no guidance) is compared with the real latent: the estimate's detail
energy and its projection on the real detail, both relative to the real detail's energy
(1 and 1: all of it recovered; 0: none).

``perturb``: is the decoder's swing fragile? Real val + test waves' latents with Gaussian
noise added (in the P-Flow's standardised units: everywhere, in the fine detail only, in
the pair means only), and with their fine detail shrunk, decoded: wrist speed and swings.

``overfit``: can the P-Flow make a swing at all? It is trained (AdamW, lr 2e-4, batches of
64) on the latents of ``--clips`` real val + test waves alone (``--split train``: training
waves; their first 160 frames, or
with ``--crops K`` K random 160-frame crops of each, canonical at the crop's start as in
training, so that the swing's phase is random), with the label's prompt, and
every 200 steps 16 people are sampled with that prompt: the time variation of their
latents (standardised, the tokens of 4 s), how near each is to a real latent (the median
squared distance per element to its nearest real latent, and how many distinct real
latents are nearest: a model that memorised them gives distances far below the real
latents' own from each other) and the decoded wrist speed and swings, against the same
numbers for the real clips. At the end, each person of the last sample beside the real
latent it came nearest to, both decoded (160 frames): the swings of a near-copy should be
that real latent's; the median over people also depends on which real latents the model
picks, and real waves' first 160 frames often have no swing at all. ``--fresh
WIDTH,LAYERS`` trains a new, untrained P-Flow of that width and depth (feed-forward twice
the width; the model's latent statistics) instead of the model's own; ``--detail-norm``
trains with ``pflow.detail_norm``, its gains fitted on the training latents (the model's
weights, or a fresh P-Flow's with ``--fresh``). Distances are in the model's own
standardised units either way. Nothing is written.

``churn``: does stochastic sampling bring the swing back? The P-Flow sampled with
Euler-Maruyama steps that add a Langevin term to each stage (``churn_sample``: it leaves
the path's marginals as they are, so it changes nothing for an exact field, and pulls a
too-smooth learnt field's samples back towards the statistics its noise estimate implies),
for the wave's and the walk's prompts, at several churn levels and step counts.

``nyquist``: does the VAE keep a swing faster than its tokens can follow? Every real wave
(first 160 frames) encoded and decoded, grouped by the real swing's frequency (FFT peak
of the wrist's sideways trace) against half the latent's token rate: swings per second
and the hand's side-to-side range, real and reconstructed.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from umf.eval import motion_stats as MS
from umf.flows.pyramid import split_detail

LATENT_LABELS = ("wave-right-hand", "walk", "raise-up-both-hands")


def swing_frequency(trace: np.ndarray, fps: float = 30.0) -> float:
    """The strongest frequency (Hz, above 0) of a 1-D trace, by FFT of the Hann-windowed
    trace less its straight-line trend: how often a waving hand goes back and forth."""
    y = np.asarray(trace, dtype=np.float64)
    x = np.arange(len(y))
    y = y - np.polyval(np.polyfit(x, y, 1), x)
    power = np.abs(np.fft.rfft(y * np.hanning(len(y)))) ** 2
    return float(np.fft.rfftfreq(len(y), 1.0 / fps)[1 + power[1:].argmax()])


def time_variation(z: torch.Tensor) -> tuple[float, float]:
    """Latents (B, p, r) -> (mean squared neighbour-token difference, mean variance of the
    tokens about each latent's own mean token)."""
    step = (z[:, 1:] - z[:, :-1]).pow(2).mean()
    spread = (z - z.mean(1, keepdim=True)).pow(2).mean()
    return float(step), float(spread)


def sq_distances(z: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
    """(B, N) squared distances per element between latents z (B, p, r) and ref (N, p, r),
    in float64."""
    return torch.cdist(z.flatten(1).double(), ref.flatten(1).double()).pow(2) / ref[0].numel()


def nearest(z: torch.Tensor, ref: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For latents z (B, p, r): the squared distance per element to the nearest of ``ref``
    (N, p, r), and its index. A model that memorised ``ref`` gives distances far below those
    between the ``ref`` latents themselves."""
    dist, which = sq_distances(z, ref).min(1)
    return dist.float(), which


def pair_mean(z: torch.Tensor) -> torch.Tensor:
    """Each pair of neighbouring tokens replaced by its mean (the 1-D pyramid's one-level
    down then up)."""
    return split_detail(z, "1d")[0]


def time_mean(z: torch.Tensor) -> torch.Tensor:
    """Every token replaced by the latent's mean token."""
    return z.mean(1, keepdim=True).expand_as(z)


def _encode(pipe, feats: list[np.ndarray]) -> torch.Tensor:
    """Posterior means (B, p, r) of real features (B, T, 262), as the pipeline encodes."""
    return _encode_normalized(
        pipe, pipe.normalizer.normalize(torch.as_tensor(np.stack(feats), dtype=torch.float32))
    )


def _encode_normalized(pipe, x: torch.Tensor) -> torch.Tensor:
    """Posterior means (B, p, r) of normalised features (B, T, 262), every frame present."""
    with torch.no_grad():
        return pipe.vae.encode(x, torch.ones(x.shape[:2], dtype=torch.bool))[0]


def _joints(pipe, z: torch.Tensor, frames: int) -> list[np.ndarray]:
    """Latents (B, p, r) decoded as the pipeline decodes person 1 -> joints (T, 22, 3)."""
    from umf.representation import features_to_joints

    with torch.no_grad():
        return [features_to_joints(f).numpy() for f in pipe.decode(z, frames)]


def latents(args: argparse.Namespace) -> None:
    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    corpus = Corpus.load(args.corpus)
    pipe = UMFPipeline.from_pretrained(args.model)
    captured: list[torch.Tensor] = []
    decode = pipe._decode_raw

    def record(z: torch.Tensor, frames: int) -> torch.Tensor:
        captured.append(z.detach().clone())
        return decode(z, frames)

    pipe._decode_raw = record  # type: ignore[method-assign]
    clips = MS.real_clips_by_label(corpus, splits=("train",), labels=LATENT_LABELS)
    print("| label | latent | clips or people | neighbour step² | spread² about the mean |")
    print("|---|---|---:|---:|---:|")
    for label in LATENT_LABELS:
        feats = [f for c in clips[label] if len(f := corpus.clip_features(c)[0][:120]) == 120]
        mu = _encode(pipe, feats[:64])
        captured.clear()
        pipe([MS.LABELS[label][0]] * 32, num_people=1, seconds=4.0, seed=0, fit=False)
        k = round(120 / pipe.config.vae.token_span)  # the tokens of 4 s
        for name, z in (("real, encoded", mu[:, :k]), ("generated", torch.cat(captured)[:, :k])):
            step, spread = time_variation(z)
            print(f"| {label} | {name} | {len(z)} | {step:.3f} | {spread:.3f} |", flush=True)


def decode(args: argparse.Namespace) -> None:
    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline
    from umf.representation import features_to_joints

    corpus = Corpus.load(args.corpus)
    clips = MS.real_clips_by_label(corpus, ("val", "test"), ["wave-right-hand"])
    feats = [f for c in clips["wave-right-hand"]
             if len(f := corpus.clip_features(c)[0][:160]) == 160]  # fmt: skip
    stats = ["right_wrist_energy", "right_wrist_swings"]
    real = [features_to_joints(torch.as_tensor(f, dtype=torch.float32)).numpy() for f in feats]
    speed, swings = MS.median_statistics(real, stats)
    print(f"{len(feats)} real val + test waves, 160 frames: right-wrist speed {speed:.2f} m/s, "
          f"{swings:.2f} swings/s")  # fmt: skip
    every = MS.real_joints_by_label(corpus, labels=["wave-right-hand"])["wave-right-hand"]
    hz = [swing_frequency(MS.sideways(j)) for j in every if len(j) >= 60]
    q = np.percentile(hz, [25, 50, 75])
    print(
        f"all {len(hz)} real waves of 2 s or more, whole clips (up to 300 frames): the hand "
        f"swings at {q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f} Hz (25 / 50 / 75 %)"
    )
    print("| model | latent decoded | right-wrist speed (m/s) | swings/s |")
    print("|---|---|---:|---:|")
    for path in args.models:
        pipe = UMFPipeline.from_pretrained(path)
        mu = _encode(pipe, feats)
        for name, z in (("as encoded", mu), ("token pairs averaged", pair_mean(mu)),
                        ("mean token everywhere", time_mean(mu))):  # fmt: skip
            speed, swings = MS.median_statistics(_joints(pipe, z, 160), stats)
            print(f"| {path} | {name} | {speed:.2f} | {swings:.2f} |", flush=True)


@torch.no_grad()
def refine(args: argparse.Namespace) -> None:
    from umf.data.corpus import Corpus
    from umf.flows import integrate
    from umf.models.pflow import _stage_field, stage_scales
    from umf.pipeline import UMFPipeline

    corpus = Corpus.load(args.corpus)
    pipe = UMFPipeline.from_pretrained(args.model)
    pflow = pipe.pflow
    z1 = pflow.latent_norm.normalize(_real_latents(pipe, corpus, "wave-right-hand"))
    b = len(z1)
    cond, uncond = _conditions(pipe, MS.LABELS["wave-right-hand"][0], b)
    field = _stage_field(pflow.net, stage_scales(pflow.cfg), cond, uncond)
    window, start = _fine_stage_start(pflow, z1)
    stage = torch.ones(b, dtype=torch.long)

    def local(x: torch.Tensor, t_local: torch.Tensor) -> torch.Tensor:
        return field(x, window.global_time(t_local), stage=stage)

    stats = ["right_wrist_energy", "right_wrist_swings"]
    print(f"{b} real val + test waves, 160 frames; fine stage flow time "
          f"{window.start:g} -> 1, guidance {stage_scales(pflow.cfg)[-1]}")  # fmt: skip
    print("| fine stage finished from (local t') | global t | right-wrist speed (m/s) | "
          "swings/s |")  # fmt: skip
    print("|---:|---:|---:|---:|")
    for t0 in (0.0, 0.25, 0.5, 0.75, 1.0):
        x = t0 * z1 + (1 - t0) * start
        if t0 < 1.0:
            x = integrate(local, x, steps=10, t0=t0, t1=1.0).x
        joints = _joints(pipe, pflow.latent_norm.denormalize(x), 160)
        speed, swings = MS.median_statistics(joints, stats)
        print(f"| {t0:g} | {window.global_time(t0):g} | {speed:.2f} | {swings:.2f} |",
              flush=True)  # fmt: skip


def stage_noise_estimate(x: torch.Tensor, v: torch.Tensor, t_local: float, window,
                         layout: str) -> tuple[torch.Tensor, float]:  # fmt: skip
    """(the noise eps the state x holds, as the velocity v implies; the noise's scale S) on a
    pyramid stage's path at local time t'.

    On the stage [s, e], x = A X + S eps and the target v = B X + C eps, with S = t'(1-e) +
    (1-t')(1-s) and C = s - e for every component, and A, B = t'e + (1-t')s, e - s for the
    block means, t'e, e for the detail (the stage's start holds the block means of X at s).
    Each pair solves for eps = (A v - B x) / (A C - B S). The score is then -eps / S.
    """
    s, e = window.start, window.end
    scale = t_local * (1 - e) + (1 - t_local) * (1 - s)
    parts = [(x, v, t_local * e + (1 - t_local) * s, e - s)]  # the whole state when s = 0
    if s > 0:
        (xm, xd), (vm, vd) = split_detail(x, layout), split_detail(v, layout)
        parts = [(xm, vm, t_local * e + (1 - t_local) * s, e - s), (xd, vd, t_local * e, e)]
    c = s - e
    return sum((a * vv - b * xx) / (a * c - b * scale) for xx, vv, a, b in parts), scale


def churn_sample(field, cfg, noise: torch.Tensor, churn: tuple[float, ...],
                 steps: tuple[int, ...], generator: torch.Generator) -> torch.Tensor:  # fmt: skip
    """Standardised latents from a pyramid (``cfg``) with Euler-Maruyama steps, from the
    coarsest stage's ``noise``; ``field(x, t, stage=...)`` as ``sample_pyramid`` calls it.
    Per stage, dx = (v - churn/2 eps_hat) dt' + sqrt(churn S dt') dW: a Langevin term
    (score -eps_hat / S, diffusion churn * S) that leaves every marginal of the path as it
    is, so the exact marginal field samples the same distribution with any churn (a
    guided field is not one); a learnt field that is too smooth gets its noise-level
    statistics pulled back. The last step of each stage is a plain Euler step; churn 0 is
    the bundled Euler sampler."""
    from umf.flows.pyramid import jump, jump_alpha
    from umf.flows.solvers import time_grid

    x, b = noise, len(noise)
    windows = cfg.windows
    for i, (w, n, c) in enumerate(zip(windows, steps, churn, strict=True)):
        stage = torch.full((b,), w.stage, dtype=torch.long)
        grid = time_grid(n)  # the grid sample_pyramid's Euler steps take
        for k, (t_local, t_next) in enumerate(itertools.pairwise(grid)):
            h = t_next - t_local
            v = field(x, torch.full((b,), float(w.global_time(t_local))), stage=stage)
            if c > 0 and k < n - 1:
                eps, scale = stage_noise_estimate(x, v, t_local, w, cfg.layout)
                step_noise = torch.randn(x.shape, generator=generator)
                x = x + h * (v - 0.5 * c * eps) + (c * scale * h) ** 0.5 * step_noise
            else:
                x = x + h * v
        if i + 1 < len(windows):
            s_next = windows[i + 1].start
            x = jump(x, s=s_next, e=w.end, alpha=jump_alpha(s_next, cfg.correlation),
                     layout=cfg.layout, g=cfg.correlation, generator=generator)  # fmt: skip
    return x


def churn(args: argparse.Namespace) -> None:
    from umf.flows.pyramid import initial_noise
    from umf.models.pflow import _stage_field, stage_scales
    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(args.model)
    pflow = pipe.pflow
    settings = (((0.0, 0.0), (45, 5)), ((0.0, 1.0), (45, 20)), ((0.0, 2.0), (45, 20)),
                ((1.0, 1.0), (45, 20)), ((0.0, 4.0), (45, 20)), ((0.0, 8.0), (45, 40)),
                ((0.0, 16.0), (45, 80)), ((4.0, 4.0), (90, 40)))  # fmt: skip
    print("32 people per prompt, 160 frames, seed 0; churn and Euler-Maruyama steps per stage "
          "(coarse / fine); medians, and the share swinging at least once a second")  # fmt: skip
    print("| churn | steps | label | statistics (median) | swinging >= 1/s |")
    print("|---|---|---|---|---:|")
    for label in ("wave-right-hand", "walk"):
        prompt, names = MS.LABELS[label]
        cond, uncond = _conditions(pipe, prompt, 32)
        field = _stage_field(pflow.net, stage_scales(pflow.cfg), cond, uncond)
        for c, steps in settings:
            gen = torch.Generator().manual_seed(0)
            noise = initial_noise(pflow.pyramid, 32, pflow.latent_dim, generator=gen)
            with torch.no_grad():
                z = churn_sample(field, pflow.pyramid, noise, c, steps, gen)
            per = np.array([MS.median_statistics([j], list(names)) for j in
                            _joints(pipe, pflow.latent_norm.denormalize(z), 160)])  # fmt: skip
            med = ", ".join(f"{n} {m:.2f}" for n, m in zip(names, np.median(per, 0), strict=True))
            share = (f"{np.mean(per[:, list(names).index('right_wrist_swings')] >= 1):.2f}"
                     if "right_wrist_swings" in names else "")  # fmt: skip
            print(f"| {c[0]:g} / {c[1]:g} | {steps[0]} / {steps[1]} | {label} | {med} | {share} |",
                  flush=True)  # fmt: skip


def nyquist(args: argparse.Namespace) -> None:
    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    corpus = Corpus.load(args.corpus)
    pipe = UMFPipeline.from_pretrained(args.model)
    span = pipe.config.vae.token_span
    limit = 30.0 / span / 2  # half the latent's token rate (30 fps clips)
    clips = MS.real_clips_by_label(corpus, ("train", "val", "test"), ["wave-right-hand"])
    clips = [c for c in clips["wave-right-hand"] if c.num_frames >= 161]
    feats = [corpus.clip_features(c)[0][:160] for c in clips]
    rec: list[np.ndarray] = []
    for i in range(0, len(feats), 32):
        rec += _joints(pipe, _encode(pipe, feats[i : i + 32]), 160)
    rows = []
    for clip, out in zip(clips, rec, strict=True):
        real = clip.joints[0][:161]
        real_side = MS.sideways(real)
        rows.append((swing_frequency(real_side),
                     MS.motion_statistics(real)["right_wrist_swings"],
                     MS.motion_statistics(out)["right_wrist_swings"],
                     np.ptp(real_side), np.ptp(MS.sideways(out))))  # fmt: skip
    table = np.array(rows)
    print(f"{len(table)} real waves of every split (their first 160 frames) encoded and "
          f"decoded; tokens of {span:g} frames: the latent's Nyquist frequency is "
          f"{limit:g} Hz")  # fmt: skip
    print("| real swing frequency | clips | swings/s: real | reconstructed | kept "
          "| side-to-side range (cm): real | reconstructed |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|")
    for lo, hi in ((0.0, limit / 2), (limit / 2, limit), (limit, np.inf)):
        sel = table[(table[:, 0] >= lo) & (table[:, 0] < hi)]
        if len(sel):
            real, out, r_range, o_range = np.median(sel[:, 1:], axis=0)
            print(f"| {lo:g}-{hi:g} Hz | {len(sel)} | {real:.2f} | {out:.2f} | "
                  f"{out / real if real else float('nan'):.2f} | {100 * r_range:.0f} "
                  f"| {100 * o_range:.0f} |")  # fmt: skip


def detail_retention(estimate: torch.Tensor, truth: torch.Tensor) -> tuple[float, float]:
    """(energy, projection) of an estimate's fine detail relative to the truth's: the
    estimate's detail energy / the truth's, and <estimate's detail, truth's detail> / the
    truth's energy. Detail: each token less the mean of its token pair (1-D pyramid)."""
    d_est, d_true = split_detail(estimate, "1d")[1], split_detail(truth, "1d")[1]
    energy = float(d_true.pow(2).sum())
    return float(d_est.pow(2).sum()) / energy, float((d_est * d_true).sum()) / energy


def _real_latents(
    pipe, corpus, label: str, limit: int | None = None, splits: tuple[str, ...] = ("val", "test")
) -> torch.Tensor:
    """Posterior means of real clips of ``label`` in ``splits`` (their first 160 frames)."""
    clips = MS.real_clips_by_label(corpus, splits, [label])[label]
    feats = [f for c in clips if len(f := corpus.clip_features(c)[0][:160]) == 160]
    return _encode(pipe, feats[:limit])


def _crop_latents(
    pipe,
    corpus,
    label: str,
    clips: int,
    crops: int,
    splits: tuple[str, ...] = ("val", "test"),
    mirror: bool = False,
    captions: list[str] | None = None,
) -> torch.Tensor:
    """Posterior means of ``crops`` random 160-frame crops of each of the first ``clips``
    clips of ``label`` in ``splits`` at least 160 frames long, each canonical at its own start
    as the P-Flow's training crops are (mirrored at random with ``mirror``): the swing's
    phase at the crop's start is then random, as in training."""
    from umf.train.datasets import SingleMotionDataset

    kw = dict(min_frames=160, max_frames=160, mirror=mirror, labels=[label])
    ds = [SingleMotionDataset(corpus, split, pipe.normalizer, **kw) for split in splits]
    items = [(d, i) for d in ds for i in range(len(d)) if d.items[i][0].num_frames > 160]
    feats = []
    for epoch in range(crops):
        for d, i in items[:clips]:
            d.set_epoch(epoch)
            item = d[i]
            feats.append(item["features"])
            if captions is not None:  # each crop's own caption (mirrored with it), as trained
                captions.append(item["caption"])
    return _encode_normalized(pipe, torch.stack(feats).float())


def _fine_stage_start(pflow, z1: torch.Tensor):
    """(window, start) of the finest pyramid stage for standardised latents z1 (B, p, r):
    where the sampler hands over from the coarse stage, their block means plus noise
    (seed 0)."""
    window = pflow.pyramid.window(1)
    eps = torch.randn(z1.shape, generator=torch.Generator().manual_seed(0))
    coarse, _ = split_detail(z1, pflow.pyramid.layout)
    return window, window.start * coarse + (1 - window.start) * eps


def _conditions(pipe, prompt: str, b: int) -> tuple[dict, dict]:
    """The fine field's conditional (prompt, single-person dataset) and unconditional
    inputs for a batch of ``b``."""
    from umf.models.pflow import encode_uncond
    from umf.text import respell_prompt

    net = pipe.pflow.net
    prompt = respell_prompt(prompt, pipe.config.text.respell)
    cond = {"text": net.encode_text(pipe.text_encoder.encode([prompt] * b)),
            "dataset": torch.zeros(b, dtype=torch.long)}  # fmt: skip
    return cond, {**cond, "text": encode_uncond(net, pipe.text_encoder.encode([""]), b)}


def detail(args: argparse.Namespace) -> None:
    from umf.data.corpus import Corpus
    from umf.models.pflow import _stage_field
    from umf.pipeline import UMFPipeline

    corpus = Corpus.load(args.corpus)
    pipe = UMFPipeline.from_pretrained(args.model)
    pflow = pipe.pflow
    if pflow.pyramid.num_stages < 2 or pflow.pyramid.layout != "1d":
        raise SystemExit("detail needs a P-Flow with a 1-D pyramid of at least two stages")
    times = (0.0, 0.25, 0.5, 0.75, 0.9)
    window = pflow.pyramid.window(1)  # the finest stage
    gain = getattr(pflow.latent_norm, "detail_gain", None)  # pflow.detail_norm
    if gain is not None:
        print(f"pflow.detail_norm: detail gains {float(gain.min()):.2f}-{float(gain.max()):.2f} "
              "(energies below are in the flow's units, the detail amplified)\n")  # fmt: skip
    print("| label | real detail energy | " + " | ".join(
        f"t' {t:g} (t {window.global_time(t):.2f})" for t in times) + " |")  # fmt: skip
    print("|---|---:|" + "---:|" * len(times))
    for label in ("wave-right-hand", "walk", "raise-up-both-hands", "run"):
        z1 = pflow.latent_norm.normalize(_real_latents(pipe, corpus, label, 48))
        b = len(z1)
        cond, uncond = _conditions(pipe, MS.LABELS[label][0], b)
        field = _stage_field(pflow.net, (None,) * pflow.pyramid.num_stages, cond, uncond)
        stage = torch.ones(b, dtype=torch.long)
        _, start = _fine_stage_start(pflow, z1)
        cells = []
        for t in times:
            x = t * z1 + (1 - t) * start
            with torch.no_grad():
                v = field(x, torch.full((b,), float(window.global_time(t))), stage=stage)
            energy, proj = detail_retention(x + (1 - t) * v, z1)
            cells.append(f"{energy:.2f} / {proj:.2f}")
        own = float(split_detail(z1, "1d")[1].pow(2).mean())
        print(f"| {label} | {own:.3f} | " + " | ".join(cells) + " |", flush=True)


def perturb(args: argparse.Namespace) -> None:
    from umf.data.corpus import Corpus
    from umf.pipeline import UMFPipeline

    corpus = Corpus.load(args.corpus)
    pipe = UMFPipeline.from_pretrained(args.model)
    norm = pipe.pflow.latent_norm
    z1 = norm.normalize(_real_latents(pipe, corpus, "wave-right-hand"))
    eps = torch.randn(z1.shape, generator=torch.Generator().manual_seed(0))
    stats = ["right_wrist_energy", "right_wrist_swings"]

    def scored(z: torch.Tensor) -> str:
        speed, swings = MS.median_statistics(_joints(pipe, norm.denormalize(z), 160), stats)
        return f"{speed:.2f} m/s, {swings:.2f}/s"

    sigmas = (0.0, 0.1, 0.2, 0.4)
    print(f"{len(z1)} real val + test waves, 160 frames: right-wrist speed, swings per second")
    print("| noise added (std, standardised units) | " + " | ".join(f"{s:g}" for s in sigmas)
          + " |")  # fmt: skip
    print("|---|" + "---:|" * len(sigmas))
    coarse_eps, fine_eps = split_detail(eps, "1d")  # each: variance 1/2 per element
    for name, noise in (("everywhere", eps), ("fine detail only", fine_eps * 2**0.5),
                        ("pair means only", coarse_eps * 2**0.5)):  # fmt: skip
        cells = [scored(z1 + s * noise) for s in sigmas]
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    print()
    print("| fine detail kept | 1 | 0.75 | 0.5 | 0.25 |")
    print("|---|---:|---:|---:|---:|")
    coarse, fine = split_detail(z1, "1d")
    cells = [scored(coarse + k * fine) for k in (1.0, 0.75, 0.5, 0.25)]
    print("| decoded | " + " | ".join(cells) + " |", flush=True)


CAPTIONS = {None: "with the prompt", "own": "each with its own caption",
            "shuffled": "each with another crop's caption (shuffled)"}  # fmt: skip


def overfit(args: argparse.Namespace) -> None:
    import dataclasses

    from umf.data.corpus import Corpus
    from umf.models.denoiser import expand_text
    from umf.models.pflow import PFlow
    from umf.pipeline import UMFPipeline
    from umf.text import TextFeatures, respell_prompt

    torch.manual_seed(args.seed)
    corpus = Corpus.load(args.corpus)
    pipe = UMFPipeline.from_pretrained(args.model)
    pflow = pipe.pflow.float()
    splits = ("train",) if args.split == "train" else ("val", "test")
    captions: list[str] | None = [] if args.captions else None
    if (args.mirror or args.captions) and not args.crops:
        raise SystemExit("--mirror and --captions need --crops")
    if (args.mirror or args.caption_mix) and args.captions != "own":
        raise SystemExit("--mirror and --caption-mix need --captions own (the crops' captions)")
    if not 0 <= args.caption_mix <= 1:
        raise SystemExit(f"--caption-mix must be between 0 and 1, got {args.caption_mix}")
    units = pflow.latent_norm  # distances in the model's own standardised units, either way
    if args.crops:
        mu = _crop_latents(pipe, corpus, "wave-right-hand", args.clips, args.crops, splits,
                           args.mirror, captions)  # fmt: skip
    else:
        mu = _real_latents(pipe, corpus, "wave-right-hand", args.clips, splits)
    if args.fresh or args.detail_norm:  # a new P-Flow: another size, or the detail normaliser
        cfg = dataclasses.replace(pflow.cfg, detail_norm=args.detail_norm or pflow.cfg.detail_norm)
        if args.fresh:
            width, layers = (int(v) for v in args.fresh.split(","))
            den = dataclasses.replace(cfg.denoiser, d_model=width, num_layers=layers,
                                      ff_dim=2 * width)  # fmt: skip
            cfg = dataclasses.replace(cfg, denoiser=den)
        new = PFlow(cfg, pflow.num_tokens, pflow.latent_dim, pipe.text_encoder.dim)
        if not args.fresh:  # the model's weights; only the normaliser's gains may be new
            keys = new.load_state_dict(pflow.state_dict(), strict=False)
            if keys.unexpected_keys or set(keys.missing_keys) - {"latent_norm.detail_gain"}:
                raise SystemExit(f"weights do not match the new P-Flow: {keys}")
        new.latent_norm.load_state_dict(units.state_dict(), strict=False)
        new.latent_norm.fit_detail(mu)  # no-op without detail_norm
        pflow = new
        size = sum(p.numel() for p in pflow.parameters()) / 1e6
        what = f"a fresh P-Flow, {args.fresh.replace(',', ' wide, ')} layers" if args.fresh else (
            "the model's P-Flow")  # fmt: skip
        gains = ", with pflow.detail_norm (gains fitted on these latents)"
        print(f"{what}: {size:.2f} M parameters{gains if args.detail_norm else ''}")
    ref = units.normalize(mu)
    apart = sq_distances(ref, ref)[~torch.eye(len(ref), dtype=torch.bool)]  # two real ones
    prompt = respell_prompt(MS.LABELS["wave-right-hand"][0], pipe.config.text.respell)
    text, empty = pipe.text_encoder.encode([prompt]), pipe.text_encoder.encode([""])
    stats = ["right_wrist_energy", "right_wrist_swings"]
    k = round(120 / pipe.config.vae.token_span)  # the tokens of 4 s

    def row(name: str, z: torch.Tensor, near: str = "") -> None:
        step, spread = time_variation(units.normalize(z)[:, :k])
        speed, swings = MS.median_statistics(_joints(pipe, z, 120), stats)
        print(f"| {name} | {step:.3f} | {spread:.3f} | {near} | {speed:.2f} | {swings:.2f} |",
              flush=True)  # fmt: skip

    def sampled(name: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """16 people: their latents, and each one's distance to and index of its nearest
        real latent."""
        scale = {} if args.guidance is None else {"guidance": args.guidance}
        z, _ = pflow.sample(text, empty, num_samples=16, dataset=0,  # single person, as trained
                            generator=torch.Generator().manual_seed(args.seed + 1),
                            **scale)  # fmt: skip
        dist, which = nearest(units.normalize(z), ref)
        row(name, z, f"{float(dist.median()):.3f} ({len(set(which.tolist()))})")
        return z, dist, which

    scale_used = pflow.cfg.guidance if args.guidance is None else args.guidance
    schedule = "cosine to 0" if args.cosine else "constant"
    mix = f", a random crop's caption at chance {args.caption_mix}" if args.caption_mix else ""
    what = f"{args.crops} random crops each of" if args.crops else "the first 160 frames of"
    print(f"P-Flow trained on the latents of {what} {args.clips} real {' + '.join(splits)} "
          f"waves alone ({len(mu)} latents{', mirrored at random' if args.mirror else ''}), "
          f"{CAPTIONS[args.captions]}{mix}; lr 2e-4 {schedule}; sampled "
          f"with the prompt {prompt!r} (guidance {scale_used}); 4 s, 16 people, "
          f"seed {args.seed + 1}")  # fmt: skip
    print("| latents | neighbour step² | spread² | nearest real: dist² (distinct) "
          "| right-wrist speed (m/s) | swings/s |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|")
    row(f"the {len(mu)} real latents", mu, f"two of them: {float(apart.median()):.3f}")
    z, dist, which = sampled("generated, before")
    opt = torch.optim.AdamW(pflow.parameters(), lr=2e-4)
    # --cosine: the learning rate falls to 0 at the last step, as `umf train` anneals it
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: 0.5 * (1 + math.cos(math.pi * s / args.steps)) if args.cosine else 1.0
    )
    batch = 64
    text_b, empty_b = expand_text(text, batch), expand_text(empty, batch)
    if captions and args.captions == "shuffled":  # varied text that says nothing of the crop
        order = torch.randperm(len(captions), generator=torch.Generator().manual_seed(args.seed))
        captions = [captions[i] for i in order.tolist()]
    if captions:  # every crop's own caption: the text of a batch is gathered per crop
        names = sorted(set(captions))
        table = pipe.text_encoder.encode(names)
        of_crop = torch.tensor([names.index(c) for c in captions])
    dataset = torch.zeros(batch, dtype=torch.long)
    gen = torch.Generator().manual_seed(args.seed)
    t0 = time.time()
    for step in range(1, args.steps + 1):
        pflow.train()
        idx = torch.randint(0, len(mu), (batch,), generator=gen)
        if captions:
            rows = of_crop[idx]
            if args.caption_mix:  # each sample, with this chance, takes a random crop's caption
                swap = torch.rand(batch, generator=gen) < args.caption_mix
                rows = torch.where(
                    swap, of_crop[torch.randint(0, len(mu), (batch,), generator=gen)], rows
                )
            text_b = TextFeatures(table.tokens[rows], table.mask[rows], table.pooled[rows])
        loss = pflow.loss(mu[idx], text_b, empty_b, dataset=dataset, generator=gen)["total"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step % 200 == 0:
            z, dist, which = sampled(f"generated, after {step} steps ({time.time() - t0:.0f} s)")
    # each person of the last sample beside the real latent it came nearest to, decoded
    gen_j, real_j = _joints(pipe, z, 160), _joints(pipe, mu, 160)
    print("\nThe last sample, person by person, against its nearest real latent (160 frames):")
    print("| person | nearest real | dist² | generated: m/s, swings/s | that real: m/s, swings/s |")
    print("|---:|---:|---:|---|---|")
    real_stats = [MS.median_statistics([j], stats) for j in real_j]  # speed, swings/s each
    seconds = (len(gen_j[0]) - 1) / 30.0

    def turns(per_second: float) -> int:
        return round(per_second * seconds)

    swinging = kept = of = 0
    for i in range(len(z)):
        g, r = MS.median_statistics([gen_j[i]], stats), real_stats[int(which[i])]
        print(f"| {i} | {int(which[i])} | {float(dist[i]):.3f} | {g[0]:.2f}, {g[1]:.2f} "
              f"| {r[0]:.2f}, {r[1]:.2f} |")  # fmt: skip
        swinging += g[1] >= 1.0
        if r[1] >= 1.0:  # its nearest real latent swings: did the person keep half its turns?
            of += 1
            kept += 2 * turns(g[1]) >= turns(r[1])
    print(f"\n{swinging} of {len(z)} people swing at least once a second; {of} came nearest a "
          f"real latent that does, {kept} of them kept at least half of its turns")  # fmt: skip
    swings = np.array([swings_per_s for _, swings_per_s in real_stats])
    print(f"\nThe {len(mu)} real latents: swings/s quartiles "
          f"{' / '.join(f'{q:.2f}' for q in np.percentile(swings, [25, 50, 75]))}, "
          f"{int((swings == 0).sum())} with none")  # fmt: skip


def finetune(args: argparse.Namespace) -> None:
    import importlib.util

    from safetensors.torch import save_file

    from umf.data.corpus import Corpus
    from umf.models.vae import vae_losses
    from umf.train.datasets import SingleMotionDataset

    # the VAE alone, as research/vae_recipe.py loads it (a script, not a package module)
    spec = importlib.util.spec_from_file_location("vae_recipe", Path(__file__).with_name(
        "vae_recipe.py"))  # fmt: skip
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    load_vae = recipe.load_vae

    out_dir = Path(args.out).expanduser()
    if out_dir.exists():
        raise SystemExit(f"{out_dir} exists: choose another --out (nothing is overwritten)")
    torch.manual_seed(0)
    corpus = Corpus.load(args.corpus)
    vae, cfg = load_vae(Path(args.model).expanduser())
    vae.freeze_encoder()
    ds = SingleMotionDataset(corpus, "train", corpus.normalizer, min_frames=140, max_frames=160,
                             random_placement=True)  # fmt: skip
    picks = [i for i, (clip, _, _) in enumerate(ds.items) if clip.meta.get("content") == args.label]
    if not picks:
        raise SystemExit(f"no training clips of label {args.label!r}")
    params = [p for p in vae.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=args.lr)
    rng = np.random.default_rng(0)
    vae.train()
    t0 = time.time()
    for step in range(1, args.steps + 1):
        batch = ds.collate([ds[int(i)] for i in rng.choice(picks, 32)])
        out = vae(batch["features"], batch["mask"])
        loss = vae_losses(out, batch["features"], batch["mask"], corpus.normalizer, cfg.vae,
                          fps=cfg.fps)["total"]  # fmt: skip
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        if step % 100 == 0:
            print(f"step {step}: loss {loss.item():.4f} ({time.time() - t0:.0f} s)", flush=True)
    tmp = out_dir.with_name(f".{out_dir.name}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    shutil.copytree(Path(args.model).expanduser(), tmp)
    state = {k: v.detach().to(torch.float16).contiguous() for k, v in vae.state_dict().items()}
    save_file(state, str(tmp / "vae.safetensors"))
    fmt = json.loads((tmp / "format.json").read_text())  # reports must not call it the source
    fmt["name"] = f"{fmt.get('name', 'model')}-decoder-{args.label}-{args.steps}"
    (tmp / "format.json").write_text(json.dumps(fmt, indent=2) + "\n")
    tmp.rename(out_dir)
    print(f"wrote {out_dir} ({len(picks)} training clips of {args.label})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    la = sub.add_parser("latents")
    la.add_argument("model")
    de = sub.add_parser("decode")
    de.add_argument("models", nargs="+")
    rf = sub.add_parser("refine")
    rf.add_argument("model")
    ft = sub.add_parser("finetune")
    ft.add_argument("model")
    ft.add_argument("--out", required=True)
    ft.add_argument("--label", default="wave-right-hand", choices=sorted(MS.LABELS))
    ft.add_argument("--steps", type=int, default=400)
    ft.add_argument("--lr", type=float, default=2e-4)
    dt = sub.add_parser("detail")
    dt.add_argument("model")
    pt = sub.add_parser("perturb")
    pt.add_argument("model")
    of = sub.add_parser("overfit")
    of.add_argument("model")
    of.add_argument("--clips", type=int, default=16)
    of.add_argument("--steps", type=int, default=600)
    of.add_argument("--fresh", default="",
                    help="WIDTH,LAYERS: train a new P-Flow of that size instead")  # fmt: skip
    of.add_argument("--seed", type=int, default=0,
                    help="training seed S (the people are sampled with seed S + 1)")  # fmt: skip
    of.add_argument("--detail-norm", action="store_true",
                    help="train with pflow.detail_norm (gains fitted on the latents)")  # fmt: skip
    of.add_argument("--cosine", action="store_true",
                    help="anneal the learning rate to 0 (cosine), as umf train does")  # fmt: skip
    of.add_argument(
        "--mirror",
        action="store_true",
        help="mirror half the crops (left-hand waves, captions swapped), as trained",
    )
    of.add_argument("--captions", choices=["own", "shuffled"], default=None,
                    help="train each crop with its own caption (or one of another crop's), "
                    "not the prompt")  # fmt: skip
    of.add_argument("--guidance", type=float, default=None,
                    help="sample at this guidance scale (default: the model's)")  # fmt: skip
    of.add_argument("--caption-mix", type=float, default=0.0,
                    help="with --captions own: the chance that a sample takes a random crop's "
                    "caption at each step")  # fmt: skip
    of.add_argument("--split", choices=["val+test", "train"], default="val+test",
                    help="the held-out waves (default) or the training ones")  # fmt: skip
    of.add_argument(
        "--crops",
        type=int,
        default=0,
        help="random crops per clip (0: each clip's first 160 frames)",
    )
    ch = sub.add_parser("churn")
    ch.add_argument("model")
    ny = sub.add_parser("nyquist")
    ny.add_argument("model")
    for p in (la, de, rf, ft, dt, pt, of, ch, ny):
        p.add_argument("--corpus", default="out/corpus")
        p.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    commands = {"latents": latents, "decode": decode, "refine": refine, "finetune": finetune,
                "detail": detail, "perturb": perturb, "overfit": overfit,
                "churn": churn, "nyquist": nyquist}  # fmt: skip
    commands[args.cmd](args)


if __name__ == "__main__":
    main()
