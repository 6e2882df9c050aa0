"""Score motion VAEs on reconstructions of real test clips (the VAE recipe table).

    python scripts/vae_recipe.py score NAME=VAE_DIR ... --corpus out/corpus --out results/vae-recipe
    python scripts/vae_recipe.py train NAME --run ~/umf-runs/recipe --corpus out/corpus \
        --steps 300 --set vae.target=global ...

``score`` takes model directories (``src/umf/assets/model``) or VAE stage directories of a
run (``RUN/vae``), reconstructs every single-person test clip (posterior mean), and writes
``recipe.json`` and ``README.md``: MPJPE (global, root-relative, wrists), R^2 per feature
group against the mean-pose baseline, the bundled single-person evaluator's FID and
R-precision of the reconstructions (real clips scored the same way), and how high the
reconstructed wrists of the real "raise both hands" clips get relative to the head.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from umf.config import UMFConfig
from umf.data.corpus import Corpus
from umf.eval.protocol import ProtocolConfig, corpus_items, embed_motions, embed_texts, set_metrics
from umf.eval.reconstruction import reconstruct, reconstruction_metrics
from umf.models.vae import MotionVAE
from umf.train.checkpoint import load_checkpoint
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
    vals = []
    for f in features:
        j = f[:, :66].reshape(-1, 22, 3)
        vals.append((np.minimum(j[:, 20, 1], j[:, 21, 1]) - j[:, 15, 1]).max())
    return float(np.median(vals))


def protocol(evaluator, items, recon, replications: int = 5) -> dict[str, float]:
    """Single-person FID / R-precision of reconstructions, aligned with the real items."""
    cfg = ProtocolConfig(replications=replications)
    real_emb = embed_motions(evaluator, [it.features for it in items])
    rec_emb = embed_motions(evaluator, [r[None] for r in recon])
    caps = sorted({c for it in items for c in it.captions})
    text_of = dict(zip(caps, embed_texts(evaluator, caps), strict=True))
    rows = {"real": [], "recon": []}
    for r in range(replications):
        rng = np.random.default_rng([0, r])
        order = rng.permutation(len(items))
        n = (len(items) // cfg.group) * cfg.group
        idx = order[:n]
        text = np.stack([text_of[items[i].captions[int(rng.integers(len(items[i].captions)))]]
                         for i in idx])  # fmt: skip
        for name, emb in (("real", real_emb), ("recon", rec_emb)):
            rows[name].append(set_metrics(text, emb[idx], real_emb, np.random.default_rng(r), cfg))
    return {f"{name}_{k}": float(np.mean([row[k] for row in v]))
            for name, v in rows.items() for k in ("fid", "r_precision_top3")}  # fmt: skip


def score(args: argparse.Namespace) -> None:
    from umf.eval.report import load_evaluators

    torch.set_num_threads(args.threads)
    corpus = Corpus.load(args.corpus)
    norm = corpus.normalizer
    items = corpus_items(corpus, "test", "single")
    real = [it.features[0] for it in items]
    raise_idx = [i for i, it in enumerate(items) if "raise-up-both-hands" in it.id]
    evaluator = load_evaluators(None, corpus.root / "text-cache", "cpu")["single"]
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("score")
    s.add_argument("models", nargs="+", help="NAME=DIR (model directory or RUN/vae)")
    s.add_argument("--corpus", default="out/corpus")
    s.add_argument("--out", default="results/vae-recipe")
    s.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    score(args)


if __name__ == "__main__":
    main()
