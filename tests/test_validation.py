"""umf.validation called directly: every check accepts its documented edges, refuses one
step past them, and says so in the exact words a user reads (the CLI tests reach these
through a subprocess, where a mutation run cannot see them)."""

from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from umf import validation as v
from umf.errors import UMFError


def refused(message: str):
    """pytest.raises for a UMFError whose whole text is ``message``."""
    return pytest.raises(UMFError, match="^" + re.escape(message) + "$")


# ----------------------------------------------------------------- scalars
def test_check_int_accepts_both_ends_and_names_the_bounds():
    assert v.check_int("--people", 1, 1, 16) == 1
    assert v.check_int("--people", 16, 1, 16) == 16
    assert v.check_int("--people", np.int64(3), 1, 16) == 3
    assert type(v.check_int("--people", np.int64(3), 1, 16)) is int
    with refused("--people must be between 1 and 16, got 17"):
        v.check_int("--people", 17, 1, 16)
    with refused("--people must be between 1 and 16, got 0"):
        v.check_int("--people", 0, 1, 16)
    with refused("--people must be an integer, got True"):
        v.check_int("--people", True, 1, 16)
    with refused("--people must be an integer, got 2.5"):
        v.check_int("--people", 2.5, 1, 16)


def test_check_float_accepts_both_ends_and_refuses_non_finite():
    assert v.check_float("--seconds", 0.5, 0.5, 10.0) == 0.5
    assert v.check_float("--seconds", 10, 0.5, 10.0) == 10.0
    assert type(v.check_float("--seconds", 10, 0.5, 10.0)) is float
    with refused("--seconds must be between 0.5 and 10, got 10.01"):
        v.check_float("--seconds", 10.01, 0.5, 10.0)
    with refused("--seconds must be between 0.5 and 10, got 0.49"):
        v.check_float("--seconds", 0.49, 0.5, 10.0)
    with refused("--seconds must be a finite number, got nan"):
        v.check_float("--seconds", float("nan"), 0.5, 10.0)
    with refused("--seconds must be a finite number, got inf"):
        v.check_float("--seconds", float("inf"), 0.5, 10.0)
    with refused("--seconds must be a number, got False"):
        v.check_float("--seconds", False, 0.5, 10.0)
    with refused("--seconds must be a number, got '4'"):
        v.check_float("--seconds", "4", 0.5, 10.0)


# ----------------------------------------------------------------- prompts and steps
def test_check_prompts():
    assert v.check_prompts("a walk") == ("a walk",)
    assert v.check_prompts(["a", "b"]) == ("a", "b")
    assert v.check_prompts(["x" * v.MAX_PROMPT_CHARS] * v.MAX_SCENES)[0] == "x" * 1000
    with refused("a prompt may have at most 1000 characters, got 1001"):
        v.check_prompts("x" * 1001)
    with refused("at most 256 prompts per call, got 257"):
        v.check_prompts(["a"] * 257)
    with refused("the prompt is empty"):
        v.check_prompts([])
    with refused("the prompt is empty"):
        v.check_prompts(["a", "  \n"])
    with refused("every prompt must be a string, got 3"):
        v.check_prompts(["a", 3])
    with refused("the prompt must be a string or a list of strings, got b'a walk'"):
        v.check_prompts(b"a walk")
    with refused("the prompt must be a string or a list of strings, got 7"):
        v.check_prompts(7)
    with refused("the prompt is not valid text (unpaired surrogate in 'a\\ud800')"):
        v.check_prompts("a\ud800")


def test_check_steps():
    assert v.check_steps(None) is None
    assert v.check_steps(5) == (5,)
    assert v.check_steps([45, 5]) == (45, 5)
    assert v.check_steps([200]) == (200,)
    assert v.check_steps([100, 100]) == (100, 100)
    assert v.check_steps([1] * 8) == (1,) * 8
    with refused("--steps may total at most 200, got 201"):
        v.check_steps([100, 101])
    with refused("--steps must be between 1 and 200, got 0"):
        v.check_steps([5, 0])
    with refused("--steps takes 1 to 8 integers like 45,5, got [1, 1, 1, 1, 1, 1, 1, 1, 1]"):
        v.check_steps([1] * 9)
    with refused("--steps takes 1 to 8 integers like 45,5, got []"):
        v.check_steps([])
    with refused("--steps takes 1 to 8 integers like 45,5, got '45'"):
        v.check_steps("45")
    with refused("--steps takes 1 to 8 integers like 45,5, got True"):
        v.check_steps(True)


def test_default_sample_indices_count_copies_of_each_prompt():
    assert v.default_sample_indices(["a", "b", "a", "a", "b", "c"]) == (0, 0, 1, 2, 1, 0)
    assert v.default_sample_indices([]) == ()


# ----------------------------------------------------------------- a request
def test_check_request_defaults_and_top_bounds():
    req = v.check_request("a walk")
    assert req == v.Request(("a walk",), 2, 4.0, 0, None, None, None, (0,))
    top = v.check_request(["a", "a"], num_people=16, seconds=10, seed=2**64 - 1, guidance=20,
                          pflow_steps=[150, 50], sflow_steps=200)  # fmt: skip
    assert top == v.Request(("a", "a"), 16, 10.0, 2**64 - 1, 20.0, (150, 50), 200, (0, 1))
    low = v.check_request("a", num_people=1, seconds=0.5, seed=None, guidance=0, sflow_steps=1)
    assert (low.num_people, low.seconds, low.seed, low.guidance, low.sflow_steps) == (
        1, 0.5, None, 0.0, 1)  # fmt: skip
    assert v.check_request(["a", "b"], sample_indices=[7, 2**31 - 1]).sample_indices == (
        7, 2**31 - 1)  # fmt: skip


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"num_people": 17}, "--people must be between 1 and 16, got 17"),
        ({"num_people": 0}, "--people must be between 1 and 16, got 0"),
        ({"seconds": 10.5}, "--seconds must be between 0.5 and 10, got 10.5"),
        ({"seed": 2**64}, f"--seed must be between 0 and {2**64 - 1}, got {2**64}"),
        ({"seed": -1}, f"--seed must be between 0 and {2**64 - 1}, got -1"),
        ({"guidance": 20.5}, "--guidance must be between 0 and 20, got 20.5"),
        ({"guidance": -0.1}, "--guidance must be between 0 and 20, got -0.1"),
        ({"sflow_steps": 201}, "--sflow-steps must be between 1 and 200, got 201"),
        ({"sflow_steps": 0}, "--sflow-steps must be between 1 and 200, got 0"),
        ({"pflow_steps": [201]}, "--steps must be between 1 and 200, got 201"),
        ({"sample_indices": "01"}, "sample_indices must be a list of integers, one per prompt"),
        ({"sample_indices": 3}, "sample_indices must be a list of integers, one per prompt"),
        ({"sample_indices": [0, 1]}, "2 sample indices for 1 prompts"),
        ({"sample_indices": [-1]}, f"a sample index must be between 0 and {2**31 - 1}, got -1"),
        ({"sample_indices": [2**31]},
         f"a sample index must be between 0 and {2**31 - 1}, got {2**31}"),
    ],
)  # fmt: skip
def test_check_request_refuses_one_past_each_bound(kwargs, message):
    with refused(message):
        v.check_request("a walk", **kwargs)


def _config(stages: int = 3, fps: float = 30.0, max_frames: int = 300):
    return SimpleNamespace(pflow=SimpleNamespace(num_stages=stages), fps=fps,
                           vae=SimpleNamespace(max_frames=max_frames))  # fmt: skip


def test_check_for_model_frames_and_stage_counts():
    cfg = _config()
    assert v.check_for_model(v.check_request("a", seconds=4.0), cfg) == 120
    assert v.check_for_model(v.check_request("a", seconds=10.0), cfg) == 300
    assert v.check_for_model(v.check_request("a", seconds=0.5), cfg) == 15
    assert v.check_for_model(v.check_request("a", pflow_steps=[3]), cfg) == 120
    assert v.check_for_model(v.check_request("a", pflow_steps=[4, 4, 2]), cfg) == 120
    with refused("--seconds must be between 0.5 and 5.0, got 5.1"):
        v.check_for_model(v.check_request("a", seconds=5.1), _config(max_frames=150))
    with refused("--seconds must be between 1.0 and 10.0, got 0.9"):
        v.check_for_model(v.check_request("a", seconds=0.9), _config(fps=15.0, max_frames=150))
    # acting, the length is the actor's, so --seconds is not held against the model
    assert v.check_for_model(v.check_request("a", seconds=10.0), _config(max_frames=20),
                             acting=True) == 0  # fmt: skip
    with refused("--steps needs 3 count(s) for this model's 3-stage pyramid (coarse to fine), "
                 "got 2"):  # fmt: skip
        v.check_for_model(v.check_request("a", pflow_steps=[4, 4]), cfg, acting=True)
    with refused("--steps 2 in total is fewer than this model's 3 pyramid stages "
                 "(at least one step each)"):  # fmt: skip
        v.check_for_model(v.check_request("a", pflow_steps=[2]), cfg, acting=True)


def test_check_batch_caps_prompts_times_batch():
    assert v.check_batch(256, 1) == 256
    assert v.check_batch(128, 2) == 128
    assert v.check_batch(1, 256) == 1
    with refused("at most 256 scenes per command: 2 prompt(s) x --batch 129 is 258"):
        v.check_batch(129, 2)
    with refused("--batch must be between 1 and 256, got 257"):
        v.check_batch(257, 1)
    with refused("--batch must be between 1 and 256, got 0"):
        v.check_batch(0, 1)


# ----------------------------------------------------------------- files
def test_check_out_dir_and_targets(tmp_path, monkeypatch):
    assert v.check_out_dir(tmp_path) == tmp_path
    deep = tmp_path / "a" / "b" / "c"
    assert v.check_out_dir(deep) == deep and not (tmp_path / "a").exists()
    f = tmp_path / "file.txt"
    f.write_text("x")
    with refused(f"--out {f} exists and is not a directory"):
        v.check_out_dir(f)
    with refused(f"--out {f / 'sub'}: {f} is not a directory"):
        v.check_out_dir(f / "sub")
    monkeypatch.setattr(v.os, "access", lambda p, mode: mode != v.os.W_OK | v.os.X_OK)
    with refused(f"--out {deep}: {tmp_path} is not writable"):
        v.check_out_dir(deep)
    monkeypatch.undo()
    v.check_targets([tmp_path / "new.npz", f])
    (tmp_path / "taken.glb").mkdir()
    with refused(f"cannot write {tmp_path / 'taken.glb'}: a directory has that name"):
        v.check_targets([f, tmp_path / "taken.glb"])


# ----------------------------------------------------------------- an actor's motion
@pytest.fixture
def body(real_joints):
    """``body(frames)``: a real walk (metres), its frames repeated to the length asked."""
    walk = real_joints.numpy()
    return lambda frames=40: walk[np.arange(frames) % len(walk)]


def test_check_actor_accepts_16_to_max_frames_plus_one(body):
    for frames in (16, 301):
        walk = body(frames)
        assert v.check_actor(walk, 30.0, 300) is walk
    with refused("the actor motion must have 16..301 frames (0.5-10.0 s), got 15"):
        v.check_actor(body(15), 30.0, 300)
    with refused("the actor motion must have 16..301 frames (0.5-10.0 s), got 302"):
        v.check_actor(body(302), 30.0, 300)
    with refused("the actor motion must have 16..151 frames (0.8-7.5 s), got 152"):
        v.check_actor(body(152), 20.0, 150)


def test_check_actor_refuses_what_is_not_a_metre_sizedbody(body):
    with refused("the actor motion must be a numpy array, got list"):
        v.check_actor(body().tolist(), 30.0, 300)
    with refused("the actor motion must be (T, 22, 3) joints, got (40, 21, 3)"):
        v.check_actor(body()[:, :21], 30.0, 300)
    with refused("the actor motion must be (T, 22, 3) joints, got (40, 66)"):
        v.check_actor(body().reshape(40, 66), 30.0, 300)
    bad = body()
    bad[3, 4, 1] = np.nan
    with refused("the actor motion contains NaN or infinite values"):
        v.check_actor(bad, 30.0, 300)
    with refused("the actor motion contains NaN or infinite values"):
        v.check_actor(body().astype(str), 30.0, 300)
    point = np.zeros((40, 22, 3))
    point[:, :, 0] = 0.01 * np.arange(40)[:, None]  # it moves, but every frame is one point
    with refused("the actor motion spans only 0.000 m: not a body (all joints at one point?)"):
        v.check_actor(point, 30.0, 300)
    small = body() * 0.1  # a tenth of a body: the extent of one frame, not of the path, decides
    small[:, :, 0] += 0.05 * np.arange(40)[:, None]
    with refused("the actor motion spans only 0.136 m: not a body (all joints at one point?)"):
        v.check_actor(small, 30.0, 300)
    with refused("the actor motion looks like it is in cm, not metres (a body 100 times too "
                 "large): multiply it by 0.01"):  # fmt: skip
        v.check_actor(body() * 100, 30.0, 300)


# ----------------------------------------------------------------- outputs, devices, chunks
def test_check_finite():
    v.check_finite(np.zeros(3), "x")
    v.check_finite(torch.zeros(3), "x")
    with refused("non-finite values (NaN or inf) in the decoded joints"):
        v.check_finite(torch.tensor([0.0, float("inf")]), "the decoded joints")
    with refused("non-finite values (NaN or inf) in a scene"):
        v.check_finite(np.array([np.nan]), "a scene")


def test_check_device(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)
    assert v.check_device("auto") == "cpu"
    assert v.check_device("cpu") == "cpu"
    with refused("--device cuda: no CUDA device on this machine"):
        v.check_device("cuda")
    with refused("--device must be auto, cpu or cuda[:i], got 'mps'"):
        v.check_device("mps")
    with refused("--device must be auto, cpu or cuda[:i], got 'gpu'"):
        v.check_device("gpu")
    with refused("--device must be auto, cpu or cuda[:i], got 'AUTO'"):
        v.check_device("AUTO")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert v.check_device("auto") == "cuda"
    assert v.check_device("cuda") == "cuda"
    assert v.check_device("cuda:1") == "cuda:1"
    with refused("--device cuda:2: this machine has 2 CUDA device(s)"):
        v.check_device("cuda:2")
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    assert v.check_device("cuda:0") == "cuda:0"


def test_chunks_hold_at_most_the_budget():
    assert v.chunk_size(16, 300) == 16
    assert v.chunk_size(2, 120) == v.CHUNK_PERSON_FRAMES // 240
    assert v.chunk_size(16, 300, budget=100) == 1
    assert v.chunk_size(0, 0, budget=7) == 7
    assert v.chunks(5, 2) == [range(0, 2), range(2, 4), range(4, 5)]
    assert v.chunks(4, 4) == [range(0, 4)]
    assert v.chunks(0, 3) == []


def test_check_actor_accepts_the_edges_of_body_size(body):
    """Exactly MIN_BODY_EXTENT is a body ("smaller than" is refused), and a body no known
    unit makes adult-sized (a child, a giant) is taken as it is: the pipeline rescales it."""
    edge = np.zeros((40, 22, 3))
    edge[:, 1::2, 0] = v.MIN_BODY_EXTENT  # every frame spans exactly 0.2 m, along x only
    assert float(np.ptp(edge, axis=1).max()) == v.MIN_BODY_EXTENT
    assert v.check_actor(edge, 30.0, 300) is edge
    from umf.units import choose_unit

    for scale in (0.6, 3.0):
        odd = body() * scale
        assert choose_unit(odd)[1] == "stature"
        assert v.check_actor(odd, 30.0, 300) is odd


def test_check_finite_takes_tensors_numpy_cannot_read():
    v.check_finite(torch.zeros(3, requires_grad=True), "the latents")  # a model's output
    v.check_finite(torch.zeros(3, dtype=torch.bfloat16), "the latents")
    with refused("non-finite values (NaN or inf) in the latents"):
        v.check_finite(torch.tensor([0.0, float("nan")], dtype=torch.bfloat16), "the latents")
    with refused("non-finite values (NaN or inf) in the latents"):
        v.check_finite(torch.tensor([float("inf")], requires_grad=True), "the latents")


def test_check_out_dir_still_checks_the_top_when_no_ancestor_exists(monkeypatch):
    """The walk up stops at the top (here the relative "."), which is then checked like any
    existing ancestor, not waved through."""
    with monkeypatch.context() as m:
        m.setattr(v.Path, "exists", lambda self: False)
        m.setattr(v.Path, "is_dir", lambda self: False)
        with refused("--out a/b: . is not a directory"):
            v.check_out_dir(v.Path("a/b"))
