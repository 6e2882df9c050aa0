"""The layers of `src/umf` as its imports draw them, checked and pictured.

    python scripts/import_graph.py [--svg docs/architecture.svg] [--check]

Reads every module's imports with :mod:`ast` (imports inside functions count: they run
too), places each module on its layer (:data:`LAYERS`, bottom first) and reports the
circles (strongly connected modules), the arrows that run up a layer and the files over
600 lines. ``--svg`` redraws the picture of ``docs/architecture.md``; ``--check`` exits 1
when the house has a circle, an arrow up or a file that is too long (``tests/test_layers.py``
runs the same check in ``make test``).
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "umf"
MAX_LINES = 600

# Bottom first. A module may import its own layer and those below, never one above. A
# module is placed by the longest prefix of its dotted name listed here ("umf" itself, the
# package's lazy front door ``from umf import UMFPipeline``, names only itself).
LAYERS: list[tuple[str, list[str]]] = [
    ("foundations", ["umf.version", "umf.errors", "umf.io", "umf.streams", "umf.rotations",
                     "umf.config", "umf.validation", "umf.units"]),
    ("body and representation", ["umf.skeleton", "umf.representation", "umf.body_frame",
                                 "umf.kinematics", "umf.bvh", "umf.humanml3d",
                                 "umf.capsules"]),
    ("text and flows", ["umf.text", "umf.flows"]),
    ("files: exports and pictures", ["umf.exports", "umf.writer", "umf.render",
                                     "umf.frame_files"]),
    ("motion container", ["umf.scene"]),
    ("data", ["umf.data"]),
    ("models", ["umf.models", "umf.checkpoint", "umf.model_checks"]),
    ("pipeline (Algorithm 1)", ["umf.pipeline", "umf.separation", "umf.anchoring",
                                "umf.coverage", "umf.reroll", "umf.person_prompts",
                                "umf.warm_start", "umf.clearance", "umf.path_follow",
                                "umf.warm_follow",
                                "umf.reaction_bank",
                                "umf.take_start",
                                "umf.untangle", "umf.clean_up"]),
    ("evaluation", ["umf.eval"]),
    ("training", ["umf.train"]),
    ("applications", ["umf", "umf.__main__", "umf.serve", "umf.cli"]),
]  # fmt: skip


def module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(SRC.rglob("*.py"))}


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """The umf modules ``name`` imports anywhere in its file (``from umf.x import y``
    counts as ``umf.x.y`` when that is a module, else ``umf.x``)."""
    tree = ast.parse(path.read_text(), str(path))
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()

    def add(target: str) -> None:
        while target and target not in known:
            target = target.rpartition(".")[0]
        if target and target != name:
            out.add(target)

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("umf"):
                    add(alias.name)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                mod = f"{base}.{node.module}" if node.module else base
            else:
                mod = node.module or ""
            if not mod.startswith("umf"):
                continue
            for alias in node.names:
                full = f"{mod}.{alias.name}"
                add(full if full in known else mod)
    return out


def graph() -> dict[str, set[str]]:
    mods = modules()
    known = set(mods)
    return {name: imports_of(name, path, known) for name, path in mods.items()}


def layer_of(name: str) -> int:
    best, depth = None, -1
    for k, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            inside = name == prefix or (prefix != "umf" and name.startswith(prefix + "."))
            if inside and prefix.count(".") > depth:
                best, depth = k, prefix.count(".")
    if best is None:
        raise SystemExit(f"{name}: on no layer (add it to LAYERS in {Path(__file__).name})")
    return best


def circles(g: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(g[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    sys.setrecursionlimit(10_000)
    for v in sorted(g):
        if v not in index:
            visit(v)
    return out


def upward(g: dict[str, set[str]]) -> list[tuple[str, str]]:
    """Arrows from a module to one on a higher layer."""
    return sorted((a, b) for a, targets in g.items() for b in targets
                  if layer_of(b) > layer_of(a))  # fmt: skip


def long_files() -> list[tuple[str, int]]:
    return [(name, n) for name, path in modules().items()
            if (n := len(path.read_text().splitlines())) > MAX_LINES]  # fmt: skip


def packages(g: dict[str, set[str]]) -> dict[str, set[str]]:
    """The graph with each package's modules drawn as one box (``umf.data.*`` ->
    ``umf.data``): the picture a newcomer reads first."""
    short = lambda name: ".".join(name.split(".")[:2])  # noqa: E731
    out: dict[str, set[str]] = defaultdict(set)
    for a, targets in g.items():
        out[short(a)] |= {short(b) for b in targets if short(b) != short(a)}
    return dict(out)


def draw(g: dict[str, set[str]], out: Path) -> None:
    """Layers as rows (bottom first), each module (or package) a box, each import an
    arrow; arrows between boxes of one layer bow above the row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # text as text and no date or random ids: the same imports draw the same file
    matplotlib.rcParams.update({"svg.fonttype": "none", "svg.hashsalt": "umf"})

    rows: dict[int, list[str]] = defaultdict(list)
    for name in sorted(g):
        rows[layer_of(name)].append(name)
    width = max(len(r) for r in rows.values())
    pos: dict[str, tuple[float, float]] = {}
    for k, names in rows.items():
        for i, name in enumerate(names):
            pos[name] = ((i + 0.5) * width / len(names), k * 1.6)
    fig, ax = plt.subplots(figsize=(max(14, width * 1.25), len(LAYERS) * 1.25))
    up = set(upward(g))
    for a in sorted(g):  # sorted: sets iterate in a different order every run
        for b in sorted(g[a]):
            if a in pos and b in pos:
                bad = (a, b) in up
                same = pos[a][1] == pos[b][1]
                ax.annotate("", xy=pos[b], xytext=pos[a], arrowprops=dict(
                    arrowstyle="-|>", lw=1.4 if bad else 0.6, alpha=0.9 if bad else 0.3,
                    color="crimson" if bad else "0.3", shrinkA=11, shrinkB=11,
                    connectionstyle="arc3,rad=-0.35" if same else "arc3,rad=0.0"))  # fmt: skip
    for name, (x, y) in pos.items():
        short = name.removeprefix("umf.")
        ax.text(x, y, short, ha="center", va="center", fontsize=7,
                bbox=dict(boxstyle="round,pad=0.25", fc="white", ec="0.4", lw=0.6))  # fmt: skip
    for k, (title, _) in enumerate(LAYERS):
        ax.axhspan(k * 1.6 - 0.6, k * 1.6 + 0.6, color="0.93" if k % 2 else "0.97", zorder=-1)
        ax.text(-0.3, k * 1.6, f"{k}  {title}", ha="right", va="center", fontsize=9)
    ax.set_xlim(-width * 0.22, width + 0.2)
    ax.set_ylim(-1, len(LAYERS) * 1.6 - 0.6)
    ax.axis("off")
    ax.set_title("src/umf: every arrow an import, pointing at what is imported "
                 "(red: up a layer)", fontsize=10)  # fmt: skip
    fig.tight_layout()
    from umf.io import atomic_path

    kind = out.suffix.lstrip(".") or "svg"
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format=kind, metadata={"Date": None} if kind == "svg" else None)
    plt.close(fig)


def report(g: dict[str, set[str]]) -> list[str]:
    arrows = sum(len(t) for t in g.values())
    lines = [f"{len(g)} modules, {arrows} arrows, {len(LAYERS)} layers"]
    lines += [f"circle: {' -> '.join(c)}" for c in circles(g)]
    lines += [f"up a layer: {a} ({LAYERS[layer_of(a)][0]}) -> {b} ({LAYERS[layer_of(b)][0]})"
              for a, b in upward(g)]  # fmt: skip
    lines += [f"over {MAX_LINES} lines: {name} ({n})" for name, n in long_files()]
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--svg", type=Path, help="draw the layers to this file (.svg or .png)")
    ap.add_argument("--modules", action="store_true", help="draw every module, not each "
                    "package as one box")  # fmt: skip
    ap.add_argument("--check", action="store_true", help="exit 1 on a circle, an arrow up "
                    f"or a file over {MAX_LINES} lines")  # fmt: skip
    args = ap.parse_args()
    g = graph()
    lines = report(g)
    print("\n".join(lines))
    if args.svg:
        draw(g if args.modules else packages(g), args.svg)
        print(f"wrote {args.svg}")
    if args.check and len(lines) > 1:
        sys.exit(1)


if __name__ == "__main__":
    main()
