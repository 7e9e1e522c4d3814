"""The batched evaluation's job on the host/device overlap (:mod:`torchakvf.pipeline.overlap`):
host workers load, clean and decimate each PSB mesh; the solving process packs a batch, solves
its AKVFs as one and untangles and clusters every round (:func:`~torchakvf.parts.rounds.segment_rounds`);
host workers cut each mesh's parts at each k, write its .seg and meta files and score it.

The run's stage seconds (:class:`~torchakvf.pipeline.overlap.OverlapTimes`: ``pack``, ``akvf``,
``rounds``, ``jobs`` in the solving process; ``prepare``, ``cut``, ``score`` in the host
workers; the waits and ``host_share``) go to the run's ``settings.json``.
"""
from __future__ import annotations

import json
import time

import numpy as np

from ..io.outputs import atomic_write_bytes, write_seg
from ..parts.rounds import cut_mesh_rounds, mesh_cut_job, segment_rounds
from ..parts.solve import solve_akvfs, solve_quality
from ..pipeline.overlap import LOOKAHEAD, OverlapTimes, PreparedMesh, pack, prepare_mesh, run_overlapped, solver_threads
from .predict import PredictSettings, eval_akvf_count
from .score import score_mesh

__all__ = ["predict_on_device", "cut_and_score", "EvalOverlap",
           # the overlap's own, in torchakvf.pipeline.overlap
           "prepare_mesh", "PreparedMesh", "DeviceRunTimes", "LOOKAHEAD", "pack", "solver_threads"]

#: The stage seconds of a batched run: :class:`~torchakvf.pipeline.overlap.OverlapTimes`.
DeviceRunTimes = OverlapTimes

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


class EvalOverlap:
    """The :class:`~torchakvf.pipeline.overlap.OverlapJob` of an evaluation with given k's: its
    items are :class:`~torchakvf.evaluate.plan.PredictionPlan` s. Picklable."""

    def __init__(self, settings: PredictSettings, score_args: tuple):
        self.settings, self.score_args = settings, score_args

    def prepare(self, plan) -> PreparedMesh:
        return prepare_mesh(plan.entry.mesh_path, self.settings.coarse_faces)

    def solve(self, ready: list, times: OverlapTimes) -> list:
        """Pack, solve and cluster every missing k of the batch; one (cut job, mesh, meta) per
        mesh, its meta's seconds its preparation plus its face share of the solve."""
        s = self.settings
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
        t4 = time.perf_counter()
        times.add(times.stages, {"pack": t1 - t0, "akvf": t2 - t1, "rounds": t3 - t2, "jobs": t4 - t3})
        faces = np.array([len(m.faces) for m in fields.batch.meshes], dtype=np.float64)
        for b, (_, prep) in enumerate(ready):
            metas[b]["seconds"] = prep.seconds + (t4 - t0) * faces[b] / faces.sum()
        return [(jobs[b], prep.mesh, metas[b]) for b, (_, prep) in enumerate(ready)]

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

    def cut(self, plan, cut_input) -> tuple:
        """In a host worker: (scores.csv row, {"cut": s, "score": s})."""
        job, mesh, meta = cut_input
        row, cut_s, score_s = cut_and_score(job, plan, mesh, meta, self.settings, self.score_args)
        return row, {"cut": cut_s, "score": score_s}


def predict_on_device(batches: list, settings: PredictSettings, workers: int, score_args: tuple,
                      finish, tell=lambda line: None) -> OverlapTimes:
    """Predict (given k's) and score ``batches`` of :class:`~torchakvf.evaluate.plan.PredictionPlan`
    on the batched path (:func:`~torchakvf.pipeline.overlap.run_overlapped`).

    workers : processes in all: this one solves, ``workers - 1`` do the host stages (<= 1: all
        in this process)
    score_args : (protocol, metric groups, auto) of :func:`~torchakvf.evaluate.score.score_mesh`
    finish : ``finish(plan, mesh, error, row)`` once per mesh, in this process: ``row`` its
        scores.csv row, or ``error`` why it failed (``mesh``: its input as loaded, or None)
    tell : one line per event worth a line (a bisected batch)
    """
    def done(plan, prep, error, row):
        finish(plan, None if prep is None else prep.mesh, error, row)

    return run_overlapped(batches, EvalOverlap(settings, score_args), workers, settings.device, done, tell)
