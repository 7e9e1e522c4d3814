"""``torchakvf bench``: throughput of torchakvf's PSB segmentation, against its own baselines.

::

    torchakvf bench --psb DIR --out bench/                      # every mesh, every protocol k
    torchakvf bench --limit 20 --baseline-every 5 --out bench/   # quicker

What is measured, in one process and one run (units: seconds of wall time, ``time.perf_counter``;
faces = the face count of the input file; memory in MiB = 2**20 bytes):

* **Workload.** The PSB meshes selected (``--categories``, then the first ``--limit`` by id),
  each segmented with every k of the benchmark's default protocol, "by-segmentation": the
  distinct segment counts of its human segmentations; a mesh without ground truth gets the
  harness's :data:`~torchakvf.evaluate.harness.DEFAULT_K_NO_GT`. Reading those counts from the
  ground truth is timed apart ("plan") and is no part of any run.
* **Runs.** (a) ``batched``: the evaluation's own path (:func:`~torchakvf.pipeline.batches.prediction_batches`:
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
  repetition's ratios move by tens of percent.
* **Workers.** Runs (a), (b), (a') predict on ``--workers`` processes (one thread each; default
  one per CPU core on CPU); the scipy baseline is one process. Decimation (``--coarse-faces``,
  default 4000) is on for every torchakvf run, as in ``torchakvf eval``.

A warm-up (untimed: one small built-in shape through AKVFs + segmentation on the device) comes
first, so that lazy imports and CUDA start-up are charged to no run. Prediction files are written
to a scratch folder inside ``--out`` (removed at the end); the outputs are ``<out>/report.json``
and ``<out>/report.md`` (:mod:`torchakvf.bench.report`); the runs themselves are in
:mod:`torchakvf.bench.runs`. A mesh whose eigensolve did not converge is listed per run
(``unconverged``).
"""
from __future__ import annotations

import dataclasses
import logging
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from ..devices import resolve_device
from ..errors import TorchAKVFError
from ..evaluate.plan import DEFAULT_K_NO_GT, find_entries, plan_meshes, select_entries
from ..evaluate.predict import PredictSettings, eval_akvf_count
from ..evaluate.settings import eval_segment_options, split_overrides
from ..options import SegmentOptions
from ..pipeline.batches import default_batch_faces
from ..pipeline.outdir import check_output_dir
from ..pipeline.parallel import default_workers
from .report import report_header, write_bench_reports
from .runs import STAGES, BenchMesh, load_scipy_reference, rss_mib, run_scipy, run_torchakvf, warm_up
from .sweep import budget_sweep, check_budgets

log = logging.getLogger("torchakvf.bench")

__all__ = ["run_bench", "BenchSettings", "DEFAULT_BASELINE_EVERY", "STAGES"]

#: Baselines run on every M-th mesh of the selection by default (0: no baselines).
DEFAULT_BASELINE_EVERY = 10


@dataclass(frozen=True)
class BenchSettings:
    """What the bench runs, besides the segmentation options.

    limit : keep the first N selected meshes by id (None: all)
    baseline_every : baselines (b), (c) and run (a') on every M-th selected mesh (0: none)
    categories : PSB category names (list or comma string; None: all)
    n_fields : fields untangled per mesh (None: the engine's default per k)
    coarse_faces : decimate as ``torchakvf eval --coarse-faces`` does (None: full resolution)
    batch_faces : face budget of runs (a) and (a') (None:
        :func:`~torchakvf.pipeline.batches.default_batch_faces`)
    workers : processes of the torchakvf runs (a), (b), (a'), one thread each (None: one per
        CPU core on CPU, 1 on a GPU); the scipy baseline runs in the calling process
    device : torch device of runs (a), (b), (a')
    budgets : face budgets of the "batched vs one at a time" sweep (ints >= 1, or a comma
        string; None or empty: no sweep), see the module notes
    repeats : repetitions of the sweep's runs, interleaved; each timed by its fastest (>= 1)
    """

    limit: int | None = None
    baseline_every: int = DEFAULT_BASELINE_EVERY
    categories: object = None
    n_fields: int | None = None
    coarse_faces: int | None = None
    batch_faces: int | None = None
    workers: int | None = None
    device: str = "cpu"
    budgets: object = None
    repeats: int = 1

    def checked(self, batched: bool | None = None) -> "BenchSettings":
        """These settings with the device resolved and the defaults filled in (``batched``: the
        options' :attr:`~torchakvf.options.SegmentOptions.batched`, which sets the default batch
        budget); one-line errors."""
        if self.limit is not None and int(self.limit) < 1:
            raise TorchAKVFError(f"--limit must be an integer >= 1, got {self.limit}")
        if int(self.baseline_every) < 0:
            raise TorchAKVFError(f"--baseline-every must be an integer >= 0, got {self.baseline_every}")
        if int(self.repeats) < 1:
            raise TorchAKVFError(f"--repeats must be an integer >= 1, got {self.repeats}")
        device = str(resolve_device(self.device))
        coarse = int(self.coarse_faces or 0) or None
        batch_faces = int(default_batch_faces(device, coarse, batched=batched) if self.batch_faces is None
                          else self.batch_faces)
        if batch_faces < 1:
            raise TorchAKVFError(f"--batch-faces must be an integer >= 1, got {batch_faces}")
        workers = default_workers(device) if self.workers is None else int(self.workers)
        return dataclasses.replace(self, device=device, coarse_faces=coarse, batch_faces=batch_faces,
                                   workers=workers, budgets=check_budgets(self.budgets),
                                   baseline_every=int(self.baseline_every), repeats=int(self.repeats))


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


# ---- the bench ----------------------------------------------------------------------------

def run_bench(psb_root, out_dir, options: SegmentOptions | None = None,
              settings: BenchSettings | None = None, *, command_line: dict | None = None,
              **overrides) -> dict:
    """Run the bench (see the module notes) and write ``<out>/report.json`` and ``report.md``.

    psb_root : folder with ``meshes/N.off[.gz]`` and ``gt/N/N_k.seg[.gz]``
    out_dir : output folder (created); everything written goes inside it
    options : the :class:`~torchakvf.options.SegmentOptions` of the torchakvf runs (None: the
        evaluation's defaults, :func:`~torchakvf.evaluate.settings.eval_segment_options`)
    settings : the :class:`BenchSettings` (None: the defaults)
    command_line : the command-line options as given, recorded in the report
    overrides : any field of ``settings`` or ``options`` by name, e.g.
        ``run_bench(root, out, limit=20, baseline_every=5, seed=1)``

    Returns the report as a dict (what ``report.json`` holds; ``problems``: inputs left out).
    """
    mine, seg = split_overrides(overrides, BenchSettings)
    options = eval_segment_options(options, seg)
    settings = dataclasses.replace(settings or BenchSettings(), **mine).checked(options.batched)
    predict = PredictSettings(auto=False, n_fields=settings.n_fields, k_range=None, k_rule=None,
                              coarse_faces=settings.coarse_faces, options=options,
                              device=settings.device)
    # The evaluation's AKVF count: the largest default field count plus the engine's spares.
    n_akvf = eval_akvf_count(predict)
    t_bench = time.perf_counter()
    psb_root = Path(psb_root)
    entries, problems = _select(psb_root, settings.categories, settings.limit)
    out = check_output_dir(out_dir)
    t0 = time.perf_counter()
    meshes, more = _plan(entries, DEFAULT_K_NO_GT, out)
    problems += more
    report = report_header(psb_root, out, settings, options, n_akvf, command_line)
    report["selection"] = _selection(meshes, time.perf_counter() - t0)
    report["problems"] = problems
    for line in problems:
        log.warning("bench: %s", line)
    log.info("bench: %d meshes, %d faces, %d (mesh, k) predictions; plan %.1f s",
             len(meshes), report["selection"]["faces"], report["selection"]["predictions"],
             report["selection"]["plan_seconds"])
    # Written after every run, so that a bench stopped at a time limit leaves the runs it
    # finished: report.json/md with "partial" set, until the final write.
    report.update(comparison=None, wall_seconds=None, partial=True,
                  peak_memory=dict.fromkeys(("ru_maxrss_mib", "worker_maxrss_mib",
                                             "total_rss_bound_mib", "cuda_max_memory_allocated_mib")))

    def checkpoint():
        report["wall_seconds"] = time.perf_counter() - t_bench
        write_bench_reports(out, report)

    work = Path(tempfile.mkdtemp(dir=out, prefix=".bench-work-"))
    try:
        report["warm_up_seconds"] = warm_up(predict, n_akvf)

        def run_one(name, subset, batch_faces):
            return run_torchakvf(name, subset, work, predict, batch_faces=batch_faces,
                                 workers=settings.workers)

        runs = report["runs"]
        runs["batched"] = run_one("batched", meshes, settings.batch_faces)
        checkpoint()
        if settings.baseline_every == 0:
            report["notes"].append("baselines not run (--baseline-every 0)")
        else:
            report["comparison"] = _baselines(meshes, settings, runs, report["notes"], run_one, work,
                                              dict(seed=options.seed, n_akvf=n_akvf), checkpoint)
        if settings.budgets:
            report["budget_sweep"] = budget_sweep(meshes, settings.baseline_every, settings.budgets,
                                                  runs, report["notes"], run_one, settings.repeats,
                                                  checkpoint)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    report["peak_memory"] = _peak_memory(report["runs"])
    report["wall_seconds"] = time.perf_counter() - t_bench
    report["partial"] = False
    write_bench_reports(out, report)
    return report


def _selection(meshes, plan_seconds: float) -> dict:
    return {"meshes": len(meshes), "faces": sum(m.faces for m in meshes),
            "predictions": sum(len(m.ks) for m in meshes),
            "meshes_without_ground_truth": sum(not m.entry.has_gt for m in meshes),
            "mesh_ids": [m.mesh_id for m in meshes],
            "ks": {str(m.mesh_id): m.ks for m in meshes},
            "plan_seconds": plan_seconds}


def _baselines(meshes, settings: BenchSettings, runs: dict, notes: list, run_one, work: Path,
               scipy_args: dict, checkpoint) -> dict:
    """Runs (b), (c) and (a') on every ``baseline_every``-th mesh; returns the report's
    ``comparison`` (the ratios of the baselines to run (a'))."""
    subset = meshes[::settings.baseline_every]
    runs["one_at_a_time"] = run_one("one_at_a_time", subset, 1)
    checkpoint()
    ref, why = load_scipy_reference()
    if ref is None:
        notes.append(why)
        log.warning("bench: %s", why)
        runs["scipy"] = {"name": "scipy", "kind": "scipy", "skipped": why}
    else:
        runs["scipy"] = run_scipy(ref, subset, work, **scipy_args)
        checkpoint()
    baselines = [r for r in (runs["one_at_a_time"], runs["scipy"]) if "skipped" not in r]
    excluded = {}
    for m in subset:
        why_not = [f"{r['name']}: {r['failed'][m.mesh_id]}"
                   for r in (runs["batched"], *baselines) if m.mesh_id in r["failed"]]
        if why_not:
            excluded[str(m.mesh_id)] = "; ".join(why_not)
    compared = [m for m in subset if str(m.mesh_id) not in excluded]
    comp = {"baseline_every": settings.baseline_every, "subset_ids": [m.mesh_id for m in subset],
            "mesh_ids": [m.mesh_id for m in compared], "meshes": len(compared),
            "faces": sum(m.faces for m in compared), "excluded": excluded,
            "torchakvf_run": "batched_subset", "ratios": {}}
    if compared:
        runs["batched_subset"] = run_one("batched_subset", compared, settings.batch_faces)
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
    return comp


def _peak_memory(runs: dict) -> dict:
    bounds = [r["total_rss_bound_mib"] for r in runs.values() if r.get("total_rss_bound_mib")]
    cuda = [r["cuda_max_memory_allocated_mib"] for r in runs.values()
            if r.get("cuda_max_memory_allocated_mib") is not None]
    return {"ru_maxrss_mib": rss_mib(),
            "worker_maxrss_mib": rss_mib(children=True) if bounds else None,
            "total_rss_bound_mib": max(bounds) if bounds else rss_mib(),
            "cuda_max_memory_allocated_mib": max(cuda, default=None)}
