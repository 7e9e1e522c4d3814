"""Thread control for small dense LAPACK calls."""
from __future__ import annotations

import contextlib

import torch


@contextlib.contextmanager
def single_threaded():
    """Run small dense factorizations (n×n eigh/svd with n ~ 10-150) on one CPU thread.

    Measured here: a 144×144 float64 ``eigh`` took 3.7 ms on one thread and up to 3 s with
    two OpenMP threads when the cores were busy (spin-waiting threads); such matrices are too
    small to gain from threads anyway. The previous thread count is restored on exit.
    """
    before = torch.get_num_threads()
    if before == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)
