"""File exports of generated scenes, one format per module (``umf.exports.gltf``: GLB)."""

from umf.exports.gltf import scene_to_gltf, write_glb

__all__ = ["scene_to_gltf", "write_glb"]
