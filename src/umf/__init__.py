"""umf: Unified Motion Flow, text + number of people -> synchronized 3-D motion.

``from umf import UMFPipeline, Scene``; both are imported on first use, so ``import umf``
(and ``umf --version``) stays cheap.
"""

from typing import Any

from umf.version import __version__

__all__ = ["Scene", "UMFPipeline", "__version__"]


def __getattr__(name: str) -> Any:
    if name == "UMFPipeline":
        from umf.pipeline import UMFPipeline

        return UMFPipeline
    if name == "Scene":
        from umf.scene import Scene

        return Scene
    raise AttributeError(f"module 'umf' has no attribute {name!r}")
