"""An exponential moving average of a model's weights (what `ema_decay` turns on), saved
and resumed with the run."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from typing import Any

import torch
from torch import Tensor, nn

from umf.errors import UMFError


# --------------------------------------------------------------------- EMA
class EMA:
    """Exponential moving average of the trainable parameters.

    The decay ramps up as min(decay, (1 + n) / (10 + n)) so early averages are not stuck
    at the random initialisation.
    """

    def __init__(self, module: nn.Module, decay: float) -> None:
        self.decay = decay
        self.params = {n: p for n, p in module.named_parameters() if p.requires_grad}
        self.shadow = {n: p.detach().clone() for n, p in self.params.items()}
        self.num_updates = 0

    @torch.no_grad()
    def update(self) -> None:
        self.num_updates += 1
        d = min(self.decay, (1 + self.num_updates) / (10 + self.num_updates))
        for name, p in self.params.items():
            self.shadow[name].lerp_(p.detach(), 1.0 - d)

    def by_id(self) -> dict[int, Tensor]:
        return {id(p): self.shadow[n] for n, p in self.params.items()}

    @contextlib.contextmanager
    def applied(self) -> Iterator[None]:
        """Temporarily put the averaged weights into the module (for validation)."""
        backup = {n: p.detach().clone() for n, p in self.params.items()}
        with torch.no_grad():
            for n, p in self.params.items():
                p.copy_(self.shadow[n])
        try:
            yield
        finally:
            with torch.no_grad():
                for n, p in self.params.items():
                    p.copy_(backup[n])

    def state_dict(self) -> dict[str, Any]:
        raw = {n: p.detach() for n, p in self.params.items()}
        return {"decay": self.decay, "num_updates": self.num_updates,
                "shadow": self.shadow, "raw": raw}  # fmt: skip

    @torch.no_grad()
    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore the averages and the raw weights (checkpoint files hold the averages)."""
        missing = set(self.params) - set(state["shadow"])
        if missing:
            raise UMFError(f"EMA state lacks {sorted(missing)[0]} (different model?)")
        self.num_updates = int(state["num_updates"])
        for n, p in self.params.items():
            self.shadow[n].copy_(state["shadow"][n])
            if "raw" in state:
                p.copy_(state["raw"][n])
