"""The speed scripts' timers (scripts/benchmark.py, scripts/gpu_timing.py): a device's queued
work is waited for before every clock read, stages are attributed, and the pyramid is timed
against the same weights run flat. Figures themselves live in the scripts' output, not here."""

from __future__ import annotations

import pytest
import torch

from conftest import FakeText, load_script, tiny_config

benchmark = load_script("benchmark")


@pytest.fixture(scope="module")
def tiny_pipe():
    from umf.pipeline import UMFPipeline

    torch.manual_seed(0)
    return UMFPipeline.build(tiny_config(), text_encoder=FakeText())


def test_timed_waits_for_the_device_after_every_call():
    events = []
    benchmark.timed(lambda: events.append("call"), 3, sync=lambda: events.append("sync"))
    assert events == ["call", "sync"] * 4  # the warm-up, then 3 timed calls


def test_stage_profile_names_each_stage_and_adds_up(tiny_pipe):
    syncs = []
    prof = benchmark.stage_profile(tiny_pipe, 2, 1.0, 1, sync=lambda: syncs.append(1), batch=2)
    for stage in ("text", "P-Flow", "S-Flow", "VAE", "clean-up", "other", "total"):
        assert stage in prof, stage
    assert prof["other"] >= 0  # the stages happen inside the call, not around it
    assert min(v for k, v in prof.items() if k != "other") > 0
    assert len(syncs) >= 10  # around every wrapped stage, not just the whole call
    assert "encode" not in vars(tiny_pipe.text_encoder)  # the wrappers were taken off


def test_the_flat_pflow_is_the_same_network_in_one_stage(tiny_pipe):
    flat = benchmark.flat_pflow(tiny_pipe)
    assert flat.cfg.num_stages == 1 and tiny_pipe.pflow.cfg.num_stages > 1
    ours, theirs = tiny_pipe.pflow.state_dict(), flat.state_dict()
    assert set(theirs) <= set(ours) and len(theirs) >= len(ours) - 1  # no stage embedding
    assert all(torch.equal(ours[k], theirs[k]) for k in theirs)
    pyr, full = benchmark.pyramid_vs_flat(tiny_pipe, 1, batch=2)
    assert pyr > 0 and full > 0


def test_gpu_timing_rows_count_scenes_per_second(tiny_pipe):
    gpu_timing = load_script("gpu_timing")
    timed, _ = gpu_timing.synced_timer(torch.device("cpu"))
    rows = gpu_timing.family_rows(tiny_pipe, "tiny", timed, 1, [1, 2], [2], full_batches=[1])
    assert [(r["batch"], r["people"]) for r in rows] == [(1, 2), (2, 2)]
    for r in rows:
        assert r["scenes_per_s"] == pytest.approx(r["batch"] / r["generator_s"], rel=0.01)
        assert r["gflop"] > 0
    assert "pipeline_s" in rows[0] and "pipeline_s" not in rows[1]


def test_gpu_timing_without_a_gpu_is_a_one_line_refusal(monkeypatch):
    gpu_timing = load_script("gpu_timing")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(SystemExit, match="no CUDA device"):
        gpu_timing.main(["--device", "cuda"])
