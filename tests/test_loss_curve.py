"""research/loss_curve.py: the train and val totals of metrics.csv files, drawn."""

from __future__ import annotations

import sys

from conftest import load_script


def test_loss_curve_reads_the_totals_and_draws_them(tmp_path, monkeypatch):
    lc = load_script("loss_curve")
    csv = tmp_path / "metrics.csv"
    rows = [
        "step,split,name,value,time",
        "50,train,lr,0.001,1.0",
        "50,train,total,0.5,1.0",
        "100,train,total,0.4,2.0",
        "100,val,total,0.3,2.5",
        "100,val,stage1,0.9,2.5",
    ]
    csv.write_text("\n".join(rows) + "\n")
    assert lc.read_totals(csv) == {"train": [(50, 0.5), (100, 0.4)], "val": [(100, 0.3)]}
    out = tmp_path / "loss.png"
    monkeypatch.setattr(sys, "argv", ["loss_curve.py", str(out), f"run={csv}"])
    lc.main()
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
