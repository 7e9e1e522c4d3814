"""The batched evaluation (the accelerator's path): host processes feed the solving process and
cut what it solved, so that the device never waits on one core's host work.

::

    host workers      prepare_mesh: load, clean, decimate + surface map   (per mesh, ahead)
         │ queue (futures, LOOKAHEAD batches ahead)
    solving process   pack, AKVFs of the batch as one, untangling and k-means of every round
         │ mesh_cut_job per mesh (its rows only)
    host workers      cut_and_score: boundaries, merge, graph cut, generators per (mesh, k);
                      .seg files, meta file, the mesh's scores.csv row

While batch i is solved, the workers prepare batches i+1 .. i+LOOKAHEAD and cut batches i-1,
i-2, ...; the solving process does host work only where it would otherwise wait: a call no
worker has started when it is needed (the last cuts) is run there, and it prepares the first
batch itself while the workers start.
With ``workers`` <= 1 every stage runs in the solving process, in order (the single-process
device path).

A batch whose solve raises is bisected (its halves solved again, recursively), so one mesh
that cannot be solved fails alone and the others keep their shared solve; a mesh whose load or
cut fails fails alone. Every stage's seconds are in :class:`DeviceRunTimes` (the run's
``settings.json`` records them): ``host_share`` is the share of wall time the solving process
spent on host stages or waiting for them.
"""
from __future__ import annotations

import collections
import json
import logging
import time
from concurrent.futures import FIRST_COMPLETED, wait
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field

import numpy as np

from ..errors import MeshError
from ..io import load_mesh
from ..io.outputs import OutputSpaceError, atomic_write_bytes, write_seg
from ..mesh import MeshBatch, clean_mesh
from ..mesh.coarse import coarse_mesh
from ..parts.rounds import cut_mesh_rounds, mesh_cut_job, segment_rounds
from ..parts.solve import solve_akvfs, solve_quality
from ..pipeline.parallel import InlineExecutor, error_text, halves, host_pool, is_programming_error, usable_cores
from .predict import PredictSettings, eval_akvf_count
from .score import score_mesh

log = logging.getLogger("torchakvf.evaluate")

__all__ = ["predict_on_device", "prepare_mesh", "cut_and_score", "PreparedMesh", "DeviceRunTimes",
           "LOOKAHEAD"]

#: Batches prepared ahead of the one being solved: one hides the host work when it is shorter
#: than a solve, two absorb a slow mesh.
LOOKAHEAD = 2


@dataclass
class PreparedMesh:
    """One mesh ready to pack: the input as read (scored against), cleaned, and its decimation
    (None: solved at full resolution); seconds spent preparing it."""

    mesh: object
    clean: object
    coarse: object
    seconds: float


def prepare_mesh(path, coarse_faces: int | None) -> PreparedMesh:
    """Load, clean and (above 1.25x ``coarse_faces`` faces) decimate one mesh, as
    ``MeshBatch.from_meshes(..., coarse_faces=...)`` does (a failed decimation: full resolution)."""
    t0 = time.perf_counter()
    mesh = load_mesh(path)
    clean = clean_mesh(mesh)
    coarse = None
    if coarse_faces is not None:
        try:
            coarse = coarse_mesh(clean, coarse_faces)
        except MeshError as exc:
            log.warning("%s: solving at full resolution, decimation to %d faces failed: %s",
                        clean.name, coarse_faces, exc.problem)
    return PreparedMesh(mesh, clean, coarse, time.perf_counter() - t0)


def pack(prepared: list, device, coarse_faces: int | None) -> MeshBatch:
    """The batch ``MeshBatch.from_meshes([p.mesh ...], device, coarse_faces)`` makes, from
    meshes prepared elsewhere."""
    mb = MeshBatch.from_meshes([p.clean if p.coarse is None else p.coarse.coarse for p in prepared],
                               device=device)
    if coarse_faces is not None:
        mb.coarse = [p.coarse for p in prepared]
    return mb


def cut_and_score(job, plan, mesh, meta: dict, settings: PredictSettings, score_args: tuple):
    """In a host worker: mesh ``plan``'s parts at each k of ``job``, written as .seg files, its
    meta file, then its scores.csv row. Returns (row, cut seconds, score seconds)."""
    t0 = time.perf_counter()
    costs = {}
    for k, seg in cut_mesh_rounds(job, settings.options):
        write_seg(plan.pred_path(k), seg.labels)
        costs[str(k)] = float(seg.cost)
    old = plan.meta()
    t1 = time.perf_counter()
    meta = {**old, **meta, "costs": {**old.get("costs", {}), **costs}}
    meta["seconds"] = float(old.get("seconds", 0.0)) + meta["seconds"] + (t1 - t0)
    atomic_write_bytes(plan.meta_path, json.dumps(meta, indent=1).encode())
    t2 = time.perf_counter()
    row = score_mesh(plan, mesh, *score_args, None)
    dt = time.perf_counter() - t2
    row.seconds += dt
    return row, t2 - t0, dt


@dataclass
class DeviceRunTimes:
    """Seconds of a batched evaluation's stages. In the solving process: ``pack``, ``akvf``,
    ``rounds`` (untangling + k-means), ``jobs`` (the cut jobs' arrays to the host), ``wait_prepare``
    / ``wait_cut`` (waiting for host workers, or doing their work itself: with no worker, or
    host calls no worker had started when they were needed, ``run_here`` of them), ``other``;
    summed over the host work: ``prepare`` and ``cut`` (+ meta, scoring ``score``)."""

    workers: int = 0
    batches: int = 0
    bisections: int = 0
    run_here: int = 0
    wall: float = 0.0
    pack: float = 0.0
    akvf: float = 0.0
    rounds: float = 0.0
    jobs: float = 0.0
    wait_prepare: float = 0.0
    wait_cut: float = 0.0
    prepare: float = 0.0
    cut: float = 0.0
    score: float = 0.0
    device_seconds: list = field(default_factory=list)

    @property
    def host_share(self) -> float:
        """Share of the wall time the solving process spent on host work or waiting for it."""
        return (self.wait_prepare + self.wait_cut) / self.wall if self.wall > 0 else 0.0

    def record(self) -> dict:
        out = {k: v for k, v in asdict(self).items() if k != "device_seconds"}
        out["solve"] = self.pack + self.akvf + self.rounds + self.jobs
        out["other"] = self.wall - out["solve"] - self.wait_prepare - self.wait_cut
        out["host_share"] = self.host_share
        return out


class _DeviceRun:
    """One batched evaluation under way (see the module notes)."""

    def __init__(self, pool, settings: PredictSettings, score_args: tuple, finish, tell, inline: bool):
        self.pool, self.settings, self.score_args = pool, settings, score_args
        self.finish, self.tell, self.inline = finish, tell, inline
        self.times = DeviceRunTimes()
        self.cutting: dict = {}          # future -> (plan, mesh)
        self.calls: dict = {}            # future -> (fn, args)

    def submit(self, fn, *args):
        """``fn(*args)`` handed to the host workers; the call is kept so that this process can
        run it itself if it has to wait for it before a worker started it (:meth:`outcome`)."""
        fut = self.pool.submit(fn, *args)
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
        pool = InlineExecutor() if here else self.pool
        futures = []
        for p in batch:
            fut = pool.submit(prepare_mesh, p.entry.mesh_path, self.settings.coarse_faces)
            self.calls[fut] = (prepare_mesh, (p.entry.mesh_path, self.settings.coarse_faces))
            futures.append(fut)
        self.times.wait_prepare += time.perf_counter() - t0
        return futures

    def wait_prepared(self, batch, futures) -> list:
        """[(plan, PreparedMesh)] of the batch's meshes that loaded; the others fail here."""
        t0 = time.perf_counter()
        ready = []
        for p, fut in zip(batch, futures):
            try:
                prep = self.outcome(fut)
            except Exception as exc:  # noqa: BLE001 - a bad input fails alone, a bug ends the run
                if is_programming_error(exc):
                    raise
                self.finish(p, None, error_text(exc), None)
                continue
            self.times.prepare += prep.seconds
            ready.append((p, prep))
        self.times.wait_prepare += time.perf_counter() - t0
        return ready

    def solve(self, ready: list) -> None:
        """Solve the meshes ``ready`` as one batch and hand each its cut job; a batch that
        raises is bisected."""
        if not ready:
            return
        s = self.settings
        try:
            t0 = time.perf_counter()
            mb = pack([prep for _, prep in ready], s.device, s.coarse_faces)
            t1 = time.perf_counter()
            fields, fell_back = solve_akvfs(mb, eval_akvf_count(s), s.options)
            t2 = time.perf_counter()
            missing = [sorted(p.missing(False)) for p, _ in ready]
            rounds = list(segment_rounds(fields, missing, s.options, n_fields=s.n_fields, cut=False))
            t3 = time.perf_counter()
            jobs = [mesh_cut_job(fields, rounds, b) for b in range(len(ready))]
            metas = [self.meta(fields, b, fell_back, ready[b][1]) for b in range(len(ready))]
        except Exception as exc:  # noqa: BLE001
            if is_programming_error(exc) or isinstance(exc, OutputSpaceError):
                raise
            exc.__traceback__ = None     # the failed batch's tensors are freed
            if len(ready) == 1:
                self.finish(ready[0][0], ready[0][1].mesh, error_text(exc), None)
                return
            self.times.bisections += 1
            self.tell(f"a batch of {len(ready)} meshes failed ({error_text(exc)}); solving its halves")
            for half in halves(ready):
                self.solve(half)
            return
        t4 = time.perf_counter()
        solve_s = t4 - t0
        self.times.pack += t1 - t0
        self.times.akvf += t2 - t1
        self.times.rounds += t3 - t2
        self.times.jobs += t4 - t3
        self.times.device_seconds.append(solve_s)
        faces = np.array([len(m.faces) for m in fields.batch.meshes], dtype=np.float64)
        for b, (p, prep) in enumerate(ready):
            metas[b]["seconds"] = prep.seconds + solve_s * faces[b] / faces.sum()
            fut = self.submit(cut_and_score, jobs[b], p, prep.mesh, metas[b], s, self.score_args)
            self.cutting[fut] = (p, prep.mesh)
        dt = time.perf_counter() - t4
        if self.inline:              # the cuts ran in this process, in submit
            self.times.wait_cut += dt
            self.collect(block=True)
        else:                        # handing the jobs to the workers' queue
            self.times.jobs += dt

    @staticmethod
    def meta(fields, b: int, fell_back: list, prep: PreparedMesh) -> dict:
        coarse = fields.batch.coarse_of(b)
        meta = {"faces": int(prep.mesh.n_faces),
                "eigenvalues": fields.eigenvalues[b].detach().cpu().numpy().astype(float).tolist(),
                "coarse_faces": None if coarse is None else len(coarse.coarse.faces)}
        meta["converged"], meta["max_residual"] = solve_quality(fields, b)
        why = [w for i, w in fell_back if i == b]
        if why:
            meta["full_resolution_because"] = why[0]
        return meta

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
                plan, mesh = self.cutting.pop(fut)
                try:
                    row, cut_s, score_s = self.outcome(fut)
                except Exception as exc:  # noqa: BLE001
                    if is_programming_error(exc) or isinstance(exc, OutputSpaceError):
                        raise
                    self.finish(plan, mesh, error_text(exc), None)
                    continue
                self.times.cut += cut_s
                self.times.score += score_s
                self.finish(plan, mesh, None, row)
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


def predict_on_device(batches: list, settings: PredictSettings, workers: int, score_args: tuple,
                      finish, tell=lambda line: None) -> DeviceRunTimes:
    """Predict (given k's) and score ``batches`` of :class:`~torchakvf.evaluate.plan.PredictionPlan`
    on the batched path (see the module notes).

    workers : processes in all: this one solves, ``workers - 1`` do the host stages (<= 1: all
        in this process)
    score_args : (protocol, metric groups, auto) of :func:`~torchakvf.evaluate.score.score_mesh`
    finish : ``finish(plan, mesh, error, row)`` once per mesh, in this process: ``row`` its
        scores.csv row, or ``error`` why it failed (``mesh``: its input as loaded, or None)
    tell : one line per event worth a line (a bisected batch)
    """
    t_start = time.perf_counter()
    host = max(int(workers) - 1, 0)
    with host_pool(host) as pool, solver_threads(settings.device, host):
        run = _DeviceRun(pool, settings, score_args, finish, tell, inline=host == 0)
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
