import dataclasses
import math

import numpy as np
import pytest
import torch

from conftest import prepare_fixture_corpus
from umf.data import extension as E
from umf.data.corpus import Corpus
from umf.data.scenes import yaw_rotate
from umf.errors import UMFError
from umf.representation import (
    CONTACT,
    FEATURE_DIM,
    POS,
    ROT,
    VEL,
    assemble_features,
    features_to_joints,
    heading_angle,
    joints_to_rot6d,
    mirror_features,
)
from umf.train import batching as B
from umf.train import datasets as D


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    out = tmp_path_factory.mktemp("train-corpus")
    return Corpus.load(prepare_fixture_corpus(out, train_scenes=8, val_scenes=2, test_scenes=2,
                                              test_groups=2))  # fmt: skip


def _raw(item_features: torch.Tensor, corpus: Corpus) -> torch.Tensor:
    return corpus.normalizer.denormalize(item_features.double())


def _assert_canonical(features: torch.Tensor, atol: float = 1e-4) -> None:
    """Person 1 (features (P, T, 262) or (T, 262)) starts over the origin facing +Z."""
    first = features if features.ndim == 2 else features[0]
    joints0 = features_to_joints(first[0])
    assert abs(float(joints0[0, 0])) < atol and abs(float(joints0[0, 2])) < atol
    assert abs(float(heading_angle(joints0))) < 1e-3


# --------------------------------------------------------------------- pure functions
def test_place_features_equals_features_of_moved_joints(real_joints):
    joints = real_joints[:60]
    rot6d = joints_to_rot6d(joints)
    f = assemble_features(joints, rot6d)
    for yaw, dx, dz in [(0.7, 1.5, -2.0), (-3.0, 0.0, 0.4), (math.pi / 2, -2.5, 2.5)]:
        moved = torch.from_numpy(yaw_rotate(joints.numpy(), yaw))
        moved[..., 0] += dx
        moved[..., 2] += dz
        want = assemble_features(moved, rot6d)
        got = D.place_features(f, yaw, dx, dz)
        torch.testing.assert_close(got, want, atol=1e-9, rtol=0)
        torch.testing.assert_close(got[:, ROT], f[:, ROT], atol=0, rtol=0)
        torch.testing.assert_close(got[:, CONTACT], f[:, CONTACT], atol=0, rtol=0)


def test_canonicalize_features_is_rigid_and_invariant(corpus):
    f = torch.from_numpy(corpus.scene_features(corpus.scenes["train"][0])).double()[:, 25:]
    canon = D.canonicalize_features(f)
    _assert_canonical(canon, atol=1e-9)
    # heights are kept, and any rigid placement of the input gives the same canonical form
    torch.testing.assert_close(canon[..., 1:66:3], f[..., 1:66:3])
    moved = D.place_features(f, 2.1, -1.3, 0.8)
    torch.testing.assert_close(D.canonicalize_features(moved), canon, atol=1e-9, rtol=0)
    # relative placement of person 2 is unchanged (pairwise distances preserved)
    d = lambda x: (x[0, :, 0:3] - x[1, :, 0:3]).norm(dim=-1)  # noqa: E731
    torch.testing.assert_close(d(canon), d(f))
    single = D.canonicalize_features(f[1])
    _assert_canonical(single, atol=1e-9)


def test_mirror_caption_swaps_sides_and_is_an_involution():
    cases = {
        "A person raises the right hand and waves.": "A person raises the left hand and waves.",
        "Left foot first, then RIGHT.": "Right foot first, then LEFT.",
        "They circle clockwise, then counterclockwise.": (
            "They circle counterclockwise, then clockwise."
        ),
        "turns counter-clockwise": "turns clockwise",
        "walks leftward": "walks rightward",
        "the leftover bright light": "the leftover bright light",
    }
    for text, want in cases.items():
        assert D.mirror_caption(text) == want
    for text in [*list(cases)[:3], "walks leftward"]:
        assert D.mirror_caption(D.mirror_caption(text)) == text


def test_respell_caption_swaps_spellings_and_is_an_involution():
    cases = {
        "A person walks backwards.": "A person walks backward.",
        "Someone steps BACKWARD, then forward": "Someone steps BACKWARDS, then forwards",
        "Forwards and towards the door.": "Forward and toward the door.",
        "a backwardness test, walks leftward": "a backwardness test, walks leftward",
    }
    for text, want in cases.items():
        assert D.respell_caption(text) == want
        assert D.respell_caption(want) == text


def test_preferred_spellings_map_what_the_captions_never_write():
    caps = ["A person walks backwards.", "Someone runs forward.", "Walks forward, then forwards"]
    # backward: never written, backwards is -> mapped; forward / forwards both written: no
    # mapping; toward / towards: neither written -> no mapping
    assert D.preferred_spellings(caps) == ("backward=backwards",)
    assert D.preferred_spellings([]) == ()
    assert D.preferred_spellings(["TOWARD the wall"]) == ("towards=toward",)


def test_respelled_captions_leave_every_other_draw_alone(corpus, monkeypatch):
    """``respell`` only rewrites about half the captions that have such a word; crops,
    mirroring and features are the draws of the dataset without it."""
    kw = dict(min_frames=20, max_frames=60, random_placement=False, mirror=True, seed=3)
    plain = D.SingleMotionDataset(corpus, "train", None, **kw)
    respelled = D.SingleMotionDataset(corpus, "train", None, respell=True, **kw)
    for clip, _, _ in plain.items:  # every caption gets a word with another spelling
        said = [c.rstrip(".") + ", then walks backwards." for c in clip.captions]
        monkeypatch.setattr(clip, "captions", said)
    changed = 0
    for epoch in range(4):
        plain.set_epoch(epoch), respelled.set_epoch(epoch)
        for i in range(len(plain)):
            a, b = plain[i], respelled[i]
            assert (a["start"], a["length"], a["mirrored"]) == (b["start"], b["length"],
                                                                b["mirrored"])  # fmt: skip
            torch.testing.assert_close(a["features"], b["features"])
            assert b["caption"] in (a["caption"], D.respell_caption(a["caption"]))
            changed += b["caption"] != a["caption"]
    total = 4 * len(plain)
    assert 0.2 * total < changed < 0.8 * total, (changed, total)


def test_crop_window_in_range():
    rng = np.random.default_rng(0)
    for _ in range(200):
        total = int(rng.integers(1, 200))
        start, length = D.crop_window(rng, total, 30, 120)
        assert min(30, total) <= length <= min(120, total)
        assert 0 <= start and start + length <= total


# --------------------------------------------------------------------- single person
def test_single_dataset_items(corpus):
    norm = corpus.normalizer
    ds = D.SingleMotionDataset(corpus, "train", norm, 20, 60, random_placement=False, mirror=True)
    assert len(ds) == len(corpus.split_clips("train"))
    seen_mirrored = set()
    for i in range(len(ds)):
        it = ds[i]
        f = it["features"]
        assert f.dtype == torch.float32 and f.shape == (it["length"], FEATURE_DIM)
        assert 20 <= it["length"] <= 60 and it["dataset"] == D.SINGLE_PERSON
        assert isinstance(it["caption"], str) and it["caption"]
        _assert_canonical(_raw(f, corpus))
        seen_mirrored.add(it["mirrored"])
    assert seen_mirrored == {True, False}
    # an item depends only on (seed, epoch, index)
    torch.testing.assert_close(ds[3]["features"], ds[3]["features"])
    first = ds[3]
    ds.set_epoch(1)
    assert ds[3]["start"] != first["start"] or ds[3]["length"] != first["length"]


def test_single_dataset_mirroring_matches_mirror_features(corpus):
    kw = dict(min_frames=20, max_frames=60, random_placement=False, seed=5)
    plain = D.SingleMotionDataset(corpus, "train", None, mirror=False, **kw)
    mirror = D.SingleMotionDataset(corpus, "train", None, mirror=True, **kw)
    checked = 0
    for i in range(len(plain)):
        a, b = plain[i], mirror[i]
        assert (a["start"], a["length"]) == (b["start"], b["length"])
        if b["mirrored"]:
            torch.testing.assert_close(b["features"], mirror_features(a["features"]))
            assert b["caption"] == D.mirror_caption(a["caption"])
            torch.testing.assert_close(mirror_features(b["features"]), a["features"])
            checked += 1
    assert checked > 0


def test_single_dataset_random_placement(corpus):
    ds = D.SingleMotionDataset(
        corpus, "train", None, 20, 60, random_placement=True, mirror=False, placement_radius=2.0
    )
    headings = []
    for i in range(len(ds)):
        joints0 = features_to_joints(ds[i]["features"][0])
        assert float(joints0[0, [0, 2]].abs().max()) <= 2.0 + 1e-4
        headings.append(float(heading_angle(joints0)))
    assert np.ptp(headings) > 1.0  # people face many directions


def test_single_dataset_empty_split_is_an_error(corpus):
    with pytest.raises(UMFError, match="no clips"):
        D.SingleMotionDataset(corpus, "nope", None)
    with pytest.raises(UMFError, match="min_frames"):
        D.SingleMotionDataset(corpus, "train", None, 50, 20)


def test_label_repeats_shares():
    labels = ["a"] * 8 + ["b"] * 2 + ["c"]
    assert D.label_repeats(labels, 0.0) == [1] * 11
    # power 1: every label gets the commonest one's share (8 items' worth)
    r = D.label_repeats(labels, 1.0)
    assert r == [1] * 8 + [4, 4] + [8]
    # power 0.5: shares move towards sqrt(count): 8 : 2 * 2 : 1 * round(sqrt(8)) = 8 : 4 : 3
    r = D.label_repeats(labels, 0.5)
    assert r == [1] * 8 + [2, 2] + [3]
    # unlabelled items (other corpora) appear once and do not set the commonest count
    assert D.label_repeats([None] * 50 + ["x", "x", "y"], 1.0) == [1] * 50 + [1, 1, 2]
    assert D.label_repeats([None, None], 1.0) == [1, 1]
    assert D.label_repeats([], 1.0) == []
    for bad in (-0.5, 1.5):
        with pytest.raises(ValueError, match="between 0 and 1"):
            D.label_repeats(labels, bad)


def test_single_dataset_balance_repeats_rare_labels(corpus, monkeypatch):
    clips = [c for c in corpus.split_clips("train") if c.num_people == 1]
    assert len(clips) >= 8
    for clip in clips[:6]:
        monkeypatch.setitem(clip.meta, "content", "common")
    plain = D.SingleMotionDataset(corpus, "train", None, 20, 60)
    ds = D.SingleMotionDataset(corpus, "train", None, 20, 60, balance=1.0)
    ids = [clip.id for clip, _, _ in ds.items]
    for clip in clips[:6]:
        assert ids.count(clip.id) == 1
    for clip in clips[6:]:  # a label of its own: six times, like the "common" label's six
        assert ids.count(clip.id) == 6
    assert len(ds) == len(plain) + 5 * len(clips[6:])
    # each repeat is its own random crop
    rare = [i for i, key in enumerate(ids) if key == clips[-1].id]
    crops = {(ds[i]["start"], ds[i]["length"], ds[i]["mirrored"]) for i in rare}
    assert len(crops) > 1
    for bad in (-1.0, 2.0):
        with pytest.raises(UMFError, match="balance_labels must be between 0 and 1"):
            D.SingleMotionDataset(corpus, "train", None, balance=bad)


def test_single_dataset_label_times_repeat_those_labels_after_balance(corpus, monkeypatch):
    """``train_*.label_repeats``: items of the named labels that many times more, on top of
    ``balance_labels``; other labels as they were."""
    clips = [c for c in corpus.split_clips("train") if c.num_people == 1]
    for clip in clips[:6]:
        monkeypatch.setitem(clip.meta, "content", "common")
    monkeypatch.setitem(clips[6].meta, "content", "jump")
    monkeypatch.setitem(clips[7].meta, "content", "crawl")
    plain = D.SingleMotionDataset(corpus, "train", None, 20, 60, balance=1.0)
    ds = D.SingleMotionDataset(corpus, "train", None, 20, 60, balance=1.0,
                               label_times={"jump": 3, "roll": 5})  # fmt: skip
    ids = [clip.id for clip, _, _ in ds.items]
    assert ids.count(clips[6].id) == 3 * 6  # balanced to six, then three times that
    assert ids.count(clips[7].id) == 6 and ids.count(clips[0].id) == 1
    assert len(ds) == len(plain) + 2 * 6


def test_label_repeats_are_checked_as_label_times():
    from conftest import tiny_config
    from umf.config import set_option
    from umf.model_checks import check_config_values

    check_config_values(set_option(tiny_config(), "train_pflow.label_repeats=[jump=4]"))
    for bad in ("[jump]", "[jump=0]", "[jump=x]"):
        with pytest.raises(UMFError, match="label_repeats"):
            check_config_values(set_option(tiny_config(), f"train_pflow.label_repeats={bad}"))


def test_single_dataset_labels_keep_only_those_clips(corpus, monkeypatch):
    for clip in corpus.clips:
        monkeypatch.setitem(clip.meta, "content", "walk")
    clips = [c for c in corpus.split_clips("train") if c.num_people == 1]
    for clip in clips[:3]:
        monkeypatch.setitem(clip.meta, "content", "wave")
    ds = D.SingleMotionDataset(corpus, "train", None, 20, 60, labels=["wave"])
    assert sorted(c.id for c, _, _ in ds.items) == sorted(c.id for c in clips[:3])
    both = D.SingleMotionDataset(corpus, "train", None, 20, 60, labels=["wave", "walk"])
    assert len(both) == len(D.SingleMotionDataset(corpus, "train", None, 20, 60))
    with pytest.raises(UMFError, match=r"unknown content label 'kick' \(known: walk, wave\)"):
        D.SingleMotionDataset(corpus, "train", None, 20, 60, labels=["kick"])
    # a label of the corpus that one split lacks: that split's own error, not "unknown"
    with pytest.raises(UMFError, match="no clips labelled wave in split 'val'"):
        D.SingleMotionDataset(corpus, "val", None, 20, 60, labels=["wave"])


def _standing(frames: int = 40, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(1, 22, 3))
    return np.repeat(base, frames, axis=0) + rng.normal(scale=1e-4, size=(frames, 22, 3))


def test_ends_at_rest_needs_a_still_pelvis_and_still_feet():
    still = _standing()
    assert E.ends_at_rest(still)
    waving = still.copy()  # the arms may move: gestures are cut while the hands come down
    waving[:, [18, 19, 20, 21]] += np.linspace(0, 1.0, len(waving))[:, None, None]
    assert E.ends_at_rest(waving)
    for joints in ([0], [7], [11]):  # pelvis, left ankle, right toe: 0.3 m/s over the end
        moving = still.copy()
        moving[-11:, joints, 2] += np.arange(11)[:, None] * 0.01
        assert not E.ends_at_rest(moving), joints
        speeds = E.end_speeds(moving)  # the one moving joint at 0.01 m x 30 fps, the rest ~0
        k = E.REST_JOINTS.index(joints[0])
        assert speeds[k] == pytest.approx(0.3, abs=0.01)
        assert np.delete(speeds, k).max() < 0.01
    early = still.copy()  # moved before the last ten frames, still during them
    early[:-11, 0, 2] += np.arange(len(early) - 11) * 0.05
    assert E.ends_at_rest(early)
    assert not E.ends_at_rest(still[:1])
    assert E.end_speeds(still[:1]).size == 0


def test_hold_rest_serves_short_clips_at_rest_whole_then_held(corpus):
    clips = {c.id: c for c in corpus.split_clips("train")}
    longest = max(c.num_frames for c in clips.values())
    lo, hi = longest + 10, longest + 40  # every clip is shorter than the shortest crop
    plain = D.SingleMotionDataset(corpus, "train", None, lo, hi, mirror=False)
    held = D.SingleMotionDataset(corpus, "train", None, lo, hi, mirror=False, hold_rest=True)
    assert not plain.extended
    expected = {(c.id, p) for c in clips.values() for p in range(c.num_people)
                if E.ends_at_rest(c.joints[p])}  # fmt: skip
    assert held.extended == dict.fromkeys(expected, 0) and 0 < len(expected) < len(held.items)
    for i, (clip, person, _) in enumerate(held.items):
        a, b = plain[i], held[i]
        n = clip.num_frames - 1  # frames a crop of the whole clip has (one more for velocity)
        assert a["length"] == n and a["start"] == 0  # as before: the whole clip, no more
        if (clip.id, person) not in expected:
            torch.testing.assert_close(a["features"], b["features"])
            continue
        assert b["start"] == 0 and lo <= b["length"] <= hi
        assert b["caption"] in clip.captions
        f = b["features"].double()
        torch.testing.assert_close(f[:n], a["features"].double())  # the clip itself first
        tail = f[n:]
        torch.testing.assert_close(tail[:, VEL], torch.zeros_like(tail[:, VEL]))
        torch.testing.assert_close(tail[:, POS], tail[:1, POS].expand_as(tail[:, POS]))
        torch.testing.assert_close(tail[:, ROT], tail[:1, ROT].expand_as(tail[:, ROT]))
    # a crop length is drawn per epoch, and the rest of the item's draws stay its own
    key = next(i for i, (c, p, _) in enumerate(held.items) if (c.id, p) in expected)
    lengths = set()
    for epoch in range(6):
        held.set_epoch(epoch)
        lengths.add(held[key]["length"])
    assert len(lengths) > 1


def test_settle_times_ease_the_last_frames_to_a_stop():
    s = E.settle_times(20, 0, 40, frames=5)  # the last 5 frames (14..19) over 10, then held
    np.testing.assert_array_equal(s[:15], np.arange(15))  # as it is up to the ease
    assert s[24] == 19 and (s[24:] == 19).all()  # reaches the last frame, then holds
    pace = np.diff(s)
    assert pace[:14] == pytest.approx(1.0) and (pace[24:] == 0).all()
    falling = pace[14:24]  # linear in time: each step 1/10 slower than the one before
    np.testing.assert_allclose(np.diff(falling), -0.1, atol=1e-12)
    assert falling[0] == pytest.approx(0.95) and falling[-1] == pytest.approx(0.05)
    np.testing.assert_array_equal(E.settle_times(20, 5, 30, frames=5), s[5:30])  # a window
    short = E.settle_times(4, 0, 12, frames=10)  # fewer frames than the ease: all of them
    assert short[0] == 0 and short[6] == 3 and (np.diff(short) >= 0).all()
    assert E.settle_times(1, 0, 3).tolist() == [0, 0, 0]


def test_interpolate_frames_is_exact_on_frames_and_linear_between():
    x = np.arange(5 * 2, dtype=np.float32).reshape(5, 2) ** 2
    np.testing.assert_array_equal(E.interpolate_frames(x, np.array([0.0, 3.0, 4.0])), x[[0, 3, 4]])
    mid = E.interpolate_frames(x, np.array([1.5, 3.25]))
    np.testing.assert_allclose(mid, [(x[1] + x[2]) / 2, 0.75 * x[3] + 0.25 * x[4]])
    assert mid.dtype == x.dtype


def test_extension_period_settles_slow_ends_only():
    still = _standing(60)
    slow = still.copy()  # the pelvis still rising at 0.3 m/s over the last frames
    slow[-11:, 0, 1] += np.arange(11) * 0.01
    fast = still.copy()  # a foot still stepping at 1.5 m/s
    fast[-11:, 7, 2] += np.arange(11) * 0.05
    assert E.extension_period(slow, 100, True, True) is None  # settle off: as it is
    assert E.extension_period(slow, 100, True, True, settle=True) == E.SETTLE
    assert E.extension_period(fast, 100, True, True, settle=True) is None
    assert E.extension_period(still, 100, True, True, settle=True) == 0  # at rest: held
    assert E.extension_period(slow, 59, True, True, settle=True) is None  # long enough


def test_settle_serves_slow_ending_clips_whole_then_eased_to_a_stop(corpus, monkeypatch):
    monkeypatch.setattr(E, "SETTLE_SPEED", 100.0)  # every clip not at rest and not a gait
    clips = {c.id: c for c in corpus.split_clips("train")}
    longest = max(c.num_frames for c in clips.values())
    lo, hi = longest + 2 * E.SETTLE_FRAMES + 10, longest + 2 * E.SETTLE_FRAMES + 40
    plain = D.SingleMotionDataset(corpus, "train", None, lo, hi, mirror=False)
    eased = D.SingleMotionDataset(corpus, "train", None, lo, hi, mirror=False, hold_rest=True,
                                  settle=True)  # fmt: skip
    settled = {k for k, v in eased.extended.items() if v == E.SETTLE}
    assert settled and all(not E.ends_at_rest(clips[c].joints[p]) for c, p in settled)
    full = 0
    for i, (clip, person, _) in enumerate(eased.items):
        if (clip.id, person) not in settled:
            continue
        n = clip.num_frames - 1
        lengths = []
        for epoch in range(12):  # lengths from the clip's own up, not from min_frames
            eased.set_epoch(epoch)
            lengths.append(eased[i]["length"])
        assert n <= min(lengths) and max(lengths) <= hi and min(lengths) < lo
        epoch = next((e for e, length in enumerate(lengths) if length > n + 2 * E.SETTLE_FRAMES),
                     None)  # fmt: skip
        if epoch is None:
            continue
        full += 1
        eased.set_epoch(epoch)
        a, b = plain[i], eased[i]
        ease = n - E.SETTLE_FRAMES  # frames before it are the clip's own, untouched
        assert b["start"] == 0
        f, g = b["features"].double(), a["features"].double()
        torch.testing.assert_close(f[:ease, POS], g[:ease, POS])
        torch.testing.assert_close(f[:ease, VEL], g[:ease, VEL])
        torch.testing.assert_close(f[:ease, ROT], g[:ease, ROT], atol=1e-5, rtol=0)
        # the pace falls to zero over twice the eased frames, then the last pose is held
        speed = f[:, VEL].reshape(len(f), 22, 3).norm(dim=-1).max(dim=-1).values
        end = ease + 2 * E.SETTLE_FRAMES
        assert speed[end:].max() < 1e-6
        assert (speed[end - 3 : end] < speed[ease : ease + 3].max() + 1e-9).all()
        last = g[n - 1, POS] + g[n - 1, VEL]  # the clip's last pose: where the ease ends
        torch.testing.assert_close(f[end, POS], last)
        pos = f[end:, POS]
        torch.testing.assert_close(pos, pos[:1].expand_as(pos))
        rot = f[end:, ROT]
        torch.testing.assert_close(rot, rot[:1].expand_as(rot))
    assert full


def test_repeat_gait_carries_short_walks_on(corpus):
    clips = {c.id: c for c in corpus.split_clips("train")}
    longest = max(c.num_frames for c in clips.values())
    lo, hi = longest + E.GAIT_FRAMES[1] + 1, longest + E.GAIT_FRAMES[1] + 30  # room for a cycle
    ds = D.SingleMotionDataset(corpus, "train", None, lo, hi, mirror=False, hold_rest=True,
                               repeat_gait=True)  # fmt: skip
    gaits = {k: v for k, v in ds.extended.items() if v}
    assert gaits and all(not E.ends_at_rest(clips[c].joints[p]) for c, p in gaits)
    assert all(v == 0 for k, v in ds.extended.items() if E.ends_at_rest(clips[k[0]].joints[k[1]]))
    for i, (clip, person, _) in enumerate(ds.items):
        period = gaits.get((clip.id, person))
        if not period:
            continue
        it = ds[i]
        assert it["start"] == 0 and lo <= it["length"] <= hi
        joints = features_to_joints(it["features"].double()).numpy()
        src = np.asarray(clip.joints[person], dtype=np.float64)
        step = np.linalg.norm(src[-1, 0, [0, 2]] - src[-1 - period, 0, [0, 2]]) / period
        n = clip.num_frames
        moved = np.linalg.norm(joints[n - 1 + period, 0, [0, 2]] - joints[n - 1, 0, [0, 2]])
        assert moved == pytest.approx(step * period, abs=1e-3)  # one more cycle of travel
        f = it["features"]  # one cycle on, the pose (rotations) comes round again
        torch.testing.assert_close(f[n - 1 + period, ROT], f[n - 1, ROT])
        pose = joints - joints[:, :1]
        np.testing.assert_allclose(pose[n - 1 + period], pose[n - 1], atol=1e-5)


def _tiled_walk(corpus, cycle: int = 24, frames: int = 200) -> np.ndarray:
    """An exactly periodic walk: one stretch of ``cycle`` frames of a real walk, repeated and
    carried on along the floor by the stretch's own travel."""
    walks = [c for s in ("train", "val", "test") for c in corpus.split_clips(s) if "_walk_" in c.id]
    walk = max(walks, key=lambda c: c.num_frames).joints[0]
    piece = np.asarray(walk[40 : 40 + cycle], dtype=np.float64)
    travel = (walk[40 + cycle, 0] - walk[40, 0]) * np.array([1.0, 0.0, 1.0])
    return np.concatenate([piece + k * travel for k in range(frames // cycle + 1)])[:frames]


def test_extended_frames_hold_or_repeat_the_last_cycle():
    for bad in (-1, 10):
        with pytest.raises(ValueError, match="period"):
            E.extended_frames(10, 0, 12, period=bad)
    src, cycles = E.extended_frames(10, 7, 16)  # held
    assert src.tolist() == [7, 8, 9, 9, 9, 9, 9, 9, 9] and not cycles.any()
    src, cycles = E.extended_frames(10, 7, 17, period=3)  # frames 7, 8, 9 then 7, 8, 9, ...
    assert src.tolist() == [7, 8, 9, 7, 8, 9, 7, 8, 9, 7]
    assert cycles.tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3]
    src, cycles = E.extended_frames(10, 2, 6, period=3)  # inside the clip: untouched
    assert src.tolist() == [2, 3, 4, 5] and not cycles.any()


def test_repeating_the_last_cycle_continues_a_periodic_walk_exactly(corpus):
    walk = _tiled_walk(corpus, cycle=24, frames=200)
    cut = walk[:70].astype(np.float32)
    walk = walk.astype(np.float32)
    assert E.gait_period(cut) == 24
    np.testing.assert_allclose(E.extend_joints(cut, 0, 200, 24), walk, atol=1e-4)
    np.testing.assert_allclose(E.extend_joints(cut, 50, 120, 24), walk[50:120], atol=1e-4)
    assert E.extend_joints(cut, 0, 200, 24).dtype == cut.dtype
    held = E.extend_joints(cut, 0, 100)
    np.testing.assert_array_equal(held[70:], np.repeat(cut[-1:], 30, axis=0))


def test_gait_period_wants_a_steady_straight_travelling_cycle(corpus):
    walk = _tiled_walk(corpus, cycle=24, frames=70)
    assert E.gait_period(walk) == 24
    assert E.gait_period(walk, match=1.0) == 24
    assert E.gait_period(_standing(70), match=1.0) == 0  # still: no travel
    assert E.gait_period(walk[:15]) == 0  # no room for the shortest cycle (15 frames)
    jittered = walk + np.random.default_rng(0).normal(scale=0.1, size=walk.shape)
    assert E.gait_period(jittered) == 0  # the last pose matches no earlier one
    # turning: each frame yawed a little further about the last pelvis position
    yaws = np.linspace(0, math.radians(120), len(walk))  # 26 degrees or more per cycle
    turned = np.stack([yaw_rotate(f, a) for f, a in zip(walk, yaws, strict=True)])
    assert E.gait_period(turned, match=1.0) == 0


# --------------------------------------------------------------------- scenes
def test_crop_recipe_equals_cropped_scene(corpus):
    actors = corpus.actors()
    for recipe in corpus.scenes["train"][:4]:
        full = corpus.scene_features(recipe)
        n = full.shape[1]
        for start, length in [(0, 20), (n - 25, 25), (n // 2, n - n // 2)]:
            crop = corpus.scene_features(D.crop_recipe(recipe, actors, start, length + 1))
            np.testing.assert_allclose(crop, full[:, start : start + length], atol=1e-5)


def test_scene_dataset_items(corpus):
    norm = corpus.normalizer
    ds = D.SceneDataset(corpus, "train", norm, 20, 80, mirror=True, seed=1)
    assert len(ds) == len(corpus.scenes["train"])
    for i in range(len(ds)):
        it = ds[i]
        f = it["features"]
        assert f.shape == (it["num_people"], it["length"], FEATURE_DIM)
        assert it["num_people"] == 2 and it["dataset"] == D.MULTI_PERSON
        assert 20 <= it["length"] <= 80
        _assert_canonical(_raw(f, corpus))
    groups = D.SceneDataset(corpus, "test_groups", norm, 20, 80, max_people=8)
    assert all(groups[i]["num_people"] >= 3 for i in range(len(groups)))
    with pytest.raises(UMFError, match="no multi-person"):
        D.SceneDataset(corpus, "test_groups", norm, max_people=2)


def test_scene_crop_matches_recanonicalised_full_scene(corpus):
    ds = D.SceneDataset(corpus, "train", None, 20, 80, mirror=False, seed=2)
    it = ds[0]
    full = torch.from_numpy(corpus.scene_features(corpus.scenes["train"][0]))
    want = D.canonicalize_features(full[:, it["start"] : it["start"] + it["length"]])
    torch.testing.assert_close(it["features"], want, atol=1e-5, rtol=0)
    assert not torch.equal(it["features"][:, :, POS], full[:, : it["length"], POS])


# --------------------------------------------------------------------- batching
def test_collate_single_pads_and_masks(corpus):
    ds = D.SingleMotionDataset(corpus, "train", corpus.normalizer, 10, 50)
    items = [ds[i] for i in range(4)]
    b = B.collate_single(items)
    t = max(it["length"] for it in items)
    assert b["features"].shape == (4, t, FEATURE_DIM) and b["mask"].shape == (4, t)
    for i, it in enumerate(items):
        n = it["length"]
        assert b["mask"][i].sum() == n and bool(b["mask"][i, :n].all())
        torch.testing.assert_close(b["features"][i, :n], it["features"])
        assert float(b["features"][i, n:].abs().sum()) == 0.0
    assert b["dataset"].dtype == torch.long and b["captions"] == [it["caption"] for it in items]
    assert b["lengths"].tolist() == [it["length"] for it in items] and len(b["ids"]) == 4


def test_collate_scenes_pads_people_and_time(corpus):
    pairs = D.SceneDataset(corpus, "train", corpus.normalizer, 10, 40)
    groups = D.SceneDataset(corpus, "test_groups", corpus.normalizer, 10, 40)
    items = [pairs[0], groups[0], pairs[1]]
    b = B.collate_scenes(items)
    p = max(it["num_people"] for it in items)
    t = max(it["length"] for it in items)
    assert b["features"].shape == (3, p, t, FEATURE_DIM)
    assert b["mask"].shape == (3, t) and b["people_mask"].shape == (3, p)
    for i, it in enumerate(items):
        n_p, n_t = it["num_people"], it["length"]
        assert b["people_mask"][i].sum() == n_p and b["mask"][i].sum() == n_t
        torch.testing.assert_close(b["features"][i, :n_p, :n_t], it["features"])
        assert float(b["features"][i, n_p:].abs().sum()) == 0.0
    assert b["num_people"].tolist() == [it["num_people"] for it in items]


def test_mixed_batches_alternate(corpus):
    single = D.SingleMotionDataset(corpus, "train", corpus.normalizer, 10, 30)
    scenes = D.SceneDataset(corpus, "train", corpus.normalizer, 10, 30)
    a = B.make_loader(single, 4, shuffle=True)
    b = B.make_loader(scenes, 4, shuffle=True)
    batches = list(B.MixedBatches(a, b))
    kinds = ["people_mask" in x for x in batches]
    assert kinds[:4] == [False, True, False, True]
    assert len(batches) >= 2 * max(len(a), len(b)) - 1


def test_sharded_sampler_shards_and_resumes():
    s0 = B.ShardedSampler(10, shuffle=True, seed=3, rank=0, world_size=3)
    s1 = B.ShardedSampler(10, shuffle=True, seed=3, rank=1, world_size=3)
    s2 = B.ShardedSampler(10, shuffle=True, seed=3, rank=2, world_size=3)
    shards = [list(s) for s in (s0, s1, s2)]
    assert all(len(s) == 4 for s in shards) and set().union(*shards) == set(range(10))
    epoch0 = list(s0)
    s0.set_epoch(1)
    assert list(s0) != epoch0
    s0.set_epoch(0)
    s0.start = 2
    assert list(s0) == epoch0[2:] and len(s0) == 2


def test_usable_workers_capped_at_the_cpus(monkeypatch):
    monkeypatch.setattr(B.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert B.usable_workers(9) == 2 and B.usable_workers(1) == 1 and B.usable_workers(0) == 0
    loader = B.make_loader(list(range(8)), 4, shuffle=False, num_workers=9)
    assert loader.num_workers == 2
    # without affinity (macOS, Windows): the CPU count; unknown: one worker at most
    monkeypatch.delattr(B.os, "sched_getaffinity", raising=False)
    monkeypatch.setattr(B.os, "cpu_count", lambda: 3)
    assert B.usable_workers(9) == 3
    monkeypatch.setattr(B.os, "cpu_count", lambda: None)
    assert B.usable_workers(9) == 1 and B.usable_workers(0) == 0


def test_corpus_captions_hold_every_respelled_and_mirrored_form(corpus):
    """The text cache must already hold what respelling and mirroring ask for, and a cache
    built before respelling existed still serves runs that do not respell."""
    from umf.train.run import corpus_captions

    texts = set(corpus_captions(corpus, respell=True))
    plain = set(corpus_captions(corpus))
    base = {c for clip in corpus.clips for c in clip.captions}
    extra = texts - plain  # only asked for: every extra is a respelling of a caption
    assert extra and all(D.respell_caption(t) in plain for t in extra)
    assert any(D.respell_caption(c) != c for c in base)  # the fixture has such words
    for c in base:
        assert D.respell_caption(c) in texts and D.mirror_caption(c) in texts
        assert D.respell_caption(D.mirror_caption(c)) in texts


def test_respelling_reaches_the_training_splits_only(corpus):
    """``respell_captions`` respells training captions (flows and evaluators); validation
    keeps the corpus's own words, so val losses stay comparable between runs."""
    from umf.config import small_config
    from umf.train.evaluator_stage import evaluator_loaders
    from umf.train.run import _loaders

    cfg = small_config()
    t = dataclasses.replace(cfg.train_pflow, respell_captions=True, num_workers=0)
    train, val, _ = _loaders("pflow", corpus, cfg, t, progress=False)
    assert [dl.dataset.respell for dl in train.loaders] == [True, True]
    assert [dl.dataset.respell for dl in val.loaders] == [False, False]
    plain = dataclasses.replace(t, respell_captions=False)
    assert not any(dl.dataset.respell for dl in _loaders("pflow", corpus, cfg, plain,
                                                         progress=False)[0].loaders)  # fmt: skip
    for kind in ("single", "interaction"):
        train, val = evaluator_loaders(corpus, kind, t, 60, 4)
        assert train.dataset.respell and not val.dataset.dataset.respell


def test_caption_mix_draws_captions_of_the_same_label_only(corpus, monkeypatch):
    """``caption_mix`` swaps an item's caption for one of a random clip of its group (content
    label and style by default, or the keys asked) at about the asked rate (the clip itself
    may be drawn), never across groups, and leaves every other draw (crop, mirror, features)
    as without it."""
    clips = [c for c in corpus.split_clips("train") if c.num_people == 1]
    assert len(clips) >= 8
    owner = {}
    for i, clip in enumerate(clips):
        label, style = ("wave" if i % 2 else "walk"), ("old" if i % 4 < 2 else "young")
        monkeypatch.setitem(clip.meta, "content", label)
        monkeypatch.setitem(clip.meta, "style", style)
        said = [f"clip {i} take {k}." for k in range(2)]  # no side words: mirroring keeps them
        monkeypatch.setattr(clip, "captions", said)
        owner.update({c: (clip.id, (label, style)) for c in said})
    kw = dict(min_frames=20, max_frames=60, mirror=True, seed=5)
    plain = D.SingleMotionDataset(corpus, "train", None, **kw)
    cases = [(0.5, ("content", "style")), (1.0, ("content", "style")), (1.0, ("content",))]
    for mix, within in cases:
        mixed = D.SingleMotionDataset(corpus, "train", None, caption_mix=mix,
                                      caption_mix_within=within, **kw)  # fmt: skip
        crossed_style = 0
        swapped = total = 0
        for epoch in range(6):
            plain.set_epoch(epoch), mixed.set_epoch(epoch)
            for i, (clip, _, _) in enumerate(plain.items):
                if clip.num_people != 1:
                    continue
                a, b = plain[i], mixed[i]
                assert (a["start"], a["length"], a["mirrored"]) == (b["start"], b["length"],
                                                                    b["mirrored"])  # fmt: skip
                torch.testing.assert_close(a["features"], b["features"])
                whose, (label, style) = owner[b["caption"]]
                assert label == clip.meta["content"]
                if "style" in within:
                    assert style == clip.meta["style"]
                crossed_style += style != clip.meta["style"]
                swapped += whose != clip.id
                total += 1
        group = len(clips) / 2 ** len(within)  # the draw may be the clip itself
        want = mix * (1 - 1 / group)
        assert abs(swapped / total - want) < 0.15, (mix, within, swapped, total, want)
        assert (crossed_style > 0) == ("style" not in within)
    for bad in (-0.1, 1.5):
        with pytest.raises(UMFError, match="caption_mix must be between 0 and 1"):
            D.SingleMotionDataset(corpus, "train", None, caption_mix=bad)


def test_caption_mix_from_draws_only_the_matching_clips(corpus, monkeypatch):
    """``caption_mix_from`` ["style=old"]: mixed captions come from old-style clips of the
    item's label only, so an unmarked wording can stand for every style of its label."""
    clips = [c for c in corpus.split_clips("train") if c.num_people == 1]
    owner = {}
    for i, clip in enumerate(clips):
        style = "old" if i % 3 == 0 else "young"
        monkeypatch.setitem(clip.meta, "content", "walk")
        monkeypatch.setitem(clip.meta, "style", style)
        said = [f"clip {i} take {k}." for k in range(2)]
        monkeypatch.setattr(clip, "captions", said)
        owner.update({c: (clip.id, style) for c in said})
    mix = dict(caption_mix=1.0, caption_mix_within=("content",), caption_mix_from=("style=old",))
    ds = D.SingleMotionDataset(corpus, "train", None, 20, 60, seed=2, **mix)
    seen = set()
    for epoch in range(4):
        ds.set_epoch(epoch)
        for i, (clip, _, _) in enumerate(ds.items):
            if clip.num_people == 1:
                whose, style = owner[ds[i]["caption"]]
                assert style == "old"
                seen.add(whose)
    assert len(seen) > 1  # several donors, not one
    # items of rare labels repeat (balance): a donor still counts once in its group
    monkeypatch.setitem(clips[0].meta, "content", "rare")
    monkeypatch.setitem(clips[3].meta, "content", "rare")
    rep = D.SingleMotionDataset(corpus, "train", None, 20, 60, seed=2, balance=1.0, **mix)
    assert len(rep.items) > len(ds.items)
    assert [len(g) for g in rep.mix_groups.values()] == [
        len({id(c) for c in g}) for g in rep.mix_groups.values()
    ]
    assert len(rep.mix_groups[("rare",)]) == 2
    for bad in (("old",), ("=old",)):  # the same reading as the config check's
        with pytest.raises(UMFError, match="caption_mix_from takes key=value pairs"):
            D.SingleMotionDataset(corpus, "train", None, caption_mix=0.5, caption_mix_from=bad)
    # no clip has the keys (a corpus without such metadata): an error, not a silent no-op
    with pytest.raises(UMFError, match=r"caption_mix: no captioned clip .* \['no_such_key'\]"):
        D.SingleMotionDataset(
            corpus, "train", None, caption_mix=0.5, caption_mix_within=("no_such_key",)
        )
    off = D.SingleMotionDataset(corpus, "train", None, caption_mix_within=("no_such_key",))
    assert off.caption_mix == 0.0  # without mixing the keys are not needed


def test_caption_mix_reaches_the_training_split_only(corpus):
    from umf.config import small_config
    from umf.train.run import _loaders

    cfg = small_config()
    t = dataclasses.replace(cfg.train_pflow, caption_mix=0.5, num_workers=0)
    train, val, _ = _loaders("pflow", corpus, cfg, t, progress=False)
    single = [dl.dataset for dl in train.loaders if isinstance(dl.dataset, D.SingleMotionDataset)]
    assert [ds.caption_mix for ds in single] == [0.5]
    assert all(getattr(dl.dataset, "caption_mix", 0.0) == 0.0 for dl in val.loaders)


# --------------------------------------------------------------------- per-person prompts
def test_scene_items_carry_each_persons_own_caption_of_their_clip(corpus, monkeypatch):
    """The own captions are wordings of the clip each person plays, side words swapped
    when the item (or the person in the recipe) is mirrored, and their draw leaves every
    other draw of the item as it was."""
    ds = D.SceneDataset(corpus, "train", None, 20, 80, mirror=True, seed=4)
    captions = {c.id: c.captions for c in corpus.clips}
    flips = set()
    for i in range(len(ds)):
        it = ds[i]
        recipe = corpus.scenes["train"][i]
        assert len(it["person_captions"]) == it["num_people"]
        for p, own in zip(recipe["people"], it["person_captions"], strict=True):
            mirrored = it["mirrored"] != bool(p.get("mirrored"))
            flips.add(mirrored)
            assert (D.mirror_caption(own) if mirrored else own) in captions[p["clip"]]
    assert flips == {True, False}  # both kinds were checked
    # the own captions draw from a stream of their own: however many numbers they draw,
    # the crop, mirror and caption of the item stay as they were
    before = [ds[i] for i in range(len(ds))]

    def greedy(captions, rng, present=1.0):
        rng.random(1000)
        return captions[0] if captions else ""

    monkeypatch.setattr(D, "own_caption", greedy)
    for i, b in enumerate(before):
        a = ds[i]
        assert torch.equal(b["features"], a["features"]) and b["start"] == a["start"]
        assert b["caption"] == a["caption"] and b["mirrored"] == a["mirrored"]


def test_single_items_repeat_their_action_in_half_their_own_captions(corpus):
    ds = D.SingleMotionDataset(corpus, "train", None, 20, 80, mirror=True, seed=3)
    owns = []
    for epoch in range(30):
        ds.set_epoch(epoch)
        for i in range(len(ds)):
            it, clip = ds[i], ds.items[i][0]
            (own,) = it["person_captions"]
            owns.append(own)
            if own:
                assert (D.mirror_caption(own) if it["mirrored"] else own) in clip.captions
    share = sum(bool(o) for o in owns) / len(owns)
    assert abs(share - D.OWN_SINGLE) < 0.1, share
    ds.set_epoch(0)
    batch = ds.collate([ds[0], ds[1]])
    assert batch["person_captions"] == [ds[0]["person_captions"], ds[1]["person_captions"]]


def test_own_caption_present_share_and_empty_clips():
    rng = np.random.default_rng(0)
    assert D.own_caption([], rng) == ""
    draws = [D.own_caption(["a", "b"], rng, present=0.25) for _ in range(2000)]
    assert abs(draws.count("") / 2000 - 0.75) < 0.04
    assert {"a", "b"} <= set(draws)


def test_relation_repeats_serve_a_relations_scenes_more_often(corpus):
    from umf.config import key_times

    base = D.SceneDataset(corpus, "train", None, 20, 80, real_clips=False)
    rel = corpus.scenes["train"][0]["relation"]
    more = D.SceneDataset(corpus, "train", None, 20, 80, real_clips=False,
                          relation_repeats={rel: 3})  # fmt: skip
    count = sum(r["relation"] == rel for r in corpus.scenes["train"])
    assert len(more) == len(base) + 2 * count
    assert sum(it[1]["relation"] == rel for it in more.items) == 3 * count
    assert key_times(["stand_facing=4"]) == {"stand_facing": 4}
    for bad in (["stand_facing"], ["stand_facing=0"], ["stand_facing=x"]):
        with pytest.raises(UMFError, match="relation_repeats"):
            key_times(bad)


# --------------------------------------------------------------------- scenes carried on
def _striding_actors(corpus, cut: int = 70, cycle: int = 24) -> dict:
    """Two actors whose clips are ``cut`` frames of an exactly periodic walk (joints and
    rotations tiled alike): clips that end in a steady, straight gait."""
    from umf.data.scenes import Actor

    walks = [c for s in ("train", "val", "test") for c in corpus.split_clips(s) if "_walk_" in c.id]
    walk = max(walks, key=lambda c: c.num_frames)
    j, r = np.asarray(walk.joints[0], dtype=np.float64), np.asarray(walk.rot6d[0])
    travel = (j[40 + cycle, 0] - j[40, 0]) * np.array([1.0, 0.0, 1.0])
    reps = cut // cycle + 1
    joints = np.concatenate([j[40 : 40 + cycle] + k * travel for k in range(reps)])[:cut]
    rot = np.concatenate([r[40 : 40 + cycle]] * reps)[:cut]
    return {name: Actor.from_joints(name, joints.astype(np.float32), "walk", "", rot)
            for name in ("walker-a", "walker-b")}  # fmt: skip


def _recipe(gap: tuple[float, float], yaw: float, constraints: list[dict], frames: int = 70):
    person = {"delay": 0, "start": 0, "mirrored": False}
    return {"id": "scene-walk", "relation": "walk_side_by_side", "num_people": 2,
            "num_frames": frames, "captions": ["Two people walk side by side."],
            "people": [{**person, "clip": "walker-a", "yaw": 0.0, "xz": (0.0, 0.0)},
                       {**person, "clip": "walker-b", "yaw": yaw, "xz": gap}],
            "constraints": constraints}  # fmt: skip


SIDE_BY_SIDE = [{"type": "distance", "a": 0, "b": 1, "min": 0.6, "max": 1.6},
                {"type": "same_heading", "a": 0, "b": 1}]  # fmt: skip


def test_scene_gait_periods_carry_on_striders_only_while_their_relation_holds(corpus):
    from umf.data.relations import check
    from umf.data.scenes import build_scene

    actors = _striding_actors(corpus)
    side = _recipe((1.0, 0.0), 0.0, SIDE_BY_SIDE)
    assert E.scene_gait_periods(build_scene(side, actors), side, 200) == [24, 24]
    assert E.scene_gait_periods(build_scene(side, actors), side, 60) is None  # long enough
    # one of them stands still: nothing to carry on
    stands = np.repeat(actors["walker-b"].joints[:1], 70, axis=0)
    still = {**actors, "walker-b": dataclasses.replace(actors["walker-b"], joints=stands)}
    assert E.scene_gait_periods(build_scene(side, still), side, 200) is None
    # walking towards each other: met after 120 frames, so carried on they would collide
    pelvis = actors["walker-a"].joints[:, 0, [0, 2]]
    speed = float(np.linalg.norm(pelvis[-1] - pelvis[0])) / 69  # m/frame
    no_contact = [{"type": "no_contact", "min_distance": 0.25},
                  {"type": "same_heading", "a": 0, "b": 0}]  # fmt: skip
    toward = _recipe((0.0, 2 * speed * 120), math.pi, no_contact)
    joints = build_scene(toward, actors)
    assert check(joints, toward["constraints"][0]).passed  # the 70 frames composed
    assert E.scene_gait_periods(joints, toward, 200) is None
    # people who do not travel together are not carried on, even where nothing would fail
    apart = _recipe((0.0, 50.0), math.pi, no_contact[:1])
    assert E.scene_gait_periods(build_scene(apart, actors), apart, 200) is None
    apart["constraints"] = no_contact
    assert E.scene_gait_periods(build_scene(apart, actors), apart, 200) == [24, 24]


def test_repeat_scene_gait_serves_short_striding_scenes_whole_carried_on(corpus, monkeypatch):
    actors = _striding_actors(corpus)
    side = _recipe((1.0, 0.0), 0.0, SIDE_BY_SIDE)
    monkeypatch.setattr(corpus, "scenes", {"train": [side]})
    monkeypatch.setattr(corpus, "actors", lambda: actors)
    plain = D.SceneDataset(corpus, "train", None, 100, 130, mirror=False, real_clips=False)
    assert not plain.extended and plain[0]["length"] == 69  # the whole scene, no more
    ds = D.SceneDataset(corpus, "train", None, 100, 130, mirror=False, real_clips=False,
                        repeat_gait=True)  # fmt: skip
    assert ds.extended == {"scene-walk": [24, 24]}
    for epoch in range(3):
        ds.set_epoch(epoch)
        it = ds[0]
        assert it["start"] == 0 and 100 <= it["length"] <= 130
        f = it["features"]
        own = D.canonicalize_features(torch.from_numpy(corpus.scene_features(side)))
        torch.testing.assert_close(f[:, :68], own[:, :68], atol=1e-5, rtol=0)  # as composed
        joints = features_to_joints(f.double()).numpy()
        pose = joints - joints[:, :, :1]  # one cycle on, every pose comes round again
        np.testing.assert_allclose(pose[:, 69 + 24], pose[:, 69], atol=1e-4)
        gap = joints[1, :, 0, [0, 2]] - joints[0, :, 0, [0, 2]]  # still side by side
        np.testing.assert_allclose(gap[:, -1], gap[:, 0], atol=1e-3)


def test_leader_gait_carries_person_1_on_and_holds_the_others(corpus, monkeypatch):
    """``leader_gait`` (the P-Flow's scenes): person 1 striding at the end repeats their last
    cycle whatever the others do; the others hold their last pose; a walk up to someone is
    not carried past them."""
    actors = _striding_actors(corpus)
    stands = np.repeat(actors["walker-b"].joints[:1], 70, axis=0)
    actors["walker-b"] = dataclasses.replace(actors["walker-b"], joints=stands)
    side = _recipe((1.0, 0.0), 0.0, SIDE_BY_SIDE)  # person 2 stands: no whole-scene gait
    toward = {**_recipe((0.0, 6.0), math.pi, []), "id": "toward", "relation": "walk_toward"}
    monkeypatch.setattr(corpus, "scenes", {"train": [side, toward]})
    monkeypatch.setattr(corpus, "actors", lambda: actors)
    both = D.SceneDataset(corpus, "train", None, 100, 130, mirror=False, real_clips=False,
                          repeat_gait=True)  # fmt: skip
    assert not both.extended
    ds = D.SceneDataset(corpus, "train", None, 100, 130, mirror=False, real_clips=False,
                        leader_gait=True)  # fmt: skip
    assert ds.extended == {"scene-walk": [24, 0]}  # the walk up to someone stays as it is
    it = ds[0]
    assert it["start"] == 0 and 100 <= it["length"] <= 130
    joints = features_to_joints(it["features"].double()).numpy()
    pose = joints[0] - joints[0, :, :1]
    np.testing.assert_allclose(pose[69 + 24], pose[69], atol=1e-4)  # person 1 strides on
    travel = np.linalg.norm(joints[0, -1, 0, [0, 2]] - joints[0, 68, 0, [0, 2]])
    assert travel > 0.3
    np.testing.assert_allclose(joints[1, 69:], joints[1, 68:-1], atol=1e-4)  # person 2 held
    assert ds[1]["length"] == 69  # walk_toward: served whole, no longer


def test_repeat_leader_gait_is_the_p_flows_only():
    from umf.config import UMFConfig, set_option
    from umf.errors import UMFError
    from umf.train.run import check_run_config

    cfg = set_option(UMFConfig(), "train_pflow.repeat_leader_gait=true")
    check_run_config(cfg)
    with pytest.raises(UMFError, match=r"train_sflow\.repeat_leader_gait: only the P-Flow"):
        check_run_config(set_option(cfg, "train_sflow.repeat_leader_gait=true"))
