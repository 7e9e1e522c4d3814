"""The PSB evaluation as a task of the corpus runner (:func:`torchakvf.pipeline.runner.run_corpus`):
the runner loads the meshes, runs the batches (in turn, side by side in ``workers`` processes,
or through the host/device overlap with ``batched``), writes the manifest and holds the folder's
lock; the task says which k's each mesh needs, writes ``pred/<id>/<id>_k<k>.seg`` and the meta
file, and scores each mesh as it is written (its scores.csv row travels back in its manifest
record, ``score``).

Hooks the runner calls (see :mod:`torchakvf.pipeline.execute`):

* ``done_already(item)``: resume is the evaluation's own: a mesh is done when every k it needs
  has its prediction file (or it cannot be evaluated at all); the manifest records, but does not
  decide. Predictions accumulate across runs and protocols, and ``settings.json`` guards the
  folder (:func:`~torchakvf.evaluate.settings.settings_guard`).
* ``plan_batches(items, ...)``: :func:`~torchakvf.pipeline.batches.prediction_batches`: meshes
  sorted by how many k's they need, then size.
* ``process(items, device)``: one AKVF solve per batch shared by every k, segmented in rounds
  (:func:`~torchakvf.evaluate.predict.predict_batch`); each round's predictions are written as
  soon as it is done, so an interrupt loses at most one round of one batch.
* ``solve_prepared(batch, items)`` / ``cut(cut input)``: the batched path's two halves
  (given k's; k auto runs whole, :attr:`overlappable`).
* ``write(item, output, out_dir)``: the cut predictions and the meta file (batched path), then
  the mesh's score.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.outputs import write_seg
from ..parts.rounds import cut_mesh_rounds, mesh_cut_job, segment_rounds
from ..parts.solve import solve_akvfs
from ..pipeline.batches import MemoryBudget, batch_bytes_budget, prediction_batches
from .predict import PredictSettings, eval_akvf_count, predict_batch, solve_meta, write_meta
from .score import MeshScore, score_mesh

__all__ = ["EvalTask", "EvalOutput", "row_of_record"]


@dataclass
class EvalOutput:
    """What the task computed for one mesh.

    labels : {k: labels [F]} still to write (batched path); None: written during the rounds
    meta : this run's entries of the mesh's meta file (batched path); None: written already
    row : the mesh's scores.csv row, once :meth:`EvalTask.write` scored it
    """

    labels: dict | None = None
    meta: dict | None = None
    row: MeshScore | None = None


def _plain(value):
    """``value`` with numpy scalars as Python ones (same numbers), for the manifest's JSON."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def row_of_record(record: dict) -> MeshScore:
    """The scores.csv row a manifest record of :class:`EvalTask` carries (``score``; the k's of
    its k auto details are ints again where the record went through JSON)."""
    row = MeshScore(**record["score"])
    if row.k_auto is not None:
        by_k = row.k_auto.get("rand_index_error_by_k", {})
        row.k_auto = {**row.k_auto, "rand_index_error_by_k": {int(k): v for k, v in by_k.items()}}
    return row


class EvalTask:
    """Predict and score PSB meshes (see the module notes).

    plans : the :class:`~torchakvf.evaluate.plan.PredictionPlan` of every selected mesh
    predict : how a batch is predicted (options, k auto, fields, decimation, device)
    protocol, groups : how a mesh is scored (:func:`~torchakvf.evaluate.score.score_mesh`)
    params : what the manifest records as the task's parameters (settings.json's "prediction")
    batch_bytes : on the batched path, bytes a batch's padded solver arrays may take (None: the
        device's default, :func:`~torchakvf.pipeline.batches.batch_bytes_budget`)
    """

    name = "eval"
    stages = ("akvf", "segment")

    def __init__(self, plans, predict: PredictSettings, *, protocol: str, groups, params: dict,
                 batch_bytes: int | None = None):
        self.plans = {str(Path(p.entry.mesh_path).resolve()): p for p in plans}
        self.by_stem: dict = {}
        self.predict, self.protocol, self.groups = predict, protocol, tuple(groups)
        self.params = params
        self.batch_bytes = batch_bytes

    @property
    def options(self):
        return self.predict.options

    @property
    def auto(self) -> bool:
        return self.predict.auto

    @property
    def coarse_faces(self):
        return self.predict.coarse_faces

    @property
    def seed(self) -> int:
        return int(self.options.seed)

    @property
    def overlappable(self) -> bool:
        """k auto runs whole (its scan cuts every k of a mesh to read the merge costs)."""
        return not self.auto

    def plan_of(self, item):
        return self.plans[item.key]

    def done_already(self, item) -> bool:
        """Whether ``item``'s mesh needs no prediction: every k it needs has its file, or it
        cannot be evaluated (its plan's failure)."""
        plan = self.plan_of(item)
        self.by_stem[item.stem] = plan
        return plan.failure is not None or not plan.missing(self.auto)

    def todo(self) -> list:
        """The plans of the meshes still to predict."""
        return [p for p in self.plans.values() if p.failure is None and p.missing(self.auto)]

    def plan_batches(self, items, batch_faces: int, *, device="cpu", workers=None) -> list:
        """Batches of ``items`` by (k's still needed, faces), as the evaluation has always cut
        them: a mesh's predictions depend on the meshes that share its batched solve."""
        from ..pipeline.runner import overlapped

        by_id = {self.plan_of(it).mesh_id: it for it in items}
        plans = [self.plan_of(it) for it in items]
        faces_of = {p.mesh_id: p.faces for p in plans}
        n_missing = {p.mesh_id: len(p.missing(self.auto)) for p in plans}
        memory = None
        if overlapped(self, device):     # one solving process under the memory budget
            workers = 1
            memory = MemoryBudget(batch_bytes_budget(device, self.batch_bytes), eval_akvf_count(self.predict))
        batches = prediction_batches(plans, faces_of, n_missing, batch_faces, coarse_faces=self.coarse_faces,
                                     workers=1 if workers is None else int(workers), device=device,
                                     memory=memory)
        return [[by_id[p.mesh_id] for p in b] for b in batches]

    def output_paths(self, out_dir, stem: str) -> list[Path]:
        """The mesh's prediction files (the k's it needs, or the k it chose) and meta file."""
        plan = self.by_stem[stem]
        ks = [plan.auto_k()] if self.auto else plan.ks
        return [plan.pred_path(k) for k in ks if k is not None] + [plan.meta_path]

    def process(self, items, device):
        """Predict a batch (in turn or side by side): its predictions and meta files are
        written round by round here; :meth:`write` scores."""
        plans = [self.plan_of(it) for it in items]
        timings: dict = {}
        predict_batch(plans, self.predict, timings=timings,
                      loaded={p.mesh_id: (it.mesh, it.clean) for p, it in zip(plans, items)})
        seconds = {"akvf": timings.get("pack", 0.0) + timings.get("akvf", 0.0),
                   "segment": timings.get("segment", 0.0) + timings.get("write", 0.0)}
        return [EvalOutput() for _ in items], seconds

    def solve_prepared(self, batch, items):
        """The batched path's device half: AKVFs, then every missing k untangled and clustered
        in rounds, not cut. One (cut job, meta entries) per mesh."""
        s = self.predict
        t0 = time.perf_counter()
        fields, fell_back = solve_akvfs(batch, eval_akvf_count(s), s.options)
        t1 = time.perf_counter()
        missing = [sorted(self.plan_of(it).missing(False)) for it in items]
        rounds = list(segment_rounds(fields, missing, s.options, n_fields=s.n_fields, cut=False))
        t2 = time.perf_counter()
        jobs = [mesh_cut_job(fields, rounds, b) for b in range(len(items))]
        metas = [solve_meta(fields, b, fell_back, it.mesh.n_faces) for b, it in enumerate(items)]
        t3 = time.perf_counter()
        faces = np.array([len(m.faces) for m in fields.batch.meshes], dtype=np.float64)
        for b, it in enumerate(items):
            metas[b]["seconds"] = it.seconds.get("load", 0.0) + (t3 - t0) * faces[b] / faces.sum()
        return list(zip(jobs, metas)), {"akvf": t1 - t0, "rounds": t2 - t1, "jobs": t3 - t2}

    def cut(self, cut_input) -> EvalOutput:
        """The batched path's host half for one mesh: its parts at each k."""
        job, meta = cut_input
        t0 = time.perf_counter()
        labels, costs = {}, {}
        for k, seg in cut_mesh_rounds(job, self.options, extras=False):
            labels[k], costs[str(k)] = seg.labels, float(seg.cost)
        meta = {**meta, "costs": costs, "seconds": meta["seconds"] + time.perf_counter() - t0}
        return EvalOutput(labels, meta)

    def write(self, item, out: EvalOutput, out_dir) -> list[Path]:
        """The cut predictions and the meta file where the batched path left them to write,
        then the mesh's scores.csv row (into ``out.row``)."""
        plan = self.plan_of(item)
        if out.labels is not None:
            for k, labels in out.labels.items():
                write_seg(plan.pred_path(k), labels)
            write_meta(plan, out.meta)
        t0 = time.perf_counter()
        out.row = score_mesh(plan, item.mesh, self.protocol, self.groups, self.auto, None)
        dt = time.perf_counter() - t0
        out.row.seconds += dt
        item.seconds["score"] = dt
        return self.output_paths(out_dir, item.stem)

    @staticmethod
    def manifest_fields(out: EvalOutput) -> dict:
        """The mesh's scores.csv row (``score``) and whether its eigensolve converged."""
        return {"converged": out.row.converged, "score": _plain(dataclasses.asdict(out.row))}
