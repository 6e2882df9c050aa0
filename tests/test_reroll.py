"""Re-rolling one person of a scene (`pipe.reroll`, `umf reroll`): the others bit for bit,
the new person from S-Flow with exactly the others as its context."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import MODULE, FakeText, save_tiny_model
from umf.errors import UMFError
from umf.pipeline import UMFPipeline

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope=MODULE)
def model(tmp_path_factory):
    return save_tiny_model(tmp_path_factory.mktemp("tiny") / "model", seed=1)


@pytest.fixture(scope=MODULE)
def pipe(model):
    return UMFPipeline.from_pretrained(model, text_encoder=FakeText())


@pytest.fixture(scope=MODULE)
def scene(pipe):
    return pipe("three people walk side by side", num_people=3, seconds=1.0, seed=4)[0]


def _closest(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a[:, :, None] - b[:, None], axis=-1).min())


@pytest.mark.parametrize("person", [1, 2, 3])
def test_everyone_else_is_bit_identical_and_the_person_is_new(pipe, scene, person):
    new = pipe.reroll(scene, person, seed=9)
    k = person - 1
    for i in range(3):
        if i == k:
            continue
        assert np.array_equal(new.joints[i], scene.joints[i])
        assert np.array_equal(new.raw_joints[i], scene.raw_joints[i])
        assert np.array_equal(new.features[i], scene.features[i])
        assert np.array_equal(new.bodies.rotations[i], scene.bodies.rotations[i])
        assert np.array_equal(new.bodies.root[i], scene.bodies.root[i])
        # the clean-up kept the new person off everyone else (the separation's 28 cm, fitted)
        assert _closest(new.joints[k], new.joints[i]) > 0.2
    assert np.abs(new.joints[k] - scene.joints[k]).max() > 0.05
    assert np.allclose(new.bodies.joints()[k], new.joints[k], atol=1e-5)  # joints are its FK
    assert new.meta["rerolled"] == [{"person": person, "seed": 9, "prompt": scene.text}]
    assert new.text == scene.text and new.seed == scene.seed
    again = pipe.reroll(scene, person, seed=9)
    assert np.array_equal(again.joints, new.joints)  # a function of the seed
    assert not np.allclose(pipe.reroll(scene, person, seed=10).joints[k], new.joints[k])


def test_the_context_is_everybody_else_encoded_in_the_first_ones_frame(pipe, scene, monkeypatch):
    from umf.representation import assemble_features, canonical_transform, joints_to_rot6d

    seen = []
    sample = pipe.sflow.sample

    def spy(prev, mask, *a, **k):
        seen.append((prev.clone(), mask.clone(), k["steps"]))
        return sample(prev, mask, *a, **k)

    monkeypatch.setattr(pipe.sflow, "sample", spy)
    pipe.reroll(scene, 1, seed=0)  # person 1: people 2 and 3 are the context, 2's frame
    ((prev, mask, steps),) = seen
    joints = torch.from_numpy(scene.joints)
    frame = canonical_transform(joints[1])
    want = []
    for i in (1, 2):
        j = frame.apply(joints[i])
        want.append(pipe._encode(assemble_features(j, joints_to_rot6d(j))[None])[0])
    assert prev.shape[:2] == (1, 2) and mask.all()
    assert torch.allclose(prev[0], torch.stack(want), atol=1e-4)
    assert steps == pipe.config.sflow.steps_for(3)


def test_a_prompt_of_its_own_changes_the_new_person_only(pipe, scene):
    a = pipe.reroll(scene, 2, seed=3)
    b = pipe.reroll(scene, 2, seed=3, prompt="a person bows politely")
    assert np.array_equal(a.joints[[0, 2]], b.joints[[0, 2]])
    assert not np.allclose(a.joints[1], b.joints[1])
    assert b.meta["rerolled"][0]["prompt"] == "a person bows politely"
    assert b.text == scene.text  # the scene keeps its prompt; the re-roll records its own


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"person": 0}, "person must be between 1 and 3"),
        ({"person": 4}, "person must be between 1 and 3"),
        ({"person": 1, "seed": -1}, "seed must be between"),
        ({"person": 1, "guidance": float("nan")}, "finite"),
        ({"person": 1, "sflow_steps": 201}, "sflow-steps must be between 1 and 200"),
        ({"person": 1, "prompt": ""}, "the prompt is empty"),
        ({"person": 1, "prompt": ["a", "b"]}, "must be a string"),
    ],
)
def test_bad_requests_are_one_clear_error(pipe, scene, kwargs, message):
    with pytest.raises(UMFError, match=message):
        pipe.reroll(scene, **kwargs)


def test_scenes_it_cannot_reroll(pipe, scene):
    (one,) = pipe("a person waves", num_people=1, seconds=1.0, seed=0)
    with pytest.raises(UMFError, match="one-person scene"):
        pipe.reroll(one, 1)
    from umf.scene import Scene

    slow = Scene(scene.joints, None, scene.text, 20.0, fit=False)
    with pytest.raises(UMFError, match="20 fps, the model at 30"):
        pipe.reroll(slow, 1)
    with pytest.raises(UMFError, match="takes a Scene"):
        pipe.reroll(scene.joints, 1)


def test_the_cli_keeps_the_file_people_and_refuses_bad_input(pipe, scene, model, tmp_path,
                                                            fake_text, capsys):  # fmt: skip
    from umf.cli.main import run

    src = scene.save(tmp_path / "in" / "scene", ["npz"])[0]
    with pytest.raises(SystemExit) as done:
        run(["reroll", str(src), "--person", "3", "--seed", "2", "--format", "npz,bvh",
             "--out", str(tmp_path / "out"), "--model", str(model)])  # fmt: skip
    assert done.value.code in (0, None)
    old, new = np.load(src), np.load(next((tmp_path / "out").glob("*.npz")))
    for key in ("joints", "rotations", "root", "offsets"):
        assert np.array_equal(new[key][:2], old[key][:2]), key
    assert not np.allclose(new["joints"][2], old["joints"][2])
    assert np.array_equal(new["joints"][2], pipe.reroll(scene, 3, seed=2).joints[2])
    assert len(list((tmp_path / "out").glob("*.bvh"))) == 3
    capsys.readouterr()
    from umf.scene import Scene

    long = Scene(np.concatenate([scene.joints] * 12, axis=1), None, scene.text, 30.0, fit=False)
    long_file = long.save(tmp_path / "in" / "long", ["npz"])[0]
    (one,) = pipe("a person waves", num_people=1, seconds=1.0, seed=0)
    one_file = one.save(tmp_path / "in" / "one", ["npz"])[0]
    for path, needle in ((long_file, "the model re-rolls scenes of at most"),
                         (one_file, "one person, nobody to react to")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_:
            run(["reroll", str(path), "--person", "1", "--out", str(tmp_path / "bad"),
                 "--model", str(model)])  # fmt: skip
        err = capsys.readouterr().err
        assert exit_.value.code == 1 and needle in err, err
    for bad, needle in ((["--person", "4"], "has 3 people, no person 4"),
                        (["--person", "1", "--sflow-steps", "0"], "between 1 and 200"),
                        (["--person", "1", "--prompt", " "], "the prompt is empty")):  # fmt: skip
        out = tmp_path / "bad"
        with pytest.raises(SystemExit) as exit_:
            run(["reroll", str(src), *bad, "--out", str(out), "--model", str(model)])
        err = capsys.readouterr().err
        assert exit_.value.code == 1 and err.startswith("umf: error:") and needle in err, err
        assert err.count("\n") == 1 and not list(out.glob("*.npz"))
