"""README and docs: every relative link resolves (files and #anchors), and every `umf ...`
command line shown in the README parses (options known, values of the right type)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CARD = ROOT / "src" / "umf" / "assets" / "model" / "README.md"
PAGES = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md")), CARD,
         ROOT / "data" / "mocap" / "README.md", ROOT / "research" / "README.md"]  # fmt: skip
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def anchors(path: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    out = set()
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            title = line.lstrip("#").strip().lower()
            out.add(re.sub(r"\s", "-", re.sub(r"[^\w\s-]", "", title)))
    return out


@pytest.mark.parametrize("page", [p for p in PAGES if p.exists()], ids=lambda p: p.name)
def test_every_relative_link_resolves(page):
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    broken = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):
            continue  # http(s), mailto
        file, _, anchor = target.partition("#")
        dest = (page.parent / file).resolve() if file else page
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: broken links {broken}"


def readme_commands() -> list[str]:
    """Every `umf ...` line of the README's code blocks and inline code (continuations
    joined, comments cut)."""
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, flags=re.S)
    lines = []
    for block in blocks:
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split("  #")[0].strip()
            if line.startswith(("umf ", ".venv/bin/umf ")):
                lines.append(line.removeprefix(".venv/bin/"))
    lines += [c for c in re.findall(r"`(umf [^`]+)`", text) if "..." not in c]
    return lines


def test_the_readme_shows_commands():
    assert len(readme_commands()) >= 5


@pytest.mark.parametrize("line", readme_commands())
def test_every_readme_command_parses(line, monkeypatch):
    """The command line is accepted by the CLI's parser: each (sub)command exists and every
    option is one it has, with a value of its type (nothing runs: the command's function
    is replaced)."""
    import click
    import typer.main

    from umf.cli.main import app

    argv = shlex.split(line)[1:]
    group = typer.main.get_command(app)
    ctx = group.make_context("umf", list(argv), resilient_parsing=False)
    cmd, rest = group, list(argv)
    while isinstance(cmd, click.Group):
        name, cmd, rest = cmd.resolve_command(ctx, rest)
        ctx = cmd.make_context(name, rest, parent=ctx)
    assert ctx.command is cmd
