"""Counting the calls that would force a host synchronization on a GPU, on any device.

On CUDA the host waits for the device wherever a value goes back to Python or to host memory
(``item``, ``bool``, ``int``, ``float``, ``tolist``, ``cpu``, ``numpy``, ``torch.equal``), where an
output's size depends on values (``nonzero``, boolean-mask indexing, ``masked_select``,
``unique``, ``repeat_interleave`` without ``output_size``), where Python data is copied to the
device (``torch.tensor(..., device=)``) and where torch checks a dense solver's error code
(``torch.linalg.eigh``/``svd``/``cholesky``/...). :class:`SyncCounter` wraps those calls (a
context manager) and counts them by name, so a test on the CPU can put a ceiling on them.
``paused()`` leaves out what a block calls (e.g. a sparse factor's solve, which is the factor
library's on the device).
"""
from __future__ import annotations

import contextlib
from collections import Counter

import torch

_TENSOR_METHODS = ("item", "__bool__", "__int__", "__float__", "tolist", "nonzero", "cpu", "numpy",
                   "masked_select", "unique")
_TORCH_FUNCTIONS = ("nonzero", "equal", "masked_select", "unique")
#: Dense solvers whose error code torch reads back on CUDA.
_CHECKED_SOLVERS = ("eigh", "eigvalsh", "svd", "cholesky", "qr", "inv", "solve")


def _bool_index(index) -> bool:
    items = index if isinstance(index, tuple) else (index,)
    return any(isinstance(i, torch.Tensor) and i.dtype == torch.bool for i in items)


class SyncCounter:
    """``with SyncCounter() as c: ...`` then ``c.total`` and ``c.counts`` (by call name)."""

    def __init__(self):
        self.counts: Counter = Counter()
        self._saved: list = []
        self._paused = 0

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def _count(self, name: str) -> None:
        if not self._paused:
            self.counts[name] += 1

    @contextlib.contextmanager
    def paused(self):
        self._paused += 1
        try:
            yield
        finally:
            self._paused -= 1

    def _wrap(self, owner, attr: str, name: str, when=None) -> None:
        real = getattr(owner, attr)
        self._saved.append((owner, attr, real))

        def wrapper(*args, **kwargs):
            if when is None or when(*args, **kwargs):
                self._count(name)
            with self.paused():                 # calls made inside count once, as this one
                return real(*args, **kwargs)

        setattr(owner, attr, wrapper)

    def __enter__(self) -> "SyncCounter":
        for attr in _TENSOR_METHODS:
            self._wrap(torch.Tensor, attr, attr)
        self._wrap(torch.Tensor, "to", "to(cpu)", when=lambda self_, *a, **k: _to_host(a, k))
        self._wrap(torch.Tensor, "__getitem__", "mask index", when=lambda self_, i: _bool_index(i))
        self._wrap(torch.Tensor, "__setitem__", "mask index", when=lambda self_, i, v: _bool_index(i))
        self._wrap(torch, "repeat_interleave", "repeat_interleave",
                   when=lambda x, repeats=None, *a, **k: isinstance(repeats, torch.Tensor)
                   and k.get("output_size") is None)
        self._wrap(torch, "tensor", "tensor(device=)", when=lambda *a, **k: k.get("device") is not None)
        for attr in _TORCH_FUNCTIONS:
            self._wrap(torch, attr, attr)
        for attr in _CHECKED_SOLVERS:
            self._wrap(torch.linalg, attr, f"linalg.{attr}")
        return self

    def __exit__(self, *exc) -> None:
        for owner, attr, real in reversed(self._saved):
            setattr(owner, attr, real)
        self._saved.clear()


def _to_host(args, kwargs) -> bool:
    target = kwargs.get("device", args[0] if args else None)
    return isinstance(target, (str, torch.device)) and torch.device(target).type == "cpu"
