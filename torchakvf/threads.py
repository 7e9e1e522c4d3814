"""Thread control for small dense LAPACK calls."""
from __future__ import annotations

import contextlib
import threading

import torch

_lock = threading.Lock()
_depth = 0
_saved = 1


@contextlib.contextmanager
def single_threaded():
    """Context manager: run small dense factorizations (n×n eigh/svd with n ~ 10-150) on one
    CPU thread, then give the process back the thread count it had.

    Such matrices are too small to gain from threads, and OpenMP threads spin-waiting on busy
    cores made them up to a thousand times slower (see docs/design.md).

    torch's intra-op thread count is process-wide, so the blocks are counted across threads
    and nesting: the first to enter saves the count, the last to leave restores it (two
    overlapping blocks on two threads cannot leave the process at one thread for good).
    Other threads' work runs single-threaded while a block is open.
    """
    global _depth, _saved
    with _lock:
        if _depth == 0:
            _saved = torch.get_num_threads()
            if _saved != 1:
                torch.set_num_threads(1)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0 and torch.get_num_threads() != _saved:
                torch.set_num_threads(_saved)
