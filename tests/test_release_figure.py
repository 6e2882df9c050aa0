"""research/release_figure.py: two releases in one picture."""

from __future__ import annotations

import pytest

from conftest import load_script

fig = load_script("release_figure")


def test_shares_and_a_picture(tmp_path):
    keep = {"run-2": {"seeds_meeting_target": 3, "seeds": [{}, {}, {}, {}]},
            "walk-2": {"seeds_meeting_target": 4, "seeds": [{}, {}, {}, {}]}}  # fmt: skip
    assert fig.keep_shares(keep) == {"run-2": 0.75, "walk-2": 1.0}
    metrics = {"relations": {"groups": {
        "real": {"by_relation": {"audience": 1.0}},
        "m": {"by_relation": {"audience": 0.5, "group_line": 0.0}},
        "m, delivered": {"by_relation": {"audience": 0.9}}}}}  # fmt: skip
    assert fig.group_shares(metrics) == {"audience": 0.5, "group_line": 0.0}
    out = tmp_path / "f.png"
    fig.draw(out, {"a": keep, "b": keep}, {"a": metrics})
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob("*.tmp.png"))
    with pytest.raises(SystemExit, match="NAME=FILE"):
        fig.named_files(["nofile"])
