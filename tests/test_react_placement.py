"""scripts/react_placement.py: its two measures on motions whose answer is known."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "react_placement.py"


def _load():
    spec = importlib.util.spec_from_file_location("react_placement", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_distance_and_speed_on_the_floor_plane():
    rp = _load()
    t = np.arange(31) / 30.0
    a = np.zeros((31, 22, 3))
    a[:, :, 1] = 1.0  # height never counts
    b = a.copy()
    b[:, :, 0] = 3.0  # 3 m to the side ...
    b[:, 0, 2] = 1.2 * t  # ... walking forward at 1.2 m/s
    assert np.isclose(rp.pelvis_distance(a, a), 0.0)
    assert np.isclose(rp.pelvis_distance(a, b), np.mean(np.hypot(3.0, 1.2 * t)))
    assert np.isclose(rp.start_distance(a, b), 3.0)
    assert np.isclose(rp.pelvis_speed(b, 30.0), 1.2)
    assert np.isclose(rp.pelvis_speed(a, 30.0), 0.0)
