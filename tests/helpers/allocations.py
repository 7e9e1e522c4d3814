"""A tensor-size audit: the peak bytes of the tensor storages alive at once while a block runs,
counted from every tensor an operation returns (torch's dispatch mode sees them all), each
storage once (views share it) until the last tensor on it is gone. What the block's caller
already held (its inputs) is not counted."""
from __future__ import annotations

import weakref

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten


class PeakBytes(TorchDispatchMode):
    """``with PeakBytes(min_bytes) as audit: ...`` then ``audit.peak`` (bytes): storages smaller
    than ``min_bytes`` (scalars, index lists) are left out."""

    def __init__(self, min_bytes: int = 0):
        super().__init__()
        self.min_bytes = min_bytes
        self.live = 0
        self.peak = 0
        self._refs: dict[int, int] = {}
        self._sizes: dict[int, int] = {}
        self._known: set[int] = set()

    def _seen(self, t: torch.Tensor) -> None:
        if t.layout != torch.strided or t.device.type == "meta":
            return
        ptr = t.untyped_storage().data_ptr()
        if ptr == 0:
            return
        if ptr not in self._refs:
            size = t.untyped_storage().nbytes()
            if size < self.min_bytes:
                return
            self._refs[ptr], self._sizes[ptr] = 0, size
            self.live += size
            self.peak = max(self.peak, self.live)
        self._refs[ptr] += 1
        weakref.finalize(t, self._gone, ptr)

    def _gone(self, ptr: int) -> None:
        if ptr in self._refs:
            self._refs[ptr] -= 1
            if self._refs[ptr] == 0:
                self.live -= self._sizes.pop(ptr)
                del self._refs[ptr]

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        inputs = {id(a) for a in tree_flatten((args, kwargs))[0] if isinstance(a, torch.Tensor)}
        for t in tree_flatten(out)[0]:
            if isinstance(t, torch.Tensor) and id(t) not in inputs:
                self._seen(t)
        return out
