"""research/wrist_trace.py and the wave statistics on the committed real wave clip."""

from __future__ import annotations

import sys

import numpy as np

from conftest import load_script, prepare_fixture_corpus, save_tiny_model
from umf.eval import motion_stats as MS


def test_a_real_wave_swings_and_its_middle_pose_held_does_not(bandai_clips):
    clip = next(c for c in bandai_clips if c.meta["content"] == "wave-right-hand")
    wave = np.asarray(clip.joints[0], dtype=np.float64)
    s = MS.motion_statistics(wave)
    assert s["right_wrist_swings"] > 1.0 and np.ptp(MS.sideways(wave)) > 0.2
    held = np.repeat(wave[len(wave) // 2][None], len(wave), axis=0)  # the hand up, still
    h = MS.motion_statistics(held)
    assert h["right_wrist_swings"] == 0 and h["right_wrist_energy"] == 0


def test_wrist_trace_plots_real_and_generated(tmp_path, fake_text, monkeypatch, capsys):
    wt = load_script("wrist_trace")
    corpus = prepare_fixture_corpus(tmp_path / "c", train_scenes=2, val_scenes=1,
                                    test_scenes=1, test_groups=1)  # fmt: skip
    model = save_tiny_model(tmp_path / "m")
    out = tmp_path / "trace.png"
    monkeypatch.setattr(sys, "argv", ["wrist_trace.py", f"tiny={model}", "--out", str(out),
                                      "--corpus", str(corpus), "--people", "2"])  # fmt: skip
    wt.main()
    text = capsys.readouterr().out
    assert "real clips: medians over 1 people" in text and "tiny: medians over 16 people" in text
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*tmp*"))  # written atomically
