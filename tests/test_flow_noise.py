"""umf.flows.noise.randn: one generator for a batch, or one per row, in the dtype asked for."""

from __future__ import annotations

import pytest
import torch

from umf.flows.noise import randn


def _gens(*seeds: int) -> list[torch.Generator]:
    return [torch.Generator().manual_seed(s) for s in seeds]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_one_generator_draws_the_whole_batch_in_its_dtype(dtype):
    z = randn((3, 4, 2), torch.Generator().manual_seed(5), dtype=dtype)
    want = torch.randn((3, 4, 2), generator=torch.Generator().manual_seed(5), dtype=dtype)
    assert z.dtype == dtype and z.shape == (3, 4, 2)
    torch.testing.assert_close(z, want, rtol=0, atol=0)
    assert randn([2, 3], dtype=dtype).dtype == dtype  # no generator: the global one


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_row_i_is_drawn_from_generator_i_alone(dtype):
    z = randn((3, 4, 2), _gens(1, 2, 3), dtype=dtype)
    assert z.dtype == dtype and z.shape == (3, 4, 2)
    for i, seed in enumerate((1, 2, 3)):  # as if row i were a batch of one
        alone = randn((1, 4, 2), _gens(seed), dtype=dtype)[0]
        torch.testing.assert_close(z[i], alone, rtol=0, atol=0)
    # so a row does not depend on its neighbours
    torch.testing.assert_close(randn((2, 4, 2), _gens(9, 2), dtype=dtype)[1], z[1], rtol=0, atol=0)


def test_an_empty_batch_of_generators_keeps_shape_and_dtype():
    z = randn((0, 4), [], dtype=torch.float64)
    assert z.shape == (0, 4) and z.dtype == torch.float64


def test_generators_must_match_the_batch():
    with pytest.raises(ValueError, match=r"^2 generators for a batch of 3$"):
        randn((3, 5), _gens(1, 2))
