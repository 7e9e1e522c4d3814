"""Benchmark evaluation on the Princeton Segmentation Benchmark: predict, score, summarise.

:func:`evaluate_psb` runs the method on (a selection of) the PSB meshes and writes::

    <out>/pred/<id>/<id>_k<k>.seg     one prediction per distinct k asked for (PSB format)
    <out>/pred/<id>/<id>_meta.json    per mesh: compute seconds, Killing eigenvalues, k-means costs
                                      (and, with k = "auto", the scan of k's and the k chosen)
    <out>/scores.csv                  per mesh: category, faces, k's, every metric, seconds, status
    <out>/summary.md                  per category and overall, with reference rows
    <out>/rand_index.png              per-category 1 - RI bars (the paper's Figure 11)
    <out>/settings.json               the settings that made the predictions

Protocols (:data:`PROTOCOLS`)
    ``"by-segmentation"`` (the benchmark's default): for each human segmentation j of a mesh,
    the prediction with k = its segment count k_j is compared with segmentation j only; the
    mesh's score is the mean over its human segmentations. ``"by-model"``: one prediction per
    mesh with k = the most common human segment count (ties: the smaller), compared with every
    human segmentation, mean. With ``k_mode="auto"`` each mesh gets one prediction with the k
    :mod:`torchakvf.evaluate.k_auto` chooses, compared with every human segmentation, mean.

Meshes without human segmentations (held-back categories) are predicted with
:data:`DEFAULT_K_NO_GT` parts (or the automatic k) and get status ``"no score"``.

Batching (:func:`torchakvf.pipeline.batches.prediction_batches`): meshes are sorted by (number
of k's needed, face count) and grouped into batches of at most ``batch_faces`` faces. Per batch
the AKVFs are computed once (segment's largest default field count plus its spare fields, or
``n_fields``; :func:`~torchakvf.evaluate.predict.eval_akvf_count`) and shared by every k.
Meshes need different sets of k's, so the batch is segmented in *rounds*: round r segments
every mesh with its r-th k (ascending; :func:`torchakvf.parts.rounds.segment_rounds`). A mesh
with fewer k's than the round count is clustered with k = 1 in the later rounds (trivial) and
its parts are not cut. Rounds whose field counts agree share one untangling. The default
budget is :func:`torchakvf.pipeline.batches.default_batch_faces` for the device.

Resume: a prediction file is written atomically as soon as its round is done; a re-run skips
every (mesh, k) whose file exists, so an interrupted run loses at most one round of one batch.
A mesh whose predictions all exist is only scored. ``settings.json`` guards against mixing
predictions made with different settings in one output folder.

Bad inputs do not end the run: a human ``.seg`` that cannot be used (wrong line count,
non-integer label, empty, in another mesh's folder), a mesh file outside the benchmark's
numbering and a corrupt meta file are each reported on their own line naming the file (also in
summary.md, "Input problems"); a mesh whose header cannot be read fails alone. Everything else
is scored and the reports are written; :attr:`EvalSummary.failed` then says something went
wrong (``torchakvf eval`` exits 1). A mesh whose eigensolve did not converge is scored and
flagged (``converged`` in its meta file and scores.csv, a summary.md section).

Modules: :mod:`~torchakvf.evaluate.plan` (selection, k's, batches),
:mod:`~torchakvf.evaluate.predict` (one batch), :mod:`~torchakvf.evaluate.score` (one mesh),
:mod:`~torchakvf.evaluate.report` (scores.csv, summary.md, rand_index.png); this one runs them.

The ``seconds`` of a mesh are its share (by face count) of the AKVF solve of its batch and of
each segmentation round it took part in (accumulated over runs, kept in ``_meta.json``), plus
the time spent scoring it in this run.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from ..devices import resolve_device
from ..errors import TorchAKVFError
from ..io.outputs import OutputSpaceError, atomic_write_bytes
from ..operators import REMEDIES
from ..options import SegmentOptions
from ..pipeline.batches import MemoryBudget, batch_bytes_budget, default_batch_faces, prediction_batches
from ..pipeline.parallel import default_workers, map_batches
from ..progress import progress as progress_bar
from ..solvers.akvf_solver import batched_by_default
from .plan import DEFAULT_K_NO_GT, PROTOCOLS, find_entries, human_mode, plan_meshes, select_entries
from .predict import PredictSettings, eval_akvf_count, predict_in_worker
from .report import REFERENCES, EvalSummary, write_reports
from .score import METRIC_GROUPS, METRICS, MeshScore, parse_metrics, score_mesh, score_segmentation
from .settings import EvalSettings, eval_segment_options, prediction_record, settings_guard, split_overrides

__all__ = ["evaluate_psb", "resolve_eval_settings", "EvalSettings", "EvalSummary", "MeshScore",
           "PROTOCOLS", "METRIC_GROUPS", "METRICS", "DEFAULT_K_NO_GT", "REFERENCES", "parse_metrics",
           "score_segmentation", "human_mode"]


def resolve_eval_settings(options: SegmentOptions | None, settings: EvalSettings | None,
                          overrides: dict) -> tuple[SegmentOptions, EvalSettings]:
    """(segmentation options, evaluation settings) of a run: ``options`` and ``settings`` (None:
    the defaults) with the keyword ``overrides`` applied, each to the one it names; the device
    resolved and the batch budget filled in. One-line errors for bad values."""
    mine, seg = split_overrides(overrides, EvalSettings)
    settings = EvalSettings(**mine) if settings is None else EvalSettings(**{**vars(settings), **mine})
    # before any work: one line, not every mesh failed
    settings = EvalSettings(**{**vars(settings), "device": str(resolve_device(settings.device))}).checked()
    options = eval_segment_options(options, seg, auto=settings.auto)
    if settings.batch_faces is None:
        budget = default_batch_faces(settings.device, settings.coarse_faces, batched=options.batched)
        settings = EvalSettings(**{**vars(settings), "batch_faces": budget})
    if options.remedy not in REMEDIES:
        raise TorchAKVFError(f"unknown remedy {options.remedy!r}; choose from {', '.join(REMEDIES)}")
    return options, settings


def evaluate_psb(psb_root, out_dir, options: SegmentOptions | None = None,
                 settings: EvalSettings | None = None, *, progress=True, **overrides) -> EvalSummary:
    """Run the method on PSB meshes, score it against the human segmentations, write reports.

    Parameters
    ----------
    psb_root : folder with ``meshes/N.off[.gz]`` and ``gt/N/N_k.seg[.gz]``
    out_dir : output folder (see the module notes for what is written; re-running resumes)
    options : the :class:`~torchakvf.options.SegmentOptions` of every prediction (None:
        the package's defaults, except ``refine=False``:
        :data:`~torchakvf.evaluate.settings.EVAL_SEGMENT_DEFAULTS`; with k auto, the scan's
        merge weights)
    settings : the :class:`~torchakvf.evaluate.settings.EvalSettings` (selection, protocol, k,
        n_fields, decimation, metrics, batch budget, workers, device, plot; None: defaults)
    progress : True (a bar on a terminal, log lines otherwise), False, or a callable taking
        one line (each batch and each problem)
    overrides : any field of ``settings`` or ``options`` by name, e.g.
        ``evaluate_psb(root, out, categories="Human", k_mode="auto", seed=1, method="paper")``

    Returns
    -------
    EvalSummary (``.failed``: whether any mesh failed or any input was left out)
    """
    t_start = time.perf_counter()
    options, settings = resolve_eval_settings(options, settings, overrides)
    groups = parse_metrics(settings.metrics)
    root = Path(psb_root)
    entries, problems = find_entries(root)
    entries = select_entries(entries, settings.categories, settings.ids, settings.per_category)
    if not entries:
        raise TorchAKVFError(f"no PSB meshes selected under {root}")
    out = Path(out_dir)
    recorded = _record_settings(out, root, entries, options, settings, groups)
    plans = plan_meshes(entries, out, settings.protocol, settings.auto, settings.default_k)
    for p in plans:
        problems.extend(p.problems)
    run = _EvalRun(out, plans, options, settings, groups, recorded, problems, progress, t_start)
    run.score_the_rest()
    run.predict()
    return run.finish()


def _record_settings(out: Path, root: Path, entries, options, settings: EvalSettings, groups) -> dict:
    """settings.json: what makes the predictions (guarded: a folder holds one kind) and how
    this run ran. Returns {"prediction": ..., "run": ...}."""
    pred = prediction_record(options, settings)
    settings_guard(out, pred)
    s = settings
    run = dict(psb_root=str(root), protocol=s.protocol,
               categories=None if s.categories is None else sorted({e.category for e in entries}),
               ids=None if s.ids is None else sorted(e.mesh_id for e in entries),
               per_category=s.per_category, batch_faces=int(s.batch_faces), metrics=list(groups),
               device=str(s.device))
    recorded = {"prediction": pred, "run": run}
    atomic_write_bytes(out / "settings.json", json.dumps(recorded, indent=2).encode())
    return recorded


#: Meshes finished between two rewrites of the reports on the batched path.
REPORT_EVERY = 16


class _EvalRun:
    """One evaluation under way: its rows so far, its failures and its progress lines."""

    def __init__(self, out, plans, options, settings: EvalSettings, groups, recorded, problems,
                 progress, t_start):
        self.out, self.plans, self.options, self.settings = out, plans, options, settings
        self.groups, self.recorded, self.problems, self.t_start = groups, recorded, problems, t_start
        self.auto = settings.auto
        self.todo = [p for p in plans if p.failure is None and p.missing(self.auto)]
        self.faces_of = {p.mesh_id: p.faces for p in self.todo}
        self.say = progress if callable(progress) else None
        self.progress = progress
        self.bar = progress_bar(sum(self.faces_of.values()), "torchakvf eval", "faces",
                                enabled=progress is True)
        self.rows: dict[int, MeshScore] = {}
        self.failed: dict[int, str] = {}
        self.score_seconds = 0.0
        self.predict_seconds = 0.0
        self.device_times = None
        self.tell(f"torchakvf eval: {len(plans)} meshes ({len(plans) - len(self.todo)} already "
                  f"predicted or failed), protocol {settings.protocol}{', k auto' if self.auto else ''}, "
                  f"remedy {options.remedy}, out {out}")
        for line in problems:
            self.tell(f"problem: {line}")

    def tell(self, line: str) -> None:
        if self.say is not None:
            self.say(line)
        elif self.progress:
            self.bar.write(line)

    def score(self, plan, mesh) -> None:
        t0 = time.perf_counter()
        row = score_mesh(plan, mesh, self.settings.protocol, self.groups, self.auto,
                         self.failed.get(plan.mesh_id))
        dt = time.perf_counter() - t0
        self.score_seconds += dt
        row.seconds += dt
        self.rows[plan.mesh_id] = row

    def score_the_rest(self) -> None:
        """Score the meshes already predicted (or that cannot be)."""
        todo_ids = {p.mesh_id for p in self.todo}
        for p in self.plans:
            if p.mesh_id not in todo_ids:
                self.score(p, None)
                if p.failure is not None:
                    self.tell(f"mesh {p.mesh_id} failed: {p.failure}")

    @property
    def batched(self) -> bool:
        """Whether batches are solved as one (the accelerator's path; the device's default)."""
        b = self.options.batched
        return batched_by_default(self.settings.device) if b is None else bool(b)

    def predict(self) -> None:
        """Predict the missing (mesh, k)'s batch by batch, scoring each batch's meshes as it
        finishes and rewriting the reports (without plots) after each. A batched run with given
        k's goes through :func:`~torchakvf.evaluate.device_run.predict_on_device` (host workers
        feed the solving process)."""
        if self.batched and not self.auto:
            return self.predict_on_device()
        s = self.settings
        t_pred = time.perf_counter()
        score_before = self.score_seconds
        n_missing = {p.mesh_id: len(p.missing(self.auto)) for p in self.todo}
        workers = 1 if s.workers is None else int(s.workers)
        batches = prediction_batches(self.todo, self.faces_of, n_missing, s.batch_faces,
                                     coarse_faces=s.coarse_faces, workers=workers, device=s.device)
        predict = PredictSettings(auto=self.auto, n_fields=s.n_fields, k_range=s.k_range,
                                  k_rule=s.k_rule, coarse_faces=s.coarse_faces, options=self.options,
                                  device=s.device)
        n_batch = 0
        # A full output disk ends the run (as in the corpus runner) instead of failing every mesh.
        for res in map_batches(batches, predict_in_worker, (predict,), workers=workers,
                               fatal=(OutputSpaceError,)):
            if res.split:
                self.tell(f"a batch of {len(res.batch)} meshes failed ({res.error}); retrying its halves")
                continue
            n_batch += 1
            self._batch_done(res, n_batch)
            write_reports(self.out, self.rows, self.plans, s, self.groups,
                          time.perf_counter() - self.t_start, self.recorded, plot=False,
                          problems=self.problems)
        self.bar.close()
        self.predict_seconds = time.perf_counter() - t_pred - (self.score_seconds - score_before)

    def predict_on_device(self) -> None:
        from .device_run import predict_on_device

        s = self.settings
        t_pred = time.perf_counter()
        workers = default_workers(s.device, batched=True) if s.workers is None else int(s.workers)
        n_missing = {p.mesh_id: len(p.missing(self.auto)) for p in self.todo}
        # one solving process: consecutive batches under the face and memory budgets
        memory = MemoryBudget(batch_bytes_budget(s.device, s.batch_bytes), eval_akvf_count(s))
        batches = prediction_batches(self.todo, self.faces_of, n_missing, s.batch_faces,
                                     coarse_faces=s.coarse_faces, workers=1, device=s.device, memory=memory)
        predict = PredictSettings(auto=False, n_fields=s.n_fields, k_range=s.k_range, k_rule=s.k_rule,
                                  coarse_faces=s.coarse_faces, options=self.options, device=s.device)
        done = [0]

        def finish(plan, mesh, error, row):
            if error is not None:
                self.failed[plan.mesh_id] = error
                self.tell(f"mesh {plan.mesh_id} failed: {error}")
                self.score(plan, mesh)
            else:
                self.rows[plan.mesh_id] = row
            self.bar.update(self.faces_of[plan.mesh_id], note=f"mesh {plan.mesh_id}")
            done[0] += 1
            if done[0] % REPORT_EVERY == 0:
                self.write_reports()

        self.device_times = predict_on_device(batches, predict, workers,
                                              (s.protocol, self.groups, False), finish, self.tell)
        self.bar.close()
        host_score = self.device_times.host.get("score", 0.0)     # in the host workers
        self.score_seconds += host_score
        self.predict_seconds = time.perf_counter() - t_pred - host_score
        self.recorded["run"]["timings"] = self.device_times.record()
        atomic_write_bytes(self.out / "settings.json", json.dumps(self.recorded, indent=2).encode())
        self.tell(self.device_times.line())

    def write_reports(self) -> None:
        write_reports(self.out, self.rows, self.plans, self.settings, self.groups,
                      time.perf_counter() - self.t_start, self.recorded, plot=False, problems=self.problems)

    def _batch_done(self, res, n_batch: int) -> None:
        if res.error is not None:
            p = res.batch[0]
            self.failed[p.mesh_id] = res.error
            self.tell(f"mesh {p.mesh_id} failed: {res.error}")
            meshes = {}
            self.bar.update(self.faces_of[p.mesh_id], note=f"mesh {p.mesh_id}: failed")
        else:
            meshes, msg, _ = res.result
            self.bar.update(int(sum(self.faces_of[p.mesh_id] for p in res.batch)), note=msg)
            if self.say is not None:
                self.say(f"batch {n_batch}: {msg}")
        for p in res.batch:
            self.score(p, meshes.get(p.mesh_id))

    def finish(self) -> EvalSummary:
        wall = time.perf_counter() - self.t_start
        summary = write_reports(self.out, self.rows, self.plans, self.settings, self.groups, wall,
                                self.recorded, plot=self.settings.plot, problems=self.problems)
        summary.predict_seconds = self.predict_seconds
        summary.score_seconds = self.score_seconds
        n_failed = sum(r.status.startswith("failed") for r in summary.rows)
        self.tell(f"done in {wall / 60:.1f} min: overall 1-RI {summary.rand_index_error:.4f} "
                  f"({sum(r.scored for r in summary.rows)} meshes scored, {n_failed} failed, "
                  f"{len(self.problems)} input problems) -> {self.out / 'summary.md'}")
        return summary
