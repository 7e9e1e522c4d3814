"""A corpus run's batches through the host/device overlap (:mod:`.overlap`): the runner's path
for a task solved as one batch (``torchakvf segment --batched``, ``features --batched``, and on
a GPU by default).

A task takes this path when it has the two halves of its ``process``:

* ``solve_prepared(batch, items) -> (cut inputs, {stage: seconds})``: in the solving process,
  the packed :class:`~torchakvf.mesh.MeshBatch`'s device work (``items``: its meshes' run
  items, in batch order); one small picklable cut input per
  mesh; the stages are the task's ``stages`` plus ``rounds`` / ``jobs`` as it names them;
* ``cut(cut input) -> output``: in a host worker, what ``process`` would have returned for that
  mesh (then written by the task's ``write`` there too).

Loading (:func:`~.execute.load_item`: checks, load, clean, validate) and decimation run in the
host workers ahead of the solve; writing and the outputs' fingerprints after it. Each mesh gets
the same manifest record as on the single-process path; the run's stage seconds
(:class:`~.overlap.OverlapTimes`) are written to ``timings.json`` in the output folder.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..io.outputs import atomic_write_bytes
from .execute import Item, base_record, failed_record, load_item, output_record, write_item
from .overlap import OverlapTimes, PreparedMesh, pack, run_overlapped

__all__ = ["CorpusOverlap", "run_batches_overlapped", "overlaps", "TIMINGS"]

#: The file of a batched corpus run's stage seconds, beside the manifest.
TIMINGS = "timings.json"


def overlaps(task) -> bool:
    """Whether ``task`` can run on the overlapped path (it has ``solve_prepared`` and ``cut``,
    and does not say otherwise through ``overlappable``)."""
    return (callable(getattr(task, "solve_prepared", None)) and callable(getattr(task, "cut", None))
            and getattr(task, "overlappable", True))


class CorpusOverlap:
    """The :class:`~.overlap.OverlapJob` of a corpus task (see the module notes). Picklable."""

    def __init__(self, task, out_dir: Path, device, seed: int):
        self.task, self.out_dir, self.device, self.seed = task, Path(out_dir), str(device), int(seed)

    @property
    def coarse_faces(self):
        return getattr(self.task, "coarse_faces", None)

    def prepare(self, item: Item) -> PreparedMesh:
        """In a host worker: load, clean, check and decimate one mesh (its ``item`` comes back
        with the load's seconds and the input's fingerprint); decimated as the task's
        ``coarse_mesh(clean, faces)`` says where it has one, else as segmentations are."""
        from ..mesh.batch import coarse_or_none

        t0 = time.perf_counter()
        if not load_item(item, self.task, self.out_dir):      # copied from the task's cache
            return PreparedMesh(None, None, None, time.perf_counter() - t0, item=item)
        coarse = getattr(self.task, "coarse_mesh", coarse_or_none)(item.clean, self.coarse_faces)
        item.seconds["load"] = time.perf_counter() - t0
        return PreparedMesh(item.mesh, item.clean, coarse, time.perf_counter() - t0, item=item)

    def solve(self, ready: list, times: OverlapTimes) -> list:
        """In the solving process: pack, solve; each mesh's cut input carries its item (mesh as
        read, seconds so far, the batch's stage seconds charged by its share of the faces); a
        mesh found in the task's cache is not solved (its cut input: (item, None))."""
        solved = {id(prep): inp for prep, inp in self.solve_loaded([p for _, p in ready if p.mesh is not None], times)}
        return [solved.get(id(prep), (prep.item, None)) for _, prep in ready]

    def solve_loaded(self, preps: list, times: OverlapTimes) -> list:
        """[(PreparedMesh, cut input)] of the loaded meshes, solved as one batch."""
        if not preps:
            return []
        t0 = time.perf_counter()
        batch = pack(preps, self.device, self.coarse_faces)
        t_pack = time.perf_counter() - t0
        inputs, stage_s = self.task.solve_prepared(batch, [p.item for p in preps])
        times.add(times.stages, {"pack": t_pack, **stage_s})
        faces = np.array([len(p.clean.faces) for p in preps], dtype=np.float64)
        share = faces / faces.sum()
        out = []
        for b, prep in enumerate(preps):
            it = prep.item
            it.clean = None            # the cut reads its job; the write reads the mesh as read
            for stage in self.task.stages:
                it.seconds[stage] = stage_s.get(stage, 0.0) * share[b]
            it.seconds[self.task.stages[0]] += t_pack * share[b]
            out.append((prep, (it, inputs[b])))
        return out

    def cut(self, item: Item, cut_input) -> tuple:
        """In a host worker: the task's cut of one mesh, then its files and manifest record.
        Returns (record, {"cut": s, "write": s})."""
        it, inp = cut_input
        t0 = time.perf_counter()
        if inp is None:                # copied from the cache when it was prepared
            rec = base_record(it, self.task, self.seed)
            rec.update(status="ok", cached=True)
            return output_record(rec, self.task, self.out_dir, it.stem), {}
        output = self.task.cut(inp)
        t1 = time.perf_counter()
        it.seconds[self.task.stages[-1]] = it.seconds.get(self.task.stages[-1], 0.0) + (t1 - t0)
        rec = write_item(it, output, self.task, self.out_dir, self.seed)
        return rec, {"cut": t1 - t0, "write": time.perf_counter() - t1}


def run_batches_overlapped(batches: list, task, out_dir: Path, device, seed: int, workers: int,
                           record, tell) -> OverlapTimes:
    """Run a corpus run's ``batches`` through the overlap; ``record(records)`` is called with
    each finished mesh's manifest record (in this process). Writes :data:`TIMINGS`."""
    job = CorpusOverlap(task, out_dir, device, seed)

    def finish(item, prep, error, rec):
        if error is not None:
            rec = failed_record(prep.item if prep is not None and prep.item is not None else item,
                                task, seed, error)
        record([rec], item)

    times = run_overlapped(batches, job, workers, device, finish, tell)
    atomic_write_bytes(Path(out_dir) / TIMINGS, json.dumps(times.record(), indent=2).encode())
    return times
