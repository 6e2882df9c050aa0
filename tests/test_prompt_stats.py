"""research/prompt_stats.py: per-prompt medians of the motion statistics."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import load_script, save_tiny_model


def test_median_row_tells_a_backward_walk_from_a_forward_one(real_joints):
    ps = load_script("prompt_stats")
    walk = real_joints[:90].numpy()  # a real forward walk
    back = walk[::-1].copy()  # the same frames played backwards: a backward walk
    fwd_row, back_row = ps.median_row([walk, walk]), ps.median_row([back])
    i = ps.STATS.index("backward_speed")
    assert fwd_row[i] < -0.5 and back_row[i] > 0.5
    j = ps.STATS.index("pelvis_speed")
    assert np.isclose(fwd_row[j], back_row[j])
    text = ps.format_rows([("a walk", 2, fwd_row), ("reversed", 1, back_row)])
    lines = text.splitlines()
    assert lines[0].startswith("| prompt | people | pelvis_speed | backward_speed")
    assert len(lines) == 4 and lines[2].startswith("| a walk | 2 | ")


def test_prompt_stats_runs_on_a_model(tmp_path, fake_text, monkeypatch, capsys):
    ps = load_script("prompt_stats")
    model = save_tiny_model(tmp_path / "m")
    monkeypatch.setattr(sys, "argv", ["prompt_stats.py", str(model), "a walk", "a bow",
                                      "--samples", "2"])  # fmt: skip
    ps.main()
    out = capsys.readouterr().out.splitlines()
    assert [row.split(" | ")[0] for row in out[2:]] == ["| a walk", "| a bow"]
    assert all(row.split(" | ")[1] == "2" for row in out[2:])


def test_real_people_of_any_content_label(tmp_path):
    from conftest import prepare_fixture_corpus
    from umf.data.corpus import Corpus

    ps = load_script("prompt_stats")
    corpus = Corpus.load(prepare_fixture_corpus(tmp_path / "c", train_scenes=2, val_scenes=1,
                                                test_scenes=1))  # fmt: skip
    singles = [c for c in corpus.clips if c.num_people == 1]
    label = singles[0].meta["content"]
    want = [c for c in singles if c.meta.get("content") == label]
    people = ps.real_people(corpus, label)
    assert len(people) == len(want) >= 1
    assert all(p.shape[1:] == (22, 3) and len(p) <= 300 for p in people)
    # labels outside the motion-statistics check are found too, unknown ones give nothing
    other = next(c.meta["content"] for c in singles
                 if c.meta["content"] not in ps.MS.LABELS)  # fmt: skip
    assert ps.real_people(corpus, other)
    assert ps.real_people(corpus, "no-such-label") == []


def test_prompt_stats_refuses_zero_samples(tmp_path, monkeypatch, capsys):
    ps = load_script("prompt_stats")
    monkeypatch.setattr(sys, "argv", ["prompt_stats.py", str(tmp_path), "a walk",
                                      "--samples", "0"])  # fmt: skip
    with pytest.raises(SystemExit) as exit_:
        ps.main()
    assert exit_.value.code == 2
    assert "--samples must be at least 1" in capsys.readouterr().err
