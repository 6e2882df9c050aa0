"""scripts/wrist_trace.py and the wave statistics on the committed real wave clip."""

from __future__ import annotations

import sys

import numpy as np
import pytest

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


def test_wave_latent_measures_change_along_time():
    wl = load_script("wave_latent")
    import torch

    still = torch.ones(3, 8, 4)
    assert wl.time_variation(still) == (0.0, 0.0)
    alt = torch.tensor([1.0, -1.0] * 4)[None, :, None].expand(2, 8, 4)  # +1 -1 +1 ...
    step, spread = wl.time_variation(alt)
    assert step == 4.0 and spread == 1.0
    assert torch.equal(wl.pair_mean(alt), torch.zeros_like(alt))  # the pairs cancel
    ramp = torch.arange(8.0)[None, :, None]
    assert wl.pair_mean(ramp).flatten().tolist() == [0.5, 0.5, 2.5, 2.5, 4.5, 4.5, 6.5, 6.5]
    assert torch.equal(wl.time_mean(ramp), torch.full_like(ramp, 3.5))
    assert wl.time_variation(wl.time_mean(ramp)) == (0.0, 0.0)
    t = np.arange(150) / 30.0
    assert wl.swing_frequency(0.2 * np.sin(2 * np.pi * 1.2 * t) + 0.5 * t) == pytest.approx(1.2)
