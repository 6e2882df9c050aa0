"""research/short_clips.py: which short clips the dataset extends, per label."""

from __future__ import annotations

import sys

from conftest import load_script, prepare_fixture_corpus
from umf.data import extension as E
from umf.data.corpus import Corpus
from umf.train import datasets as D


def test_short_clips_agrees_with_the_dataset(tmp_path, monkeypatch, capsys):
    sc = load_script("short_clips")
    corpus = Corpus.load(prepare_fixture_corpus(tmp_path / "c", train_scenes=2, val_scenes=1,
                                                test_scenes=1, test_groups=1))  # fmt: skip
    clips = corpus.split_clips("train")
    lo = max(c.num_frames for c in clips)  # every clip is short
    ds = D.SingleMotionDataset(corpus, "train", None, lo, lo + 20, hold_rest=True,
                               repeat_gait=True)  # fmt: skip
    kinds, seams, lengths, as_is = sc.classify(clips, lo)
    assert sum(c["held"] for c in kinds.values()) == sum(v == 0 for v in ds.extended.values())
    repeated = sum(c["cycle repeated"] for c in kinds.values())
    assert repeated == sum(v > 0 for v in ds.extended.values()) == len(seams) > 0
    assert sum(c["as is"] for c in kinds.values()) == len(ds.items) - len(ds.extended)
    assert all(seam <= E.GAIT_MATCH and turn < E.GAIT_TURN for seam, turn in seams)
    assert sum(map(len, lengths.values())) == len(ds.items)
    assert len(as_is) == len(ds.items) - len(ds.extended) > 0  # each refused by the rest test
    assert all(v.max() >= E.REST_SPEED and how == "as is" for _, _, how, v in as_is)
    monkeypatch.setattr(sys, "argv", ["short_clips.py", "--corpus", str(tmp_path / "c"),
                                      "--min-frames", str(lo)])  # fmt: skip
    sc.main()
    out = capsys.readouterr().out
    assert f"train: {len(ds.items)} people, {len(ds.items)} shorter than" in out
    assert "| label | short | held | cycle repeated | eased to a stop | as is |" in out
    assert ("not at rest" in out) == bool(as_is)
    # with --settle, the slow ends of those are eased to a stop, as the dataset's settle does
    monkeypatch.setattr(E, "SETTLE_SPEED", 100.0)  # every clip not at rest and not a gait
    settled = D.SingleMotionDataset(corpus, "train", None, lo, lo + 20, hold_rest=True,
                                    repeat_gait=True, settle=True)  # fmt: skip
    kinds, _, _, eased = sc.classify(clips, lo, settle=True)
    assert sum(c["eased to a stop"] for c in kinds.values()) == len(as_is) > 0
    assert sum(v == E.SETTLE for v in settled.extended.values()) == len(eased) == len(as_is)
    assert all(how == "eased to a stop" for _, _, how, _ in eased)
    assert sum(c["as is"] for c in kinds.values()) == 0
