"""The host/device overlap of a batched run (the accelerator's path): host processes feed the
solving process and finish what it solved, so that the device never waits on one core's host
work. Every batched corpus command goes through it (``segment``, ``features`` and ``eval`` with
``--batched``, or on a GPU).

::

    host workers      job.prepare(item): load, clean, decimate        (per mesh, ahead)
         │ queue (futures, LOOKAHEAD batches ahead)
    solving process   job.solve(ready): pack, AKVFs of the batch as one, untangling, k-means
         │ one small picklable job per mesh (its rows only)
    host workers      job.cut(item, cut_input): boundaries, merge, graph cut; files, records

While batch i is solved, the workers prepare batches i+1 .. i+LOOKAHEAD and cut batches i-1,
i-2, ...; the solving process does host work only where it would otherwise wait: a call no
worker has started when it is needed (the last cuts) is run there, and it prepares the first
batch itself while the workers start. With ``workers`` <= 1 every stage runs in the solving
process, in order (the single-process device path).

A batch whose solve raises is bisected (its halves solved again, recursively), so one mesh
that cannot be solved fails alone and the others keep their shared solve; a mesh whose prepare
or cut fails fails alone; a programming error or a full output disk ends the run.

A job (see :class:`OverlapJob`) is picklable: its ``prepare`` and ``cut`` run in spawned
processes. Every stage's seconds are in :class:`OverlapTimes`: ``host_share`` is the share of
wall time the solving process spent on host stages or waiting for them.
"""
from __future__ import annotations

import collections
import time
from concurrent.futures import FIRST_COMPLETED, wait
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from typing import Callable, Protocol

from ..io import load_mesh
from ..io.outputs import OutputSpaceError
from ..mesh import MeshBatch, clean_mesh
from ..mesh.batch import coarse_or_none
from .parallel import InlineExecutor, error_text, halves, host_pool, is_programming_error, usable_cores

__all__ = ["run_overlapped", "OverlapJob", "OverlapTimes", "PreparedMesh", "prepare_mesh",
           "pack", "solver_threads", "LOOKAHEAD"]

#: Batches prepared ahead of the one being solved: one hides the host work when it is shorter
#: than a solve, two absorb a slow mesh.
LOOKAHEAD = 2


@dataclass
class PreparedMesh:
    """One mesh ready to pack: the input as read, cleaned, and its decimation (None: solved at
    full resolution); seconds spent preparing it; ``item``: the runner's record of it, where a
    job keeps one."""

    mesh: object
    clean: object
    coarse: object
    seconds: float
    item: object = None


def prepare_mesh(path, coarse_faces: int | None) -> PreparedMesh:
    """Load, clean and (above 1.25x ``coarse_faces`` faces) decimate one mesh file."""
    t0 = time.perf_counter()
    mesh = load_mesh(path)
    clean = clean_mesh(mesh)
    return PreparedMesh(mesh, clean, coarse_or_none(clean, coarse_faces), time.perf_counter() - t0)


def pack(prepared: list, device, coarse_faces: int | None) -> MeshBatch:
    """The batch ``MeshBatch.from_meshes([p.clean ...], device, coarse_faces)`` makes, from
    meshes prepared elsewhere."""
    mb = MeshBatch.from_meshes([p.clean if p.coarse is None else p.coarse.coarse for p in prepared],
                               device=device)
    if coarse_faces is not None:
        mb.coarse = [p.coarse for p in prepared]
    return mb


class OverlapJob(Protocol):
    """What :func:`run_overlapped` runs. ``prepare`` and ``cut`` run in host workers (the job is
    pickled to them), ``solve`` in the solving process.

    prepare(item) -> PreparedMesh : per mesh (its ``seconds`` are counted as ``prepare``)
    solve(ready, times) -> [cut input] : ``ready`` [(item, PreparedMesh)] solved as one batch;
        one picklable cut input per mesh; the solve's stage seconds added to ``times.stages``
        (by name, in order)
    cut(item, cut input) -> (result, {host stage: seconds}) : per mesh
    """

    def prepare(self, item) -> PreparedMesh: ...

    def solve(self, ready: list, times: OverlapTimes) -> list: ...

    def cut(self, item, cut_input) -> tuple: ...


@dataclass
class OverlapTimes:
    """Seconds of a batched run's stages. In the solving process: ``stages`` (the job's solve
    stages, e.g. pack, akvf, rounds, jobs: handing the cut inputs to the host workers counts as
    ``jobs``), ``wait_prepare`` / ``wait_cut`` (waiting for host workers, or doing their work
    itself: with no worker, or host calls no worker had started when they were needed,
    ``run_here`` of them), ``other``; summed over the host work: ``prepare`` and ``host`` (the
    job's cut stages, e.g. cut, score or write)."""

    workers: int = 0
    batches: int = 0
    bisections: int = 0
    run_here: int = 0
    wall: float = 0.0
    stages: dict = field(default_factory=dict)
    wait_prepare: float = 0.0
    wait_cut: float = 0.0
    prepare: float = 0.0
    host: dict = field(default_factory=dict)
    device_seconds: list = field(default_factory=list)

    def add(self, where: dict, seconds: dict) -> None:
        for name, s in seconds.items():
            where[name] = where.get(name, 0.0) + float(s)

    @property
    def solve(self) -> float:
        return sum(self.stages.values())

    @property
    def host_share(self) -> float:
        """Share of the wall time the solving process spent on host work or waiting for it."""
        return (self.wait_prepare + self.wait_cut) / self.wall if self.wall > 0 else 0.0

    def record(self) -> dict:
        """Flat {name: number}: the counts, the solve stages, the waits, the host stages, and
        ``solve``, ``other``, ``host_share``."""
        out = {k: v for k, v in asdict(self).items() if k not in ("device_seconds", "stages", "host")}
        out.update(self.stages)
        out.update(self.host)
        out["solve"] = self.solve
        out["other"] = self.wall - self.solve - self.wait_prepare - self.wait_cut
        out["host_share"] = self.host_share
        return out

    def line(self) -> str:
        """One line: batches, processes, solve and host share."""
        return (f"batched: {self.batches} batches on 1 solving process + {self.workers} host workers, "
                f"solve {self.solve:.1f}s of {self.wall:.1f}s, host share {100 * self.host_share:.0f}%")


def _fatal(exc: BaseException) -> bool:
    """A programming error or a full output disk is no mesh's fault: it ends the run."""
    return is_programming_error(exc) or isinstance(exc, OutputSpaceError)


class _Overlap:
    """One batched run under way (see the module notes)."""

    def __init__(self, pool, job, finish: Callable, tell: Callable, inline: bool):
        self.pool, self.job, self.finish, self.tell, self.inline = pool, job, finish, tell, inline
        self.times = OverlapTimes()
        self.cutting: dict = {}          # future -> (item, PreparedMesh)
        self.calls: dict = {}            # future -> (fn, args)

    def submit(self, fn, *args, pool=None):
        """``fn(*args)`` handed to the host workers; the call is kept so that this process can
        run it itself if it has to wait for it before a worker started it (:meth:`outcome`)."""
        fut = (pool or self.pool).submit(fn, *args)
        self.calls[fut] = (fn, args)
        return fut

    def outcome(self, fut):
        """The future's result: a call no worker has started yet is run here (it is cancelled
        there), so the solving process never idles on queued host work (the first batch, the
        last cuts)."""
        fn, args = self.calls.pop(fut)
        if fut.cancel():
            self.times.run_here += 1
            return fn(*args)
        return fut.result()

    def prepare(self, batch, here: bool = False) -> list:
        """The batch's meshes handed to the host workers (prepared now, in this process, with
        none or with ``here``)."""
        t0 = time.perf_counter()
        pool = InlineExecutor() if here else None
        futures = [self.submit(self.job.prepare, it, pool=pool) for it in batch]
        self.times.wait_prepare += time.perf_counter() - t0
        return futures

    def wait_prepared(self, batch, futures) -> list:
        """[(item, PreparedMesh)] of the batch's meshes that were prepared; the others fail here."""
        t0 = time.perf_counter()
        ready = []
        for it, fut in zip(batch, futures):
            try:
                prep = self.outcome(fut)
            except Exception as exc:  # noqa: BLE001 - a bad input fails alone, a bug ends the run
                if _fatal(exc):
                    raise
                self.finish(it, None, error_text(exc), None)
                continue
            self.times.prepare += prep.seconds
            ready.append((it, prep))
        self.times.wait_prepare += time.perf_counter() - t0
        return ready

    def solve(self, ready: list) -> None:
        """Solve the meshes ``ready`` as one batch and hand each its cut; a batch that raises is
        bisected."""
        if not ready:
            return
        t0 = time.perf_counter()
        stages = dict(self.times.stages)
        try:
            inputs = self.job.solve(ready, self.times)
        except Exception as exc:  # noqa: BLE001
            if _fatal(exc):
                raise
            exc.__traceback__ = None     # the failed batch's tensors are freed
            self.times.stages = stages   # a failed solve's stages are not the run's
            if len(ready) == 1:
                self.finish(ready[0][0], ready[0][1], error_text(exc), None)
                return
            self.times.bisections += 1
            self.tell(f"a batch of {len(ready)} meshes failed ({error_text(exc)}); solving its halves")
            for half in halves(ready):
                self.solve(half)
            return
        t1 = time.perf_counter()
        self.times.device_seconds.append(t1 - t0)
        for (it, prep), cut_input in zip(ready, inputs):
            fut = self.submit(self.job.cut, it, cut_input)
            self.cutting[fut] = (it, prep)
        dt = time.perf_counter() - t1
        if self.inline:              # the cuts ran in this process, in submit
            self.times.wait_cut += dt
            self.collect(block=True)
        else:                        # handing the jobs to the workers' queue
            self.times.add(self.times.stages, {"jobs": dt})

    def collect(self, block: bool) -> None:
        """Hand the finished cuts to ``finish`` (all of them with ``block``)."""
        t0 = time.perf_counter()
        while self.cutting:
            if block:        # the last cuts: queued ones are run here too (in reverse: the
                # workers take the queue's head), the others waited for
                queued = [f for f in self.cutting if not f.running() and not f.done()]
                done = queued[-1:] or wait(list(self.cutting), return_when=FIRST_COMPLETED)[0]
            else:
                done = [f for f in self.cutting if f.done()]
            if not done:
                break
            for fut in done:
                it, prep = self.cutting.pop(fut)
                try:
                    result, host_seconds = self.outcome(fut)
                except Exception as exc:  # noqa: BLE001
                    if _fatal(exc):
                        raise
                    self.finish(it, prep, error_text(exc), None)
                    continue
                self.times.add(self.times.host, host_seconds)
                self.finish(it, prep, None, result)
        if block:
            self.times.wait_cut += time.perf_counter() - t0


@contextmanager
def solver_threads(device, host_workers: int):
    """On the CPU with host workers, the solving process's torch threads are the cores the
    workers leave (at least one): threads beyond the free cores spin-wait on a busy machine."""
    if not str(device).startswith("cpu") or host_workers == 0:
        yield
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(max(1, usable_cores() - host_workers))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def run_overlapped(batches: list, job: OverlapJob, workers: int, device, finish: Callable,
                   tell: Callable = lambda line: None) -> OverlapTimes:
    """Run ``job`` over ``batches`` (lists of items) with the host/device overlap (see the
    module notes).

    workers : processes in all: this one solves, ``workers - 1`` prepare and cut (<= 1: all in
        this process)
    finish : ``finish(item, prepared, error, result)`` once per item, in this process, as each
        finishes: ``result`` what ``job.cut`` returned, or ``error`` why it failed
        (``prepared``: its :class:`PreparedMesh`, None where it was not prepared)
    tell : one line per event worth a line (a bisected batch)
    """
    t_start = time.perf_counter()
    host = max(int(workers) - 1, 0)
    with host_pool(host) as pool, solver_threads(device, host):
        run = _Overlap(pool, job, finish, tell, inline=host == 0)
        run.times.workers = host
        ahead = collections.deque()
        todo = collections.deque(batches)
        first = todo.popleft() if todo else None
        for _ in range(LOOKAHEAD - 1 if host else 0):
            if todo:         # the workers start (seconds of imports) on these
                batch = todo.popleft()
                ahead.append((batch, run.prepare(batch)))
        if first is not None:  # meanwhile this process, idle until then, prepares the first batch
            ahead.appendleft((first, run.prepare(first, here=True)))
        while ahead:
            batch, futures = ahead.popleft()
            ready = run.wait_prepared(batch, futures)
            if todo:         # keep the queue full before the solve occupies this process
                nxt = todo.popleft()
                ahead.append((nxt, run.prepare(nxt)))
            run.solve(ready)
            run.times.batches += 1
            run.collect(block=False)
        run.collect(block=True)
    run.times.wall = time.perf_counter() - t_start
    return run.times
