"""research/salsa_figure.py: the salsa couple against sflow.warm_take, beside the real takes."""

from __future__ import annotations

import pytest

from conftest import load_script

fig = load_script("salsa_figure")


def test_medians_per_value_and_a_picture(tmp_path):
    rows = [{"warm_take": t, "seed": s, "hands_near": t + 0.1 * s, "penetration_cm": s}
            for t in (0.7, 0.0) for s in range(3)]  # fmt: skip
    takes, hands = fig.medians(rows, "hands_near")
    assert takes == [0.0, 0.7] and hands == pytest.approx([0.1, 0.8])
    assert fig.medians(rows, "penetration_cm")[1] == [1.0, 1.0]
    real = [{"hands_near": 0.74, "penetration_cm": 0.77}, {"hands_near": 0.43,
                                                             "penetration_cm": 0.01}]  # fmt: skip
    out = tmp_path / "salsa.png"
    fig.draw(rows, real, out, chosen=0.7)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["salsa.png"]  # no temporary file left
