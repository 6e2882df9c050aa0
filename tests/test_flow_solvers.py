"""Fixed-step solvers: NFE accounting, convergence order against dopri5, CFG wrapper."""

from __future__ import annotations

import itertools
import math
import re
from typing import Any

import pytest
import torch
from torchdiffeq import odeint

from umf.flows import EVALS_PER_STEP, Method, classifier_free_guidance, integrate, time_grid

F64 = torch.float64
ORDER = {"euler": 1.0, "heun": 2.0, "rk4": 4.0}

# dx/dt = A x: a damped rotation, solution x(t) = expm(A (t - t0)) x0.
A = torch.tensor([[-0.5, 2.0], [-2.0, -0.3]], dtype=F64)


def linear_field(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    return x @ A.T


def nonlinear_field(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    tt = t[:, None]
    return -(x**3) + torch.sin(3.0 * tt) * x.roll(1, dims=-1) + tt


def _x0() -> torch.Tensor:
    return torch.randn(5, 2, dtype=F64, generator=torch.Generator().manual_seed(0))


def _dopri5(field: Any, x0: torch.Tensor, t0: float, t1: float) -> torch.Tensor:
    def f(t: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        return field(x, t.expand(x.shape[0]))

    ts = torch.tensor([t0, t1], dtype=F64)
    return odeint(f, x0, ts, method="dopri5", rtol=1e-12, atol=1e-12)[-1]


def test_time_grid() -> None:
    g = time_grid(4, 0.2, 1.0)
    assert len(g) == 5 and g[0] == 0.2 and g[-1] == 1.0
    assert all(b > a for a, b in itertools.pairwise(g))
    with pytest.raises(ValueError):
        time_grid(0)


def test_dopri5_reference_matches_exact_linear_solution() -> None:
    x0 = _x0()
    exact = x0 @ torch.linalg.matrix_exp(A * 0.8).T
    torch.testing.assert_close(_dopri5(linear_field, x0, 0.1, 0.9), exact, atol=1e-10, rtol=0)


@pytest.mark.parametrize("method", ["euler", "heun", "rk4"])
def test_nfe_count(method: Method) -> None:
    calls = []

    def v(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        calls.append(t)
        assert t.shape == (x.shape[0],)
        return -x

    sol = integrate(v, torch.ones(3, 4), steps=7, method=method)
    assert sol.nfe == 7 * EVALS_PER_STEP[method] == len(calls)
    assert sol.x.shape == (3, 4)


@pytest.mark.parametrize("problem", ["linear", "nonlinear"])
@pytest.mark.parametrize("method", ["euler", "heun", "rk4"])
def test_convergence_order(method: Method, problem: str) -> None:
    field = linear_field if problem == "linear" else nonlinear_field
    x0, t0, t1 = _x0(), 0.1, 0.9
    ref = _dopri5(field, x0, t0, t1)
    if problem == "linear":
        torch.testing.assert_close(
            ref, x0 @ torch.linalg.matrix_exp(A * (t1 - t0)).T, atol=1e-10, rtol=0
        )
    steps = [16, 32, 64, 128]
    errs = []
    for n in steps:
        x = integrate(field, x0, steps=n, t0=t0, t1=t1, method=method).x
        errs.append((x - ref).abs().max().item())
    rates = [math.log2(a / b) for a, b in itertools.pairwise(errs)]
    expected = ORDER[method]
    assert all(e < 1e-1 for e in errs[-1:]), errs
    assert abs(rates[-1] - expected) < 0.25, (rates, errs)
    assert all(r > expected - 0.3 for r in rates), (rates, errs)


def test_custom_grid_equals_steps() -> None:
    x0 = _x0()
    a = integrate(linear_field, x0, steps=5, method="heun")
    b = integrate(linear_field, x0, grid=time_grid(5), method="heun")
    assert torch.equal(a.x, b.x) and a.nfe == b.nfe


def _toy_model(calls: list[int]) -> Any:
    def v(
        x: torch.Tensor,
        t: torch.Tensor,
        *,
        text: torch.Tensor,
        stage: torch.Tensor,
        flag: str = "a",
    ) -> torch.Tensor:
        calls.append(x.shape[0])
        assert t.shape[0] == x.shape[0] == text.shape[0] == stage.shape[0]
        return x * text[:, None, None] + t[:, None, None] + stage[:, None, None]

    return v


@pytest.mark.parametrize("batched", [True, False])
def test_cfg_matches_formula(batched: bool) -> None:
    calls: list[int] = []
    model = _toy_model(calls)
    x = torch.randn(3, 4, 2)
    t = torch.full((3,), 0.3)
    stage = torch.full((3,), 2)
    cond = {"text": torch.tensor([1.0, 2.0, 3.0]), "flag": "a"}
    uncond = {"text": torch.zeros(3), "flag": "a"}
    guided = classifier_free_guidance(model, 2.5, cond, uncond, batched=batched)
    out = guided(x, t, stage=stage)
    v_c = model(x, t, stage=stage, **cond)
    v_u = model(x, t, stage=stage, **uncond)
    torch.testing.assert_close(out, v_u + 2.5 * (v_c - v_u))
    assert calls[:-2] == ([6] if batched else [3, 3])


def test_cfg_scale_one_and_zero() -> None:
    model = _toy_model([])
    x, t, st = torch.randn(2, 4, 2), torch.rand(2), torch.ones(2)
    cond, uncond = {"text": torch.ones(2)}, {"text": torch.zeros(2)}
    one = classifier_free_guidance(model, 1.0, cond, uncond)(x, t, stage=st)
    zero = classifier_free_guidance(model, 0.0, cond, uncond)(x, t, stage=st)
    torch.testing.assert_close(one, model(x, t, stage=st, **cond))
    torch.testing.assert_close(zero, model(x, t, stage=st, **uncond))


def test_cfg_inside_solver_counts_guided_evaluations() -> None:
    calls: list[int] = []
    model = _toy_model(calls)
    guided = classifier_free_guidance(model, 3.0, {"text": torch.ones(2)}, {"text": torch.zeros(2)})
    sol = integrate(
        guided, torch.zeros(2, 4, 2), steps=4, method="heun", cond={"stage": torch.ones(2)}
    )
    assert sol.nfe == 8 and calls == [4] * 8


def test_cfg_rejects_mismatched_keys() -> None:
    with pytest.raises(ValueError):
        classifier_free_guidance(_toy_model([]), 2.0, {"text": 1}, {})


# ------------------------------------------------- defaults, messages, CFG batching
def _refused(message: str) -> Any:
    """pytest.raises for a ValueError whose whole text is ``message``."""
    return pytest.raises(ValueError, match="^" + re.escape(message) + "$")


def test_integrate_defaults_to_euler_from_0_to_1() -> None:
    x0 = torch.ones(2, 3, dtype=F64)
    seen: list[float] = []

    def v(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        seen.append(float(t[0]))
        return -x

    sol = integrate(v, x0, steps=4)  # Euler: x <- x + h * (-x) = 0.75 x, four times
    assert sol.nfe == 4 and seen == [0.0, 0.25, 0.5, 0.75]
    assert torch.equal(sol.x, x0 * 0.75**4)


def test_solver_messages() -> None:
    def v(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        return x

    with _refused("give either steps or grid"):
        integrate(v, torch.ones(1, 2))
    with _refused("unknown method 'rk5'; choose from ['euler', 'heun', 'rk4']"):
        integrate(v, torch.ones(1, 2), steps=2, method="rk5")  # type: ignore[arg-type]
    with _refused("steps must be >= 1, got 0"):
        time_grid(0)
    with _refused("cond and uncond must have the same keys"):
        classifier_free_guidance(v, 2.0, {"text": 1}, {"mask": 1})


def _recording_model(seen: dict[str, Any]) -> Any:
    def v(x: torch.Tensor, t: torch.Tensor, **kw: Any) -> torch.Tensor:
        seen.update(kw)
        seen["batch"] = x.shape[0]
        level, gain, offset = kw["level"], kw["gain"], kw["offset"]
        return x * kw["text"][:, None] * level + gain.sum() + offset + t[:, None]

    return v


def test_batched_cfg_doubles_only_per_sample_tensors() -> None:
    """Shared call-time values: a (B, ...) tensor is repeated for [cond; uncond]; a 0-dim
    tensor, a tensor of another length and a plain number go to the model unchanged."""
    x, t = torch.randn(3, 2, dtype=F64), torch.rand(3, dtype=F64)
    cond = {"text": torch.tensor([1.0, 2.0, 3.0], dtype=F64)}
    uncond = {"text": torch.zeros(3, dtype=F64)}
    shared = {"level": torch.tensor(2.0, dtype=F64), "gain": torch.ones(5, dtype=F64),
              "offset": 0.5, "per_sample": torch.arange(3.0)}  # fmt: skip
    seen: dict[str, Any] = {}
    model = _recording_model(seen)
    out = classifier_free_guidance(model, 2.5, cond, uncond)(x, t, **shared)
    assert seen["batch"] == 6 and seen["offset"] == 0.5
    assert seen["level"] is shared["level"] and seen["gain"] is shared["gain"]
    assert seen["per_sample"].tolist() == [0.0, 1.0, 2.0, 0.0, 1.0, 2.0]
    v_c, v_u = model(x, t, **shared, **cond), model(x, t, **shared, **uncond)
    torch.testing.assert_close(out, v_u + 2.5 * (v_c - v_u))


def test_batched_cfg_shares_equal_non_tensors_and_refuses_different_ones() -> None:
    x, t = torch.randn(2, 2, dtype=F64), torch.rand(2, dtype=F64)
    seen: dict[str, Any] = {}
    base = {"level": 1.0, "gain": torch.ones(1, dtype=F64), "offset": 0.0}

    def run(cond: dict[str, Any], uncond: dict[str, Any], batched: bool = True) -> Any:
        guided = classifier_free_guidance(_recording_model(seen), 2.0, cond, uncond,
                                          batched=batched)  # fmt: skip
        return guided(x, t, **base)

    cond = {"text": torch.ones(2, dtype=F64), "names": ["a", "b"]}
    uncond = {"text": torch.zeros(2, dtype=F64), "names": ["a", "b"]}  # equal, not the same
    run(cond, uncond)
    assert seen["names"] == ["a", "b"] and seen["text"].tolist() == [1.0, 1.0, 0.0, 0.0]
    same = ["a"]
    run({**cond, "names": same}, {**uncond, "names": same})
    assert seen["names"] is same
    with _refused("cond/uncond entry 'names' differs but is not a tensor; cannot batch"):
        run(cond, {**uncond, "names": ["a"]})
    with _refused("cond/uncond entry 'text' differs but is not a tensor; cannot batch"):
        run(cond, {**uncond, "text": None})
    with _refused("cond/uncond entry 'text' differs but is not a tensor; cannot batch"):
        run({**cond, "text": None}, uncond)
    # unbatched, each call gets its own value: no need to agree
    out = run(cond, {**uncond, "names": ["z"]}, batched=False)
    assert out.shape == x.shape and seen["names"] == ["z"]
