"""research/any_order_figure.py: the groups as recorded and in any order, per relation."""

from __future__ import annotations

from conftest import load_script

fig = load_script("any_order_figure")


def _acc(strict: dict, loose: dict) -> dict:
    return {"by_relation": strict, "any_order": {"by_relation": loose}}


def test_bars_per_reading_and_a_picture(tmp_path):
    groups = {
        "m": _acc({"row": 0.0, "audience": 0.5}, {"row": 0.25, "audience": 0.5}),
        "m, delivered": _acc({"row": 0.1, "audience": 0.6}, {"row": 0.75, "audience": 0.6}),
    }
    relations, values = fig.bars(groups, "m")
    assert relations == ["audience", "row"]
    assert values == {"raw": [0.5, 0.0], "raw, any order": [0.5, 0.25],
                      "delivered": [0.6, 0.1], "delivered, any order": [0.6, 0.75]}  # fmt: skip
    out = tmp_path / "groups.png"
    fig.draw(groups, "m", out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["groups.png"]  # no temporary file left
