"""A toy :class:`~torchakvf.pipeline.overlap.OverlapJob` (picklable, importable by spawned host
workers): items are ints; prepare, solve and cut fail on the items named."""
from __future__ import annotations

from torchakvf.pipeline.overlap import PreparedMesh


class ToyJob:
    """prepare(i) -> i; solve -> 10 i per item (raises on a batch holding ``poison``); cut ->
    10 i + 1. ``bad_prepare`` / ``bad_cut`` raise ValueError there, ``bug`` a TypeError in cut.
    ``solved`` lists the batches solve saw (in the solving process)."""

    def __init__(self, poison=(), bad_prepare=(), bad_cut=(), bug=()):
        self.poison, self.bad_prepare, self.bad_cut, self.bug = set(poison), set(bad_prepare), set(bad_cut), set(bug)
        self.solved = []

    def prepare(self, i):
        if i in self.bad_prepare:
            raise ValueError(f"cannot read {i}")
        return PreparedMesh(mesh=i, clean=i, coarse=None, seconds=0.5)

    def solve(self, ready, times):
        items = [i for i, _ in ready]
        self.solved.append(items)
        if self.poison & set(items):
            raise RuntimeError("factorization failed")
        times.add(times.stages, {"akvf": 1.0, "rounds": 2.0})
        return [10 * i for i in items]

    def cut(self, i, x):
        if i in self.bug:
            raise TypeError("a bug")
        if i in self.bad_cut:
            raise ValueError(f"cannot cut {i}")
        return x + 1, {"cut": 0.25}
