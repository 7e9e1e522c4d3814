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

The run: the meshes still to predict are a corpus run
(:func:`torchakvf.pipeline.runner.run_corpus`, or :func:`~torchakvf.pipeline.ray_runner.run_corpus_ray`
with ``ray_workers``) of :class:`~torchakvf.evaluate.eval_task.EvalTask`, which plans the
batches, writes the predictions and scores each mesh; the runner loads, runs the batches in
turn, side by side (``workers``) or through the host/device overlap (``batched``), holds the
folder's lock and appends one ``manifest.jsonl`` line per mesh (with its scores.csv row).

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

Modules: :mod:`~torchakvf.evaluate.plan` (selection, k's), :mod:`~torchakvf.evaluate.eval_task`
(the runner's task), :mod:`~torchakvf.evaluate.predict` (one batch), :mod:`~torchakvf.evaluate.score` (one mesh),
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
from ..io.outputs import atomic_write_bytes
from ..operators import REMEDIES
from ..options import SegmentOptions
from ..pipeline.batches import default_batch_faces
from ..pipeline.runner import overlapped, run_corpus
from ..progress import progress as progress_bar
from .eval_task import EvalTask, row_of_record
from .plan import DEFAULT_K_NO_GT, PROTOCOLS, find_entries, human_mode, plan_meshes, select_entries
from .predict import PredictSettings
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
    task = EvalTask(plans, predict_settings(options, settings), protocol=settings.protocol, groups=groups,
                    params=recorded["prediction"], batch_bytes=settings.batch_bytes)
    run = _EvalRun(out, plans, task, settings, recorded, problems, progress, t_start)
    run.score_the_rest()
    run.predict()
    return run.finish()


def predict_settings(options: SegmentOptions, settings: EvalSettings) -> PredictSettings:
    """How each batch of an evaluation is predicted."""
    s = settings
    return PredictSettings(auto=s.auto, n_fields=s.n_fields, k_range=s.k_range, k_rule=s.k_rule,
                           coarse_faces=s.coarse_faces, options=options, device=s.device)


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
    """One evaluation under way: a corpus run of its :class:`~torchakvf.evaluate.eval_task.EvalTask`,
    with its rows so far, its failures and its progress lines."""

    def __init__(self, out, plans, task: EvalTask, settings: EvalSettings, recorded, problems,
                 progress, t_start):
        self.out, self.plans, self.task, self.settings = out, plans, task, settings
        self.recorded, self.problems, self.t_start = recorded, problems, t_start
        self.todo = task.todo()
        self.say = progress if callable(progress) else None
        self.lines = progress_bar(0, "torchakvf eval", "faces", enabled=progress is True)
        self.progress = progress
        self.rows: dict[int, MeshScore] = {}
        self.score_seconds = 0.0
        self.predict_seconds = 0.0
        self.tell(f"torchakvf eval: {len(plans)} meshes ({len(plans) - len(self.todo)} already "
                  f"predicted or failed), protocol {settings.protocol}{', k auto' if task.auto else ''}, "
                  f"remedy {task.options.remedy}, out {out}")
        for line in problems:
            self.tell(f"problem: {line}")

    def tell(self, line: str) -> None:
        if self.say is not None:
            self.say(line)
        elif self.progress:
            self.lines.write(line)

    def score(self, plan, failure=None) -> None:
        t0 = time.perf_counter()
        row = score_mesh(plan, None, self.settings.protocol, self.task.groups, self.task.auto, failure)
        dt = time.perf_counter() - t0
        self.score_seconds += dt
        row.seconds += dt
        self.rows[plan.mesh_id] = row

    def score_the_rest(self) -> None:
        """Score the meshes already predicted (or that cannot be)."""
        todo_ids = {p.mesh_id for p in self.todo}
        for p in self.plans:
            if p.mesh_id not in todo_ids:
                self.score(p)
                if p.failure is not None:
                    self.tell(f"mesh {p.mesh_id} failed: {p.failure}")

    def predict(self) -> None:
        """The missing (mesh, k)'s as a corpus run (:func:`~torchakvf.pipeline.runner.run_corpus`),
        each mesh scored as it is written; the reports are rewritten (without plots) after each
        batch (every :data:`REPORT_EVERY` meshes on the batched path)."""
        s, task = self.settings, self.task
        if not self.todo:
            return
        every = REPORT_EVERY if overlapped(task, s.device) else 1
        plan_of = {p.mesh_id: p for p in self.plans}
        seen = [0]

        def on_batch(_, records):
            for rec in records:
                plan = task.plans[rec["path"]]
                if rec["status"] == "ok":
                    self.rows[plan.mesh_id] = row_of_record(rec)
                    self.score_seconds += rec["seconds"].get("score", 0.0)
                else:
                    self.tell(f"mesh {plan.mesh_id} failed: {rec['error']}")
                    self.score(plan_of[plan.mesh_id], rec["error"])
            seen[0] += 1
            if self.say is not None and every == 1:
                faces = sum(task.plans[r["path"]].faces for r in records)
                self.say(f"batch {seen[0]}: {len(records)} meshes, {faces} faces")
            if seen[0] % every == 0:
                self.write_reports()

        paths = [p.entry.mesh_path for p in self.todo]
        if s.ray_workers:
            from ..pipeline.ray_runner import run_corpus_ray

            summary = run_corpus_ray(paths, self.out, task, batch_faces=s.batch_faces, device=s.device,
                                     seed=task.seed, workers=s.ray_workers, on_batch=on_batch)
        else:
            summary = run_corpus(paths, self.out, task, batch_faces=s.batch_faces, device=s.device,
                                 seed=task.seed, progress=self.say is None and bool(self.progress),
                                 on_batch=on_batch, workers=s.workers)
        self.predict_seconds = summary.elapsed - self.score_seconds
        if summary.timings is not None:
            self.recorded["run"]["timings"] = summary.timings
            atomic_write_bytes(self.out / "settings.json", json.dumps(self.recorded, indent=2).encode())

    def write_reports(self) -> None:
        write_reports(self.out, self.rows, self.plans, self.settings, self.task.groups,
                      time.perf_counter() - self.t_start, self.recorded, plot=False, problems=self.problems)

    def finish(self) -> EvalSummary:
        wall = time.perf_counter() - self.t_start
        summary = write_reports(self.out, self.rows, self.plans, self.settings, self.task.groups, wall,
                                self.recorded, plot=self.settings.plot, problems=self.problems)
        summary.predict_seconds = self.predict_seconds
        summary.score_seconds = self.score_seconds
        n_failed = sum(r.status.startswith("failed") for r in summary.rows)
        self.tell(f"done in {wall / 60:.1f} min: overall 1-RI {summary.rand_index_error:.4f} "
                  f"({sum(r.scored for r in summary.rows)} meshes scored, {n_failed} failed, "
                  f"{len(self.problems)} input problems) -> {self.out / 'summary.md'}")
        return summary
