"""Random field arrays for the tests of the untangling kernels (Horst steps, fourth moments)."""
from __future__ import annotations

import torch


def random_forms(m: int, e: int, n: int, seed: int) -> torch.Tensor:
    """[m, e, n] float64 normal entries, three times heavier on the first quarter of the rows
    for the first half of the fields (some structure for the rotations to find)."""
    gen = torch.Generator().manual_seed(seed)
    y = torch.randn(m, e, n, generator=gen, dtype=torch.float64)
    y[:, : e // 4, : n // 2] *= 3
    return y
