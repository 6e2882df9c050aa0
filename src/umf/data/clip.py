"""The record every dataset adapter produces: one clip of one or more people."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FPS = 30.0


@dataclass
class MotionClip:
    """Real motion of ``P`` people, already in umf conventions.

    Attributes:
        id: unique within its source, e.g. ``"dataset-1_bow_normal_001"``.
        source: ``"bandai"``, ``"humanml3d"`` or ``"interhuman"``.
        joints: (P, T, 22, 3) float32 SMPL-22 joints, metres, Y up, ``fps`` frames/s,
            in the scene's own world frame (adapters do not canonicalise).
        captions: natural-language descriptions of the whole clip (several).
        fps: frame rate (30 after every adapter).
        rotations: (P, T, 22, 3, 3) local rotations when the source has them.
        rot6d: (P, T, 21, 6) local 6-D rotations of joints 1..21 as used in the
            features (filled by the corpus, from ``rotations`` or inverse kinematics).
        split: the dataset's own split ("train"/"val"/"test") if it defines one.
        meta: free-form labels (content, style, source file, ...).
    """

    id: str
    source: str
    joints: np.ndarray
    captions: list[str]
    fps: float = FPS
    rotations: np.ndarray | None = None
    rot6d: np.ndarray | None = None
    split: str | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.joints.ndim != 4 or self.joints.shape[-2:] != (22, 3):
            raise ValueError(f"{self.id}: joints must be (P, T, 22, 3), got {self.joints.shape}")

    @property
    def num_people(self) -> int:
        return int(self.joints.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.joints.shape[1])

    def to_scene(self):
        """The clip as a :class:`umf.scene.Scene` (fitted to rigid bodies), to view or
        write in any format; the dataset labels go into ``meta``."""
        from umf.scene import Scene

        meta = {**self.meta, "id": self.id, "source": self.source, "split": self.split}
        return Scene(self.joints, None, self.captions[0] if self.captions else "", self.fps,
                     meta=meta)  # fmt: skip
