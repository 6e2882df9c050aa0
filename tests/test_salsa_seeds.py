"""research/salsa_seeds.py --real-crops: which 4 s crops of a real couple are read."""

from __future__ import annotations

import numpy as np

from conftest import load_script

salsa_seeds = load_script("salsa_seeds")


def test_crops_passing_reads_every_whole_4_second_crop(monkeypatch):
    """Crops of 121 frames every 30: a 200-frame take gives starts 0, 30 and 60 (90 would
    run past its end); each crop is judged by the salsa targets on its own frames."""
    seen = []

    def closeness(joints):
        seen.append((int(joints[0, 0, 0, 0]), joints.shape))
        return {"hands_near": 0.6, "pelvis": 0.5, "facing": 0.9 if seen[-1][0] != 30 else 0.1}

    monkeypatch.setattr(salsa_seeds, "closeness", closeness)
    joints = np.zeros((3, 200, 22, 3))  # a third person is left out: the couple is 1 and 2
    joints[..., 0] = np.arange(200)[None, :, None]  # each frame's index, to see the crop
    assert salsa_seeds.crops_passing(joints) == [True, False, True]
    assert seen == [(0, (2, 121, 22, 3)), (30, (2, 121, 22, 3)), (60, (2, 121, 22, 3))]
    assert salsa_seeds.crops_passing(joints[:, :120]) == []  # shorter than one crop
