"""``torchakvf bench``: throughput of torchakvf's PSB segmentation, against its own baselines.

::

    torchakvf bench --psb ../shared/psb --out bench/            # every mesh, every protocol k
    torchakvf bench --limit 20 --baseline-every 5 --out bench/   # quicker

What is measured, in one process and one run (units: seconds of wall time, ``time.perf_counter``;
faces = the face count of the input file; memory in MiB = 2**20 bytes):

* **Workload.** The PSB meshes selected (``--categories``, then the first ``--limit`` by id),
  each segmented with every k of the benchmark's default protocol, "by-segmentation": the
  distinct segment counts of its human segmentations; a mesh without ground truth gets the
  harness's :data:`~torchakvf.evaluate.harness.DEFAULT_K_NO_GT`. Reading those counts from the
  ground truth is timed apart ("plan") and is no part of any run.
* **Runs.** (a) ``batched``: the evaluation's own path (:func:`~torchakvf.evaluate.plan.make_batches`:
  with several workers, batches of equal estimated work under the budget, at least one per
  worker; + :func:`~torchakvf.evaluate.predict.predict_batch`: one AKVF solve per batch shared by every k,
  segmentation in rounds, one ``.seg`` per (mesh, k)) with the ``--batch-faces`` budget (default: the harness's,
  that of ``torchakvf eval``). On every ``--baseline-every``-th mesh of the selection (the 1st,
  the (M+1)-th, ...): (b) ``one_at_a_time``: the same path with a face budget of 1, so each mesh
  is a batch alone; (c) ``scipy``: the plain baseline :mod:`torchakvf.scipy_reference` (skipped with a
  note when it cannot be imported): per mesh one
  ``eigsh`` for the same number of fields, then numpy untangling + numpy spherical k-means per k;
  then (a') ``batched_subset``: a separate batched run on exactly the meshes every run finished,
  the torchakvf time that the baselines are compared with.
* **Per run:** wall seconds, meshes/s and faces/s (finished meshes over wall time), seconds per
  stage ("load": reading files; "pack": clean-up + packing + transfer to the device; "akvf": the
  eigensolve, operator assembly included; "segment": untangling + k-means + boundaries, also
  split by k; "write": prediction files; "other": the rest of the wall time: batch planning,
  bookkeeping), per-mesh seconds (exact for one-mesh batches, face-share estimates in a larger
  batch), failures, ``resource.getrusage(RUSAGE_SELF).ru_maxrss`` after the run (the process's
  peak so far: it never goes down, so a run shows its own peak only where that is a new one) and,
  on CUDA, ``torch.cuda.max_memory_allocated`` (reset before each run).
* **Ratios:** baseline seconds / torchakvf seconds on the same meshes in this run (> 1: torchakvf
  is faster): the baseline's per-mesh seconds summed over the compared meshes (for a baseline
  on several workers, its wall time split over its meshes by their seconds), divided by the wall
  seconds of run (a'); also per stage ("akvf", "segment": summed stage seconds, i.e. per core).
* **Face budgets** (``--budgets B1,B2,...``, off by default): "batched against one at a
  time" at several budgets, on the same meshes in the same run: the baseline subset (every
  ``--baseline-every``-th mesh; every mesh with ``--baseline-every 0``) once one mesh per batch
  (run (b), also run for the sweep when the baselines are off) and once per budget B (runs
  ``budget_B``: batches of <= B solved faces, i.e. decimated faces under ``--coarse-faces``);
  when the subset is every mesh, run (a) is the row of the default budget (not run again).
  Per budget: one-at-a-time seconds / budget_B seconds (>= 1: batching at least as fast), the
  same with CPU seconds (``resource.getrusage`` of this process and its finished workers: what
  other processes' load on a shared machine does not inflate; on CUDA the wall ratio is the one
  that counts), and per stage; a budget whose run had other failures than run (b) is flagged not
  comparable. ``--repeats R`` runs the sweep R times, interleaved (one at a time, B1, B2, ...,
  then again), and times each run by its fastest repetition: on a shared machine one
  repetition's ratios moved by +-30 % (two one-mesh-per-batch runs of the same 6 meshes,
  32.7 s and 38.5 s against 47.8 s).
* **Workers.** Runs (a), (b), (a') predict on ``--workers`` processes (one thread each; default
  one per CPU core on CPU); the scipy baseline is one process. Decimation (``--coarse-faces``,
  default 4000) is on for every torchakvf run, as in ``torchakvf eval``.

A warm-up (untimed: one small built-in shape through AKVFs + segmentation on the device) comes
first, so that lazy imports and CUDA start-up are charged to no run. Prediction files are written
to a scratch folder inside ``--out`` (removed at the end); the outputs are ``<out>/report.json``
and ``<out>/report.md`` (:mod:`torchakvf.evaluate.bench_report`); the runs themselves are in
:mod:`torchakvf.evaluate.bench_runs`. A mesh whose eigensolve did not converge is listed per run
(``unconverged``).
"""
from __future__ import annotations

import logging
import shutil
import tempfile
import time
from pathlib import Path

from .. import __version__
from ..devices import resolve_device
from ..errors import TorchAKVFError
from ..parts.engine import DEFAULT_REMEDY
from ..pipeline.parallel import default_workers
from ..pipeline.runner import check_output_dir
from .bench_report import report_header, write_bench_reports
from .bench_runs import (STAGES, BenchMesh, load_scipy_reference, predict_settings, rss_mib,
                         run_scipy, run_torchakvf, warm_up)
from .predict import eval_akvf_count
from .plan import DEFAULT_K_NO_GT, default_eval_batch_faces, find_entries, plan_meshes, select_entries

log = logging.getLogger("torchakvf.bench")

__all__ = ["run_bench", "DEFAULT_BASELINE_EVERY", "STAGES"]

#: Baselines run on every M-th mesh of the selection by default (0: no baselines).
DEFAULT_BASELINE_EVERY = 10


def _select(psb_root: Path, categories, limit: int | None) -> tuple[list, list]:
    """(the selected entries, problem lines of files left out)."""
    if not (psb_root / "meshes").is_dir():
        raise TorchAKVFError(f"no PSB data at {psb_root} (expected meshes/N.off.gz and "
                             f"gt/N/N_k.seg.gz); pass --psb DIR or set TORCHAKVF_PSB")
    entries, problems = find_entries(psb_root)
    entries = select_entries(entries, categories)
    if limit is not None:
        entries = entries[:int(limit)]
    if not entries:
        raise TorchAKVFError(f"no PSB meshes selected under {psb_root}")
    return entries, problems


def _plan(entries, default_k: int, out: Path) -> tuple[list, list]:
    """Protocol "by-segmentation", as ``evaluate_psb`` plans it (:func:`plan_meshes`): the
    distinct human segment counts of each mesh, or ``[default_k]`` without ground truth.
    Returns (the :class:`BenchMesh` es, problem lines: inputs left out, meshes that cannot run)."""
    meshes, problems = [], []
    for p in plan_meshes(entries, out, "by-segmentation", False, default_k):
        problems.extend(p.problems)
        if p.failure is not None:
            problems.append(f"mesh {p.mesh_id} left out: {p.failure}")
        else:
            meshes.append(BenchMesh(p.entry, p.counts, p.ks, p.faces))
    return meshes, problems


# ---- comparison ---------------------------------------------------------------------------

def _compare(base: dict, ours: dict, ids: list) -> dict:
    """Baseline seconds / torchakvf seconds over ``ids`` (totals and per stage).

    A baseline run on several workers overlaps its meshes' seconds: its wall time is split over
    its meshes in proportion to their seconds. Stage ratios compare summed stage seconds
    (CPU-seconds across workers), i.e. the work per core."""
    per = base["per_mesh"]
    sec = sum(per[i]["seconds"] for i in ids)
    if base.get("workers", 1) > 1:
        total = sum(v["seconds"] for v in per.values())
        sec = base["wall_seconds"] * sec / total if total > 0 else sec
    out = {"baseline_seconds": sec, "torchakvf_seconds": ours["wall_seconds"],
           "ratio": sec / ours["wall_seconds"] if ours["wall_seconds"] > 0 else None,
           "stage_ratios": {}}
    for stage in ("akvf", "segment"):
        if all("stages" in base["per_mesh"][i] for i in ids):
            b = sum(base["per_mesh"][i]["stages"].get(stage, 0.0) for i in ids)
        else:
            b = base["stage_seconds"][stage] if set(ids) == set(base["mesh_ids"]) else None
        t = ours["stage_seconds"][stage]
        out["stage_ratios"][stage] = b / t if b is not None and t > 0 else None
    return out


def _check_budgets(budgets) -> list:
    """Budgets as a sorted list of distinct ints >= 1 (a comma string or a sequence; None: [])."""
    if budgets is None:
        return []
    if isinstance(budgets, str):
        budgets = [b for b in budgets.split(",") if b.strip()]
    out = []
    for b in budgets:
        try:
            v = int(str(b).strip())
        except ValueError:
            raise TorchAKVFError(f"--budgets must be integers >= 1 separated by commas, got {b!r}") from None
        if v < 1:
            raise TorchAKVFError(f"--budgets must be integers >= 1 separated by commas, got {v}")
        out.append(v)
    return sorted(set(out))


def _budget_sweep(meshes, baseline_every: int, budgets: list, runs: dict, work: Path, common: dict,
                  notes: list, repeats: int = 1, checkpoint=lambda: None) -> dict:
    """Batched against one at a time at each face budget, on the same meshes (see the module
    notes). Adds the runs ``budget_B`` (and ``one_at_a_time`` if the baselines did not run it)
    to ``runs``; returns the report's ``budget_sweep``.

    repeats : the one-at-a-time run and every budget's run are repeated, interleaved (one,
        B1, B2, ..., one, B1, ...), and each is timed by its fastest repetition (the least
        disturbed by other load); ``runs`` keeps the first repetition.
    checkpoint : called after each run (writes the partial report)"""
    subset = meshes[::baseline_every] if baseline_every else list(meshes)
    everything = len(subset) == len(meshes)
    default = runs["batched"]["batch_faces"]
    # budget 1 is the one-at-a-time run itself
    rows_budgets = sorted((set(budgets) | ({default} if everything else set())) - {1})
    seconds = {b: [] for b in [1] + rows_budgets}        # 1: the one-at-a-time run
    cpu = {b: [] for b in seconds}
    stage_s = {b: [] for b in seconds}
    failed = {b: set() for b in seconds}
    names = {1: "one_at_a_time"}
    for rep in range(int(repeats)):
        for budget in [1] + rows_budgets:
            if rep == 0 and budget == 1 and "one_at_a_time" in runs:
                run = runs["one_at_a_time"]       # the baselines' own run, on these meshes
            elif rep == 0 and budget == default and everything:
                names[budget], run = "batched", runs["batched"]   # no rerun of run (a)
            else:
                name = names.setdefault(budget, "one_at_a_time" if budget == 1 else f"budget_{budget}")
                run = run_torchakvf(name if rep == 0 else f"{name} (repeat {rep + 1})", subset, work,
                                    batch_faces=budget, **common)
                if rep == 0:
                    runs[name] = run
                checkpoint()
            seconds[budget].append(run["wall_seconds"])
            cpu[budget].append(run.get("cpu_seconds"))
            stage_s[budget].append(run["stage_seconds"])
            failed[budget] |= set(run["failed"])
    one_s = min(seconds[1])
    sweep = {"mesh_ids": [m.mesh_id for m in subset], "meshes": len(subset),
             "faces": sum(m.faces for m in subset), "baseline_run": "one_at_a_time",
             "repeats": int(repeats),
             "ratio": ("one_at_a_time seconds / budget_B seconds (>= 1: batching at least as fast); "
                       "each the fastest of its repeats"),
             "cpu_ratio": ("the same with CPU seconds (this process and its workers): what "
                           "other processes' load does not inflate"),
             "one_at_a_time_seconds_each": seconds[1], "one_at_a_time_cpu_seconds_each": cpu[1],
             "rows": []}
    for budget in rows_budgets:
        name = names[budget]
        comparable = failed[budget] == failed[1]
        if not comparable:
            notes.append(f"run {name} failed on other meshes than one_at_a_time: its ratio is not comparable")
        sec = min(seconds[budget])
        row = {"budget": budget, "run": name, "batches": runs[name]["batches"], "seconds": sec,
               "seconds_each": seconds[budget], "one_at_a_time_seconds": one_s,
               "ratio": one_s / sec if sec > 0 else None, "stage_ratios": {}, "comparable": comparable}
        c1, cb = cpu[1], cpu[budget]
        row["cpu_seconds_each"] = cb
        row["cpu_ratio"] = (min(c1) / min(cb) if None not in c1 + cb and min(cb) > 0 else None)
        for stage in ("akvf", "segment"):
            t = min(x[stage] for x in stage_s[budget])
            row["stage_ratios"][stage] = min(x[stage] for x in stage_s[1]) / t if t > 0 else None
        sweep["rows"].append(row)
        log.info("bench: budget %d: %d batches, %.2f s; one at a time %.2f s: %.2fx (CPU time %.2fx)",
                 budget, row["batches"], sec, one_s, row["ratio"] or 0.0, row["cpu_ratio"] or 0.0)
    return sweep


# ---- the bench ----------------------------------------------------------------------------

def run_bench(psb_root, out_dir, *, limit: int | None = None,
              baseline_every: int = DEFAULT_BASELINE_EVERY, device: str = "cpu", seed: int = 0,
              categories=None, batch_faces: int | None = None, remedy: str | None = None,
              n_fields: int | None = None, segment_kwargs: dict | None = None,
              options: dict | None = None, workers: int | None = None,
              budgets=None, repeats: int = 1) -> dict:
    """Run the bench (see the module notes) and write ``<out>/report.json`` and ``report.md``.

    psb_root : folder with ``meshes/N.off[.gz]`` and ``gt/N/N_k.seg[.gz]``
    out_dir : output folder (created); everything written goes inside it
    limit : keep the first N selected meshes by id (None: all)
    baseline_every : baselines (b), (c) and run (a') on every M-th selected mesh (0: none)
    device, seed : torch device of runs (a), (b), (a'); seed of every random choice
    categories : PSB category names (list or comma string; None: all)
    batch_faces : face budget of runs (a) and (a') (None: :func:`~torchakvf.evaluate.plan.default_eval_batch_faces`)
    remedy, n_fields, segment_kwargs : as in ``evaluate_psb`` (None: its defaults, refine=False;
        ``segment_kwargs["coarse_faces"]`` decimates as ``torchakvf eval --coarse-faces`` does;
        ``solver``, ``method``: the engine's)
    workers : processes of the torchakvf runs (a), (b), (a'), one thread each (None: one per
        CPU core on CPU, 1 on a GPU); the scipy baseline runs in this process
    options : the command-line options as given, recorded in the report
    budgets : face budgets of the "batched vs one at a time" sweep (ints >= 1; None or empty:
        no sweep), see the module notes; the report's ``budget_sweep``
    repeats : repetitions of the sweep's runs, interleaved; each timed by its fastest (>= 1)

    Returns the report as a dict (what ``report.json`` holds; ``problems``: inputs left out).
    """
    if limit is not None and int(limit) < 1:
        raise TorchAKVFError(f"--limit must be an integer >= 1, got {limit}")
    if int(baseline_every) < 0:
        raise TorchAKVFError(f"--baseline-every must be an integer >= 0, got {baseline_every}")
    device = str(resolve_device(device))
    segment_kwargs = dict(segment_kwargs or {})
    workers = default_workers(device) if workers is None else int(workers)
    if batch_faces is None:
        batch_faces = default_eval_batch_faces(device, segment_kwargs.get("coarse_faces"))
    batch_faces = int(batch_faces)
    if batch_faces < 1:
        raise TorchAKVFError(f"--batch-faces must be an integer >= 1, got {batch_faces}")
    budgets = _check_budgets(budgets)
    if int(repeats) < 1:
        raise TorchAKVFError(f"--repeats must be an integer >= 1, got {repeats}")
    remedy = DEFAULT_REMEDY if remedy is None else remedy
    segment_kwargs.setdefault("refine", False)
    # The evaluation's AKVF count: the largest default field count plus the engine's spares.
    n_akvf = eval_akvf_count(predict_settings(device, seed, remedy, n_fields, segment_kwargs))
    t_bench = time.perf_counter()
    psb_root = Path(psb_root)
    entries, problems = _select(psb_root, categories, limit)
    out = check_output_dir(out_dir)

    t0 = time.perf_counter()
    meshes, more = _plan(entries, DEFAULT_K_NO_GT, out)
    problems += more
    plan_seconds = time.perf_counter() - t0
    report = report_header(__version__, psb_root, out, device, seed, batch_faces, baseline_every, limit,
                     categories, remedy, n_akvf, n_fields, segment_kwargs, options)
    report["settings"]["budgets"] = budgets
    report["settings"]["repeats"] = int(repeats)
    report["selection"] = {
        "meshes": len(meshes), "faces": sum(m.faces for m in meshes),
        "predictions": sum(len(m.ks) for m in meshes),
        "meshes_without_ground_truth": sum(not m.entry.has_gt for m in meshes),
        "mesh_ids": [m.mesh_id for m in meshes],
        "ks": {str(m.mesh_id): m.ks for m in meshes},
        "plan_seconds": plan_seconds,
    }
    report["problems"] = problems
    for line in problems:
        log.warning("bench: %s", line)
    log.info("bench: %d meshes, %d faces, %d (mesh, k) predictions; plan %.1f s",
             len(meshes), report["selection"]["faces"], report["selection"]["predictions"],
             plan_seconds)
    work = Path(tempfile.mkdtemp(dir=out, prefix=".bench-work-"))
    notes = report["notes"]
    # Written after every run, so that a bench stopped at a time limit (the GPU check's) leaves
    # the runs it finished: report.json/md with "partial" set, until the final write.
    report.update(comparison=None, wall_seconds=None, partial=True,
                  peak_memory=dict.fromkeys(("ru_maxrss_mib", "worker_maxrss_mib",
                                             "total_rss_bound_mib", "cuda_max_memory_allocated_mib")))

    def checkpoint():
        report["wall_seconds"] = time.perf_counter() - t_bench
        write_bench_reports(out, report)

    try:
        report["warm_up_seconds"] = warm_up(device, seed, remedy, n_akvf, segment_kwargs)
        common = dict(device=device, seed=seed, remedy=remedy, n_fields=n_fields,
                      segment_kwargs=segment_kwargs, workers=workers)
        runs = report["runs"]
        runs["batched"] = run_torchakvf("batched", meshes, work, batch_faces=batch_faces, **common)
        checkpoint()
        if int(baseline_every) == 0:
            notes.append("baselines not run (--baseline-every 0)")
        else:
            subset = meshes[::int(baseline_every)]
            runs["one_at_a_time"] = run_torchakvf("one_at_a_time", subset, work, batch_faces=1,
                                                   **common)
            checkpoint()
            ref, why = load_scipy_reference()
            if ref is None:
                notes.append(why)
                log.warning("bench: %s", why)
                runs["scipy"] = {"name": "scipy", "kind": "scipy", "skipped": why}
            else:
                runs["scipy"] = run_scipy(ref, subset, work, seed=seed, n_akvf=n_akvf)
                checkpoint()
            baselines = [r for r in (runs["one_at_a_time"], runs["scipy"]) if "skipped" not in r]
            excluded = {}
            for m in subset:
                why_not = [f"{r['name']}: {r['failed'][m.mesh_id]}"
                           for r in (runs["batched"], *baselines) if m.mesh_id in r["failed"]]
                if why_not:
                    excluded[str(m.mesh_id)] = "; ".join(why_not)
            compared = [m for m in subset if str(m.mesh_id) not in excluded]
            comp = {"baseline_every": int(baseline_every),
                    "subset_ids": [m.mesh_id for m in subset],
                    "mesh_ids": [m.mesh_id for m in compared], "meshes": len(compared),
                    "faces": sum(m.faces for m in compared), "excluded": excluded,
                    "torchakvf_run": "batched_subset", "ratios": {}}
            if compared:
                runs["batched_subset"] = run_torchakvf("batched_subset", compared, work,
                                                        batch_faces=batch_faces, **common)
                checkpoint()
                ids = [m.mesh_id for m in compared]
                if runs["batched_subset"]["failed"]:
                    notes.append("run batched_subset had failures; its ratios are not comparable")
                for r in baselines:
                    comp["ratios"][r["name"]] = _compare(r, runs["batched_subset"], ids)
            else:
                notes.append("no mesh of the baseline subset finished in every run: no ratios")
            if ref is None:
                comp["ratios"]["scipy"] = None
            report["comparison"] = comp
        if budgets:
            report["budget_sweep"] = _budget_sweep(meshes, int(baseline_every), budgets, runs, work,
                                                   common, notes, repeats, checkpoint)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    bounds = [r["total_rss_bound_mib"] for r in report["runs"].values() if r.get("total_rss_bound_mib")]
    report["peak_memory"] = {"ru_maxrss_mib": rss_mib(),
                             "worker_maxrss_mib": rss_mib(children=True) if bounds else None,
                             "total_rss_bound_mib": max(bounds) if bounds else rss_mib(),
                             "cuda_max_memory_allocated_mib": max(
                                 [r["cuda_max_memory_allocated_mib"] for r in report["runs"].values()
                                  if r.get("cuda_max_memory_allocated_mib") is not None],
                                 default=None)}
    report["wall_seconds"] = time.perf_counter() - t_bench
    report["partial"] = False
    write_bench_reports(out, report)
    return report
