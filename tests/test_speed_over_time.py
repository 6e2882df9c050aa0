"""research/speed_over_time.py: per-second speeds of generated people."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import load_script, save_tiny_model


def test_per_second_follows_a_walk_that_stops(real_joints):
    st = load_script("speed_over_time")
    walk = real_joints[:61].numpy().astype(np.float64)  # two seconds of a real walk
    stopped = np.concatenate([walk, np.repeat(walk[-1:], 60, axis=0)])  # then two still
    pelvis, ankles = st.per_second([stopped, stopped], fps=30.0)
    assert len(pelvis) == len(ankles) == 4
    assert pelvis[0] > 0.5 and pelvis[1] > 0.5 and ankles[0] > 0.3
    assert pelvis[2] == pytest.approx(0.0, abs=1e-6) and pelvis[3] == pytest.approx(0.0, abs=1e-6)
    assert ankles[3] == pytest.approx(0.0, abs=1e-6)
    # the median over people, second by second
    still = np.repeat(walk[:1], 121, axis=0)
    p3, _ = st.per_second([stopped, still, still])
    assert p3 == pytest.approx([0.0] * 4, abs=1e-6)


def test_label_of_and_rows():
    st = load_script("speed_over_time")
    assert st.label_of("A person raises both hands.") == "raise-up-both-hands"
    assert st.label_of("A cat sleeps.") is None
    row = st.format_row("m", "a walk", [1.0, 0.5], [0.25, 0.0], "2.4 s")
    assert row == "| m | a walk | 1.00 / 0.25 | 0.50 / 0.00 | 2.4 s |"
    assert st.format_row("m", "a", [1.0], [0.0]) == "| m | a | 1.00 / 0.00 |"


def test_speed_over_time_runs_on_a_model(tmp_path, fake_text, monkeypatch, capsys):
    st = load_script("speed_over_time")
    model = save_tiny_model(tmp_path / "m")
    monkeypatch.setattr(sys, "argv", ["speed_over_time.py", str(model), "--prompt", "a walk",
                                      "--samples", "2", "--seconds", "2"])  # fmt: skip
    st.main()
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "| model | prompt | second 1 | second 2 |" and len(out) == 3
    assert out[2].startswith(f"| {model} | a walk | ") and out[2].count(" / ") == 2
