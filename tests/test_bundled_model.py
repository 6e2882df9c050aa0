"""The model and evaluator shipped inside the package load and work with no arguments."""

from __future__ import annotations

import numpy as np

from umf.pipeline import UMFPipeline, default_model_dir


def test_bundled_model_generates_without_a_path():
    assert (default_model_dir() / "README.md").exists()  # the model card ships with it
    size = sum(f.stat().st_size for f in default_model_dir().iterdir())
    assert size < 40e6
    pipe = UMFPipeline.from_pretrained()
    assert pipe.name.startswith("umf-small-bandai")
    scenes = pipe(["Two people walk side by side.", "A person waves."], num_people=3,
                  seconds=2.0, seed=0)  # fmt: skip
    for s in scenes:
        assert s.joints.shape == (3, 60, 22, 3) and np.isfinite(s.joints).all()
        # trained on real people: bodies about a person tall, feet near the floor
        span = s.joints[:, 0, :, 1].max(-1) - s.joints[:, 0, :, 1].min(-1)
        assert ((span > 1.0) & (span < 2.2)).all(), span
        assert abs(float(s.joints[..., 1].min())) < 0.3
    walk = scenes[0].joints[0, :, 0, [0, 2]]
    assert np.linalg.norm(walk[-1] - walk[0]) > 0.5  # a walk goes somewhere in 2 s


def test_bundled_evaluator_loads():
    from umf.eval.evaluator import load_evaluator
    from umf.eval.report import default_evaluator_dir

    for kind in ("interaction", "single"):
        ev = load_evaluator(default_evaluator_dir() / kind)
        emb = ev.encode_text(["Two people walk side by side."])
        assert emb.shape[0] == 1 and np.isfinite(emb.detach().numpy()).all()
