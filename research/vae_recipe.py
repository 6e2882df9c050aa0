"""Score motion VAEs on reconstructions of real test clips (the VAE recipe table).

    python research/vae_recipe.py score NAME=VAE_DIR ... --corpus out/corpus \
        --out results/vae-recipe
    python research/vae_recipe.py memorise --corpus out/corpus --set vae.w_pos=0.5 ...

``memorise`` trains a fresh small VAE (``--set`` overrides) on one fixed batch of 32
randomly placed training crops (one thread) and prints R^2 per body-frame group every 50
steps: how fast a recipe can learn the pose at all. ``--label wave-right-hand`` takes the
crops from clips of one label only; every line also gives how much of the real wrists'
and ankles' root-relative motion energy the reconstruction keeps (1 = all of it; of a
wave's, a fresh 16-token VAE keeps 0.61 after 600 steps, a 32-token one 0.99).

``labels MODEL`` encodes and decodes up to 24 real clips of every label of
``umf.eval.motion_stats`` and prints each label's statistics, real vs reconstructed
(medians): what the VAE keeps of a wave, a bow, a walk before any flow is involved.

``score`` takes model directories (``src/umf/assets/model``) or VAE stage directories of a
run (``RUN/vae``), reconstructs every single-person test clip (posterior mean), and writes
``recipe.json`` (one row per model, merged with earlier rows): MPJPE (global,
root-relative, wrists), R^2 per feature group against the mean-pose baseline, the bundled
single-person evaluator's FID and R-precision of the reconstructions (real clips scored
the same way), and how high the reconstructed wrists of the real "raise both hands" clips
get relative to the head.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from umf.checkpoint import load_checkpoint
from umf.config import UMFConfig
from umf.data.corpus import Corpus
from umf.eval.protocol import aligned_scores, corpus_items
from umf.eval.reconstruction import reconstruct, reconstruction_metrics
from umf.models.vae import MotionVAE
from umf.train.run import best_or_last


def load_vae(path: Path) -> tuple[MotionVAE, UMFConfig]:
    ck_path = path if (path / "format.json").exists() else best_or_last(path)
    ck = load_checkpoint(ck_path, {})
    legacy = "target" not in ck.config["vae"]  # models before the body frame: global target
    if legacy:
        ck.config["vae"]["target"] = "global"
    cfg = UMFConfig.from_dict(ck.config)
    vae = MotionVAE(cfg.vae)
    load_checkpoint(ck_path, {"vae": vae}, strict=not legacy)
    return vae.float().eval(), cfg


def wrists_above_head(features: list[np.ndarray]) -> float:
    """Median over clips of the highest (lower wrist - head) height, metres."""
    from umf.eval.motion_stats import motion_statistics

    stats = [motion_statistics(f[:, :66].reshape(-1, 22, 3)) for f in features]
    return float(np.median([st["both_wrists_above_head"] for st in stats]))


def protocol(evaluator, items, recon, replications: int = 5) -> dict[str, float]:
    """Single-person FID / R-precision of reconstructions, aligned with the real items."""
    real = aligned_scores(evaluator, items, [it.features for it in items], replications)
    rec = aligned_scores(evaluator, items, [r[None] for r in recon], replications)
    return {f"{name}_{k}": v for name, row in (("real", real), ("recon", rec))
            for k, v in row.items()}  # fmt: skip


def score(args: argparse.Namespace) -> None:
    from umf.eval.contenders import load_evaluators
    from umf.eval.plan import default_evaluator_dir

    torch.set_num_threads(args.threads)
    corpus = Corpus.load(args.corpus)
    norm = corpus.normalizer
    items = corpus_items(corpus, "test", "single")
    real = [it.features[0][:300] for it in items]  # the longest motion the VAEs decode
    raise_idx = [i for i, it in enumerate(items) if "raise-up-both-hands" in it.id]
    evaluator = load_evaluators(default_evaluator_dir(), corpus.root / "text-cache", "cpu")[
        "single"
    ]
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    table_path = out_dir / "recipe.json"
    table = json.loads(table_path.read_text()) if table_path.exists() else {}
    for spec in args.models:
        name, path = spec.split("=", 1)
        vae, cfg = load_vae(Path(path).expanduser())
        t0 = time.time()
        recon = reconstruct(vae, norm, real)
        row = {"path": path, "target": cfg.vae.target,
               "frames_per_token": cfg.vae.frames_per_token,
               "d_model": cfg.vae.d_model, "layers": cfg.vae.num_layers,
               "latent": f"{cfg.vae.num_tokens}x{cfg.vae.latent_dim}"}  # fmt: skip
        row |= reconstruction_metrics(real, recon)
        row["wrists_above_head_raise_m"] = wrists_above_head([recon[i] for i in raise_idx])
        row["real_wrists_above_head_raise_m"] = wrists_above_head([real[i] for i in raise_idx])
        row |= protocol(evaluator, items, recon)
        row["seconds"] = time.time() - t0
        table[name] = row
        print(name, json.dumps({k: round(v, 4) if isinstance(v, float) else v
                                for k, v in row.items()}))  # fmt: skip
    table_path.write_text(json.dumps(table, indent=1))


def memorise(args: argparse.Namespace) -> None:
    from umf.body_frame import BODY_GROUPS, to_body_frame
    from umf.config import family_config, set_option
    from umf.models.vae import vae_losses
    from umf.train.datasets import PLACEMENT_RADIUS, SingleMotionDataset
    from umf.train.run import body_normalizer

    torch.set_num_threads(1)
    torch.manual_seed(0)
    cfg = family_config("small")
    for o in args.set:
        cfg = set_option(cfg, o)
    corpus = Corpus.load(args.corpus)
    ds = SingleMotionDataset(corpus, "train", corpus.normalizer, max_frames=120,
                             random_placement=True)  # fmt: skip
    picks = [i for i, (clip, _, _) in enumerate(ds.items)
             if args.label is None or clip.meta.get("content") == args.label]  # fmt: skip
    if not picks:
        raise SystemExit(f"no training clips of label {args.label!r}")
    batch = ds.collate([ds[picks[(i * 7) % len(picks)]] for i in range(32)])
    x, m = batch["features"], batch["mask"]
    vae = MotionVAE(cfg.vae)
    body = body_normalizer(corpus, PLACEMENT_RADIUS, max_frames=20_000)
    vae.set_normalizers(corpus.normalizer, body)

    def body_space(feats: torch.Tensor) -> torch.Tensor:
        return body.normalize(to_body_frame(corpus.normalizer.denormalize(feats)))

    opt = torch.optim.AdamW(vae.parameters(), lr=cfg.train_vae.lr)
    for step in range(args.steps + 1):
        losses = vae_losses(vae(x, m), x, m, corpus.normalizer, cfg.vae)
        opt.zero_grad()
        losses["total"].backward()
        torch.nn.utils.clip_grad_norm_(vae.parameters(), 1.0)
        opt.step()
        if step % 50 == 0:
            with torch.no_grad():  # scored in the body frame whatever the VAE models
                out = vae(x, m, sample=False)
                y, y_hat = body_space(x), body_space(out.x_hat)
                err, y = (y_hat - y)[m], y[m]
            r2 = {}
            for k, g in BODY_GROUPS.items():
                sst = (y[:, g] - y[:, g].mean(0)).pow(2).sum()
                r2[k] = round(1 - float(err[:, g].pow(2).sum() / sst), 3)
            kept = energy_kept(
                corpus.normalizer.denormalize(x),
                corpus.normalizer.denormalize(out.x_hat),
                m,
                cfg.vae,
            )
            print(json.dumps({"step": step, "set": args.set, **r2, **kept}), flush=True)


def energy_kept(
    real: torch.Tensor, recon: torch.Tensor, mask: torch.Tensor, vae_cfg
) -> dict[str, float]:
    """Reconstructed / real root-relative motion energy (mean joint speed) of wrists, ankles.

    The reconstruction's positions are fused with its velocities first, as the pipeline and
    ``reconstruct`` decode them (raw decoded positions jitter frame to frame).
    """
    from umf.eval.motion_stats import L_ANKLE, L_WRIST, PELVIS, R_ANKLE, R_WRIST
    from umf.representation import features_to_joints, fuse_positions

    def speeds(feats: torch.Tensor, idx: list[int], fuse: bool) -> list[torch.Tensor]:
        out = []
        for f, m in zip(feats, mask, strict=True):
            f = f[m]
            if fuse:
                f = fuse_positions(f, vae_cfg.position_fusion, vae_cfg.root_fusion)
            j = features_to_joints(f)
            rel = j[:, idx] - j[:, PELVIS : PELVIS + 1]
            out.append((rel[1:] - rel[:-1]).norm(dim=-1).flatten())
        return out

    kept = {}
    for name, idx in (("wrists", [L_WRIST, R_WRIST]), ("ankles", [L_ANKLE, R_ANKLE])):
        a = torch.cat(speeds(recon, idx, True)).mean()
        b = torch.cat(speeds(real, idx, False)).mean()
        kept[f"{name}_energy_kept"] = round(float(a / b), 3)
    return kept


def labels(args: argparse.Namespace) -> None:
    from umf.eval.motion_stats import LABELS, motion_statistics, real_clips_by_label
    from umf.representation import features_to_joints

    torch.set_num_threads(args.threads)
    corpus = Corpus.load(args.corpus)
    vae, _ = load_vae(Path(args.model))
    clips = real_clips_by_label(corpus)

    def joints(feats: list[np.ndarray]) -> list[np.ndarray]:
        return [features_to_joints(torch.as_tensor(f, dtype=torch.float32)).numpy() for f in feats]

    print("| label | clips | statistic | real (median) | reconstructed (median) |")
    print("|---|---:|---|---:|---:|")
    for label in LABELS:
        feats = [corpus.clip_features(c)[0][:300] for c in clips.get(label, [])[: args.clips]]
        if not feats:
            continue
        real = [motion_statistics(j) for j in joints(feats)]
        rec = [motion_statistics(j) for j in joints(reconstruct(vae, corpus.normalizer, feats))]
        for stat in dict.fromkeys((*LABELS[label][1], "pelvis_speed")):
            r, c = np.median([x[stat] for x in real]), np.median([x[stat] for x in rec])
            print(f"| {label} | {len(feats)} | {stat} | {r:.2f} | {c:.2f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("score")
    s.add_argument("models", nargs="+", help="NAME=DIR (model directory or RUN/vae)")
    s.add_argument("--corpus", default="out/corpus")
    s.add_argument("--out", default="results/vae-recipe")
    s.add_argument("--threads", type=int, default=2)
    m = sub.add_parser("memorise")
    m.add_argument("--corpus", default="out/corpus")
    m.add_argument("--steps", type=int, default=100)
    m.add_argument("--label", default=None, help="crops of this label's clips only")
    m.add_argument("--set", action="append", default=[], help="config override a.b=value")
    lab = sub.add_parser("labels")
    lab.add_argument("model", help="model directory or RUN/vae")
    lab.add_argument("--corpus", default="out/corpus")
    lab.add_argument("--clips", type=int, default=24, help="clips per label, at most")
    lab.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    {"score": score, "memorise": memorise, "labels": labels}[args.cmd](args)


if __name__ == "__main__":
    main()
