"""The documented top and bottom bounds are accepted, one step past them refused.

A bound written ``<`` instead of ``<=`` refuses the very value the README documents
(``--people 16``, ``--seed 2^64-1``, ``--sflow-steps 200``). Each check's edges and exact
messages are in test_validation.py; here the documented figures, and the options the CLI
and the pipeline must honour once they pass (``--actor-person``, ``--guidance``).
"""

from __future__ import annotations

import pytest

from umf.errors import UMFError
from umf.validation import (
    MAX_BATCH,
    MAX_FLOW_STEPS,
    MAX_GUIDANCE,
    MAX_PEOPLE,
    MAX_SECONDS,
    MAX_SEED,
    MIN_SECONDS,
    check_request,
)


def test_the_documented_bounds():
    assert (MAX_PEOPLE, MAX_SECONDS, MIN_SECONDS, MAX_SEED) == (16, 10.0, 0.5, 2**64 - 1)
    assert (MAX_GUIDANCE, MAX_FLOW_STEPS, MAX_BATCH) == (20.0, 200, 256)


@pytest.fixture
def tiny_model(tmp_path, fake_text, one_thread):
    from conftest import save_tiny_model

    return save_tiny_model(tmp_path / "m")


def test_actor_person_picks_that_person(tmp_path, tiny_model):
    """--actor-person K: person 1 of the reaction is person K of the file, not person 1."""
    import numpy as np
    from typer.testing import CliRunner

    from conftest import BANDAI_FIXTURE
    from umf.cli.main import app
    from umf.data.motion_file import load_motion

    data = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data"
    bow = load_motion(data / "dataset-1_bow_normal_001.bvh").joints[0, :40]
    walk = load_motion(data / "dataset-1_walk_normal_001.bvh").joints[0, :40]
    walk = walk + np.array([2.0, 0.0, 0.0], np.float32)
    np.savez(tmp_path / "two.npz", joints=np.stack([bow, walk]))
    got = {}
    for k in (1, 2):
        out = tmp_path / f"r{k}"
        r = CliRunner().invoke(app, ["react", "two people", "--actor", str(tmp_path / "two.npz"),
                                     "--actor-person", str(k), "--model", str(tiny_model),
                                     "--out", str(out), "--format", "npz"])  # fmt: skip
        assert r.exit_code == 0, r.output
        (npz,) = out.glob("*.npz")
        with np.load(npz) as z:
            got[k] = z["joints"][0]
    t = got[1].shape[0]
    assert t >= 39
    assert np.abs(got[1] - bow[:t]).max() < 0.02 and np.abs(got[2] - walk[:t]).max() < 0.02
    assert np.abs(got[1] - got[2]).max() > 1.0


def test_guidance_changes_the_scene(tiny_model):
    """--guidance reaches both flows: another scale, another scene (same seed)."""
    import numpy as np

    from umf.pipeline import UMFPipeline

    pipe = UMFPipeline.from_pretrained(tiny_model)
    torch = pytest.importorskip("torch")
    for m in (pipe.pflow, pipe.sflow):  # untrained conditional branches would be equal
        for p in m.parameters():
            p.data += 0.05 * torch.randn_like(p)
    a, b, a2 = (pipe("a person walks", num_people=2, seconds=1.0, seed=3, guidance=g, fit=False)[0]
                for g in (0.0, 5.0, 0.0))  # fmt: skip
    assert np.array_equal(a.joints, a2.joints)
    assert np.abs(a.joints[0] - b.joints[0]).max() > 1e-3  # P-Flow: person 1
    assert np.abs(a.joints[1] - b.joints[1]).max() > 1e-3


def test_a_step_total_below_the_stage_count_and_a_lone_surrogate_are_one_line():
    from conftest import tiny_config
    from umf.validation import check_for_model

    cfg = tiny_config()  # a two-stage pyramid
    with pytest.raises(UMFError, match="fewer than this model's 2 pyramid stages"):
        check_for_model(check_request("a person walks", pflow_steps=1), cfg)
    assert check_for_model(check_request("a person walks", pflow_steps=2), cfg) > 0
    with pytest.raises(UMFError, match="not valid text"):
        check_request("a person \ud800 walks")


def test_a_full_disk_is_one_line_naming_the_file(monkeypatch, capsys):
    import errno

    import umf.cli.main as cli

    def full(*a, **k):
        try:
            raise OSError(errno.ENOSPC, "No space left on device", "out/x.npz")
        except OSError as inner:
            raise RuntimeError("while writing") from inner

    monkeypatch.setattr(cli, "app", full)
    with pytest.raises(SystemExit) as stop:
        cli.run(["generate", "x"])
    assert stop.value.code == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no space left on device writing out/x.npz" in err
    assert cli.disk_full(ValueError("x")) is None
