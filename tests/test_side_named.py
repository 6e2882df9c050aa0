"""research/side_named.py: which side person 2 keeps, by the pair checks' own rule."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import load_script

side_named = load_script("side_named")


@pytest.mark.parametrize("dx, left, right", [(0.8, True, False), (-0.8, False, True),
                                             (0.1, False, False)])  # fmt: skip
def test_person_two_to_the_left_of_a_person_facing_plus_z(actors, dx, left, right):
    walker = next(a for a in actors if "walk" in a.id)
    one = walker.joints[:30]
    assert np.asarray(one[0, 0, [0, 2]]) == pytest.approx(0.0, abs=1e-5)
    two = one + np.array([dx, 0.0, 0.0])  # +X is the left of someone facing +Z
    scene = np.stack([one, two])
    assert side_named.lateral(scene) == pytest.approx(dx, abs=0.05)
    assert side_named.passes(scene, "left") is left
    assert side_named.passes(scene, "right") is right


def test_every_named_prompt_has_a_side_to_fill():
    for template in side_named.NAMED.values():
        left, right = template.format(side="left"), template.format(side="right")
        assert left != right and "left" in left and "right" in right
    assert "left" not in side_named.UNNAMED and "right" not in side_named.UNNAMED
