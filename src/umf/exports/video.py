"""GIF / MP4: stick figures of ``scene.joints`` (:func:`umf.render.render_animation`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["write"]


def write(scene: Any, path: Path) -> list[Path]:
    """A GIF or MP4 (by suffix) of the scene, written atomically."""
    return [scene.render(path, progress=False)]
