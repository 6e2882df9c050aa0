"""The model and evaluator shipped inside the package load and work with no arguments."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from umf.pipeline import UMFPipeline, default_model_dir

_DATA = Path(__file__).resolve().parents[1] / "data" / "bandai-sample"
SAMPLE = _DATA / "Bandai-Namco-Research-Motiondataset-2" / "data"
SAMPLE1 = _DATA / "Bandai-Namco-Research-Motiondataset-1" / "data"


def test_bundled_model_generates_without_a_path():
    assert (default_model_dir() / "README.md").exists()  # the model card ships with it
    size = sum(f.stat().st_size for f in default_model_dir().iterdir())
    assert size < 40e6
    pipe = UMFPipeline.from_pretrained()
    assert pipe.name.startswith("umf-small-bandai")
    scenes = pipe(["Two people walk side by side.", "A person waves."], num_people=3,
                  seconds=2.0, seed=0)  # fmt: skip
    for s in scenes:
        assert s.joints.shape == (3, 60, 22, 3) and np.isfinite(s.joints).all()
        # trained on real people: bodies about a person tall, feet near the floor
        span = s.joints[:, 0, :, 1].max(-1) - s.joints[:, 0, :, 1].min(-1)
        assert ((span > 1.0) & (span < 2.2)).all(), span
        assert abs(float(s.joints[..., 1].min())) < 0.3
    walk = scenes[0].joints[0, :, 0, [0, 2]]
    assert np.linalg.norm(walk[-1] - walk[0]) > 0.5  # a walk goes somewhere in 2 s


def test_bundled_evaluator_loads():
    from umf.eval.evaluator import load_evaluator
    from umf.eval.plan import default_evaluator_dir

    for kind in ("interaction", "single"):
        ev = load_evaluator(default_evaluator_dir() / kind)
        emb = ev.encode_text(["Two people walk side by side."])
        assert emb.shape[0] == 1 and np.isfinite(emb.detach().numpy()).all()


# --------------------------------------------------------------------- does it keep the pose?
CLIPS = Path(__file__).parent / "clips"


def _reconstruct(pipe: UMFPipeline, joints: np.ndarray) -> np.ndarray:
    """Real joints (T, 22, 3) -> the bundled VAE's reconstruction, canonical frame."""
    from umf.eval.reconstruction import reconstruct
    from umf.representation import canonicalize_scene, joints_to_features

    canon, _ = canonicalize_scene(torch.from_numpy(joints[None]).float())
    feats = joints_to_features(canon[0]).numpy()
    rec = reconstruct(pipe.vae, pipe.normalizer, [feats])[0]
    return feats[:, :66].reshape(-1, 22, 3), rec[:, :66].reshape(-1, 22, 3)


@pytest.fixture(scope="module")
def pipe():
    return UMFPipeline.from_pretrained()


def test_reconstructed_raised_hands_are_raised(pipe):
    """A real 'raise both hands' clip (4 s) through the bundled VAE: both wrists go above
    the head as in the clip, and the pose follows it (a mean pose fails both)."""
    from umf.data.motion_file import load_motion

    clip = load_motion(CLIPS / "dataset-2_raise-up-both-hands_normal_001.bvh").joints[0][:121]
    real, rec = _reconstruct(pipe, clip)

    def above(j):  # height of the lower wrist over the head, per frame
        return np.minimum(j[:, 20, 1], j[:, 21, 1]) - j[:, 15, 1]

    assert above(real).max() > 0.15  # the clip does raise them
    assert above(rec).max() > 0.10
    pose_err = np.linalg.norm((rec - rec[:, :1]) - (real - real[:, :1]), axis=-1).mean()
    assert pose_err < 0.06, pose_err


def test_reconstructed_wave_and_bow(pipe):
    from umf.data.motion_file import load_motion

    wave = load_motion(SAMPLE / "dataset-2_wave-right-hand_normal_001.bvh").joints[0][:121]
    real, rec = _reconstruct(pipe, wave)
    assert (real[:, 21, 1] - real[:, 15, 1]).max() > 0.1
    assert (rec[:, 21, 1] - rec[:, 15, 1]).max() > 0.05  # the right hand goes above the head
    from umf.eval.motion_stats import motion_statistics

    # and swings from side to side (turns after 10 cm or more): the latent holds a wave and
    # this decoder reads it (results/wave-20261127)
    assert motion_statistics(rec)["right_wrist_swings"] > 1.0
    bow = load_motion(SAMPLE1 / "dataset-1_bow_normal_001.bvh").joints[0][:121]
    real, rec = _reconstruct(pipe, bow)
    drop = rec[:5, 15, 1].mean() - rec[:, 15, 1].min()
    assert drop > 0.08, drop  # the head goes down


def test_generated_gestures_follow_the_prompt(pipe):
    """The fast motion-statistics guard (medians over 4 seeds, 4 s): raised hands and a
    right-hand wave go above the head and the wave swings (median over 8 seeds: 0.76
    swings a second; the release before umf-small-bandai-20261127c held it still, 0.00 at
    seven seeds of eight), a bow drops the head (a guard against going back to that
    release's shallow bows, median 0.135 m, not a realism bound: real clips 0.12-0.21 m),
    a walk travels at a walking speed (real clips: 0.86-1.45 m/s, 10th-90th percentile), a
    run faster, a gesture stays nearly in place. A mean pose carried along a path fails
    the first two; a shaking pelvis the last."""
    from umf.eval.motion_stats import median_statistics

    def median(prompt: str, *stats: str, seeds: int = 4) -> list[float]:
        scenes = [pipe(prompt, num_people=1, seconds=4.0, seed=s)[0] for s in range(seeds)]
        return median_statistics([sc.joints[0] for sc in scenes], stats)

    assert median("A person raises both hands.", "both_wrists_above_head")[0] > 0.1
    # swings come in steps of 0.25 a second (one turn in 4 s): 8 seeds keep the median steady
    wave = ("right_wrist_above_head", "right_wrist_swings", "pelvis_speed")
    above, swings, wave_pelvis = median("Someone waves with the right hand.", *wave, seeds=8)
    assert above > 0.1
    assert swings > 0.3, swings
    assert median("Someone bows politely.", "head_drop")[0] > 0.15
    (walk,) = median("A person walks forward.", "pelvis_speed")
    assert 0.8 < walk < 1.8, walk
    assert median("A person runs forward.", "pelvis_speed")[0] > 1.5 * walk
    assert wave_pelvis < 0.5 * walk


def test_a_gesture_longer_than_its_clips_stands_to_the_end(pipe):
    """Real hand-raising clips last 2.4 s (median). Asked for 4 s, the model raises the
    hands and then stands: the raw pelvis floor speed over the last 1.5 s, median over 4
    seeds, stays near real standing (0.03 m/s). The release before the short-clip fine-tunes
    walked off at 0.16 m/s there (results/umf-small-bandai-20261127b)."""
    from umf.eval.motion_stats import median_statistics

    scenes = [pipe("A person raises both hands.", num_people=1, seconds=4.0, seed=s,
                   fit=False)[0] for s in range(4)]  # fmt: skip
    tails = [sc.raw_joints[0][-46:] for sc in scenes]
    (speed,) = median_statistics(tails, ("pelvis_speed",), pipe.config.fps)
    assert speed < 0.08, speed


def test_second_person_strides_beside_the_first(pipe):
    """Person 2 of "walk side by side" moves its legs, not a still pose carried along a
    path: root-relative ankle speed, median over 4 seeds, of the scenes as delivered
    (anchored feet leave a glide standing still; real walks 1.2-1.4 m/s; the S-Flow
    bundled before the noisy reaction start: 0.33, this one 0.93:
    results/umf-small-bandai-20261126c/person2-two-prompts.md)."""
    from umf.eval.motion_stats import median_statistics

    scenes = [pipe("Two people walk side by side.", num_people=2, seconds=4.0, seed=s)[0]
              for s in range(4)]  # fmt: skip
    fps = pipe.config.fps
    first, second = (median_statistics([sc.joints[k] for sc in scenes], ("ankle_energy",
                     "pelvis_speed"), fps) for k in (0, 1))  # fmt: skip
    assert second[0] > 0.6, second  # the legs swing
    assert second[1] > 0.5, second  # and carry the body forward
    assert second[0] > 0.6 * first[0], (first, second)


def test_followers_keep_pace_with_a_walking_leader(pipe):
    """The reactions issue's target: in "Two people walk side by side." (4 s, seeds 0-7) the
    follower's delivered start-to-end floor speed is within 20 % of the leader's and it ends
    at most 1 m behind. 20261210 missed one seed; retrieving at the leader's pace
    (``sflow.warm_together``) keeps all 8 (python research/keep_pace.py gives the
    numbers)."""
    fps, missed = pipe.config.fps, []
    for seed in range(8):
        (scene,) = pipe("Two people walk side by side.", num_people=2, seconds=4.0, seed=seed)
        p = np.asarray(scene.joints)[:, :, 0][..., [0, 2]]
        speed = np.linalg.norm(p[:, -1] - p[:, 0], axis=-1) * fps / (p.shape[1] - 1)
        heading = (p[0, -1] - p[0, 0]) / max(float(np.linalg.norm(p[0, -1] - p[0, 0])), 1e-6)
        behind = float((p[0, -1] - p[1, -1]) @ heading)
        if abs(speed[1] / speed[0] - 1.0) > 0.2 or behind > 1.0:
            missed.append((seed, round(float(speed[1] / speed[0]), 2), round(behind, 2)))
    assert not missed, missed


def test_running_followers_run_at_about_the_leaders_pace(pipe):
    """ "Two people run side by side.", 4 s, seeds 0-3: the follower's delivered start-to-end
    floor speed over the leader's, median within 15 % of 1. The S-Flow trained on 4-second
    runs carried on by their gait (``train_sflow.repeat_scene_gait``) gives 0.98; before it,
    the runs long enough for its crops were slow jogs and 20261208 gave 0.71
    (results/umf-small-bandai-20261209)."""
    fps, ratios = pipe.config.fps, []
    for seed in range(4):
        (scene,) = pipe("Two people run side by side.", num_people=2, seconds=4.0, seed=seed)
        p = np.asarray(scene.joints)[:, :, 0][..., [0, 2]]
        speed = np.linalg.norm(p[:, -1] - p[:, 0], axis=-1) * fps / (p.shape[1] - 1)
        assert speed[0] > 1.5, speed  # the leader runs
        ratios.append(float(speed[1] / speed[0]))
    assert abs(float(np.median(ratios)) - 1.0) <= 0.15, ratios


def test_runners_start_level_with_their_leader(pipe):
    """ "Two people run side by side.", 4 s, seeds 0-7: the follower's first-frame pelvis,
    along the leader's heading, within 0.5 m of the leader's at the median. A runner's
    decoded positions travel about half as far as its velocities, and its fused path
    started 0.9-1.6 m behind where people 2..N are placed from: 20261210's followers
    started 1.78 m ahead at the median, 20261211's -0.11 m (``vae.pin_leader_start``;
    ``research/keep_pace.py``, "starts ahead"; results/umf-small-bandai-20261211)."""
    ahead = []
    for seed in range(8):
        (scene,) = pipe("Two people run side by side.", num_people=2, seconds=4.0, seed=seed)
        p = np.asarray(scene.joints)[:, :, 0][..., [0, 2]]
        heading = (p[0, -1] - p[0, 0]) / max(float(np.linalg.norm(p[0, -1] - p[0, 0])), 1e-6)
        ahead.append(float((p[1, 0] - p[0, 0]) @ heading))
    assert abs(float(np.median(ahead))) <= 0.5, ahead


def test_runners_keep_pace_with_their_leader(pipe):
    """The reactions issue's target for runners: "Two people run side by side." and "Three
    people run side by side." (4 s, seeds 0-7), every follower's delivered start-to-end
    floor speed within 20 % of the leader's and none more than 1 m behind, in at least 15
    of the 16 scenes. 20261211 kept 5 and 5: the bank's real partners run slower than the
    P-Flow's leaders, and a third runner started on the second one's spot; 20261212 plays
    the partner at the leader's pace (``sflow.warm_play``) and keeps person 3 off person 2's
    spot (``sflow.warm_apart``): 7 and 7 (results/umf-small-bandai-20261212). Seed 7's
    leader turns 50 degrees and its straight partners ended 1.2 m behind; 20261218 carries
    them along the leader's path (``sflow.warm_follow``): 8 and 8
    (results/umf-small-bandai-20261218)."""
    fps, missed = pipe.config.fps, []
    for n, prompt in ((2, "Two people run side by side."), (3, "Three people run side by side.")):
        for seed in range(8):
            (scene,) = pipe(prompt, num_people=n, seconds=4.0, seed=seed)
            p = np.asarray(scene.joints)[:, :, 0][..., [0, 2]]
            speed = np.linalg.norm(p[:, -1] - p[:, 0], axis=-1) * fps / (p.shape[1] - 1)
            heading = (p[0, -1] - p[0, 0]) / max(float(np.linalg.norm(p[0, -1] - p[0, 0])), 1e-6)
            behind = (p[0, -1] - p[1:, -1]) @ heading
            if (np.abs(speed[1:] / speed[0] - 1.0) > 0.2).any() or (behind > 1.0).any():
                missed.append((n, seed, np.round(speed[1:] / speed[0], 2), np.round(behind, 2)))
    assert len(missed) <= 1, missed


def test_a_4_second_runner_leader_runs_straight(pipe):
    """ "Two people run side by side.", 4 s, seeds 0-7: person 1's path turns under 15
    degrees between its two halves in at least 5 seeds. Bandai's runs last 2.6 s; 20261215's
    P-Flow made up the rest and turned in 6 of 8 (-22 to -59 degrees, 2 under 15), and
    its partner was left behind; 20261216 learnt short scenes' leaders carried on by their
    own gait (``train_pflow.repeat_leader_gait``): 5 of 8 (results/umf-small-bandai-20261216)."""
    straight = []
    for seed in range(8):
        (scene,) = pipe("Two people run side by side.", num_people=2, seconds=4.0, seed=seed)
        p = np.asarray(scene.joints)[0, :, 0][:, [0, 2]]
        a, b = p[60] - p[0], p[-1] - p[60]
        turn = abs(np.degrees(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b)))
        straight.append(bool(turn < 15.0))
    assert sum(straight) >= 5, straight


def test_a_short_single_file_of_six_walks_in_order(pipe):
    """ "Six people walk in single file.", 1.6 s, raw, seeds 0-7: each person starts behind
    the one before along person 1's heading in at least 7 seeds. 20261216 placed a walker
    behind person 1 wherever its first pass drew, and 4 of 8 came out of order (the val
    groups' single files failed `order` so); 20261217's ``sflow.warm_extend`` starts each
    behind the one before: 8 of 8 (results/umf-small-bandai-20261217)."""
    from umf.data.relations import lateral_offset

    ordered = []
    for seed in range(8):
        (scene,) = pipe("Six people walk in single file.", num_people=6, seconds=1.6, seed=seed,
                        fit=False, separate=False)  # fmt: skip
        ahead = [float(lateral_offset(scene.joints, 0, k, 0)[1]) for k in range(1, 6)]
        ordered.append(ahead[0] < 0 and all(np.diff(ahead) < 0))
    assert sum(ordered) >= 7, ordered


def test_people_3_to_n_start_off_the_spots_of_those_before_them(pipe):
    """Raw (no separation), seeds 0-3: in an audience, a single file and a row of three the
    closest two first-frame pelvises are at least 0.5 m apart, 0.8 m at the median.
    20261211 put everyone after person 2 where person 2 stood (audience 0.07-0.27 m, single
    file 0.11-1.01); 20261212's ``sflow.warm_apart`` gives 0.66-1.39 and 0.57-1.59
    (results/umf-small-bandai-20261212)."""
    for prompt, n in (("A person bows to three people, who bow back.", 4),
                      ("Four people walk in single file.", 4),
                      ("Three people walk side by side.", 3)):  # fmt: skip
        gaps = []
        for seed in range(4):
            (scene,) = pipe(prompt, num_people=n, seconds=4.0, seed=seed, fit=False,
                            separate=False)  # fmt: skip
            p = np.asarray(scene.joints)[:, 0, 0][:, [0, 2]]
            gaps.append(min(float(np.linalg.norm(p[i] - p[k])) for k in range(1, n)
                            for i in range(k)))  # fmt: skip
        assert min(gaps) >= 0.5 and float(np.median(gaps)) >= 0.8, (prompt, gaps)


def test_groups_keep_off_each_others_bodies_raw(pipe):
    """Raw (no separation), seeds 0-3, a circle of five, a gathering of five and a single
    file of four: no two people's joints come within 0.25 m (the ``no_contact`` check) in at
    least 9 of the 12 scenes, and in at least 1 of the 4 gatherings. 20261214 kept 7 and 0:
    its walkers met at the caller; 20261215's ``sflow.warm_clear`` keeps 10 and 2
    (results/umf-small-bandai-20261215)."""
    from umf.data.relations import CONTACT_DISTANCE, min_interperson_distance

    apart = {}
    for prompt, n in (("Five people stand in a circle and bow.", 5),
                      ("A person calls and four people walk over to them.", 5),
                      ("Four people walk in single file.", 4)):  # fmt: skip
        for seed in range(4):
            (scene,) = pipe(prompt, num_people=n, seconds=4.0, seed=seed, fit=False,
                            separate=False)  # fmt: skip
            gap = min_interperson_distance(np.asarray(scene.joints))[0]
            apart[prompt, seed] = gap >= CONTACT_DISTANCE
    gathered = [apart[k] for k in apart if k[0].startswith("A person calls")]
    assert sum(apart.values()) >= 9 and sum(gathered) >= 1, apart


def test_a_single_file_of_three_walks_in_file(pipe):
    """ "Three people walk in single file.", 4 s, seeds 0-7, delivered: at the end each
    person stands at least 1 m behind the one before along person 1's heading in at least 6
    seeds. 20261213 did so in 3 (person 2 beside the leader: the caption shortlist had
    filled with side-by-side reactions); 20261214's ``sflow.warm_margin`` in 7
    (results/umf-small-bandai-20261214)."""
    from umf.data.relations import lateral_offset

    filed = []
    for seed in range(8):
        (scene,) = pipe("Three people walk in single file.", num_people=3, seconds=4.0,
                        seed=seed)  # fmt: skip
        j = np.asarray(scene.joints)
        ahead = [0.0] + [float(lateral_offset(j, 0, k, j.shape[1] - 1)[1]) for k in (1, 2)]
        filed.append(all(ahead[k - 1] - ahead[k] >= 1.0 for k in (1, 2)))
    assert sum(filed) >= 6, filed


def test_a_bow_back_waits_for_the_bow(pipe):
    """ "One person bows and the other bows back.", 4 s, seeds 0-15: person 2's bow starts at
    least 8 frames after person 1's (the starts_after check's reading) in at least 13 seeds,
    and 15 frames later at the median. The S-Flow alone answers at the average delay it saw
    (20261209: 5 of 8 seeds, median 11 frames); ``sflow.warm_timing`` moves the retrieved
    real answer to wait as long as it did (7 of 8, median 19; results/umf-small-bandai-20261210).
    Read on 16 seeds since 20261219: its P-Flow moves which seeds miss (seed 4 bows late,
    6 of seeds 0-7), not how many (13 of 16, median 21 frames; 20261218 13, median 21.5)."""
    from umf.data.relations import ONSET_SMOOTHING, action_onset

    lags = []
    for seed in range(16):
        (scene,) = pipe("One person bows and the other bows back.", num_people=2, seconds=4.0,
                        seed=seed, fit=False, separate=False)  # fmt: skip
        a, b = (action_onset(np.asarray(j), smooth=ONSET_SMOOTHING) for j in scene.joints)
        lags.append(b - a)
    assert sum(lag >= 8 for lag in lags) >= 13 and np.median(lags) >= 15, lags


def test_the_bundled_model_says_what_it_does_not_know(pipe):
    """It carries its vocabulary: trained wordings and close paraphrases are known, actions
    no corpus of it has are flagged (calibration: results/coverage/calibration.json)."""
    known, hug, salsa = pipe.coverage(["A person walks forward.", "Two people hug each other.",
                                       "Two people dance salsa together."])  # fmt: skip
    assert known["known"] and salsa["known"] and not hug["known"]
    assert "contact" in salsa and "contact" not in known  # a real take whose partners touch
    assert {"salsa", "backflip", "walk"} <= set(pipe.vocabulary.actions)
    # groups are composed at sampling: their captions are known too (before 2026-12-06 the
    # vocabulary held trained captions only, and these scored 0.65 and 0.68)
    row, file = pipe.coverage(["Four people walk side by side.", "Six people walk in single file."])
    assert row["known"] and file["known"] and "single_file" in pipe.vocabulary.groups


def test_each_person_does_what_their_own_prompt_says(pipe):
    """Per-person prompts (the direct-each-person issue): under "Two people stand facing
    each other.", person 1 told to raise both hands lifts both wrists above the head and
    person 2 told to bow drops the head more than 8 cm, in at least 3 of seeds 0-3, and
    with the two prompts swapped the gestures swap in at least 2 (3 of 4 here, seed 2's
    person 2 keeps its wrists 16 cm below the head; 8 and 8, then 8 and 7 of 8 seeds
    measured, results/umf-small-bandai-20261207; 20261206 swapped them in 0 of 8: person 1
    bowed 3-9 cm and person 2 kept its hands down); without the person prompts, person 2
    bows in none."""
    from umf.eval.motion_stats import motion_statistics

    assert pipe.person_prompts
    scene, hands, bow = ("Two people stand facing each other.", "A person raises both hands.",
                         "Someone bows politely.")  # fmt: skip

    def run(own):
        return pipe([scene] * 4, num_people=2, seed=0, sample_indices=range(4),
                    person_prompts=own)  # fmt: skip

    def did(scenes, first, second):
        rows = [[motion_statistics(s.joints[k]) for k in range(2)] for s in scenes]
        return [(first(r[0]), second(r[1])) for r in rows]

    raised = lambda s: s["both_wrists_above_head"] > 0  # noqa: E731
    bowed = lambda s: s["head_drop"] > 0.08  # noqa: E731
    asked = did(run([hands, bow]), raised, bowed)
    swapped = did(run([bow, hands]), bowed, raised)
    plain = did(run(None), raised, bowed)
    assert sum(a and b for a, b in asked) >= 3, asked
    assert sum(a and b for a, b in swapped) >= 2, swapped
    assert sum(b for _, b in plain) == 0, plain


def test_a_walker_keeps_the_side_the_prompt_names(pipe):
    """``sflow.warm_side``: asked for person 2 on person 1's right (the composer's wording),
    a walking pair puts it there in at least 3 of seeds 0-3 (8 of 8 seeds measured;
    20261206, which put person 2 on the left whatever the prompt said, 1 of 8;
    results/umf-small-bandai-20261207, research/side_named.py)."""
    from umf.data.relations import lateral_offset

    prompt = "Two people walk side by side, the second person on the first one's right."
    scenes = pipe([prompt] * 4, num_people=2, seed=0, sample_indices=range(4))
    right = [lateral_offset(np.asarray(s.raw_joints), 0, 1, 0)[0] < -0.2 for s in scenes]
    assert sum(right) >= 3, right


def test_the_reactions_flow_tells_a_side_named_left_from_right(pipe):
    """``train_sflow.place_loss``: the S-Flow's text tokens of a side named left and named
    right, centred on the mean over the scene prompts of ``research/scene_tokens.py``, are no
    longer one direction (umf-small-bandai-20261207: centred cosine 0.998, run 1.000;
    results/umf-small-bandai-20261208)."""
    import torch

    from conftest import load_script

    st = load_script("scene_tokens")
    names = list(st.PROMPTS)
    text = pipe.text_encoder.encode([st.PROMPTS[n] for n in names])
    with torch.no_grad():
        cos = st.centred_cosines(pipe.sflow.net.encode_text(text).float(), names)
    assert cos[("walk L", "walk R")] < 0.9, cos
    assert cos[("run L", "run R")] < 0.95, cos


def test_a_salsa_couple_takes_hands_without_passing_through_each_other(pipe):
    """ "Two people dance salsa together." is worded like the touching takes: both people
    are finished from one of their crops (sflow.warm_take). Seeds 0-3 hold hands (wrists
    within 0.3 x stature) in at least 40 % of the frames at the median (20261212: 12 % over
    seeds 0-7; the real test and val takes 59 %), face each other, and their pelvises never
    come within the 0.2 m real partners keep. The same seeds without the take hold hands
    less. A prompt that is not a couple's is not touched (the same scene with the option
    off)."""
    from umf.data.relations import pair_closeness
    from umf.separation import TOUCH_PELVIS

    salsa = "Two people dance salsa together."
    scenes = pipe([salsa] * 4, num_people=2, seconds=4.0, seed=0, sample_indices=range(4))
    close = [pair_closeness(s.joints) for s in scenes]
    assert scenes[0].meta["coverage"]["contact"]
    assert all(s.meta["take"]["take"].startswith("cmu-salsa/") for s in scenes)  # provenance
    assert np.median([c["hands_near"] for c in close]) >= 0.4
    assert np.median([c["facing"] for c in close]) > 0.5
    for s in scenes:
        pelvis = np.linalg.norm(s.joints[1, :, 0, [0, 2]] - s.joints[0, :, 0, [0, 2]], axis=0)
        assert pelvis.min() >= TOUCH_PELVIS - 0.05  # the fit may move a pelvis a little
    walk = pipe("Two people walk side by side.", num_people=2, seconds=4.0, seed=0)[0]
    take = pipe.config.sflow.warm_take
    try:
        pipe.config.sflow.warm_take = 0.0
        plain = pipe([salsa] * 4, num_people=2, seconds=4.0, seed=0, sample_indices=range(4))
        same = pipe("Two people walk side by side.", num_people=2, seconds=4.0, seed=0)[0]
    finally:
        pipe.config.sflow.warm_take = take
    hands = [pair_closeness(s.joints)["hands_near"] for s in plain]
    assert np.median(hands) < np.median([c["hands_near"] for c in close])
    assert np.array_equal(walk.joints, same.joints)


def test_the_taught_actions_do_what_their_prompts_say(pipe):
    """The DeepMimic actions, one real clip each, seeds 0-7, 4 s, delivered (the "teach it"
    issue's targets; research/teach_report.py): a cartwheel and a backflip turn the body
    over (head below the pelvis at some frame), a crawl keeps the pelvis under 0.6 m (90th
    percentile), a jump lifts the pelvis 15 cm above its median, a person lying face down
    ends standing (head above 1.2 m over the last 10 frames), each in at least 7 of 8 seeds,
    the jump in all 8: 20261218 jumped in 7 of these batched draws (0.12-0.35 m; 6 of 8 drawn
    seed by seed), 20261219's P-Flow, served the jump 4 times as often, in 8 (0.21-0.40 m)."""
    checks = {
        "A person does a cartwheel.": lambda p, h: (h - p).min() < 0,
        "A person does a backflip.": lambda p, h: (h - p).min() < 0,
        "A person crawls on hands and knees.": lambda p, h: np.percentile(p, 90) < 0.6,
        "A person jumps up.": lambda p, h: p.max() - np.median(p) >= 0.15,
        "A person lying face down gets up.": lambda p, h: h[-10:].mean() > 1.2,
    }
    for prompt, check in checks.items():
        scenes = pipe([prompt] * 8, num_people=1, seconds=4.0, seed=0, sample_indices=range(8))
        passed = [bool(check(s.joints[0, :, 0, 1], s.joints[0, :, 15, 1])) for s in scenes]
        assert sum(passed) >= (8 if "jumps" in prompt else 7), (prompt, passed)


def test_umf_info_names_the_touching_takes_and_a_prompt_worded_like_one():
    """`umf info` lists the captions of the real takes whose people touch and says a couple
    worded like one is finished from one of them; `--prompt` says which prompts are."""
    from typer.testing import CliRunner

    from umf.cli.main import app

    out = CliRunner().invoke(app, ["info"])
    assert out.exit_code == 0, out.output
    line = next(x for x in out.stdout.splitlines() if x.startswith("people who touch"))
    assert "salsa" in line and "warm_take 0.7" in line
    out = CliRunner().invoke(app, ["info", "--prompt", "Two people dance salsa together.",
                                   "--prompt", "Two people walk side by side."])  # fmt: skip
    salsa, walk = [x for x in out.stdout.splitlines() if x.startswith("'Two people")]
    assert "people touch" in salsa and "people touch" not in walk


def test_a_rerolled_salsa_partner_is_untangled_like_a_generated_one(pipe, monkeypatch):
    """``umf reroll`` of a salsa couple's person 2 goes through the same clean-up as a
    generated partner: its bones are moved out of person 1's (umf.untangle), so it overlaps
    person 1 less than the same re-roll left tangled; person 1 is untouched either way."""
    import umf.reroll as rr
    from umf.eval.physics import capsule_penetration

    (scene,) = pipe("Two people dance salsa together.", num_people=2, seconds=4.0, seed=2)
    depth = {}
    for name in ("with", "without"):
        if name == "without":
            monkeypatch.setattr(rr, "untangle", lambda bodies, *a, **k: bodies)
        again = rr.reroll_person(pipe, scene, 2, seed=0)
        assert np.array_equal(again.joints[0], scene.joints[0])
        depth[name] = capsule_penetration(again.joints[1], again.joints[0]).mean()
    assert depth["without"] > 0.02, depth  # 3.7 cm on average, seed 0
    assert depth["with"] < 0.5 * depth["without"], depth  # 1.0 cm
