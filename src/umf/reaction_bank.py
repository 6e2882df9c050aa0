"""Real reactions a model was trained on, for the warm start of people 2..N.

The S-Flow's own first pass knows a person's role and place (who walks over, who steps
back, on which side) but glides; a real reaction strides. ``sflow.warm_proposal =
"retrieved"`` (:mod:`umf.warm_start`) warm-starts each added person from one of the real
reactions of the training split nearest to the first pass, in the S-Flow's latent space,
so the second pass keeps the role and gains the stride.

A model directory carries them in ``reactions.safetensors``: for each length of a set
(``frames_30``, ``frames_45`` ... feature frames), the VAE's posterior means (N, p, r) of
people 2..N of the training scenes, cropped to that length in person 1's frame (the crop
the S-Flow trains on). They are derived from the training data and carry its licence.
``umf train reactions`` (:func:`umf.train.reactions.build_reaction_bank`) writes them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from umf.errors import UMFError
from umf.flows.noise import Generators, randn
from umf.io import save_tensors_atomic

REACTIONS = "reactions.safetensors"
PREFIX = "frames_"

Tensor = torch.Tensor


@dataclass
class ReactionBank:
    """Real reactions per length: ``latents[frames]`` (N, p, r) on the VAE's scale."""

    latents: dict[int, Tensor]

    def lengths(self) -> list[int]:
        return sorted(self.latents)

    def save(self, model_dir: str | Path) -> Path:
        """Write ``reactions.safetensors`` into a model directory atomically (fp16)."""
        path = Path(model_dir) / REACTIONS
        save_tensors_atomic({f"{PREFIX}{k}": v.to(torch.float16).contiguous()
                             for k, v in self.latents.items()}, path)  # fmt: skip
        path.chmod(0o644)
        return path

    @classmethod
    def load(cls, model_dir: str | Path, shape: Sequence[int] | None = None) -> ReactionBank | None:
        """The model's reactions, or None when it has none; ``shape`` (p, r) checks them."""
        from safetensors import SafetensorError
        from safetensors.torch import load_file

        path = Path(model_dir) / REACTIONS
        if not path.exists():
            return None
        try:
            raw = load_file(str(path))
            latents = {int(k.removeprefix(PREFIX)): v.float() for k, v in raw.items()}
        except (OSError, ValueError, RuntimeError, SafetensorError) as exc:
            raise UMFError(f"{path}: corrupt reaction bank ({type(exc).__name__})") from None
        for frames, z in latents.items():
            fits = z.ndim == 3 and len(z) and (shape is None or z.shape[1:] == tuple(shape))
            if not fits or not torch.isfinite(z).all():
                raise UMFError(f"{path}: reactions of {frames} frames do not fit the model")
        if not latents:
            raise UMFError(f"{path}: an empty reaction bank")
        return cls(latents)

    def bucket(self, frames: int) -> int:
        """The stored length nearest to ``frames`` (the shorter on a tie)."""
        return min(self.latents, key=lambda k: (abs(k - frames), k))

    def nearest(
        self,
        query: Tensor,
        frames: int,
        neighbours: int,
        generator: Generators = None,
        scale: Callable[[Tensor], Tensor] = lambda z: z,
    ) -> Tensor:
        """For each row of ``query`` (B, p, r) a real reaction (B, p, r): one of the
        ``neighbours`` nearest (Euclidean after ``scale``, e.g. the S-Flow's latent
        normaliser) among those of the stored length nearest to ``frames``, drawn uniformly
        with row i's generator."""
        bank = self.latents[self.bucket(frames)].to(query)
        k = max(1, min(int(neighbours), bank.shape[0]))
        d = torch.cdist(scale(query).flatten(1), scale(bank).flatten(1))
        idx = d.topk(k, dim=1, largest=False).indices  # (B, k), nearest first
        pick = randn((query.shape[0], k), generator, device=query.device).argmax(dim=1)
        return bank[idx[torch.arange(query.shape[0], device=query.device), pick]]
