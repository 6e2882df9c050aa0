"""research/group_checks.py and research/scene_tokens.py: the measures behind
results/reactions-20261208 (who stands on whom, which checks fail, prompt tokens alike)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import load_script


def standing(x: float, z: float, frames: int = 5) -> np.ndarray:
    """A person (T, 22, 3) whose joints are spread 0.1 m around (x, z), facing +Z."""
    rng = np.random.default_rng(0)
    body = rng.uniform(-0.1, 0.1, (22, 3)) + np.array([x, 1.0, z])
    body[[1, 2, 16, 17], 0] = x + np.array([0.1, -0.1, 0.15, -0.15])  # hips, shoulders: +Z
    return np.repeat(body[None], frames, 0)


def test_closest_to_earlier_finds_the_person_standing_on_another():
    gc = load_script("group_checks")
    scene = np.stack([standing(0, 0), standing(2, 0), standing(2.05, 0), standing(5, 0),
                      standing(0.05, 0)])  # fmt: skip
    gaps = gc.closest_to_earlier(scene)
    assert len(gaps) == 3  # persons 3, 4, 5 (1-based), against everybody before them
    assert gaps[0] < 0.25 and gaps[1] > 2.5
    assert gaps[2] < 0.25  # person 5 stands on person 1, not on person 4 (k - 1)


def test_score_counts_scenes_kinds_and_relations():
    gc = load_script("group_checks")
    apart = np.stack([standing(0, 0), standing(1.0, 0), standing(2.0, 0)])
    stacked = np.stack([standing(0, 0), standing(1.0, 0), standing(1.02, 0)])
    record = {"relation": "group_line", "num_people": 3, "constraints": [
        {"type": "side", "a": 0, "b": 1, "side": "left"},
        {"type": "no_contact", "min_distance": 0.25}]}  # fmt: skip
    out = gc.score([record, record], [apart, stacked])
    assert out["scenes"] == {"all": 0.5, "group_line": 0.5}
    assert out["kinds"] == {"no_contact": 0.5, "side": 1.0}
    assert out["relation_kinds"]["group_line/no_contact"] == 0.5
    gaps = [gc.closest_to_earlier(apart)[0], gc.closest_to_earlier(stacked)[0]]
    assert out["closest_m"][0] == pytest.approx(np.median(gaps), abs=1e-3)
    pairs = gc.score([{**record, "num_people": 2}], [apart[:2]])
    assert pairs["closest_m"] == [None]  # nobody after person 2


def test_centred_cosines_see_through_what_every_prompt_shares():
    st = load_script("scene_tokens")
    names = list(st.PROMPTS)
    common = torch.full((len(names), 8), 10.0)
    torch.manual_seed(0)
    own = torch.randn(len(names), 8)
    cos = st.centred_cosines(common + own, names)
    assert set(cos) == set(st.PAIRS)
    raw = torch.nn.functional.normalize(common + own, dim=-1)
    assert float(raw[0] @ raw[1]) > 0.95  # alike before centring ...
    assert abs(cos[st.PAIRS[0]]) < 0.95  # ... told apart after
    same = (common + own).clone()
    same[names.index("walk R")] = same[names.index("walk L")]
    assert st.centred_cosines(same, names)[("walk L", "walk R")] == pytest.approx(1.0)
