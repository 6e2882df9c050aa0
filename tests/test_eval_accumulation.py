import numpy as np
import pytest

from umf.data.relations import facing_angle
from umf.data.scenes import Actor
from umf.eval import physics as P
from umf.eval.accumulation import (
    METRICS,
    REACTION_ONLY,
    accumulation_table,
    index_curve,
    person_index_metrics,
    plot_accumulation,
    save_table,
)

PROMPTS = ["people walk", "people wave"]
CLIPS = ["dataset-1_walk_normal_001", "dataset-2_wave-right-hand_normal_001"]
SINGLE = [m for m in METRICS if m not in REACTION_ONLY]


@pytest.fixture(scope="module")
def clips(bandai_clips):
    by_id = {c.id: c for c in bandai_clips}
    return [
        Actor.from_joints(i, by_id[i].joints[0], "", "").joints[:90].astype(np.float64)
        for i in CLIPS
    ]


def _fake(clips, gap):
    """A 'generator' that copies a real clip per prompt, person k ``gap`` m to the side."""

    def generate(prompts, num_people, seed):
        assert len(prompts) == len(PROMPTS)
        out = []
        for i in range(len(prompts)):
            scene = np.repeat(clips[i][None], num_people, 0)
            scene[..., 0] += gap * np.arange(num_people)[:, None, None]
            out.append(scene)
        return out

    return generate


def _shift(x, dx):
    return x + np.array([dx, 0.0, 0.0])


def _row(table, n, k, metric):
    (r,) = [x for x in table if x["N"] == n and x["k"] == k and x["metric"] == metric]
    return r["value"]


def test_table_matches_direct_computation(clips):
    gap = 0.35  # neighbours' arms and shoulders overlap
    table = accumulation_table(_fake(clips, gap), PROMPTS, sizes=range(2, 9), variant="fake")
    reaction = len(REACTION_ONLY)
    assert len(table) == sum(len(SINGLE) * n + reaction * (n - 1) for n in range(2, 9))
    assert {r["variant"] for r in table} == {"fake"}
    assert all(r["scenes"] == len(PROMPTS) for r in table)
    assert not any(r["k"] == 1 and r["metric"] in REACTION_ONLY for r in table)
    for n in (2, 5, 8):
        for k in range(1, n + 1):
            scenes = [_shift(c, gap * (k - 1)) for c in clips]
            skate = np.mean([P.foot_skating(s, 30.0)["skate_ratio"] for s in scenes])
            assert _row(table, n, k, "skate_ratio") == pytest.approx(skate)
            jerk = np.mean([P.jitter(s, 30.0)["jerk"] for s in scenes])
            assert _row(table, n, k, "jerk") == pytest.approx(jerk)
            if k == 1:
                continue
            # person k against persons 1..k-1: the deepest overlap per frame
            pen = [
                np.max([P.capsule_penetration(_shift(c, gap * j), s) for j in range(k - 1)], 0)
                for c, s in zip(clips, scenes, strict=True)
            ]
            assert _row(table, n, k, "penetration_prev_cm") == pytest.approx(
                100 * np.mean([p.mean() for p in pen])
            )
            assert _row(table, n, k, "distance_p1_m") == pytest.approx(gap * (k - 1), abs=1e-6)
            # person k stands beside person 1, facing the same way: about 90 degrees
            angle = np.mean([
                np.mean([facing_angle(np.stack([s, c]), 0, 1, t) for t in range(len(c))])
                for c, s in zip(clips, scenes, strict=True)
            ])  # fmt: skip
            assert _row(table, n, k, "facing_p1_deg") == pytest.approx(angle, abs=1e-6)
            assert 60 < angle < 120
    assert _row(table, 3, 2, "penetration_prev_cm") > 0


def test_person_index_metrics_single_person(clips):
    (m,) = person_index_metrics(clips[0][None])
    assert set(m) == set(SINGLE)


def test_plot_and_csv(clips, tmp_path):
    table = accumulation_table(_fake(clips, 0.35), PROMPTS, sizes=(2, 3), variant="S-Flow")
    table += accumulation_table(_fake(clips, 1.0), PROMPTS, sizes=(2, 3), variant="reaction-only")
    ks, values = index_curve(table, "S-Flow", "jerk")
    assert ks == [1, 2, 3] and len(values) == 3
    # k = 1 and 2 appear at N = 2 and 3 with the same scene counts: a plain mean
    assert values[0] == pytest.approx(
        np.mean(
            [_row([r for r in table if r["variant"] == "S-Flow"], n, 1, "jerk") for n in (2, 3)]
        )
    )
    path = tmp_path / "plots" / "accumulation.png"
    plot_accumulation(table, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in path.parent.iterdir()) == ["accumulation.png"]
    save_table(table, tmp_path / "table.csv")
    lines = (tmp_path / "table.csv").read_text().splitlines()
    assert lines[0] == "variant,N,k,metric,value,scenes" and len(lines) == len(table) + 1
    with pytest.raises(ValueError):
        plot_accumulation(table, tmp_path / "x.png", metrics=["nope"])


def test_generator_must_return_n_people(clips):
    def wrong(prompts, num_people, seed):
        return [np.repeat(clips[0][None], num_people + 1, 0)]

    with pytest.raises(ValueError, match="people"):
        accumulation_table(wrong, ["x"], sizes=(2,))
