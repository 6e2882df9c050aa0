"""Write all files of one scene together: into a hidden temporary directory, then renamed.

A failing format (a target name taken by a directory, a full disk) leaves none of the
scene's files, and an earlier result under the same name stays whole. The temporary
directory is named after the writing process; once every file is in it, a ``complete``
marker makes the renames a journal: a run killed while renaming is rolled forward by the
next run into that directory, a run killed earlier is rolled back, so a name never holds
files of two different runs.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from umf.exports import FORMATS, targets, write_formats
from umf.validation import check_finite, check_targets

TMP_PREFIX = ".umf-tmp-"
COMPLETE = ".complete"
LEGACY_TMP = re.compile(r"^\..+\.(npz|gif|mp4|bvh|glb|png)\.[A-Za-z0-9_]+\.tmp$")
STALE_AFTER_S = 600.0  # older hidden temporaries of the single-file writer are abandoned


def scene_targets(stem: Path, wanted: Sequence[str], num_people: int) -> list[Path]:
    """The final paths of one scene: ``stem.<ext>``, and ``stem-p<i><suffix>`` for the
    formats with one file per person (:mod:`umf.exports`)."""
    return targets(stem, wanted, num_people)


def _stale_people(stem: Path, wanted: Sequence[str], num_people: int) -> list[Path]:
    """Per-person files of people an earlier, larger scene under this name had and this
    one lacks (for the per-person formats being written)."""
    out = []
    for name in wanted:
        fmt = FORMATS[name]
        if not fmt.per_person:
            continue
        found = stem.parent.glob(f"{glob_escape(stem.name)}-p*{glob_escape(fmt.suffix)}")
        pattern = re.compile(re.escape(stem.name) + r"-p(\d+)" + re.escape(fmt.suffix) + "$")
        out += [p for p in found if (m := pattern.match(p.name)) and int(m.group(1)) > num_people]
    return out


def glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)


def _commit(tmp: Path, out_dir: Path, remove: Sequence[Path] = ()) -> None:
    """Rename every file of a complete temporary directory into place, then drop it."""
    for p in remove:
        p.unlink(missing_ok=True)
    for f in sorted(tmp.iterdir()):
        if f.name != COMPLETE:
            os.replace(f, out_dir / f.name)
    shutil.rmtree(tmp, ignore_errors=True)


def write_scene_files(scene: Any, stem: Path, wanted: Sequence[str]) -> list[Path]:
    """Every requested file of one scene, all or none; returns the paths written."""
    check_finite(scene.joints, "the scene's joints")
    if scene.features is not None:
        check_finite(scene.features, "the scene's features")
    targets = scene_targets(stem, wanted, scene.num_people)
    check_targets(targets)
    out_dir = stem.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f"{TMP_PREFIX}{os.getpid()}-", dir=out_dir))
    try:
        write_formats(scene, tmp / stem.name, wanted)
        names = sorted(p.name for p in tmp.iterdir())
        if names != sorted(p.name for p in targets):  # a writer left out or added a file
            raise RuntimeError(f"scene writer produced {names}")
        (tmp / COMPLETE).touch()
        stale = _stale_people(stem, wanted, scene.num_people)
        _commit(tmp, out_dir, stale)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return targets


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale(out_dir: Path, now: float | None = None) -> list[Path]:
    """Finish or remove what killed runs left in ``out_dir``; returns what was handled.

    Temporary directories of dead processes are committed when complete, else removed;
    hidden ``.<name>.<ext>.<random>.tmp`` files of the single-file writer are removed once
    older than STALE_AFTER_S (a live writer renames them within seconds).
    """
    if not out_dir.is_dir():
        return []
    now = time.time() if now is None else now
    handled = []
    for d in out_dir.glob(f"{TMP_PREFIX}*"):
        m = re.match(re.escape(TMP_PREFIX) + r"(\d+)-", d.name)
        if not d.is_dir() or m is None:
            continue
        pid = int(m.group(1))
        if pid == os.getpid() or (_alive(pid) and now - d.stat().st_mtime < 86400):
            continue
        if (d / COMPLETE).exists():
            _commit(d, out_dir)
        else:
            shutil.rmtree(d, ignore_errors=True)
        handled.append(d)
    for f in out_dir.iterdir():
        if LEGACY_TMP.match(f.name) and f.is_file() and now - f.stat().st_mtime > STALE_AFTER_S:
            f.unlink(missing_ok=True)
            handled.append(f)
    return handled
