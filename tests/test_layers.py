"""The house: every import in src/umf points down a layer or across one, no circles, no
file over 600 lines (scripts/import_graph.py draws and explains the layers)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "import_graph.py"


@pytest.fixture(scope="module")
def ig():
    spec = importlib.util.spec_from_file_location("import_graph", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def graph(ig):
    return ig.graph()


def test_imports_inside_functions_and_relative_imports_are_arrows(ig, tmp_path, monkeypatch):
    """The reader must see what runs: an import inside a function, a relative import and
    ``from package import module`` are arrows like any other."""
    pkg = tmp_path / "umf"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "low.py").write_text("X = 1\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "leaf.py").write_text("Y = 2\n")
    (pkg / "high.py").write_text(
        "def f():\n    from umf.low import X\n    return X\nfrom .sub import leaf\n"
    )
    (pkg / "sub" / "rel.py").write_text("from ..low import X\nfrom . import leaf\n")
    monkeypatch.setattr(ig, "SRC", pkg)
    g = ig.graph()
    assert g["umf.high"] == {"umf.low", "umf.sub.leaf"}
    assert g["umf.sub.rel"] == {"umf.low", "umf.sub.leaf"}
    (pkg / "low.py").write_text("import umf.high\n")
    assert ig.circles(ig.graph()) == [["umf.high", "umf.low"]]


def test_no_import_circle(ig, graph):
    assert ig.circles(graph) == []


def test_every_import_points_down_or_across(ig, graph):
    assert ig.upward(graph) == []


def test_every_module_has_a_layer_and_no_file_is_too_long(ig, graph):
    for name in graph:
        ig.layer_of(name)  # exits naming the module when it has none
    assert ig.long_files() == []


def test_inference_never_imports_training(graph):
    inference = [m for m in graph if not m.startswith(("umf.train", "umf.cli", "umf.serve"))
                 and m not in ("umf", "umf.__main__")]  # fmt: skip
    assert [(m, t) for m in inference for t in graph[m] if t.startswith("umf.train")] == []


def test_the_picture_in_the_docs_is_drawn_from_todays_imports(ig, graph, tmp_path):
    """docs/images/architecture.svg is what scripts/import_graph.py draws now (redraw it
    with `python scripts/import_graph.py --svg docs/images/architecture.svg`)."""
    out = tmp_path / "architecture.svg"
    ig.draw(ig.packages(graph), out)
    committed = SCRIPT.parents[1] / "docs" / "images" / "architecture.svg"
    assert out.read_bytes() == committed.read_bytes(), "redraw docs/images/architecture.svg"
