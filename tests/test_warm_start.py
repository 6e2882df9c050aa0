"""The warm start of people 2..N (``sflow.warm_start``): the proposal's placement and the
pipeline's second S-Flow pass (tiny models; the flow maths is in test_flow_semi_noise)."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import MODULE, FakeText, save_tiny_model
from umf import representation as rep
from umf.errors import UMFError
from umf.pipeline import UMFPipeline
from umf.rotations import yaw_matrix
from umf.warm_start import move_onto

pytestmark = pytest.mark.usefixtures("one_thread")


def _moved(joints: torch.Tensor, yaw: float, shift: tuple[float, float]) -> torch.Tensor:
    turned = joints @ yaw_matrix(torch.tensor(yaw, dtype=joints.dtype)).T
    return rep.joints_to_features(turned + torch.tensor([shift[0], 0.0, shift[1]],
                                                        dtype=joints.dtype))  # fmt: skip


def test_a_proposal_moves_rigidly_onto_the_first_frame_of_another(real_joints):
    """First-frame pelvis and facing become the target's; the motion itself (every frame's
    pelvis relative to the first, heights, local rotations) is unchanged up to the turn."""
    walk = _moved(real_joints, 2.0, (3.0, -1.0))
    there = _moved(real_joints.flip(0), -0.7, (-2.0, 4.0))  # another motion, elsewhere
    moved = move_onto(walk[None], there[None])[0]
    j, jt, j0 = (rep.features_to_joints(f) for f in (moved, there, walk))
    assert torch.allclose(j[0, 0, [0, 2]], jt[0, 0, [0, 2]], atol=1e-9)
    turn = float(rep.heading_angle(j[0]) - rep.heading_angle(jt[0]))
    assert abs(math.remainder(turn, 2 * math.pi)) < 1e-6
    assert torch.allclose(j[..., 1], j0[..., 1], atol=1e-9)  # heights kept
    travel = (j[:, 0, [0, 2]] - j[:1, 0, [0, 2]]).norm(dim=-1)
    assert torch.allclose(travel, (j0[:, 0, [0, 2]] - j0[:1, 0, [0, 2]]).norm(dim=-1), atol=1e-9)
    assert torch.allclose(moved[:, rep.VEL.stop :], walk[:, rep.VEL.stop :])


@pytest.fixture(scope=MODULE)
def models(tmp_path_factory):
    """The same tiny weights, cold and warm (``sflow.warm_start`` 0.5)."""
    cold = save_tiny_model(tmp_path_factory.mktemp("warm") / "cold", seed=4, person_prompts=True)
    warm = Path(shutil.copytree(cold, cold.parent / "warm"))
    cfg = json.loads((warm / "config.json").read_text())
    cfg["sflow"]["warm_start"] = 0.5
    (warm / "config.json").write_text(json.dumps(cfg))
    told = Path(shutil.copytree(cold, cold.parent / "told"))  # own_warm alone
    cfg = json.loads((told / "config.json").read_text())
    cfg["sflow"]["own_warm"] = 0.5
    (told / "config.json").write_text(json.dumps(cfg))
    return {k: UMFPipeline.from_pretrained(p, text_encoder=FakeText())
            for k, p in (("cold", cold), ("warm", warm), ("told", told))}  # fmt: skip


def _scene(pipe, people=3, seed=0, own=None):
    return pipe("two people walk side by side", num_people=people, seconds=1.0, seed=seed,
                fit=False, separate=False, person_prompts=own)[0]  # fmt: skip


def test_warm_start_samples_people_2_to_n_again_from_a_proposal(models):
    cold, warm = _scene(models["cold"]), _scene(models["warm"])
    # person 1 is the P-Flow's alone: the same; people 2..N differ
    assert np.array_equal(cold.joints[0], warm.joints[0])
    assert not np.allclose(cold.joints[1:], warm.joints[1:])
    # per added person: S-Flow 3 steps, the P-Flow's proposal 4 + 2, S-Flow again from 0.5
    assert cold.meta["nfe"] == 6 + 2 * 3
    assert warm.meta["nfe"] == 6 + 2 * (3 + 6 + 2)
    again = _scene(models["warm"])
    assert np.array_equal(again.joints, warm.joints)  # seeded
    assert not np.array_equal(_scene(models["warm"], seed=1).joints, warm.joints)
    assert np.isfinite(warm.joints).all()


def test_warm_start_passes_each_persons_own_prompt_to_the_proposal(models, monkeypatch):
    """Person 2's own prompt reaches the P-Flow's proposal (not only the S-Flow's passes),
    and the proposal follows it."""
    import umf.warm_start
    from umf.flows.noise import randn

    real, seen = umf.warm_start.proposal, []

    def spy(pipe, first, decoded, text, uncond, generator, guidance, own, **kw):
        seen.append(own)
        return real(pipe, first, decoded, text, uncond, generator, guidance, own, **kw)

    monkeypatch.setattr(umf.warm_start, "proposal", spy)
    _scene(models["warm"], people=2, own=[None, "waves with the right hand"])
    pipe = models["warm"]
    want = pipe.text_encoder.encode(["waves with the right hand"]).tokens
    assert len(seen) == 1 and torch.equal(seen[0]["person_text"].tokens, want)
    # the same first pass, the same noise: with and without the own prompt, two proposals
    first = randn((1, *pipe.vae.latent_shape), torch.Generator().manual_seed(0))
    text, uncond = (pipe.text_encoder.encode([p]) for p in ("two people walk", ""))
    decoded = pipe.decode(first, 30, reaction=True)
    a, b = (real(pipe, first, decoded, text, uncond, torch.Generator().manual_seed(1), None,
                 own)[0] for own in ({}, seen[0]))  # fmt: skip
    assert not torch.allclose(a, b)


def test_own_warm_samples_only_people_told_what_to_do_again(models, monkeypatch):
    """``sflow.own_warm``: a person 2..N with an own prompt is sampled again from 0.5 on the
    path to the P-Flow's single-person motion for that prompt alone (6 NFE, then 2 S-Flow
    steps); people without one, and scenes without own prompts, are exactly the cold
    model's."""
    import umf.warm_start

    cold, told = models["cold"], models["told"]
    assert np.array_equal(_scene(cold).joints, _scene(told).joints)
    own = [None, "waves with the right hand"]
    seen = []
    real = umf.warm_start.pflow_proposal

    def spy(pipe, decoded, text, uncond, generator, guidance, own_text, dataset=1):
        seen.append((text, own_text, dataset))
        return real(pipe, decoded, text, uncond, generator, guidance, own_text, dataset)

    monkeypatch.setattr(umf.warm_start, "pflow_proposal", spy)
    a, b = _scene(cold, own=own), _scene(told, own=own)
    assert len(seen) == 1  # person 2 only: person 3 has no own prompt
    text, own_text, dataset = seen[0]
    want = told.text_encoder.encode(["waves with the right hand"]).tokens
    assert torch.equal(text.tokens[:1], want) and own_text == {} and dataset == 0
    assert np.array_equal(a.joints[0], b.joints[0])
    assert not np.allclose(a.joints[1], b.joints[1])
    assert b.meta["nfe"] == a.meta["nfe"] + 6 + 2
    assert np.array_equal(_scene(told, own=own).joints, b.joints)  # seeded


def test_the_proposal_matters(models, monkeypatch):
    """The second pass starts from what :func:`umf.warm_start.proposal` returns."""
    import umf.warm_start

    base = _scene(models["warm"], people=2)
    real = umf.warm_start.proposal

    def shifted(pipe, first, *args, **kw):
        z, nfe, fits, lag, straight = real(pipe, first, *args, **kw)
        return z + 1.0, nfe, fits, lag, straight

    monkeypatch.setattr(umf.warm_start, "proposal", shifted)
    other = _scene(models["warm"], people=2)
    assert np.array_equal(base.joints[0], other.joints[0])
    assert not np.allclose(base.joints[1], other.joints[1])


@pytest.mark.parametrize("value", [1.0, 1.5, -0.1])
def test_warm_start_out_of_range_is_refused(value):
    from conftest import tiny_config
    from umf.config import set_option
    from umf.model_checks import check_config_values

    cfg = set_option(tiny_config(), f"sflow.warm_start={value}")
    with pytest.raises(UMFError, match="warm_start"):
        check_config_values(cfg)


@pytest.mark.parametrize(("option", "match"), [
    ("sflow.own_warm=1.0", "own_warm"), ("sflow.own_warm=-0.5", "own_warm"),
    ("pflow.person_composition=or", "person_composition"),
    ("sflow.warm_side=true", "warm_side needs"),  # the tiny config has no shortlist
    ("sflow.warm_margin=0.15", "warm_margin needs"),
    ("sflow.warm_margin=1.5", "warm_margin"), ("sflow.warm_margin=-0.1", "warm_margin"),
    ("sflow.warm_start_group=0.7", "warm_start_group needs"),  # tiny: no warm_start
    ("sflow.warm_start_group=1.0", "warm_start_group"),
])  # fmt: skip
def test_own_prompt_options_out_of_range_are_refused(option, match):
    from conftest import tiny_config
    from umf.config import set_option
    from umf.model_checks import check_config_values

    with pytest.raises(UMFError, match=match):
        check_config_values(set_option(tiny_config(), option))


def _gait(planted: bool, speed: float = 1.2, frames: int = 61, fps: float = 30.0):
    """Features (T, 262) of a stick walker whose pelvis travels at ``speed`` m/s along +Z:
    ``planted``: the ankles take turns resting (a stride), else both slide with the pelvis."""
    t = torch.arange(frames, dtype=torch.float64) / fps
    j = torch.zeros(frames, 22, 3, dtype=torch.float64)
    j[:, :, 1] = torch.linspace(0.0, 1.0, 22)  # heights, so the body is not degenerate
    j[:, :, 0] = torch.linspace(-0.2, 0.2, 22)
    j[:, :, 2] = (speed * t)[:, None]
    if planted:  # each ankle alternately rests and catches up at twice the pelvis's speed
        half = int(fps * 0.5)
        for k, side in ((7, 0), (8, 1)):
            z = torch.zeros(frames, dtype=torch.float64)
            for i in range(1, frames):
                moving = (i // half) % 2 == side
                z[i] = z[i - 1] + (2 * speed / fps if moving else 0.0)
            j[:, k, 2] = z
    return rep.joints_to_features(j)


def test_the_glide_score_tells_a_stride_from_a_glide():
    from umf.warm_start import MOVING, floor_speeds, floor_velocity, glide_score

    stride, glide = _gait(True), _gait(False)
    pelvis, slower = floor_speeds(torch.stack([stride, glide]), 30.0)
    torch.testing.assert_close(pelvis, torch.full((2,), 1.2, dtype=pelvis.dtype), atol=1e-6,
                               rtol=0)  # fmt: skip
    assert float(slower[0]) < 0.1 and abs(float(slower[1]) - 1.2) < 1e-6
    score = glide_score(torch.stack([stride, glide, _gait(False, speed=MOVING * 0.9)]), 30.0)
    assert float(score[0]) < 0.1 and abs(float(score[1]) - 1.0) < 1e-6
    assert float(score[2]) == 0.0  # not travelling: not gliding
    v = floor_velocity(torch.stack([stride, glide]), 30.0)
    torch.testing.assert_close(v, torch.tensor([[0.0, 1.2]] * 2, dtype=v.dtype), atol=1e-6,
                               rtol=0)  # fmt: skip


def test_warm_glide_keeps_the_first_pass_of_people_who_do_not_glide(models, monkeypatch):
    """With ``sflow.warm_glide`` only a gliding first pass is replaced by the second. A
    threshold nobody reaches keeps person 2's first pass (the cold scene's), one everybody
    passes gives the warm scene. The second pass runs either way, so the draws of the people
    after are the warm scene's whatever the glide (a row's draws never depend on its batch)."""
    import umf.warm_start

    monkeypatch.setattr(umf.warm_start, "glide_score", lambda f, fps: torch.ones(f.shape[0]))
    pipe = models["warm"]
    try:
        for people in (2, 3):
            cold, warm = _scene(models["cold"], people), _scene(pipe, people)
            pipe.config.sflow.warm_glide = 1e-9
            assert np.array_equal(_scene(pipe, people).joints, warm.joints)
            pipe.config.sflow.warm_glide = 1e9
            kept = _scene(pipe, people)
            assert kept.meta["nfe"] == warm.meta["nfe"]
            assert np.array_equal(kept.joints[:2], cold.joints[:2])
            if people == 3:
                assert not np.allclose(kept.joints[2], cold.joints[2])
            pipe.config.sflow.warm_glide = 0.0
    finally:
        pipe.config.sflow.warm_glide = 0.0


def test_warm_rows_takes_gliding_people_the_proposal_fits(models, monkeypatch):
    """The second pass replaces the rows the proposal fits, and with a glide threshold only
    the gliding ones among them; a retrieved proposal with a pace fits a row only where the
    bank has a reaction at its pace, a P-Flow proposal every row."""
    import umf.warm_start
    from umf.reaction_bank import ReactionBank
    from umf.warm_start import proposal, warm_rows

    pipe = models["warm"]
    first = torch.zeros(4, *pipe.vae.latent_shape)
    decoded = pipe.decode(first, 30, reaction=True)
    monkeypatch.setattr(umf.warm_start, "glide_score",
                        lambda f, fps: torch.tensor([0.1, 0.5, 0.5, 0.5]))  # fmt: skip
    fits = torch.tensor([True, True, False, True])
    assert torch.equal(warm_rows(decoded, fits, 30.0, 0.0), fits)  # no threshold: the fit
    assert warm_rows(decoded, fits, 30.0, 0.3).tolist() == [False, True, False, True]
    assert warm_rows(decoded, torch.ones(4, dtype=torch.bool), 30.0, 0.3).tolist() == [
        False, True, True, True]  # fmt: skip
    monkeypatch.setattr(umf.warm_start, "floor_velocity",
                        lambda f, fps: torch.tensor([[0.0, 1.0], [0.0, 1.0], [0.0, 3.0],
                                                     [0.0, 1.0]]))  # fmt: skip
    text, uncond = (pipe.text_encoder.encode([p] * 4) for p in ("two people walk", ""))
    cfg, old = pipe.config.sflow, (pipe.config.sflow.warm_pace, pipe.config.sflow.warm_proposal,
                                   pipe.reactions)  # fmt: skip
    gens = [torch.Generator().manual_seed(s) for s in range(4)]
    try:
        cfg.warm_pace, cfg.warm_proposal = 0.2, "retrieved"
        pipe.reactions = ReactionBank({30: first[:1]}, velocities={30: torch.tensor([[0.0, 1.1]])})
        got = proposal(pipe, first, decoded, text, uncond, gens, None, {})[2]
        assert got.tolist() == [True, True, False, True]
        cfg.warm_pace = 0.0  # no pace: every row fits
        assert proposal(pipe, first, decoded, text, uncond, gens, None, {})[2].all()
        cfg.warm_pace, cfg.warm_proposal = 0.2, "pflow"  # a pace is for retrieved proposals
        assert proposal(pipe, first, decoded, text, uncond, gens, None, {})[2].all()
    finally:
        cfg.warm_pace, cfg.warm_proposal, pipe.reactions = old


def test_mirror_text_encodes_the_prompts_with_their_sides_swapped(models, monkeypatch):
    """``sflow.warm_side``: the prompts' mirror images, encoded, when some prompt names a
    side; None when off or when none does."""
    from umf.text import mirror_caption
    from umf.warm_start import mirror_text

    pipe = models["warm"]
    words = ["two people walk side by side, the second on the left", "two people bow"]
    assert mirror_text(pipe, words) is None  # off
    monkeypatch.setattr(pipe.config.sflow, "warm_side", True)
    monkeypatch.setattr(models["cold"].config.sflow, "warm_side", True)
    assert mirror_text(models["cold"], words) is None  # no warm start: nothing to narrow
    assert mirror_text(pipe, ["two people bow"]) is None  # no side named
    got = mirror_text(pipe, words)
    want = pipe.text_encoder.encode([mirror_caption(w) for w in words])
    assert torch.equal(got.tokens, want.tokens) and "right" in mirror_caption(words[0])


def test_retime_makes_an_answer_wait_as_long_after_the_leader(bandai_clips):
    """A bow moved so that, as the checks read onsets, it starts ``lag`` frames after the
    leader's bow: later, on a leader who starts late, and earlier than it did."""
    from umf.warm_start import onsets, retime

    bow = next(c for c in bandai_clips if c.id == "dataset-1_bow_normal_001").joints[0][:120]
    f = rep.joints_to_features(torch.from_numpy(bow).float())
    leader = torch.stack([f, rep.shift_in_time(f, 20), f])
    reaction = torch.stack([f, f, rep.shift_in_time(f, 30)])
    lag = torch.tensor([25.0, 15.0, 10.0])
    out = retime(reaction, leader, lag)
    got = [b - a for a, b in zip(onsets(leader), onsets(out), strict=True)]
    assert all(abs(g - w) <= 1 for g, w in zip(got, lag.tolist(), strict=True)), got
    assert out.shape == reaction.shape


def test_warm_timing_retimes_only_answers(models, monkeypatch):
    """``sflow.warm_timing``: rows whose answer waited at least that long are decoded at the
    length they were stored at, carried on to the scene's (the last pose held), moved in
    time after person 1 by their wait and re-encoded; the others, a bank without waits, a
    re-rolled person 1 and the option off keep the proposal as it was."""
    import umf.warm_start as ws
    from umf.representation import VEL

    pipe = models["warm"]
    g = torch.Generator().manual_seed(0)
    guess = torch.randn(3, *pipe.vae.latent_shape, generator=g)
    prev = torch.randn(3, 1, *pipe.vae.latent_shape, generator=g)
    timing = (torch.tensor([0.0, 20.0, 7.0]), [30, 15, 30])  # row 1 stored at 15 frames
    same, answer = ws.timed_proposal(pipe, guess, prev, timing, 30)
    assert torch.equal(same, guess) and not answer.any()  # off (0)
    seen = {}

    def spy(reaction, leader, lag, passes=2):
        seen.update(reaction=reaction, leader=leader, lag=lag)
        return reaction.flip(1)  # something the re-encoding must carry

    monkeypatch.setattr(ws, "retime", spy)
    monkeypatch.setattr(pipe.config.sflow, "warm_timing", 8.0)
    out, answer = ws.timed_proposal(pipe, guess, prev, timing, 30)
    assert answer.tolist() == [False, True, False]
    assert torch.equal(out[[0, 2]], guess[[0, 2]])
    assert seen["lag"].tolist() == [20.0] and seen["reaction"].shape == (1, 30, 262)
    torch.testing.assert_close(seen["leader"], pipe.decode(prev[[1], 0], 30))
    own = pipe.decode(guess[[1]], 15, reaction=True)[0]
    torch.testing.assert_close(seen["reaction"][0, :14], own[:14])  # its own 15 frames ...
    assert float(seen["reaction"][0, 14:, VEL].abs().max()) == 0.0  # ... then held still
    torch.testing.assert_close(out[[1]], pipe._encode(seen["reaction"].flip(1)))
    kept, none = ws.timed_proposal(pipe, guess, prev, None, 30)  # no waits in the bank
    assert torch.equal(kept, guess) and not none.any()


def test_warm_timing_must_not_be_negative():
    from umf.config import set_option, small_config
    from umf.model_checks import check_config_values

    check_config_values(set_option(small_config(), "sflow.warm_timing=8"))
    with pytest.raises(UMFError, match="warm_timing"):
        check_config_values(set_option(small_config(), "sflow.warm_timing=-1"))


def test_travels_with_needs_both_moving_the_same_way():
    from umf.warm_start import MOVING, travels_with

    first = torch.tensor([[0.0, 2.0], [0.0, 2.0], [0.0, -2.0], [0.0, MOVING / 2], [1.9, 1.9]])
    lead = torch.tensor([[0.1, 2.5], [0.0, MOVING / 2], [0.0, 2.5], [0.0, 2.5], [0.0, 2.5]])
    assert travels_with(first, lead, 0.8).tolist() == [True, False, False, False, False]
    assert travels_with(first, lead, 0.7).tolist() == [True, False, False, False, True]


def test_warm_together_retrieves_at_the_leaders_pace(models, monkeypatch):
    """With ``sflow.warm_together`` a first pass travelling with person 1 retrieves the
    reaction at person 1's pace, not its own, and a reaction nearer that pace than the first
    pass fits even outside the tolerance; a row not travelling with person 1 is unchanged."""
    import umf.warm_start
    from umf.reaction_bank import ReactionBank
    from umf.warm_start import proposal

    pipe = models["warm"]
    first = torch.zeros(2, *pipe.vae.latent_shape)
    decoded = pipe.decode(first, 30, reaction=True)
    own = torch.tensor([[0.0, 1.0], [0.0, -1.0]])  # row 1 walks the other way
    lead = torch.tensor([[0.0, 2.5], [0.0, 2.5]])
    monkeypatch.setattr(umf.warm_start, "floor_velocity",
                        lambda f, fps: own if f is decoded else lead)  # fmt: skip
    slow, fast = first[:1], first[:1] + 1.0  # the first pass's latent is nearest the slow one
    bank = ReactionBank(
        {30: torch.cat([slow, fast, slow])},
        velocities={30: torch.tensor([[0.0, 1.0], [0.0, 1.8], [0.0, -1.0]])},
    )
    text, uncond = (pipe.text_encoder.encode([p] * 2) for p in ("two people run", ""))
    cfg = pipe.config.sflow
    old = (cfg.warm_pace, cfg.warm_proposal, cfg.warm_together, cfg.warm_neighbours,
           pipe.reactions)  # fmt: skip
    try:
        cfg.warm_pace, cfg.warm_proposal, cfg.warm_neighbours = 0.1, "retrieved", 1
        pipe.reactions = bank

        def run(together: float, mirror=None):
            cfg.warm_together = together
            gens = [torch.Generator().manual_seed(s) for s in range(2)]
            z, _, fits, _, _ = proposal(pipe, first, decoded, text, uncond, gens, None, {},
                                        mirror=mirror, leader=decoded.flip(0))  # fmt: skip
            return z, fits

        z, fits = run(0.0)  # its own pace: the slow one
        assert torch.equal(z[0], slow[0]) and fits.tolist() == [True, True]
        z, fits = run(0.8)  # the leader's: the fast one, 28 % slow but nearer than 1.0
        assert torch.equal(z[0], fast[0]) and fits.tolist() == [True, True]
        assert torch.equal(z[1], slow[0])  # walking away: its own pace, as before
        # the first pass starts on person 1's right: a fast reaction there, farther in latent
        # space, is taken over the one on the left
        right = fast + 0.5
        pipe.reactions = ReactionBank(
            {30: torch.cat([slow, fast, slow, right])},
            velocities={30: torch.tensor([[0.0, 1.0], [0.0, 1.8], [0.0, -1.0], [0.0, 1.8]])},
            starts={30: torch.tensor([[-0.9, 0.0], [0.9, 0.0], [-0.9, 0.0], [-0.9, 0.0]])},
        )
        monkeypatch.setattr(umf.warm_start, "start_side", lambda f: torch.tensor([-1.0, 1.0]))
        z, _ = run(0.8)
        assert torch.equal(z[0], right[0])
        # a prompt naming a side too: the first pass's side (the S-Flow reads a named side)
        other = pipe.text_encoder.encode(["two people run, the second on the left"] * 2)
        assert torch.equal(run(0.8, mirror=other)[0][0], right[0])
        z, _ = run(0.0)  # its own pace: no side asked, the slow one
        assert torch.equal(z[0], slow[0])
    finally:
        (cfg.warm_pace, cfg.warm_proposal, cfg.warm_together, cfg.warm_neighbours,
         pipe.reactions) = old  # fmt: skip


def test_warm_together_needs_a_retrieved_proposal_at_a_pace():
    from conftest import tiny_config
    from umf.config import set_option
    from umf.model_checks import check_config_values

    with pytest.raises(UMFError, match="warm_together needs"):
        check_config_values(set_option(tiny_config(), "sflow.warm_together=0.8"))
    with pytest.raises(UMFError, match="warm_together"):
        check_config_values(set_option(tiny_config(), "sflow.warm_together=1.5"))


def test_start_side_reads_the_first_frames_pelvis_beyond_the_side_margin():
    from umf.warm_start import SIDE_MARGIN, start_side

    walks = []
    for x in (1.0, -0.6, SIDE_MARGIN / 2, -SIDE_MARGIN / 2):
        f = _gait(True)  # its pelvis starts at x = -0.2
        f[:, rep.POS] += torch.tensor([x + 0.2, 0.0, 0.0], dtype=f.dtype).repeat(22)
        walks.append(f)
    assert start_side(torch.stack(walks)).tolist() == [1.0, -1.0, 0.0, 0.0]


def _retrieving_beside_leader(pipe, first, monkeypatch, **options):
    """A bank of one reaction (``first[:1] + 0.5``, walking 1 m/s) that ``pipe`` retrieves
    from for rows travelling with person 1 (``sflow`` set by ``monkeypatch``, so undone after
    the test, with ``options`` on top), and the encoded prompts."""
    from umf.reaction_bank import ReactionBank

    bank = ReactionBank({30: first[:1] + 0.5}, velocities={30: torch.tensor([[0.0, 1.0]])})
    cfg = pipe.config.sflow
    settings = {"warm_pace": 0.1, "warm_proposal": "retrieved", "warm_neighbours": 1,
                "warm_together": 0.8, **options}  # fmt: skip
    for key, value in settings.items():
        monkeypatch.setattr(cfg, key, value)
    monkeypatch.setattr(pipe, "reactions", bank)
    text, uncond = (pipe.text_encoder.encode([p] * 2) for p in ("two people run", ""))
    return bank, text, uncond


def test_warm_play_plays_a_partner_at_the_leaders_pace(models, monkeypatch):
    """With ``sflow.warm_play`` a row travelling with person 1 takes its retrieved reaction
    played at person 1's pace (rate: the leader's speed over the decoded reaction's) and
    fits, however slow the reaction; a row not travelling with person 1 keeps its latent."""
    import umf.warm_start
    from umf.warm_start import proposal

    pipe = models["warm"]
    first = torch.zeros(2, *pipe.vae.latent_shape)
    decoded = pipe.decode(first, 30, reaction=True)
    leader = decoded.flip(0)
    speeds = {"own": torch.tensor([[0.0, 1.0], [0.0, -1.0]]),  # row 1 walks the other way
              "lead": torch.tensor([[0.0, 2.5], [0.0, 2.5]])}  # fmt: skip

    def velocity(f, fps):
        if f is decoded:
            return speeds["own"]
        if f is leader:
            return speeds["lead"]
        return torch.tensor([[0.0, 1.6]] * len(f))  # the retrieved reaction, decoded

    monkeypatch.setattr(umf.warm_start, "floor_velocity", velocity)
    rates = []

    def spy(features, rate):
        rates.append(rate.clone())
        return features + 1.0  # a motion other than the reaction's

    monkeypatch.setattr(umf.warm_start, "play_at", spy)
    bank, text, uncond = _retrieving_beside_leader(pipe, first, monkeypatch, warm_play=False,
                                                   warm_clear=0.0)  # fmt: skip
    cfg = pipe.config.sflow

    def run(play: bool):
        cfg.warm_play = play
        gens = [torch.Generator().manual_seed(s) for s in range(2)]
        return proposal(pipe, first, decoded, text, uncond, gens, None, {}, leader=leader)

    z, _, fits, _, _ = run(False)
    assert fits.tolist() == [False, False] and not rates  # 1.0 m/s is no leader's pace
    z, _, fits, _, _ = run(True)
    assert fits.tolist() == [True, False]
    (rate,) = rates
    torch.testing.assert_close(rate, torch.tensor([2.5 / 1.6]))
    assert torch.equal(z[1], bank.latents[30][0])  # not with the leader: as retrieved
    assert not torch.allclose(z[0], bank.latents[30][0])
    # with warm_apart's starts and warm_clear's bodies of people 2..k - 1, the played
    # row is moved by beyond() against those (person 1 is clear_of's)
    seen = []

    def spy_beyond(features, others, bodies=None, clear=0.0):
        seen.append((others.clone(), bodies.clone(), clear))
        return features

    monkeypatch.setattr(umf.warm_start, "beyond", spy_beyond)
    cfg.warm_play, cfg.warm_clear = True, 0.55
    others = torch.tensor([[[0.9, 0.0]], [[-0.9, 0.0]]])
    bodies = torch.randn(2, 1, 30, 22, 3)
    gens = [torch.Generator().manual_seed(s) for s in range(2)]
    proposal(pipe, first, decoded, text, uncond, gens, None, {}, leader=leader,
             others=others, bodies=bodies)  # fmt: skip
    ((got_others, got_bodies, clear),) = seen
    torch.testing.assert_close(got_others, others[:1])  # row 0 travels with person 1
    torch.testing.assert_close(got_bodies, bodies[:1])
    assert clear == 0.55
    # with warm_extend's formation ends, the played row starts there before beyond()
    starts = []

    def spy_start(features, others, bodies=None, clear=0.0):
        starts.append(rep.floor_start(features))
        return features

    monkeypatch.setattr(umf.warm_start, "beyond", spy_start)
    ends = torch.tensor([[1.8, 0.2], [float("nan"), float("nan")]])
    gens = [torch.Generator().manual_seed(s) for s in range(2)]
    proposal(pipe, first, decoded, text, uncond, gens, None, {}, leader=leader,
             others=others, bodies=bodies, ends=ends)  # fmt: skip
    torch.testing.assert_close(starts[0], ends[:1], atol=1e-4, rtol=0)


def test_warm_follow_proposes_a_row_carried_and_keeps_its_straight_proposal(models, monkeypatch):
    """With ``sflow.warm_follow`` d, a row travelling with person 1 whose person 1 turns more
    than d degrees (:func:`turning`) is proposed carried along them (:func:`follow_leader`,
    then kept clear of them) and its straight proposal, as without the option, comes back
    to fall back on; without the option, or where person 1 does not turn, the proposal is
    the straight one and nothing comes back. A row not travelling with person 1 is never
    carried."""
    import umf.warm_start
    from umf.warm_start import proposal

    pipe = models["warm"]
    first = torch.zeros(2, *pipe.vae.latent_shape)
    decoded = pipe.decode(first, 30, reaction=True)
    leader = decoded.flip(0)

    def velocity(f, fps):
        if f is decoded:
            return torch.tensor([[0.0, 1.0], [0.0, -1.0]])  # row 1 walks the other way
        return torch.tensor([[0.0, 2.5]] * len(f))

    calls, turns = [], {"now": False}

    def spy_follow(features, lead):
        calls.append(("follow", lead.clone(), features.clone()))
        return features + 2.0

    def spy_clear(features, lead, distance=0.4):
        calls.append(("clear", features.clone()))
        return features + 0.5

    def spy_turning(lead, d):
        calls.append(("turning", d))
        return torch.full((len(lead),), turns["now"])

    monkeypatch.setattr(umf.warm_start, "floor_velocity", velocity)
    monkeypatch.setattr(umf.warm_start, "play_at", lambda f, rate: f)
    monkeypatch.setattr(umf.warm_start, "follow_leader", spy_follow)
    monkeypatch.setattr(umf.warm_start, "clear_of", spy_clear)
    monkeypatch.setattr(umf.warm_start, "turning", spy_turning)
    bank, text, uncond = _retrieving_beside_leader(pipe, first, monkeypatch, warm_play=True,
                                                   warm_follow=None)  # fmt: skip
    out = []
    for follow, turn in ((None, True), (20.0, False), (20.0, True)):
        pipe.config.sflow.warm_follow, turns["now"] = follow, turn
        gens = [torch.Generator().manual_seed(s) for s in range(2)]
        z, _, _, _, straight = proposal(pipe, first, decoded, text, uncond, gens, None, {},
                                        leader=leader)  # fmt: skip
        out.append((z, straight))
    assert [c[0] for c in calls] == ["clear", "clear", "turning", "clear", "turning",
                                     "follow", "clear"]  # fmt: skip
    assert calls[2][1] == 20.0  # the turn beyond which a row is carried
    torch.testing.assert_close(calls[5][1], leader[:1])  # row 0's leader only
    reaction = pipe.decode(bank.latents[30][:1], 30, reaction=True)
    torch.testing.assert_close(calls[5][2], reaction)  # the played motion, not the cleared
    torch.testing.assert_close(calls[6][1], reaction + 2.0)  # cleared once carried
    (z0, s0), (z1, s1), (z2, s2) = out
    assert s0 is None and s1 is None and torch.equal(z1, z0)  # as without the option
    rows, z_straight = s2
    assert rows.tolist() == [0] and torch.equal(z_straight[0], z0[0])
    assert torch.equal(z2[1], z0[1]) and not torch.allclose(z2[0], z0[0])
    # a row that answers (a wait retrieved for its caption) keeps the answer: never carried
    answer = torch.randn(2, *pipe.vae.latent_shape)

    def answering(bank, first, frames, z, cfg, generator, scale, prompt, others=None):
        return answer, torch.tensor([8.0, 0.0]), [30, 30]

    monkeypatch.setattr(umf.warm_start, "answers", answering)
    monkeypatch.setattr(bank, "lags", {30: torch.zeros(1)})
    monkeypatch.setattr(pipe.config.sflow, "warm_timing", 8)
    gens = [torch.Generator().manual_seed(s) for s in range(2)]
    z, *_, straight = proposal(pipe, first, decoded, text, uncond, gens, None, {}, leader=leader)
    assert straight is None and torch.equal(z, answer)


def test_follow_leader_turns_a_straight_walker_with_a_turning_leader():
    """:func:`follow_leader` on features: beside a leader at its own pace it leaves the
    walker's path as it was; beside one who turns, the walker turns the same way, where the
    turn is over the threshold."""
    from umf.warm_start import follow_leader

    walker = _gait(True, frames=91)
    walker[:, rep.POS] += torch.tensor([0.8, 0.0, 0.0], dtype=walker.dtype).repeat(22)
    straight = _gait(True, frames=91)
    same = follow_leader(walker[None], straight[None])[0]
    torch.testing.assert_close(rep.features_to_joints(same)[:, 0],
                               rep.features_to_joints(walker)[:, 0], atol=0.03, rtol=0)  # fmt: skip
    joints = rep.features_to_joints(straight).clone()
    a = torch.arange(len(joints), dtype=joints.dtype) / 30 * 1.2 / 3.0  # left, radius 3 m
    x, z = joints[..., 0], joints[..., 2]
    c, s_ = torch.cos(a)[:, None], torch.sin(a)[:, None]
    pelvis_z = z[:, :1]
    # each frame's body turned about its pelvis by a, its pelvis moved onto the circle
    rx, rz = x * c + (z - pelvis_z) * s_, (z - pelvis_z) * c - x * s_
    joints[..., 0] = rx + (3.0 - 3.0 * torch.cos(a))[:, None]
    joints[..., 2] = rz + (3.0 * torch.sin(a))[:, None]
    turning = rep.joints_to_features(joints)
    walker = walker[: len(turning)]  # a frame shorter: features are joints' differences
    out = rep.features_to_joints(follow_leader(walker[None], turning[None])[0])[:, 0]
    path = out[-1, [0, 2]] - out[-15, [0, 2]]
    heading = torch.atan2(path[0], path[1])
    assert abs(float(heading) - float(a[-8])) < 0.15  # it heads where the leader does
    lead = rep.features_to_joints(turning)[:, 0]
    gap = (out[:, [0, 2]] - lead[:, [0, 2]]).norm(dim=-1)
    assert float((gap - 0.8).abs().max()) < 0.15
    # which leaders are carried along: those turning more than the threshold (this one turns
    # about 60 degrees; the straight one not at all)
    from umf.warm_start import turning as turns

    both = torch.stack([turning, straight[: len(turning)]])
    assert turns(both, 45.0).tolist() == [True, False]
    assert turns(both, 75.0).tolist() == [False, False]


def test_warm_apart_tells_person_3_where_people_2_to_k_start(models, monkeypatch):
    """With ``sflow.warm_apart`` the proposal for person k >= 3 gets where people 2..k - 1
    start (person 1's frame, as decoded from the context), person 2's gets nothing; without
    it nobody's does."""
    import umf.warm_start

    pipe = models["warm"]
    seen = []
    real = umf.warm_start.proposal

    def spy(p, first, decoded, *args, others=None, **kwargs):
        seen.append(None if others is None else others.clone())
        return real(p, first, decoded, *args, others=others, **kwargs)

    monkeypatch.setattr(umf.warm_start, "proposal", spy)
    _scene(pipe, people=3)
    assert seen == [None, None]
    cfg = pipe.config.sflow
    try:
        cfg.warm_apart = True
        scene = _scene(pipe, people=4)
    finally:
        cfg.warm_apart = False
    assert seen[2] is None and seen[3].shape == (1, 1, 2) and seen[4].shape == (1, 2, 2)
    assert torch.isfinite(seen[4]).all()
    assert np.isfinite(scene.joints).all()


def test_warm_extend_gives_person_k_where_the_file_goes_on(models, monkeypatch):
    """With ``sflow.warm_extend`` the proposal for person k >= 3 gets where the single file
    of people 1..k - 1 goes on (:func:`formation_end` of their starts, as decoded from the
    context); person 2's gets none, nor anyone's without it."""
    import umf.warm_start
    from umf.clearance import formation_end

    pipe = models["warm"]
    seen = []
    real = umf.warm_start.proposal

    def spy(p, first, decoded, *args, others=None, leader=None, ends=None, **kwargs):
        seen.append((others, leader, ends))
        return real(p, first, decoded, *args, others=others, leader=leader, ends=ends, **kwargs)

    def everyone(a, b, cosine):  # person 2 travels with person 1
        return torch.ones(len(a), dtype=torch.bool)

    monkeypatch.setattr(umf.warm_start, "proposal", spy)
    monkeypatch.setattr(umf.warm_start, "travels_with", everyone)
    cfg = pipe.config.sflow
    try:
        cfg.warm_apart, cfg.warm_together = True, 0.8
        _scene(pipe, people=4)
        cfg.warm_extend = True
        scene = _scene(pipe, people=4)
        # re-rolled: the last person goes on from the one before; one inside the file is
        # not sent to its end
        del seen[6:]
        pipe.reroll(scene, 4, seed=1)
        pipe.reroll(scene, 3, seed=1)
    finally:
        cfg.warm_apart, cfg.warm_together, cfg.warm_extend = False, 0.0, False
    assert [ends is None for _, _, ends in seen[6:]] == [False, True]
    del seen[6:]
    assert [ends is None for _, _, ends in seen] == [True, True, True, True, False, False]
    for others, leader, ends in seen[4:]:
        starts = torch.cat([rep.floor_start(leader)[:, None], others], dim=1)
        want = formation_end(starts, torch.ones(1, dtype=torch.bool))
        torch.testing.assert_close(ends, want, equal_nan=True)
    assert np.isfinite(scene.joints).all()


def test_warm_clear_gives_person_3_everybodys_bodies(models, monkeypatch):
    """With ``sflow.warm_clear`` the proposal and :func:`turned_free` for person k >= 3 get
    the joints of people 2..k - 1 (in step with their starts), and the first pass is tested
    once against people 1..k - 1, person 1 decoded as person 1; person 2 gets none."""
    import umf.models.sflow
    import umf.warm_start
    from umf.representation import features_to_joints

    pipe = models["warm"]
    seen, turned, contexts, everyone = [], [], [], []
    real, real_turned = umf.warm_start.proposal, umf.warm_start.turned_free
    real_sample, real_touches = umf.models.sflow.SFlow.sample, umf.warm_start.touches

    def spy_touches(features, bodies, clear):
        everyone.append((bodies.clone(), clear))
        return real_touches(features, bodies, clear)

    def spy(p, first, decoded, *args, bodies=None, **kwargs):
        seen.append(None if bodies is None else bodies.clone())
        return real(p, first, decoded, *args, bodies=bodies, **kwargs)

    def spy_turned(features, others, *args, bodies=None, **kwargs):
        turned.append((others.shape, None if bodies is None else bodies.clone()))
        return real_turned(features, others, *args, bodies=bodies, **kwargs)

    def spy_sample(self, prev, *args, warm=None, **kwargs):
        if warm is None:
            contexts.append(prev.clone())
        return real_sample(self, prev, *args, warm=warm, **kwargs)

    monkeypatch.setattr(umf.warm_start, "proposal", spy)
    monkeypatch.setattr(umf.warm_start, "turned_free", spy_turned)
    monkeypatch.setattr(umf.models.sflow.SFlow, "sample", spy_sample)
    monkeypatch.setattr(umf.warm_start, "touches", spy_touches)
    cfg = pipe.config.sflow
    try:
        cfg.warm_apart, cfg.warm_clear = True, 0.45
        scene = _scene(pipe, people=4)
    finally:
        cfg.warm_apart, cfg.warm_clear = False, 0.0
    assert seen[0] is None  # person 2: nobody to keep off but person 1, a partner
    assert seen[1].shape[:2] == (1, 1) and seen[2].shape[:2] == (1, 2)
    assert seen[2].shape[-2:] == (22, 3) and torch.isfinite(seen[2]).all()
    torch.testing.assert_close(seen[1], seen[2][:, :1])  # the same person 2
    assert [t[0][1] for t in turned] == [1, 2]  # people 2..k - 1's starts ...
    torch.testing.assert_close(turned[1][1], seen[2])  # ... and their bodies
    # the first pass, once per person k >= 3, against everybody: person 1 first
    assert [(b.shape[1], clear) for b, clear in everyone] == [(2, 0.45), (3, 0.45)]
    torch.testing.assert_close(everyone[1][0][:, 1:], seen[2])
    frames = seen[1].shape[2]
    person1 = features_to_joints(pipe.decode(contexts[1][:, 0], frames, reaction=False))
    torch.testing.assert_close(everyone[0][0][:, 0], person1)  # as person 1, not a reaction
    torch.testing.assert_close(everyone[1][0][:, 0], person1)
    assert not torch.allclose(everyone[1][0][:, 0], everyone[1][0][:, 1])
    assert np.isfinite(scene.joints).all()


def test_warm_clear_takes_again_the_rows_whose_first_pass_touches(models, monkeypatch):
    """A row whose first pass touches someone (at ``sflow.warm_clear``) takes the second
    pass, whatever the other rules say; a row that touches nobody keeps its first pass
    (here every other rule keeps it: ``warm_glide`` so high that nothing glides, nobody on
    anyone's spot, nobody turned)."""
    import umf.warm_start

    pipe = models["warm"]
    prompts = ["two people walk side by side"] * 2

    def nobody(features, others, *args, **kwargs):
        return torch.zeros(len(features), dtype=torch.bool)

    def unturned(features, others, **kwargs):
        return features, nobody(features, others)

    monkeypatch.setattr(umf.warm_start, "crowded", nobody)
    monkeypatch.setattr(umf.warm_start, "turned_free", unturned)

    def marked(rows):
        def touches(features, bodies, clear):
            assert clear == 0.45
            return torch.tensor(rows[: len(features)], dtype=torch.bool)

        return touches

    cfg = pipe.config.sflow
    scenes = {}
    try:
        cfg.warm_apart, cfg.warm_clear, cfg.warm_glide = True, 0.45, 1e6
        for name, rows in (("none", [False, False]), ("first", [True, False])):
            monkeypatch.setattr(umf.warm_start, "touches", marked(rows))
            scenes[name] = pipe(prompts, num_people=3, seconds=1.0, seed=0, fit=False,
                                separate=False)  # fmt: skip
    finally:
        cfg.warm_apart, cfg.warm_clear, cfg.warm_glide = False, 0.0, 0.0
    none, first = scenes["none"], scenes["first"]
    for a, b in zip(none, first, strict=True):  # people 1 and 2 are untouched
        np.testing.assert_array_equal(a.joints[:2], b.joints[:2])
    assert not np.allclose(none[0].joints[2], first[0].joints[2])  # taken again
    np.testing.assert_array_equal(none[1].joints[2], first[1].joints[2])  # kept


def test_warm_clear_moves_a_touching_first_pass_itself_without_a_fitting_proposal(
    models, monkeypatch
):
    """Person 3's first pass touches someone in both rows; row 0's proposal does not fit
    (no real reaction at its pace), row 1's does, and row 1 answers. The second pass starts
    from row 0's own first pass, and from the proposal in row 1 (an answer keeps its retimed
    proposal, a fitting one is taken as it is)."""
    import umf.models.sflow
    import umf.warm_start

    pipe = models["warm"]
    passes = []
    real_sample = umf.models.sflow.SFlow.sample

    def spy_sample(self, prev, *args, warm=None, **kwargs):
        w, nfe = real_sample(self, prev, *args, warm=warm, **kwargs)
        if prev.shape[1] == 2:
            passes.append((w.clone(), None if warm is None else warm.clone()))
        return w, nfe

    def proposal(p, first, *args, **kwargs):
        return first * 0.0 + 3.0, 0, torch.tensor([False, True]), None, None

    def timed(p, guess, prev, lag, frames, leader):
        return guess, torch.tensor([False, False])

    def touching(features, bodies, clear):
        return torch.ones(len(features), dtype=torch.bool)

    def unturned(features, others, **kwargs):
        return features, torch.zeros(len(features), dtype=torch.bool)

    monkeypatch.setattr(umf.models.sflow.SFlow, "sample", spy_sample)
    monkeypatch.setattr(umf.warm_start, "proposal", proposal)
    monkeypatch.setattr(umf.warm_start, "timed_proposal", timed)
    monkeypatch.setattr(umf.warm_start, "touches", touching)
    monkeypatch.setattr(umf.warm_start, "turned_free", unturned)
    cfg = pipe.config.sflow

    def two_rows_of_three():
        passes.clear()
        try:
            cfg.warm_apart, cfg.warm_clear = True, 0.55
            pipe(["two people walk side by side"] * 2, num_people=3, seconds=1.0, seed=0,
                 fit=False, separate=False)  # fmt: skip
        finally:
            cfg.warm_apart, cfg.warm_clear = False, 0.0
        (first, _), (_, warm) = passes
        return first, warm

    first, warm = two_rows_of_three()
    torch.testing.assert_close(warm[0], first[0])  # itself
    torch.testing.assert_close(warm[1], torch.full_like(warm[1], 3.0))  # the proposal

    def answering(p, guess, prev, lag, frames, leader):  # an answer keeps its proposal too
        return guess, torch.tensor([True, False])

    monkeypatch.setattr(umf.warm_start, "timed_proposal", answering)
    _, warm = two_rows_of_three()
    torch.testing.assert_close(warm, torch.full_like(warm, 3.0))


def test_warm_start_group_is_person_3_onwards_time(models, monkeypatch):
    """With ``sflow.warm_start_group`` the second pass of person k >= 3 starts at that time,
    person 2's at ``warm_start`` (the S-Flow's own default); without it everybody's does."""
    import umf.models.sflow

    pipe = models["warm"]
    seen = []
    real = umf.models.sflow.SFlow.sample

    def spy(self, prev, *args, warm=None, warm_t=None, **kwargs):
        if warm is not None:
            seen.append((prev.shape[1], warm_t))
        return real(self, prev, *args, warm=warm, warm_t=warm_t, **kwargs)

    monkeypatch.setattr(umf.models.sflow.SFlow, "sample", spy)
    _scene(pipe, people=3)
    assert seen == [(1, None), (2, None)]
    cfg = pipe.config.sflow
    try:
        cfg.warm_start_group = 0.7
        scene = _scene(pipe, people=4)
    finally:
        cfg.warm_start_group = 0.0
    assert seen[2:] == [(1, None), (2, 0.7), (3, 0.7)]
    assert np.isfinite(scene.joints).all()
    # a re-roll: everybody else is the context, so person 2 of three gets the group's time,
    # person 2 of two the usual one
    three, two = _scene(pipe, people=3), _scene(pipe, people=2)
    del seen[:]
    try:
        cfg.warm_start_group = 0.7
        pipe.reroll(three, 2, seed=1)
        pipe.reroll(two, 2, seed=1)
    finally:
        cfg.warm_start_group = 0.0
    assert seen == [(2, 0.7), (1, None)]


def test_warm_play_and_apart_need_what_they_narrow():
    from conftest import tiny_config
    from umf.config import set_option
    from umf.model_checks import check_config_values

    with pytest.raises(UMFError, match="warm_play needs"):
        check_config_values(set_option(tiny_config(), "sflow.warm_play=true"))
    with pytest.raises(UMFError, match="warm_apart needs"):
        check_config_values(set_option(tiny_config(), "sflow.warm_apart=true"))
    with pytest.raises(UMFError, match="warm_follow needs"):
        check_config_values(set_option(tiny_config(), "sflow.warm_follow=20"))
    with pytest.raises(UMFError, match="warm_clear needs"):
        check_config_values(set_option(tiny_config(), "sflow.warm_clear=0.45"))
    with pytest.raises(UMFError, match="warm_extend needs"):
        check_config_values(set_option(tiny_config(), "sflow.warm_extend=true"))
    with pytest.raises(UMFError, match="warm_clear"):
        check_config_values(set_option(tiny_config(), "sflow.warm_clear=-0.1"))
