"""The mocap importer: skeleton tables, units, frame rates, DeepMimic, captions, takes.

Fixtures are written here (a fresh clone has no mocap library); the real CMU salsa,
handshake and DeepMimic files of ../shared are checked too, skipped without them.
"""

from __future__ import annotations

import json
import tarfile
from pathlib import Path

import numpy as np
import pytest

from umf.data.deepmimic import FRAME_WIDTH, HUMANOID3D, forward_kinematics, read_deepmimic
from umf.data.mocap import load_mocap, read_motion, scan_library, tile_loop
from umf.data.relations import facing_dirs, pair_closeness
from umf.data.skeletons import SKELETONS, normal_name, recognise
from umf.errors import UMFError
from umf.skeleton import JOINT_NAMES
from umf.units import NOMINAL_SPAN, body_span, choose_unit

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def _names(table) -> list[str]:
    out: list[str] = []
    for s in table:
        for n in s if isinstance(s, tuple) else (s.removeprefix("end:"),):
            if n not in out:
                out.append(n)
    return out


def star_bvh(names, offsets, root_path, fps=30.0, prefix="", end_sites=None) -> str:
    """A BVH whose joints all hang off the root at fixed offsets (no joint rotation), the
    root moving along ``root_path`` (F, 3): every joint's position is known exactly."""
    root = "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
    lines = ["HIERARCHY", f"ROOT {prefix}{names[0]}", "{", "  OFFSET 0 0 0", root]
    for n, off in zip(names[1:], offsets[1:], strict=True):
        lines += [f"  JOINT {prefix}{n}", "  {", "    OFFSET " + " ".join(f"{v:.6f}" for v in off),
                  "    CHANNELS 3 Zrotation Xrotation Yrotation"]  # fmt: skip
        end = (end_sites or {}).get(n, (0.0, 0.0, 0.01))
        lines += [
            "    End Site",
            "    {",
            "      OFFSET " + " ".join(map(str, end)),
            "    }",
            "  }",
        ]
    lines += ["}", "MOTION", f"Frames: {len(root_path)}", f"Frame Time: {1.0 / fps:.8f}"]
    zeros = " ".join(["0"] * (3 + 3 * (len(names) - 1)))
    lines += [" ".join(f"{v:.6f}" for v in p) + " " + zeros for p in root_path]
    return "\n".join(lines) + "\n"


def _layout(names: list[str], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    off = rng.normal(scale=0.2, size=(len(names), 3))
    off[0] = 0
    return off


@pytest.mark.parametrize("key", ["bandai", "cmu-cgspeed", "cmu-daz", "mixamo", "smpl", "smpl-long"])
def test_every_table_maps_its_joints_exactly(tmp_path, key):
    table = SKELETONS[key]
    names = _names(table)
    off = _layout(names) * 100.0  # centimetres
    path = np.stack([np.linspace(0, 50, 20), np.full(20, 90.0), np.zeros(20)], axis=1)
    ends = {"lFoot": (0.0, -3.0, 12.0), "rFoot": (0.0, -3.0, 12.0)}
    prefix = "mixamorig:" if key == "mixamo" else ""
    bvh = tmp_path / f"{key}.bvh"
    bvh.write_text(star_bvh(names, off, path, prefix=prefix, end_sites=ends))
    raw = read_motion(bvh)
    assert raw.skeleton == key.removesuffix("-long")
    at = {n: path[:, None] + off[i] for i, n in enumerate(names)}
    for j, src in enumerate(table):
        if isinstance(src, tuple):
            want = 0.5 * (at[src[0]] + at[src[1]])
        elif src.startswith("end:"):
            want = at[src[4:]] + np.array(ends[src[4:]])
        else:
            want = at[src]
        assert np.abs(raw.joints[:, j] - want[:, 0]).max() < 1e-4, JOINT_NAMES[j]


def test_names_are_compared_without_namespace_case_or_separators():
    assert normal_name("mixamorig:LeftUpLeg") == normal_name("left_up_leg") == "leftupleg"
    assert normal_name("L_Hip") == normal_name("l_hip")
    assert recognise([f"Character1:{n}" for n in _names(SKELETONS["mixamo"])]).name == "mixamo"


def test_an_unknown_skeleton_is_one_line_naming_skeleton_json(tmp_path):
    names = ["root", "a", "b"]
    (tmp_path / "x.bvh").write_text(star_bvh(names, _layout(names), np.zeros((3, 3))))
    with pytest.raises(UMFError, match=r"skeleton\.json"):
        read_motion(tmp_path / "x.bvh")


def test_a_mapping_that_collapses_a_bone_is_refused(tmp_path):
    names = [f"j{i}" for i in range(22)]
    joints = dict(zip(JOINT_NAMES, names, strict=True))
    joints["neck"] = joints["spine3"]  # two of our joints on one of theirs
    (tmp_path / "x.bvh").write_text(star_bvh(names, _layout(names), np.zeros((4, 3))))
    (tmp_path / "skeleton.json").write_text(json.dumps({"joints": joints}))
    problems: list = []
    assert list(load_mocap(tmp_path, problems)) == []
    assert "puts neck and spine3 at one point" in problems[0][1]


def test_skeleton_json_maps_any_skeleton_and_sets_unit_and_fps(tmp_path):
    names = [f"j{i}" for i in range(22)]
    off = _layout(names)
    path = np.stack([np.zeros(31), np.full(31, 0.9), np.linspace(0, 1, 31)], axis=1)
    (tmp_path / "x.bvh").write_text(star_bvh(names, off * 2, path * 2, fps=120.0))
    mapping = {"joints": dict(zip(JOINT_NAMES, names, strict=True)), "unit": 0.5, "fps": 60}
    (tmp_path / "skeleton.json").write_text(json.dumps(mapping))
    clips = list(load_mocap(tmp_path, []))
    assert len(clips) == 1
    c = clips[0]
    assert c.meta["unit"] == 0.5 and c.meta["source_fps"] == 60
    assert c.num_frames == 16  # 31 frames at 60 fps = 0.5 s = 16 frames at 30 fps
    assert np.abs(c.joints[0, 0] - (path[0] + off)).max() < 1e-4


@pytest.mark.parametrize(
    ("doc", "needle"),
    [({"joints": {"pelvis": "a"}}, "no entry for"), ({"joints": {"hip": "a"}}, "unknown joint"),
     ({"unit": "furlong"}, "unit"), ({"fps": 0}, "fps"), ([1], "JSON object")],
)  # fmt: skip
def test_bad_skeleton_json_is_one_line(tmp_path, doc, needle):
    (tmp_path / "skeleton.json").write_text(json.dumps(doc))
    with pytest.raises(UMFError, match=needle):
        scan_library(tmp_path)


@pytest.mark.parametrize("unit", [1.0, 0.01, 0.001, 0.0254, 0.0254 / 0.45])
def test_units_and_the_stature_scale(real_joints, unit):
    joints = real_joints.numpy()
    u, how = choose_unit(joints / unit)
    assert u == pytest.approx(unit)
    assert how != "stature"
    small = joints * 0.7  # 0.7 of an adult: no unit explains it
    u, how = choose_unit(small)
    assert how == "stature" and body_span(small * u) == pytest.approx(NOMINAL_SPAN)


def _deepmimic_rows(n: int, root_y: float = 0.9, yaw: float = 0.0) -> np.ndarray:
    rows = np.zeros((n, FRAME_WIDTH))
    rows[:, 0] = 1 / 60
    rows[:, 2] = root_y
    col = 1
    for _, _, _, dof in HUMANOID3D:
        if dof == 7:
            rows[:, col + 3] = np.cos(yaw / 2)
            rows[:, col + 5] = np.sin(yaw / 2)  # about +Y
        elif dof == 4:
            rows[:, col] = 1.0
        col += dof
    return rows


def test_deepmimic_forward_kinematics_follows_the_character():
    pos, _ = forward_kinematics(_deepmimic_rows(2))
    names = [n for n, *_ in HUMANOID3D]
    knee = pos[0, names.index("left_knee")]
    assert knee == pytest.approx([0.0, 0.9 - 0.421546, -0.084887])
    # a quarter turn of the root about +Y turns the hips: z offset -> x offset
    pos, _ = forward_kinematics(_deepmimic_rows(2, yaw=np.pi / 2))
    assert pos[0, names.index("left_hip")] == pytest.approx([-0.084887, 0.9, 0.0], abs=1e-6)
    # a bent knee (revolute, about its z axis) moves the ankle forward (+x) or back
    rows = _deepmimic_rows(1)
    knee_col = 1 + sum(d for _, _, _, d in HUMANOID3D[: names.index("left_knee")])
    rows[:, knee_col] = -np.pi / 2
    pos, _ = forward_kinematics(rows)
    ankle = pos[0, names.index("left_ankle")] - pos[0, names.index("left_knee")]
    assert abs(ankle[0]) == pytest.approx(0.40987) and abs(ankle[1]) < 1e-9


def test_deepmimic_file_reads_as_smpl22(tmp_path):
    f = tmp_path / "m.txt"
    f.write_text(json.dumps({"Loop": "none", "Frames": _deepmimic_rows(30).tolist()}))
    joints, fps, loops = read_deepmimic(f)
    assert joints.shape == (30, 22, 3) and fps == pytest.approx(60) and not loops
    assert joints[0, 15, 1] > joints[0, 12, 1] > joints[0, 9, 1] > joints[0, 0, 1]  # upright
    bad = tmp_path / "bad.txt"
    bad.write_text(json.dumps({"Frames": [[0.1, 1, 2]]}))
    with pytest.raises(UMFError, match="44 numbers"):
        read_deepmimic(bad)


def test_a_loop_is_repeated_where_it_ended():
    t = np.arange(11, dtype=np.float32)
    joints = np.zeros((11, 22, 3), np.float32)
    joints[:, 1, 0], joints[:, 2, 0] = 0.1, -0.1  # hips across x: facing +z or -z
    joints[:, 16, 0], joints[:, 17, 0] = 0.2, -0.2
    joints[..., 2] += (t * 0.1)[:, None]  # walking 1 m along z
    out = tile_loop(joints, 40)
    assert len(out) >= 40 and len(out) == 11 + 10 * 3
    assert np.allclose(np.diff(out[:, 0, 2]), 0.1, atol=1e-5)  # one steady walk
    assert np.allclose(facing_dirs(out[-1]), facing_dirs(joints[0]))


def _two_person_library(tmp_path: Path, lengths=(40, 40), fps=(30.0, 30.0)) -> Path:
    """Two SMPL-named bodies (a real standing pose) one metre apart, in CMU units."""
    from conftest import BANDAI_FIXTURE
    from umf.data.motion_file import load_motion

    walk = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data"
    pose = load_motion(walk / "dataset-1_walk_normal_001.bvh").joints[0, 0].astype(np.float64)
    names = list(JOINT_NAMES)
    off = (pose - pose[0]) / 0.05644
    for k, (n, f) in enumerate(zip(lengths, fps, strict=True)):
        path = np.stack([np.full(n, k * 1.0), np.full(n, pose[0, 1]), np.linspace(0, 1, n)], 1)
        path /= 0.05644
        (tmp_path / f"p{k + 1}.bvh").write_text(star_bvh(names, off, path, fps=f))
    (tmp_path / "takes.csv").write_text("take,file,person\nmeet,p1.bvh,1\nmeet,p2.bvh,2\n")
    (tmp_path / "captions.csv").write_text(
        "file,caption,label\nmeet,Two people meet.,meet\nmeet,Two people come together.,meet\n"
    )
    return tmp_path


def test_a_take_is_one_clip_of_its_people_in_their_shared_frame(tmp_path):
    lib = _two_person_library(tmp_path)
    (clip,) = list(load_mocap(lib, []))
    assert clip.num_people == 2 and clip.captions == [
        "Two people meet.",
        "Two people come together.",
    ]
    assert clip.meta["take"] == "meet" and clip.meta["content"] == "meet"
    assert clip.meta["unit_from"] == "cmu"
    gap = clip.joints[1, :, 0, 0] - clip.joints[0, :, 0, 0]
    assert np.allclose(gap, 1.0, atol=1e-4)  # one metre apart, as captured
    assert clip.meta["measured"]["pairs"]["1-2"]["pelvis_m"] == pytest.approx(1.0, abs=1e-3)


def test_placement_correction_moves_one_person(tmp_path):
    lib = _two_person_library(tmp_path)
    (lib / "takes.csv").write_text(
        "take,file,person,dx,dz\nmeet,p1.bvh,1,0,0\nmeet,p2.bvh,2,-0.5,0\n"
    )
    (clip,) = list(load_mocap(lib, []))
    assert np.allclose(clip.joints[1, :, 0, 0] - clip.joints[0, :, 0, 0], 0.5, atol=1e-4)


def test_a_takes_people_get_their_own_captions_and_scene_items_serve_them(tmp_path):
    """takes.csv's caption column: what each person does in the take (per-person prompts);
    a person without one has none."""
    from umf.train.datasets import SceneDataset

    (tmp_path / "lib").mkdir()
    lib = _two_person_library(tmp_path / "lib")
    (lib / "takes.csv").write_text("take,file,person,caption\nmeet,p1.bvh,1,A person leads.\n"
                                   "meet,p2.bvh,2,\n")  # fmt: skip
    (clip,) = list(load_mocap(lib, []))
    assert clip.meta["person_captions"] == [["A person leads."], []]
    (lib / "takes.csv").write_text("take,file,person\nmeet,p1.bvh,1\nmeet,p2.bvh,2\n")
    (plain,) = list(load_mocap(lib, []))
    assert "person_captions" not in plain.meta

    ds = object.__new__(SceneDataset)  # the own-caption draw alone: a take needs no corpus
    ds.seed, ds.epoch = 0, 0
    assert ds._own_captions("clip", clip, 0) == ["A person leads.", ""]
    assert ds._own_captions("clip", plain, 0) == ["", ""]


@pytest.mark.parametrize(("lengths", "fps", "needle"),
                         [((40, 30), (30.0, 30.0), "different lengths"),
                          ((40, 40), (30.0, 60.0), "different frame rates")])  # fmt: skip
def test_a_take_whose_files_disagree_is_an_error_naming_it(tmp_path, lengths, fps, needle):
    lib = _two_person_library(tmp_path, lengths, fps)
    with pytest.raises(UMFError, match=f"take 'meet'.*{needle}"):
        list(load_mocap(lib, []))


@pytest.mark.parametrize(
    ("name", "text", "needle"),
    [("captions.csv", "name,caption\n", "header must be file,caption"),
     ("captions.csv", "file,caption\nnope.bvh,hi\n", "no motion file or take 'nope.bvh'"),
     ("captions.csv", "file,caption\np1.bvh,\n", "line 2: empty caption"),
     ("takes.csv", "take,file,person\nt,p1.bvh,1\nt,p2.bvh,3\n", "1..2"),
     ("takes.csv", "take,file,person\nt,p1.bvh,x\n", "whole number"),
     ("takes.csv", "take,file,person\nt,p1.bvh,1\nu,p1.bvh,1\n", "more than one take")],
)  # fmt: skip
def test_malformed_tables_are_one_line_naming_file_and_line(tmp_path, name, text, needle):
    lib = _two_person_library(tmp_path)
    (lib / "takes.csv").unlink()
    (lib / "captions.csv").unlink()
    (lib / name).write_text(text)
    with pytest.raises(UMFError, match=needle):
        scan_library(lib)


def test_broken_and_uncaptioned_files_are_reported_not_raised(tmp_path):
    lib = _two_person_library(tmp_path)
    (lib / "broken.bvh").write_text("HIERARCHY\nROOT a {\n")
    (lib / "notes.txt").write_text("just notes")
    names = _names(SKELETONS["smpl"])
    (lib / "jump_up-02.bvh").write_text(star_bvh(names, _layout(names) * 8, np.zeros((10, 3))))
    problems: list = []
    clips = list(load_mocap(lib, problems))
    assert sorted(c.id for c in clips) == [f"{lib.name}/jump_up-02", f"{lib.name}/meet"]
    reasons = {Path(p).name: r for p, r in problems}
    assert "broken.bvh" in reasons and "notes.txt" in reasons
    assert "captioned 'a person: jump up'" in reasons["jump_up-02.bvh"]


def test_prepare_keeps_takes_whole_and_records_the_library(tmp_path):
    from conftest import BANDAI_FIXTURE
    from umf.data.corpus import Corpus, PrepareConfig, mocap_sources, prepare_corpus

    (tmp_path / "lib").mkdir()
    lib = _two_person_library(tmp_path / "lib")
    sources = {"bandai": BANDAI_FIXTURE, **mocap_sources([lib])}
    cfg = PrepareConfig(train_scenes=20, val_scenes=4, test_scenes=4, test_groups=2)
    manifest = prepare_corpus(tmp_path / "c", sources, cfg, progress=False, log=lambda s: None)
    assert [s["name"] for s in manifest["sources"]] == ["bandai", "mocap-lib"]
    corpus = Corpus.load(tmp_path / "c")
    (take,) = [c for c in corpus.clips if c.source == "mocap"]
    assert take.num_people == 2 and take.split in ("train", "val", "test")


@pytest.mark.parametrize("lib", ["cmu-salsa", "cmu-handshake", "deepmimic"])
def test_real_libraries_import(tmp_path, lib):
    archive = SHARED / lib / f"{lib}.tar.xz"
    if not archive.exists():
        pytest.skip(f"{archive} not present (../shared holds the real mocap)")
    with tarfile.open(archive) as tf:
        tf.extractall(tmp_path, filter="data")
    folder = tmp_path / lib
    for f in (Path(__file__).resolve().parents[1] / "data" / "mocap" / lib).iterdir():
        (folder / f.name).write_bytes(f.read_bytes())
    problems: list = []
    clips = {c.id.split("/", 1)[1]: c for c in load_mocap(folder, problems)}
    assert not [p for p in problems if "captioned" in p[1]]  # every file has its captions
    if lib == "cmu-salsa":
        assert len(clips) == 12 and all(c.num_people == 2 for c in clips.values())
        c = clips["salsa-01"]
        assert c.meta["source_fps"] == 60 and c.meta["unit_from"] == "stature"
        close = pair_closeness(c.joints)
        assert close["hands_near"] > 0.5 and 0.3 < close["pelvis"] < 0.8 and close["facing"] > 0.5
        assert close["min_joint_m"] > 0.0  # real partners never coincide
    elif lib == "cmu-handshake":
        (c,) = clips.values()
        hands = np.linalg.norm(c.joints[0, :, 21] - c.joints[1, :, 21], axis=-1)
        assert 0.1 < hands.min() < 0.2  # the placement correction: right hands meet
        # they walk toward each other: each one's velocity points where they face
        v = np.diff(c.joints[:, :, 0, [0, 2]], axis=1)[:, :20].sum(1)
        f = facing_dirs(c.joints[:, 0])
        assert ((v * f).sum(-1) > 0).all()
    else:
        j = {k.removeprefix("motions/humanoid3d_"): c.joints[0] for k, c in clips.items()}
        assert (j["backflip"][:, 15, 1] < j["backflip"][:, 0, 1]).any()  # head below pelvis
        assert (j["cartwheel"][:, 15, 1] < j["cartwheel"][:, 0, 1]).any()
        assert np.median(j["crawl"][:, 0, 1]) < 0.6
        assert j["jump"][:, 0, 1].max() - np.median(j["jump"][:, 0, 1]) > 0.15
        assert j["getup_faceup"][0, 0, 1] < 0.4 and j["getup_faceup"][-1, 15, 1] > 1.2  # gets up
        walk = j["walk"]
        v = np.diff(walk[:, 0, [0, 2]], axis=0).sum(0)
        assert (facing_dirs(walk[0]) @ v) > 0  # walks where it faces: left and right right


def test_the_worked_example_library_reads_back_what_it_was_made_from(tmp_path):
    """docs/teach.md's example: sample clips written as Mixamo rigs (a real hierarchy, in
    centimetres at 60 fps) come back as the same joints, metres at 30 fps."""
    from conftest import BANDAI_FIXTURE, load_script
    from umf.data.motion_file import load_motion

    script = load_script("example_library")
    import sys

    argv, sys.argv = sys.argv, ["example_library.py", str(tmp_path / "lib")]
    try:
        script.main()
    finally:
        sys.argv = argv
    problems: list = []
    clips = {c.id.split("/", 1)[1]: c for c in load_mocap(tmp_path / "lib", problems)}
    assert not problems and set(clips) == {
        "call-and-answer",
        "solo/front_kick",
        "solo/greeting_bow",
    }
    bow = clips["solo/greeting_bow"]
    assert bow.meta["skeleton"] == "mixamo" and bow.meta["unit_from"] == "cm"
    assert bow.meta["source_fps"] == 60 and bow.captions[0] == "A man bows deeply."
    src = BANDAI_FIXTURE / "Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001.bvh"
    want = load_motion(src).joints[0]
    assert bow.joints.shape[1] == want.shape[0]
    assert np.abs(bow.joints[0] - want).max() < 2e-4  # FK of the written rig, to 0.2 mm
    take = clips["call-and-answer"]
    assert take.num_people == 2 and take.meta["measured"]["pairs"]["1-2"]["facing"] > 0.9


def test_prepare_never_destroys_a_corpus_that_worked(tmp_path, monkeypatch):
    """A truncated conversion cache is rebuilt (saying so), and a prepare that fails
    part-way leaves the previous corpus whole and loadable."""
    import umf.data.corpus as corpus_mod
    from conftest import BANDAI_FIXTURE
    from umf.data.corpus import Corpus, PrepareConfig, prepare_corpus

    cfg = PrepareConfig(train_scenes=8, val_scenes=2, test_scenes=2, test_groups=1)
    out = tmp_path / "c"
    prepare_corpus(out, {"bandai": BANDAI_FIXTURE}, cfg, progress=False, log=lambda s: None)
    before = (out / "clips.json").read_text()
    (cache,) = (out / "cache").glob("bandai-*.npz")
    cache.write_bytes(cache.read_bytes()[:1000])  # truncated
    logs: list[str] = []
    prepare_corpus(out, {"bandai": BANDAI_FIXTURE}, cfg, progress=False, log=logs.append)
    assert any("unreadable" in m for m in logs)
    assert (out / "clips.json").read_text() == before

    def boom(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(corpus_mod, "fit_normalizer", boom)
    with pytest.raises(RuntimeError):
        prepare_corpus(out, {"bandai": BANDAI_FIXTURE}, cfg, progress=False, log=lambda s: None)
    assert len(Corpus.load(out).clips) == len(json.loads(before))  # the old one, whole
    assert not list(out.glob(".staging-*"))


def test_a_corrupt_corpus_is_one_line(tmp_path):
    from conftest import BANDAI_FIXTURE
    from umf.data.corpus import Corpus, PrepareConfig, prepare_corpus

    cfg = PrepareConfig(train_scenes=4, val_scenes=2, test_scenes=2, test_groups=1)
    out = prepare_corpus(tmp_path / "c", {"bandai": BANDAI_FIXTURE}, cfg, progress=False,
                         log=lambda s: None)  # fmt: skip
    assert out["total"]["clips"] > 0
    (tmp_path / "c" / "normalizer.safetensors").write_bytes(b"\x08\x00\x00\x00garbage!")
    with pytest.raises(UMFError, match=r"normalizer\.safetensors: unreadable"):
        _ = Corpus.load(tmp_path / "c").normalizer
    data = (tmp_path / "c" / "clips.npz").read_bytes()
    (tmp_path / "c" / "clips.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(UMFError, match="corrupt corpus"):
        Corpus.load(tmp_path / "c")


def test_a_source_without_a_readable_clip_leaves_nothing(tmp_path):
    from umf.data.corpus import mocap_sources, prepare_corpus

    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "broken.bvh").write_text("HIERARCHY\nROOT a {\n")
    with pytest.raises(UMFError, match="no readable clip"):
        prepare_corpus(tmp_path / "out", mocap_sources([lib]), progress=False, log=lambda s: None)
    assert not (tmp_path / "out").exists()
