"""Floating-point operations of a call, counted by PyTorch's FlopCounterMode.

Two things keep the plain counter from seeing a transformer's work on the CPU, so this
module handles both: the fused fast path of ``nn.TransformerEncoderLayer`` (one opaque op
under ``inference_mode``) is switched off while counting, and the CPU's flash attention
kernel, which the counter has no formula for, gets the standard attention count. A
multiply-add is 2 FLOPs, as in the counter.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode, sdpa_flop_count


def _cpu_attention(query, key, value, *args: Any, out_shape=None, **kwargs: Any) -> int:
    """QK^T and the weighted sum of V: 2 * B * H * L * S * (E + Ev)."""
    return sdpa_flop_count(query, key, value)


_CPU_FORMULAS = {torch.ops.aten._scaled_dot_product_flash_attention_for_cpu: _cpu_attention}


def count_flops(fn: Callable[[], Any]) -> int:
    """FLOPs of ``fn()`` (run once, without gradients); matmuls and attention, which is
    where a transformer's time goes (norms and activations are not counted)."""
    fast = torch.backends.mha.get_fastpath_enabled()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        counter = FlopCounterMode(display=False, custom_mapping=_CPU_FORMULAS)
        with torch.inference_mode(), counter:
            fn()
        return int(counter.get_total_flops())
    finally:
        torch.backends.mha.set_fastpath_enabled(fast)
