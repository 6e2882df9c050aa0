"""scripts/mutation_report.py: mutmut's exit codes read into a score per module."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conftest import load_script


def test_scores_count_killed_and_timeouts_and_leave_equivalents_out(tmp_path):
    report = load_script("mutation_report")
    meta = tmp_path / "mutants" / "src" / "umf" / "flows" / "paths.py.meta"
    meta.parent.mkdir(parents=True)
    name = "umf.flows.paths.x_f__mutmut_"
    codes = {f"{name}1": 1, f"{name}2": 0, f"{name}3": 36, f"{name}4": 33, f"{name}5": None,
             f"{name}6": 0, "umf.representation.x_g__mutmut_1": 1}  # fmt: skip
    meta.write_text(json.dumps({"exit_code_by_key": codes}))
    read = report.read_results(tmp_path / "mutants")
    assert read == codes
    assert report.module_of(f"{name}1") == "umf.flows.paths"
    modules = report.score(
        read, {f"{name}6": "x = 1"}, equivalent={("umf.flows.paths.x_f", "x = 1"): "same on a CPU"}
    )
    paths = modules["umf.flows.paths"]
    assert (paths["killed"], paths["timeout"], paths["survived"], paths["no tests"],
            paths["not run"], paths["equivalent"]) == (1, 1, 1, 1, 1, 1)  # fmt: skip
    assert paths["score"] == 0.5  # killed + timeout over killed + timeout + survived + no tests
    assert paths["survivors"] == [f"{name}2", f"{name}4"]
    assert modules["umf.representation"]["score"] == 1.0
    text = report.markdown(modules, {f"{name}2": "x = y", f"{name}6": "x = 1"})
    assert "| `umf.flows.paths` | 5 | 1 | 1 | 1 | 1 | 1 | 50.0 % |" in text
    assert f"- `{name}2`: `x = y`" in text and "same on a CPU" in text


def test_changed_lines_are_read_off_the_mutated_copies(tmp_path):
    report = load_script("mutation_report")
    copy = tmp_path / "mutants" / "src" / "umf" / "flows" / "paths.py"
    copy.parent.mkdir(parents=True)
    copy.write_text(
        "def x_f__mutmut_orig(a):\n    b = a + 1\n    return b * 2\n\n"
        "def x_f__mutmut_1(a):\n    b = a - 1\n    return b * 2\n\n"
        "def x_f__mutmut_2(a):\n    b = a + 1\n\n"
        "class C:\n    def xǁCǁg__mutmut_orig(self):\n        return 1\n"
        "    def xǁCǁg__mutmut_1(self):\n        return 2\n"
    )
    sources = report.mutant_sources(tmp_path / "mutants")
    assert set(sources) == {f"umf.flows.paths.{n}" for n in (
        "x_f__mutmut_orig", "x_f__mutmut_1", "x_f__mutmut_2", "xǁCǁg__mutmut_orig",
        "xǁCǁg__mutmut_1")}  # fmt: skip
    assert report.changed_line("umf.flows.paths.x_f__mutmut_1", sources) == "b = a - 1"
    assert report.changed_line("umf.flows.paths.x_f__mutmut_2", sources) == (
        "(removed: return b * 2)"
    )
    assert report.changed_line("umf.flows.paths.xǁCǁg__mutmut_1", sources) == "return 2"
    assert report.changed_line("umf.flows.paths.x_h__mutmut_1", sources) == ""
    codes = {"umf.flows.paths.x_f__mutmut_1": 0, "umf.flows.paths.x_f__mutmut_2": 0}
    diffs = {n: report.changed_line(n, sources) for n in codes}
    modules = report.score(codes, diffs, {("umf.flows.paths.x_f", "b = a - 1"): "same here"})
    paths = modules["umf.flows.paths"]
    assert paths["equivalents"] == {"umf.flows.paths.x_f__mutmut_1": "same here"}
    assert paths["survivors"] == ["umf.flows.paths.x_f__mutmut_2"] and paths["score"] == 0.0


def test_shared_fixtures_are_per_test_only_in_mutmuts_stats_run(monkeypatch):
    """mutmut credits a call to the test running when it happens: in its stats run a
    module fixture must be rebuilt by each test, elsewhere it stays shared."""
    from conftest import MODULE, SESSION

    monkeypatch.setenv("MUTANT_UNDER_TEST", "stats")
    assert MODULE("walk", None) == SESSION("walk", None) == "function"
    monkeypatch.setenv("MUTANT_UNDER_TEST", "umf.flows.paths.x_expand_time__mutmut_4")
    assert (MODULE("walk", None), SESSION("walk", None)) == ("module", "session")
    monkeypatch.delenv("MUTANT_UNDER_TEST")
    assert (MODULE("walk", None), SESSION("walk", None)) == ("module", "session")


def test_end_to_end_tests_run_only_for_their_own_modules_mutants():
    from types import SimpleNamespace

    from conftest import mutation_scope

    items = [SimpleNamespace(fspath=f"/x/tests/{name}") for name in
             ("test_flow_paths.py", "test_pipeline.py", "test_exports_agree.py")]  # fmt: skip

    def kept(mutant):
        return [Path(i.fspath).name for i in mutation_scope(items, mutant)[0]]

    assert kept("umf.flows.paths.x_expand_time__mutmut_4") == ["test_flow_paths.py"]
    assert kept("umf.exports.gltf.x__box__mutmut_3") == ["test_flow_paths.py"]
    everything = ["test_flow_paths.py", "test_pipeline.py", "test_exports_agree.py"]
    assert kept("umf.pipeline.x_clean_up__mutmut_1") == everything
    assert kept("stats") == kept("") == everything  # mutmut's stats run, plain pytest


def test_a_device_argument_set_to_none_or_dropped_is_equivalent_on_the_cpu():
    report = load_script("mutation_report")
    same = report.device_only
    line = "eps = torch.randn(z1.shape, generator=generator, device=z1.device, dtype=z1.dtype)"
    assert same(line, line.replace("device=z1.device", "device=None"))
    assert same(line, line.replace(" device=z1.device,", ""))
    assert same("x = torch.zeros(b, p, device=z.device)", "x = torch.zeros(b, p, )")
    assert not same(line, line.replace("dtype=z1.dtype", "dtype=None"))
    assert not same(line, line.replace("generator=generator", "generator=None"))
    assert not same("t = a + b", "t = a - b")


def test_each_named_mutation_still_finds_its_line_once():
    """scripts/named_mutations.py edits exact lines; a refactor that moves one must fail
    here, not leave the script testing nothing."""
    named = load_script("named_mutations")
    assert len(named.MUTATIONS) == 9
    for m in named.MUTATIONS:
        assert (named.REPO / m.path).read_text().count(m.before) == 1, m.name
        assert all((named.REPO / t).is_file() for t in m.tests), m.name


def test_a_rerun_of_the_survivors_keeps_the_earlier_kills(tmp_path):
    report = load_script("mutation_report")
    name = "umf.flows.noise.x_randn__mutmut_"
    previous = {"modules": {"umf.flows.noise": {
        "killed": 18, "survived": 3, "timeout": 1, "no tests": 0, "not run": 0,
        "equivalent": 1, "survivors": [f"{name}1", f"{name}2", f"{name}3"],
        "equivalents": {f"{name}4": "device"}}},
        "diffs": {f"{name}1": "a = 1", f"{name}2": "b = 2", f"{name}3": "c = 3",
                  f"{name}4": "d = 4"}}  # fmt: skip
    assert report.rerun_names(previous) == [f"{name}{i}" for i in (1, 2, 3, 4)]
    # the rerun kills one survivor, another still survives, one was not run
    codes = {f"{name}1": 1, f"{name}2": 0, f"{name}3": None, f"{name}4": 0}
    merged, carried = report.carry_over(codes, previous)
    assert merged == {f"{name}1": 1, f"{name}2": 0, f"{name}3": 0, f"{name}4": 0}
    assert carried == {"umf.flows.noise": {"killed": 18, "timeout": 1}}
    modules = report.score(
        merged,
        previous["diffs"],
        carried=carried,
        equivalent={("umf.flows.noise.x_randn", "d = 4"): "device"},
    )
    noise = modules["umf.flows.noise"]
    assert (noise["killed"], noise["timeout"], noise["survived"], noise["equivalent"]) == (
        19,
        1,
        2,
        1,
    )
    assert noise["survivors"] == [f"{name}2", f"{name}3"]
    assert noise["score"] == round(20 / 22, 4)
    with pytest.raises(ValueError, match=f"{name}9 was rerun but is no survivor"):
        report.carry_over({f"{name}9": 1}, previous)  # killed before: it would count twice


def test_a_sampled_module_is_scored_beside_the_earlier_report():
    report = load_script("mutation_report")
    names = [f"umf.pipeline.x_f__mutmut_{i}" for i in range(1, 101)]
    sample = report.sample_names(names, 10, seed=3)
    assert sample == sorted(sample) and len(set(sample)) == 10 and set(sample) <= set(names)
    assert sample == report.sample_names(list(reversed(names)), 10, seed=3)  # seeded, ordered
    assert sample != report.sample_names(names, 10, seed=4)
    noise = "umf.flows.noise.x_randn__mutmut_"
    previous = {"modules": {
        "umf.flows.noise": {"killed": 18, "survived": 1, "timeout": 1, "no tests": 0,
                            "not run": 0, "equivalent": 1, "survivors": [f"{noise}1"],
                            "equivalents": {f"{noise}2": "device"}},
        "umf.pipeline": {"killed": 0, "survived": 0, "timeout": 0, "no tests": 0,
                         "not run": 0, "equivalent": 0, "survivors": []}},
        "diffs": {f"{noise}1": "a = 1", f"{noise}2": "d = 4"}}  # fmt: skip
    codes = {n: None for n in names} | {sample[0]: 0} | {n: 1 for n in sample[1:]}
    run, kept, extra = report.carry_sample(codes, previous, "umf.pipeline", 100)
    assert run == {sample[0]: 0} | {n: 1 for n in sample[1:]}
    assert kept == {"umf.flows.noise": previous["modules"]["umf.flows.noise"]}  # as judged
    assert extra == {"umf.pipeline": {"sampled": 10, "population": 100}}
    with pytest.raises(ValueError, match=r"is not a mutant of the sampled umf\.pipeline"):
        report.carry_sample({f"{noise}7": 1}, previous, "umf.pipeline", 100)
    with pytest.raises(ValueError, match=r"no mutant of umf\.pipeline ran"):
        report.carry_sample({n: None for n in names}, previous, "umf.pipeline", 100)
    # a later rerun of the survivors leaves a sampled module to its own target
    sampled = dict(previous, modules=dict(previous["modules"], **{"umf.pipeline": {
        "killed": 9, "survived": 1, "timeout": 0, "no tests": 0, "not run": 90,
        "equivalent": 0, "survivors": [sample[0]], "sampled": 10, "population": 100}}))  # fmt: skip
    assert sample[0] not in report.rerun_names(sampled)
    assert "umf.pipeline" not in report.carry_over({}, sampled)[1]
    lo, hi = report.wilson(9, 10)
    assert 0.59 < lo < 0.6 and 0.98 < hi < 0.99  # Wilson's interval for 9 of 10
    assert report.wilson(10, 10)[1] == 1.0 and report.wilson(0, 0) == (0.0, 1.0)


def test_the_sample_names_are_mutmuts_own():
    pytest.importorskip("mutmut")
    report = load_script("mutation_report")
    names = report.module_names("umf.flows.noise")
    assert names and all(n.startswith("umf.flows.noise.x_") for n in names)
    assert all(report.module_of(n) == "umf.flows.noise" for n in names)
    assert len(set(names)) == len(names)
