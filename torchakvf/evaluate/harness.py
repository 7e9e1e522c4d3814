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

Batching: meshes are sorted by (number of k's needed, face count) and grouped into batches of
at most ``batch_faces`` faces. Per batch the AKVFs are computed once (n = 36: segment's largest
default, 32, plus its 4 spare fields; or ``n_fields``) and shared by every k. Meshes need
different sets of k's, so the batch is segmented in *rounds*:
round r segments every mesh with its r-th k (ascending;
:func:`torchakvf.parts.engine.segment_rounds`). A mesh with fewer k's than the round count is
clustered with k = 1 in the later rounds (trivial) and its parts are not cut. Rounds whose
field counts agree (every k <= 8 untangles N = 16) share one untangling. The default budget is the corpus runner's for the device
(:data:`torchakvf.pipeline.runner.DEFAULT_BATCH_FACES`: on CPU about one PSB mesh a batch,
which measured faster than larger batches).

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

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from ..devices import resolve_device
from ..errors import TorchAKVFError
from ..fields.akvf import SOLVERS
from ..io.outputs import OutputSpaceError, atomic_write_bytes
from ..operators import REMEDIES
from ..parts.engine import DEFAULT_REMEDY, SegmentOptions
from ..pipeline.parallel import map_batches
from ..progress import progress as progress_bar
from .k_auto import DEFAULT_K_RANGE, DEFAULT_RULE, RULES, check_k_range, scan_merge_weights
from .plan import (DEFAULT_K_NO_GT, PROTOCOLS, batches_per_worker, default_eval_batch_faces, find_entries,
                   heaviest_first, human_mode, make_batches, mesh_work, plan_meshes, select_entries,
                   settings_guard, solved_face_counts)
from .predict import PredictSettings, predict_in_worker
from .report import REFERENCES, EvalSummary, write_reports
from .score import METRIC_GROUPS, METRICS, MeshScore, parse_metrics, score_mesh, score_segmentation

__all__ = ["evaluate_psb", "EvalSummary", "MeshScore", "PROTOCOLS", "METRIC_GROUPS", "METRICS",
           "DEFAULT_K_NO_GT", "REFERENCES", "parse_metrics", "score_segmentation", "human_mode",
           "default_eval_batch_faces", "solved_face_counts", "segment_option_names"]


def segment_option_names() -> set:
    """The segmentation options ``evaluate_psb`` passes on (``**segment_kwargs``)."""
    return (set(SegmentOptions.names()) - {"seed", "remedy"}) | {"coarse_faces"}


def _check_settings(protocol, k_mode, remedy, batch_faces, default_k, n_fields, k_range, k_rule,
                    segment_kwargs):
    if protocol not in PROTOCOLS:
        raise TorchAKVFError(f"unknown protocol {protocol!r}; choose from {', '.join(PROTOCOLS)}")
    if k_mode not in (None, "auto"):
        raise TorchAKVFError(f"k_mode must be None or 'auto', got {k_mode!r}")
    if int(batch_faces) < 1:
        raise TorchAKVFError(f"batch_faces must be positive, got {batch_faces}")
    if not isinstance(default_k, (int, np.integer)) or default_k < 1:
        raise TorchAKVFError(f"default_k must be a positive integer, got {default_k!r}")
    if n_fields is not None and (not isinstance(n_fields, (int, np.integer)) or n_fields < 1):
        raise TorchAKVFError(f"n_fields must be a positive integer, got {n_fields!r}")
    if remedy not in REMEDIES:
        raise TorchAKVFError(f"unknown remedy {remedy!r}; choose from {', '.join(REMEDIES)}")
    unknown = sorted(set(segment_kwargs) - segment_option_names())
    if unknown:
        raise TorchAKVFError(f"unknown segment option(s) {', '.join(unknown)}; "
                             f"choose from {', '.join(sorted(segment_option_names()))}")
    if segment_kwargs.get("solver", "auto") not in SOLVERS:
        raise TorchAKVFError(f"solver must be one of {', '.join(SOLVERS)}, got {segment_kwargs['solver']!r}")
    if k_mode == "auto":
        k_range = tuple(check_k_range(DEFAULT_K_RANGE if k_range is None else k_range))
        if k_rule not in RULES:
            raise TorchAKVFError(f"k_rule must be one of {RULES}, got {k_rule!r}")
    options = {k: v for k, v in segment_kwargs.items() if k != "coarse_faces"}
    return k_range, options


def evaluate_psb(psb_root, out_dir, categories=None, protocol: str = "by-segmentation", ids=None,
                 per_category: int | None = None, seed: int = 0, remedy: str | None = None,
                 n_fields: int | None = None, batch_faces: int | None = None, k_mode: str | None = None,
                 progress=True, metrics=None, k_range=None, k_rule: str = DEFAULT_RULE,
                 default_k: int = DEFAULT_K_NO_GT, plot: bool = True, workers: int | None = None,
                 device: str = "cpu", **segment_kwargs) -> EvalSummary:
    """Run the method on PSB meshes, score it against the human segmentations, write reports.

    Parameters
    ----------
    psb_root : folder with ``meshes/N.off[.gz]`` and ``gt/N/N_k.seg[.gz]``
    out_dir : output folder (see the module notes for what is written; re-running resumes)
    categories : category names (list or comma string; default all 19)
    protocol : "by-segmentation" (default) or "by-model"
    ids : mesh ids (list, or a string like "1,5,21-23"); combined with ``categories``
    per_category : keep only the first N meshes (by id) of each category (quick runs)
    seed, remedy, n_fields : as in :func:`torchakvf.parts.segment` (remedy default
        :data:`torchakvf.parts.DEFAULT_REMEDY`; n_fields default 3 max(k, 8) in multiples of 8, in [16, 32], for method "merge", 2k for "paper")
    batch_faces : face budget of one batch (meshes larger than it run alone; default
        :func:`~torchakvf.evaluate.plan.default_eval_batch_faces` for the device)
    k_mode : None (k from the protocol) or "auto" (:mod:`torchakvf.evaluate.k_auto`)
    progress : True (a bar on a terminal, log lines otherwise), False, or a callable taking
        one line (each batch and each problem)
    metrics : metric groups, e.g. "rand,hamming" (default all: rand,hamming,gce,lce,cd)
    k_range, k_rule : the k's tried and the rule with k_mode="auto" (default (2, 10), k_auto.DEFAULT_RULE)
    default_k : parts for meshes without human segmentations (given-k protocols)
    plot : write rand_index.png
    workers : processes predicting batches side by side, each on one thread (default 1:
        this process; :func:`torchakvf.pipeline.parallel.default_workers` is one per core)
    device : torch device of the predictions (e.g. "cuda"; use one worker there)
    segment_kwargs : the options of :func:`torchakvf.parts.segment` (solver, method, boundary,
        min_part_fraction, kmeans_restarts, ...; :func:`segment_option_names`); ``refine``
        defaults to False here; ``coarse_faces=N`` solves on meshes decimated to about N faces
        (see :mod:`torchakvf.mesh.coarse`) and cuts the parts on the originals

    Returns
    -------
    EvalSummary (``.failed``: whether any mesh failed or any input was left out)
    """
    t_start = time.perf_counter()
    device = str(resolve_device(device))   # before any work: one line, not every mesh failed
    remedy = DEFAULT_REMEDY if remedy is None else remedy
    if batch_faces is None:
        batch_faces = default_eval_batch_faces(device, segment_kwargs.get("coarse_faces"))
    auto = k_mode == "auto"
    groups = parse_metrics(metrics)
    k_range, options = _check_settings(protocol, k_mode, remedy, batch_faces, default_k, n_fields,
                                       k_range, k_rule, segment_kwargs)
    options.setdefault("refine", False)
    segment_kwargs.setdefault("refine", False)
    if auto:   # the scan's own default floor (k_auto.SCAN_MIN_K), recorded in the settings
        options["merge"] = scan_merge_weights(options.get("merge"))
    seg_options = SegmentOptions(seed=int(seed), remedy=remedy, **options)

    root = Path(psb_root)
    entries, problems = find_entries(root)
    entries = select_entries(entries, categories, ids, per_category)
    if not entries:
        raise TorchAKVFError(f"no PSB meshes selected under {root}")

    out = Path(out_dir)
    pred_settings = dict(seed=int(seed), remedy=remedy, n_fields=n_fields, k_mode=k_mode,
                         k_range=list(k_range) if auto else None, k_rule=k_rule if auto else None,
                         default_k=int(default_k),
                         segment_kwargs={k: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else v
                                         for k, v in sorted(segment_kwargs.items())},
                         # every option recorded, also those left to their defaults: predictions
                         # made under other defaults (an older release's method, merge weights,
                         # graph cut, restarts) must not be resumed as these
                         method=seg_options.method,
                         options=json.loads(json.dumps(dataclasses.asdict(seg_options))))
    settings_guard(out, pred_settings)
    run_settings = dict(psb_root=str(root), protocol=protocol, categories=categories if categories is None
                        else sorted({e.category for e in entries}), ids=ids if ids is None else
                        sorted(e.mesh_id for e in entries), per_category=per_category,
                        batch_faces=int(batch_faces), metrics=list(groups), device=str(device))
    atomic_write_bytes(out / "settings.json", json.dumps(
        {"prediction": pred_settings, "run": run_settings}, indent=2).encode())

    plans = plan_meshes(entries, out, protocol, auto, default_k)
    for p in plans:
        problems.extend(p.problems)
    todo = [p for p in plans if p.failure is None and p.missing(auto)]
    faces_of = {p.mesh_id: p.faces for p in todo}
    say = progress if callable(progress) else None
    bar = progress_bar(sum(faces_of.values()), "torchakvf eval", "faces", enabled=progress is True)

    def tell(line: str) -> None:
        if say is not None:
            say(line)
        elif progress:
            bar.write(line)

    tell(f"torchakvf eval: {len(plans)} meshes ({len(plans) - len(todo)} already predicted or "
         f"failed), protocol {protocol}{', k auto' if auto else ''}, remedy {remedy}, out {out}")
    for line in problems:
        tell(f"problem: {line}")

    rows: dict[int, MeshScore] = {}
    score_seconds = 0.0
    failed: dict[int, str] = {}

    def score_and_store(plan, mesh):
        nonlocal score_seconds
        t0 = time.perf_counter()
        rows[plan.mesh_id] = score_mesh(plan, mesh, protocol, groups, auto, failed.get(plan.mesh_id))
        dt = time.perf_counter() - t0
        score_seconds += dt
        rows[plan.mesh_id].seconds += dt

    todo_ids = {p.mesh_id for p in todo}
    for p in plans:   # meshes already predicted (or that cannot be): score only
        if p.mesh_id not in todo_ids:
            score_and_store(p, None)
            if p.failure is not None:
                tell(f"mesh {p.mesh_id} failed: {p.failure}")

    # Sorted by (number of k's still missing, faces): a batch's meshes then need about the same
    # number of segmentation rounds (little padding) and have similar sizes (little padding of
    # the [B, F_max] tensors). The batches then go to the workers heaviest first.
    t_pred = time.perf_counter()
    n_missing = {p.mesh_id: len(p.missing(auto)) for p in todo}
    solved = solved_face_counts(faces_of, segment_kwargs.get("coarse_faces"))
    n_workers = 1 if workers is None else int(workers)
    batches = heaviest_first(make_batches(sorted(todo, key=lambda p: (n_missing[p.mesh_id], faces_of[p.mesh_id],
                                                                      p.mesh_id)), solved, int(batch_faces),
                                          workers=n_workers, work_of=mesh_work(faces_of, n_missing),
                                          per_worker=batches_per_worker(device)),
                             faces_of, n_missing)
    settings = PredictSettings(auto=auto, n_fields=n_fields, k_range=k_range, k_rule=k_rule,
                               coarse_faces=segment_kwargs.get("coarse_faces"), options=seg_options,
                               device=str(device))
    n_batch = 0
    # A full output disk ends the run (as in the corpus runner) instead of failing every mesh.
    for res in map_batches(batches, predict_in_worker, (settings,),
                           workers=1 if workers is None else int(workers), fatal=(OutputSpaceError,)):
        batch = res.batch
        if res.split:
            tell(f"a batch failed ({res.error}); retrying its {len(batch)} meshes one by one")
            continue
        n_batch += 1
        if res.error is not None:
            p = batch[0]
            failed[p.mesh_id] = res.error
            tell(f"mesh {p.mesh_id} failed: {res.error}")
            meshes = {}
            bar.update(faces_of[p.mesh_id], note=f"mesh {p.mesh_id}: failed")
        else:
            meshes, msg, _ = res.result
            bar.update(int(sum(faces_of[p.mesh_id] for p in batch)), note=msg)
            if say is not None:
                say(f"batch {n_batch}: {msg}")
        for p in batch:
            score_and_store(p, meshes.get(p.mesh_id))
        write_reports(out, rows, plans, protocol, groups, auto, time.perf_counter() - t_start,
                      pred_settings, run_settings, plot=False, problems=problems)
    bar.close()
    predict_seconds = time.perf_counter() - t_pred - score_seconds

    wall = time.perf_counter() - t_start
    summary = write_reports(out, rows, plans, protocol, groups, auto, wall, pred_settings,
                            run_settings, plot=plot, problems=problems, workers=n_workers)
    summary.predict_seconds = predict_seconds
    summary.score_seconds = score_seconds
    n_failed = sum(r.status.startswith("failed") for r in summary.rows)
    tell(f"done in {wall / 60:.1f} min: overall 1-RI {summary.rand_index_error:.4f} "
         f"({sum(r.scored for r in summary.rows)} meshes scored, {n_failed} failed, "
         f"{len(problems)} input problems) -> {out / 'summary.md'}")
    return summary
