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
* **Runs.** (a) ``batched``: the harness's own path (``_make_batches`` + ``_predict_batch`` of
  :mod:`torchakvf.evaluate.harness`: one AKVF solve per batch shared by every k, segmentation in
  rounds, one ``.seg`` per (mesh, k)) with the ``--batch-faces`` budget (default: the harness's,
  that of ``torchakvf eval``). On every ``--baseline-every``-th mesh of the selection (the 1st,
  the (M+1)-th, ...): (b) ``one_at_a_time``: the same path with a face budget of 1, so each mesh
  is a batch alone; (c) ``scipy``: the plain baseline of ``torchakvf/scipy_reference.py``
  (loaded by file path from the source tree; skipped with a note when absent): per mesh one
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
* **Workers.** Runs (a), (b), (a') predict on ``--workers`` processes (one thread each; default
  one per CPU core on CPU); the scipy baseline is one process. Decimation (``--coarse-faces``,
  default 4000) is on for every torchakvf run, as in ``torchakvf eval``.

A warm-up (untimed: one small built-in shape through AKVFs + segmentation on the device) comes
first, so that lazy imports and CUDA start-up are charged to no run. Prediction files are written
to a scratch folder inside ``--out`` (removed at the end); the outputs are ``<out>/report.json``
and ``<out>/report.md``.
"""
from __future__ import annotations

import collections
import datetime as _dt
import json
import logging
import math
import os
import platform
import shutil
import sys
import tempfile
import time
import warnings
from pathlib import Path

from ..errors import TorchAKVFError
from ..mesh.coarse import DEFAULT_COARSE_FACES
from .parallel import default_workers, map_batches

log = logging.getLogger("torchakvf.bench")

__all__ = ["run_bench", "add_bench_arguments", "run_bench_command",
           "DEFAULT_BASELINE_EVERY", "REPORT_JSON", "REPORT_MD"]

#: Baselines run on every M-th mesh of the selection by default (0: no baselines).
DEFAULT_BASELINE_EVERY = 10
REPORT_JSON = "report.json"
REPORT_MD = "report.md"
#: Stage names of a run, in report order.
STAGES = ("load", "pack", "akvf", "segment", "write", "other")
_MIB = 2.0 ** 20


# ---- defaults and inputs ------------------------------------------------------------------

def _load_scipy_reference():
    """(module, None) or (None, why it is skipped): scipy's sparse eigensolver stack can be
    missing pieces on exotic builds, and the bench must still run without its baseline."""
    try:
        from .. import scipy_reference
    except Exception as exc:  # noqa: BLE001 - any import problem means: no baseline, said so
        return None, f"scipy baseline skipped: importing torchakvf.scipy_reference failed ({type(exc).__name__}: {exc})"
    return scipy_reference, None


class _Mesh:
    """One selected PSB mesh: its entry, human segment counts, protocol k's and face count."""

    def __init__(self, entry, counts, ks, faces):
        self.entry, self.counts, self.ks, self.faces = entry, list(counts), list(ks), int(faces)

    @property
    def mesh_id(self) -> int:
        return self.entry.mesh_id


def _select(psb_root: Path, categories, limit: int | None) -> list:
    from ..evaluate import harness as H
    from ..evaluate import psb as P

    if not (psb_root / "meshes").is_dir():
        raise TorchAKVFError(f"no PSB data at {psb_root} (expected meshes/N.off.gz and "
                             f"gt/N/N_k.seg.gz); pass --psb DIR or set TORCHAKVF_PSB")
    try:
        entries = P.find_psb_meshes(psb_root)
    except FileNotFoundError as exc:
        raise TorchAKVFError(str(exc)) from None
    entries = H._select(entries, categories, None, None)
    if limit is not None:
        entries = entries[:int(limit)]
    if not entries:
        raise TorchAKVFError(f"no PSB meshes selected under {psb_root}")
    return entries


def _plan(entries, default_k: int) -> list:
    """Protocol "by-segmentation", as ``evaluate_psb`` plans it: the distinct human segment counts
    of each mesh (sorted), or ``[default_k]`` without ground truth."""
    from ..evaluate import harness as H
    from ..evaluate import psb as P

    out = []
    for e in entries:
        counts = P.human_segment_counts(e) if e.has_gt else []
        ks = sorted(set(counts)) if counts else [int(default_k)]
        out.append(_Mesh(e, counts, ks, H._face_count(e.mesh_path)))
    return out


# ---- measurements -------------------------------------------------------------------------

def _rss_mib(children: bool = False) -> float | None:
    """Peak resident memory so far (ru_maxrss), MiB, of this process or (``children``) of the
    largest of its finished child processes (the worker processes); None where unavailable."""
    try:
        import resource
    except ImportError:  # not on Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_CHILDREN if children else resource.RUSAGE_SELF).ru_maxrss
    return peak / _MIB if sys.platform == "darwin" else peak * 1024 / _MIB  # bytes vs KiB


def _cuda_reset(device) -> None:
    if str(device).startswith("cuda"):
        import torch

        torch.cuda.synchronize(device)
        torch.cuda.reset_peak_memory_stats(device)


def _cuda_peak_mib(device) -> float | None:
    if not str(device).startswith("cuda"):
        return None
    import torch

    torch.cuda.synchronize(device)
    return torch.cuda.max_memory_allocated(device) / _MIB


def _rate(count, seconds) -> float | None:
    return count / seconds if seconds > 0 and count else None


def _finish_run(run: dict, meshes, wall: float, stages: dict, by_k: dict, device) -> dict:
    ok = [m for m in meshes if m.mesh_id not in run["failed"]]
    run["wall_seconds"] = wall
    run["meshes_ok"] = len(ok)
    run["faces_ok"] = sum(m.faces for m in ok)
    run["predictions"] = sum(len(m.ks) for m in ok)
    run["meshes_per_second"] = _rate(len(ok), wall)
    run["faces_per_second"] = _rate(run["faces_ok"], wall)
    stages = {s: float(stages.get(s, 0.0)) for s in STAGES if s != "other"}
    stages["other"] = max(wall - sum(stages.values()), 0.0)
    run["stage_seconds"] = stages
    counts = collections.Counter(k for m in ok for k in m.ks)
    run["segment_seconds_by_k"] = {str(k): {"seconds": float(by_k.get(k, 0.0)),
                                            "predictions": int(counts.get(k, 0))}
                                   for k in sorted(set(by_k) | set(counts))}
    run["ru_maxrss_mib"] = _rss_mib()
    if run.get("workers", 1) > 1:
        # The work ran in the workers: each is at most the largest child's peak, and the run's
        # resident total at most this process's peak plus workers x that.
        run["worker_maxrss_mib"] = _rss_mib(children=True)
        run["total_rss_bound_mib"] = run["ru_maxrss_mib"] + run["workers"] * run["worker_maxrss_mib"]
    run["cuda_max_memory_allocated_mib"] = _cuda_peak_mib(device)
    return run


def _run_torchakvf(name: str, meshes, work: Path, *, batch_faces: int, device: str, seed: int,
                   remedy: str, n_fields, segment_kwargs: dict, workers: int = 1) -> dict:
    """Segment ``meshes`` at every k through the harness's batching and prediction helpers.

    As ``evaluate_psb`` does: sorted by (number of k's, faces, id), cut by ``_make_batches``;
    a failing batch of several meshes is retried one mesh at a time, a failing single mesh is
    recorded in ``failed`` and the run goes on. Returns the run's dict (see the module notes).
    """
    from ..evaluate import harness as H

    run = {"name": name, "kind": "torchakvf", "device": device, "batch_faces": int(batch_faces),
           "workers": int(workers),
           "meshes": len(meshes), "faces": sum(m.faces for m in meshes),
           "mesh_ids": [m.mesh_id for m in meshes], "failed": {}, "batches": 0, "per_mesh": {}}
    pred_root = work / name
    plans = [H._Plan(m.entry, m.counts, m.ks, pred_root / str(m.mesh_id)) for m in meshes]
    faces_of = {m.mesh_id: m.faces for m in meshes}
    n_k = {m.mesh_id: len(m.ks) for m in meshes}
    prog = H._Progress(lambda msg: log.info("bench %s: %s", name, msg), sum(faces_of.values()))
    stages: dict = {}
    by_k: dict = {}
    _cuda_reset(device)
    log.info("bench %s: %d meshes, %d faces, batches of <= %d faces, device %s", name, len(meshes),
             run["faces"], batch_faces, device)
    t_start = time.perf_counter()
    order = sorted(plans, key=lambda p: (n_k[p.mesh_id], faces_of[p.mesh_id], p.mesh_id))
    solved = H.solved_face_counts(faces_of, segment_kwargs.get("coarse_faces"))
    args = (False, seed, remedy, n_fields, None, None, segment_kwargs, faces_of, device)
    for res in map_batches(H._make_batches(order, solved, int(batch_faces)), H._predict_in_worker,
                           args, workers=workers):
        batch = res.batch
        if res.split:
            log.warning("bench %s: batch of %d meshes failed (%s); retrying them one by one",
                        name, len(batch), res.error)
            continue
        run["batches"] += 1
        if res.error is not None:
            run["failed"][batch[0].mesh_id] = res.error
            log.warning("bench %s: mesh %d failed: %s", name, batch[0].mesh_id, res.error)
            continue
        _, msg, timings = res.result
        prog.advance(int(sum(faces_of[p.mesh_id] for p in batch)), msg)
        maxrss = timings.pop("process_maxrss_mib", None)
        for key, val in timings.items():
            if key == "segment_by_k":
                for k, s in val.items():
                    by_k[k] = by_k.get(k, 0.0) + s
            else:
                stages[key] = stages.get(key, 0.0) + val
        dt = res.seconds
        total = sum(faces_of[p.mesh_id] for p in batch) or 1
        for p in batch:
            # process_maxrss_mib: the peak of the process that ran the batch, after it (a new
            # peak shows which batch set it).
            run["per_mesh"][p.mesh_id] = {"seconds": dt * faces_of[p.mesh_id] / total,
                                          "exact": len(batch) == 1, "process_maxrss_mib": maxrss}
        if len(batch) == 1:   # a batch alone: its stages are this mesh's
            run["per_mesh"][batch[0].mesh_id]["stages"] = {
                k: v for k, v in timings.items() if k != "segment_by_k"}
    wall = time.perf_counter() - t_start
    shutil.rmtree(pred_root, ignore_errors=True)  # after the clock: predictions are scratch
    return _finish_run(run, meshes, wall, stages, by_k, device)


def _scipy_segment_mesh(ref, mesh, pred_dir: Path, seed: int, n_akvf: int, stages: dict,
                        by_k: dict) -> None:
    """The plain pipeline on one mesh, its stages added to ``stages`` / ``by_k`` (seconds):
    torchakvf's loader and clean-up (the reference needs a clean, oriented mesh), the reference's
    operator + ``eigsh`` once (``n_akvf`` fields, as torchakvf computes), then per k: Algorithm 1
    on the first clamp(2k, 16, 32) fields (``segment_scipy``'s default), Whitney face vectors,
    their norms and spherical k-means (the reference's default restarts), and one ``.seg``."""
    import numpy as np

    from ..io import load_mesh
    from ..io.outputs import write_seg
    from ..mesh import clean_mesh

    last = [time.perf_counter()]

    def tick(stage, k=None):
        now = time.perf_counter()
        dt, last[0] = now - last[0], now
        stages[stage] = stages.get(stage, 0.0) + dt
        if k is not None:
            by_k[k] = by_k.get(k, 0.0) + dt

    raw = load_mesh(mesh.entry.mesh_path)
    tick("load")
    clean = clean_mesh(raw)
    tick("pack")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # star1 clamping: mesh quality, expected
        R, S1, edges, meta = ref.killing_operator_scipy(clean.vertices, clean.faces)
        S1 = ref._clamp_mass(S1)
        _, forms = ref._solve_akvf(R, S1, min(int(n_akvf), R.shape[0] - 1), -1.0)
    tick("akvf")
    for k in mesh.ks:
        n = min(int(np.clip(2 * k, 16, 32)), forms.shape[1])
        U, _ = ref.untangle_numpy(forms[:, :n], S1, seed=seed)
        feats = np.linalg.norm(ref.whitney_face_vectors_scipy(meta["V"], clean.faces, edges, U), axis=2)
        labels, _ = ref.spherical_kmeans_numpy(feats, min(int(k), len(feats)), seed=seed)
        tick("segment", k)
        write_seg(pred_dir / f"{mesh.mesh_id}_k{k}.seg", clean.labels_to_input_faces(labels))
        tick("write")


def _run_scipy(ref, meshes, work: Path, *, seed: int, n_akvf: int) -> dict:
    """Run (c): :func:`_scipy_segment_mesh` on each mesh, one after the other (CPU)."""
    name = "scipy"
    run = {"name": name, "kind": "scipy", "device": "cpu", "batch_faces": None,
           "meshes": len(meshes), "faces": sum(m.faces for m in meshes),
           "mesh_ids": [m.mesh_id for m in meshes], "failed": {}, "batches": len(meshes),
           "per_mesh": {}}
    pred_root = work / name
    stages: dict = {}
    by_k: dict = {}
    log.info("bench %s: %d meshes, %d faces, one at a time (numpy/scipy, cpu)", name, len(meshes),
             run["faces"])
    t_start = time.perf_counter()
    for i, m in enumerate(meshes, 1):
        mine: dict = {}
        t0 = time.perf_counter()
        pred_dir = pred_root / str(m.mesh_id)
        pred_dir.mkdir(parents=True, exist_ok=True)
        try:
            _scipy_segment_mesh(ref, m, pred_dir, seed, n_akvf, mine, by_k)
        except KeyboardInterrupt:
            raise
        except Exception as exc:  # noqa: BLE001
            run["failed"][m.mesh_id] = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:300]
            log.warning("bench %s: mesh %d failed: %s", name, m.mesh_id, run["failed"][m.mesh_id])
        dt = time.perf_counter() - t0
        for key, val in mine.items():
            stages[key] = stages.get(key, 0.0) + val
        if m.mesh_id not in run["failed"]:
            run["per_mesh"][m.mesh_id] = {"seconds": dt, "exact": True, "stages": mine}
        log.info("bench %s: mesh %d (%d/%d, %d faces, k %s) in %.1f s", name, m.mesh_id, i,
                 len(meshes), m.faces, ",".join(map(str, m.ks)), dt)
    wall = time.perf_counter() - t_start
    shutil.rmtree(pred_root, ignore_errors=True)
    return _finish_run(run, meshes, wall, stages, by_k, "cpu")


def _warm_up(device: str, seed: int, remedy: str, n_akvf: int) -> float:
    """Untimed: a small built-in shape through AKVFs + segment on ``device`` (lazy imports,
    CUDA context and libraries). Returns its seconds (reported, charged to no run)."""
    from .. import shapes
    from ..fields.akvf import akvf
    from ..mesh import Mesh, MeshBatch
    from ..parts import segment

    t0 = time.perf_counter()
    try:
        s = shapes.dumbbell(n_around=12)
        batch = MeshBatch.from_meshes([Mesh(s.vertices, s.faces, name="warm-up")], device=device)
        segment(akvf(batch, n=n_akvf, seed=seed, remedy=remedy), k=2, seed=seed, remedy=remedy,
                refine=False)
    except Exception as exc:  # noqa: BLE001 - a warm-up problem shows up in the runs anyway
        log.warning("bench: warm-up failed (%s: %s); timing without it", type(exc).__name__, exc)
    _cuda_reset(device)
    return time.perf_counter() - t0


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

def run_bench(psb_root, out_dir, *, limit: int | None = None,
              baseline_every: int = DEFAULT_BASELINE_EVERY, device: str = "cpu", seed: int = 0,
              categories=None, batch_faces: int | None = None, remedy: str | None = None,
              n_fields: int | None = None, segment_kwargs: dict | None = None,
              options: dict | None = None, workers: int | None = None) -> dict:
    """Run the bench (see the module notes) and write ``<out>/report.json`` and ``report.md``.

    psb_root : folder with ``meshes/N.off[.gz]`` and ``gt/N/N_k.seg[.gz]``
    out_dir : output folder (created); everything written goes inside it
    limit : keep the first N selected meshes by id (None: all)
    baseline_every : baselines (b), (c) and run (a') on every M-th selected mesh (0: none)
    device, seed : torch device of runs (a), (b), (a'); seed of every random choice
    categories : PSB category names (list or comma string; None: all)
    batch_faces : face budget of runs (a) and (a') (None: :func:`~torchakvf.evaluate.harness.default_eval_batch_faces`)
    remedy, n_fields, segment_kwargs : as in ``evaluate_psb`` (None: its defaults, refine=False;
        ``segment_kwargs["coarse_faces"]`` decimates as ``torchakvf eval --coarse-faces`` does)
    workers : processes of the torchakvf runs (a), (b), (a'), one thread each (None: one per
        CPU core on CPU, 1 on a GPU); the scipy baseline runs in this process
    options : the command-line options as given, recorded in the report

    Returns the report as a dict (what ``report.json`` holds).
    """
    from .. import __version__
    from ..evaluate import harness as H
    from ..parts import DEFAULT_REMEDY
    from ..parts.segment import SPARE_FIELDS, default_n_fields
    from .runner import check_output_dir

    if limit is not None and int(limit) < 1:
        raise TorchAKVFError(f"--limit must be an integer >= 1, got {limit}")
    if int(baseline_every) < 0:
        raise TorchAKVFError(f"--baseline-every must be an integer >= 0, got {baseline_every}")
    segment_kwargs = dict(segment_kwargs or {})
    workers = default_workers(device) if workers is None else int(workers)
    if batch_faces is None:
        batch_faces = H.default_eval_batch_faces(device, segment_kwargs.get("coarse_faces"))
    batch_faces = int(batch_faces)
    if batch_faces < 1:
        raise TorchAKVFError(f"--batch-faces must be an integer >= 1, got {batch_faces}")
    remedy = DEFAULT_REMEDY if remedy is None else remedy
    segment_kwargs.setdefault("refine", False)
    # The harness's AKVF count: the largest default field count plus segment's 4 spares.
    n_akvf = int(n_fields) if n_fields is not None else default_n_fields(10 ** 6) + SPARE_FIELDS
    t_bench = time.perf_counter()
    psb_root = Path(psb_root)
    entries = _select(psb_root, categories, limit)
    out = check_output_dir(out_dir)

    t0 = time.perf_counter()
    meshes = _plan(entries, H.DEFAULT_K_NO_GT)
    plan_seconds = time.perf_counter() - t0
    report = _header(__version__, psb_root, out, device, seed, batch_faces, baseline_every, limit,
                     categories, remedy, n_akvf, n_fields, segment_kwargs, options)
    report["selection"] = {
        "meshes": len(meshes), "faces": sum(m.faces for m in meshes),
        "predictions": sum(len(m.ks) for m in meshes),
        "meshes_without_ground_truth": sum(not m.entry.has_gt for m in meshes),
        "mesh_ids": [m.mesh_id for m in meshes],
        "ks": {str(m.mesh_id): m.ks for m in meshes},
        "plan_seconds": plan_seconds,
    }
    log.info("bench: %d meshes, %d faces, %d (mesh, k) predictions; plan %.1f s",
             len(meshes), report["selection"]["faces"], report["selection"]["predictions"],
             plan_seconds)
    work = Path(tempfile.mkdtemp(dir=out, prefix=".bench-work-"))
    notes = report["notes"]
    try:
        report["warm_up_seconds"] = _warm_up(device, seed, remedy, n_akvf)
        common = dict(device=device, seed=seed, remedy=remedy, n_fields=n_fields,
                      segment_kwargs=segment_kwargs, workers=workers)
        runs = report["runs"]
        runs["batched"] = _run_torchakvf("batched", meshes, work, batch_faces=batch_faces, **common)
        report["comparison"] = None
        if int(baseline_every) == 0:
            notes.append("baselines not run (--baseline-every 0)")
        else:
            subset = meshes[::int(baseline_every)]
            runs["one_at_a_time"] = _run_torchakvf("one_at_a_time", subset, work, batch_faces=1,
                                                   **common)
            ref, why = _load_scipy_reference()
            if ref is None:
                notes.append(why)
                log.warning("bench: %s", why)
                runs["scipy"] = {"name": "scipy", "kind": "scipy", "skipped": why}
            else:
                runs["scipy"] = _run_scipy(ref, subset, work, seed=seed, n_akvf=n_akvf)
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
                runs["batched_subset"] = _run_torchakvf("batched_subset", compared, work,
                                                        batch_faces=batch_faces, **common)
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
    finally:
        shutil.rmtree(work, ignore_errors=True)
    bounds = [r["total_rss_bound_mib"] for r in report["runs"].values() if r.get("total_rss_bound_mib")]
    report["peak_memory"] = {"ru_maxrss_mib": _rss_mib(),
                             "worker_maxrss_mib": _rss_mib(children=True) if bounds else None,
                             "total_rss_bound_mib": max(bounds) if bounds else _rss_mib(),
                             "cuda_max_memory_allocated_mib": max(
                                 [r["cuda_max_memory_allocated_mib"] for r in report["runs"].values()
                                  if r.get("cuda_max_memory_allocated_mib") is not None],
                                 default=None)}
    report["wall_seconds"] = time.perf_counter() - t_bench
    _write_reports(out, report)
    return report


def _header(version, psb_root, out, device, seed, batch_faces, baseline_every, limit, categories,
            remedy, n_akvf, n_fields, segment_kwargs, options) -> dict:
    import torch

    env = {"torchakvf": version, "torch": torch.__version__, "python": platform.python_version(),
           "platform": platform.platform(), "cpu_count": os.cpu_count(),
           "torch_threads": torch.get_num_threads()}
    if str(device).startswith("cuda"):
        env["cuda_device"] = torch.cuda.get_device_name(torch.device(device))
    if isinstance(categories, str):
        categories = [c.strip() for c in categories.split(",") if c.strip()]
    return {
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "options": dict(options) if options is not None else None,
        "settings": {"psb": str(psb_root), "out": str(out), "device": str(device), "seed": int(seed),
                     "batch_faces": int(batch_faces), "baseline_every": int(baseline_every),
                     "limit": limit, "categories": categories, "protocol": "by-segmentation",
                     "remedy": remedy, "n_akvf": n_akvf, "n_fields": n_fields,
                     "segment_kwargs": dict(sorted(segment_kwargs.items()))},
        "environment": env,
        "units": {"seconds": "wall seconds (time.perf_counter)", "faces": "faces of the input file",
                  "memory": "MiB (2**20 bytes)",
                  "ratio": "baseline seconds / torchakvf seconds on the same meshes, this run"},
        "runs": {},
        "notes": [],
    }


# ---- reports ------------------------------------------------------------------------------

def _f(v, digits=2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:,.{digits}f}"


_DESCRIPTIONS = {
    "batched": "torchakvf, harness path, batches of <= {bf} faces, every selected mesh",
    "one_at_a_time": "torchakvf, harness path, face budget 1 (one mesh per batch), baseline subset",
    "scipy": ("torchakvf/scipy_reference.py: eigsh once per mesh + numpy untangle + numpy k-means "
              "per k (load and clean-up: torchakvf's)"),
    "batched_subset": "torchakvf, batches of <= {bf} faces, the meshes compared with the baselines",
}


def _markdown(r: dict) -> str:
    s = r["settings"]
    sel = r["selection"]
    L = ["# torchakvf bench\n"]
    L.append(f"- created {r['created']}; torchakvf {r['environment']['torchakvf']}, torch "
             f"{r['environment']['torch']} ({r['environment']['torch_threads']} threads, "
             f"{r['environment']['cpu_count']} CPUs), device {s['device']}"
             + (f" ({r['environment']['cuda_device']})" if "cuda_device" in r["environment"] else ""))
    L.append(f"- PSB {s['psb']}: {sel['meshes']} meshes, {sel['faces']:,} faces, "
             f"{sel['predictions']} (mesh, k) predictions (protocol by-segmentation: every distinct "
             f"human segment count; meshes without ground truth, at the harness's default k: "
             f"{sel['meshes_without_ground_truth']})")
    L.append(f"- settings: seed {s['seed']}, batch_faces {s['batch_faces']}, baseline every "
             f"{s['baseline_every']}, limit {s['limit'] or 'none'}, categories "
             f"{','.join(s['categories']) if s['categories'] else 'all'}, remedy {s['remedy']}, "
             f"{s['n_akvf']} AKVFs per mesh, segment {s['segment_kwargs']}")
    L.append(f"- wall time {_f(r['wall_seconds'], 1)} s (plan {_f(sel['plan_seconds'], 1)} s, "
             f"warm-up {_f(r.get('warm_up_seconds'), 1)} s, neither part of a run); peak RSS "
             f"{_f(r['peak_memory']['ru_maxrss_mib'], 0)} MiB"
             + (f" in this process, {_f(r['peak_memory']['worker_maxrss_mib'], 0)} MiB in the "
                f"largest worker, at most {_f(r['peak_memory']['total_rss_bound_mib'], 0)} MiB in "
                f"all" if r["peak_memory"].get("worker_maxrss_mib") else "")
             + (f", CUDA peak allocated {_f(r['peak_memory']['cuda_max_memory_allocated_mib'], 0)} MiB"
                if r["peak_memory"]["cuda_max_memory_allocated_mib"] is not None else ""))
    L.append("\n## Runs\n")
    L.append("| run | meshes ok | faces | wall s | meshes/s | faces/s | load s | pack s | akvf s | "
             "segment s | write s | other s | workers | peak RSS MiB | CUDA peak MiB |")
    L.append("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for name, run in r["runs"].items():
        if "skipped" in run:
            L.append(f"| {name} | skipped | | | | | | | | | | | | | |")
            continue
        st = run["stage_seconds"]
        L.append(f"| {name} | {run['meshes_ok']}/{run['meshes']} | {run['faces_ok']:,} | "
                 f"{_f(run['wall_seconds'])} | {_f(run['meshes_per_second'], 3)} | "
                 f"{_f(run['faces_per_second'], 0)} | "
                 + " | ".join(_f(st[x]) for x in STAGES)
                 + f" | {run.get('workers', 1)} | {_rss_cell(run)} | {_f(run['cuda_max_memory_allocated_mib'], 0)} |")
    L.append("")
    for name, run in r["runs"].items():
        if "skipped" in run:
            L.append(f"- **{name}**: {run['skipped']}")
        else:
            how = "one mesh at a time, CPU" if run["kind"] == "scipy" else f"{run['batches']} batch(es)"
            L.append(f"- **{name}**: {_DESCRIPTIONS[name].format(bf=s['batch_faces'])} ({how})")
    L.append("\nStages: load = reading files; pack = clean-up, packing, transfer to the device; "
             "akvf = operator + eigensolve (once per batch, shared by every k); segment = "
             "untangling + spherical k-means + boundaries; write = prediction files; other = the "
             "rest of the wall time. Stage seconds add up over the workers (with W workers they "
             "can sum to W x the wall time). Peak RSS is ru_maxrss after the run: the process's "
             "peak so far, which never goes down; with workers, 'main + W x worker' where worker "
             "is the largest worker's peak so far: a bound on the run's resident total.")
    L.append("\n## Untangle + cluster seconds by k\n")
    names = [n for n, run in r["runs"].items() if "skipped" not in run]
    ks = sorted({int(k) for n in names for k in r["runs"][n]["segment_seconds_by_k"]})
    L.append("| k | " + " | ".join(f"{n}: predictions | {n}: s | {n}: s/prediction" for n in names) + " |")
    L.append("|---:|" + "---:|---:|---:|" * len(names))
    for k in ks:
        cells = []
        for n in names:
            v = r["runs"][n]["segment_seconds_by_k"].get(str(k))
            if v is None:
                cells += ["-", "-", "-"]
            else:
                per = v["seconds"] / v["predictions"] if v["predictions"] else None
                cells += [str(v["predictions"]), _f(v["seconds"]), _f(per, 3)]
        L.append(f"| {k} | " + " | ".join(cells) + " |")
    L.append("\nA round of a batch segments every mesh at one k each; its time is charged to "
             "the k's by face share (meshes padded with k = 1 charge nothing).")
    L.append("\n## Baselines / torchakvf (same meshes, this run)\n")
    c = r.get("comparison")
    if c is None:
        L.append("No baselines were run (--baseline-every 0).")
    else:
        L.append(f"Baseline subset: every M-th selected mesh (M = {c['baseline_every']}), "
                 f"{len(c['subset_ids'])} meshes; {c['meshes']} compared "
                 f"({c['faces']:,} faces; ids {', '.join(map(str, c['mesh_ids'])) or '-'}); "
                 f"torchakvf time from run {c['torchakvf_run']} on exactly those meshes.\n")
        L.append("| baseline | baseline s | torchakvf s | ratio | akvf ratio | segment ratio |")
        L.append("|---|---:|---:|---:|---:|---:|")
        for name in ("one_at_a_time", "scipy"):
            v = c["ratios"].get(name)
            if v is None:
                L.append(f"| {name} | - | - | {'skipped' if name == 'scipy' else '-'} | - | - |")
                continue
            L.append(f"| {name} | {_f(v['baseline_seconds'])} | {_f(v['torchakvf_seconds'])} | "
                     f"**{_f(v['ratio'])}** | {_f(v['stage_ratios'].get('akvf'))} | "
                     f"{_f(v['stage_ratios'].get('segment'))} |")
        L.append("\nratio = baseline seconds / torchakvf seconds (> 1: torchakvf faster); a "
                 "baseline's seconds are its per-mesh seconds summed over the compared meshes.")
        if c["excluded"]:
            L.append("\nExcluded from the comparison (failed in some run):")
            for i, why in c["excluded"].items():
                L.append(f"- {i}: {why}")
    fails = [(n, i, e) for n, run in r["runs"].items() for i, e in run.get("failed", {}).items()]
    if fails:
        L.append("\n## Failures\n")
        for n, i, e in fails:
            L.append(f"- {n}, mesh {i}: {e}")
    if r["notes"]:
        L.append("\n## Notes\n")
        for note in r["notes"]:
            L.append(f"- {note}")
    return "\n".join(L) + "\n"


def _jsonable(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def _rss_cell(run: dict) -> str:
    if run.get("worker_maxrss_mib") is None:
        return _f(run.get("ru_maxrss_mib"), 0)
    return (f"{_f(run['ru_maxrss_mib'], 0)} + {run['workers']} x {_f(run['worker_maxrss_mib'], 0)}"
            f" <= {_f(run['total_rss_bound_mib'], 0)}")


def _write_reports(out: Path, report: dict) -> None:
    from ..io.outputs import atomic_write_bytes

    clean = _jsonable(report)
    atomic_write_bytes(out / REPORT_JSON, (json.dumps(clean, indent=1) + "\n").encode())
    atomic_write_bytes(out / REPORT_MD, _markdown(clean).encode())


def summary_lines(report: dict, out: Path) -> list:
    """The short stdout summary of a report."""
    a = report["runs"]["batched"]
    L = [f"torchakvf bench: {a['meshes_ok']}/{a['meshes']} meshes, {a['faces_ok']:,} faces, "
         f"{report['selection']['predictions']} predictions in {_f(a['wall_seconds'], 1)} s: "
         f"{_f(a['meshes_per_second'], 3)} meshes/s, {_f(a['faces_per_second'], 0)} faces/s "
         f"(batches of <= {a['batch_faces']} faces, {a['device']}, {a.get('workers', 1)} "
         f"worker(s)); peak RSS {_f(report['peak_memory']['total_rss_bound_mib'], 0)} MiB at most"]
    c = report.get("comparison")
    if c is not None:
        parts = []
        for name in ("one_at_a_time", "scipy"):
            v = c["ratios"].get(name)
            parts.append(f"{name} {_f(v['ratio'])}x" if v else f"{name} skipped")
        L.append(f"  baseline / torchakvf on {c['meshes']} meshes: " + ", ".join(parts))
    for note in report["notes"]:
        L.append(f"  note: {note}")
    L.append(f"  wrote {out / REPORT_MD} and {out / REPORT_JSON}")
    return L


# ---- command line -------------------------------------------------------------------------

def add_bench_arguments(p) -> None:
    """The options of ``torchakvf bench`` (values are checked in :func:`run_bench_command`)."""
    p.add_argument("--psb", default=None, metavar="DIR",
                   help="PSB folder with meshes/ and gt/ (default: $TORCHAKVF_PSB, else "
                        "<repo>/../shared/psb)")
    p.add_argument("--out", default="bench", metavar="DIR",
                   help="output folder for report.md and report.json (default: bench/)")
    p.add_argument("--limit", default=None, metavar="N", help="only the first N meshes by id (default: all)")
    p.add_argument("--baseline-every", default=str(DEFAULT_BASELINE_EVERY), metavar="M",
                   help="run the one-at-a-time and scipy baselines on every M-th mesh of the "
                        f"selection (default {DEFAULT_BASELINE_EVERY}; 0: none)")
    p.add_argument("--device", default="cpu", help="torch device, e.g. cpu or cuda (default cpu)")
    p.add_argument("--seed", default="0", help="random seed (default 0)")
    p.add_argument("--categories", default=None, metavar="A,B",
                   help="comma-separated PSB category names (default: all)")
    p.add_argument("--batch-faces", default=None, metavar="N",
                   help="face budget per batch of the batched runs (default: the harness's, "
                        "as torchakvf eval)")
    p.add_argument("--coarse-faces", default=None, metavar="N",
                   help=f"solve on meshes decimated to about N faces, as torchakvf eval does "
                        f"(default {DEFAULT_COARSE_FACES}; 0: full resolution)")
    p.add_argument("--workers", default=None, metavar="W",
                   help="processes of the torchakvf runs, one thread each (default: one per CPU "
                        "core on CPU, at most 8; 1 on a GPU)")


def run_bench_command(args) -> int:
    """``torchakvf bench``: 0 when every mesh finished in every torchakvf run, else 1."""
    from ..evaluate.commands import default_psb_arg
    from .commands import _device, _int

    limit = _int(args.limit, "--limit", 1) if args.limit is not None else None
    every = _int(args.baseline_every, "--baseline-every", 0)
    seed = _int(args.seed, "--seed", 0)
    batch_faces = _int(args.batch_faces, "--batch-faces", 1) if args.batch_faces is not None else None
    coarse = DEFAULT_COARSE_FACES if args.coarse_faces is None else _int(args.coarse_faces, "--coarse-faces", 0)
    workers = _int(args.workers, "--workers", 1) if args.workers is not None else None
    categories = None
    if args.categories is not None:
        categories = [c.strip() for c in args.categories.split(",") if c.strip()]
        if not categories:
            raise TorchAKVFError("--categories: name at least one PSB category")
    device = _device(args.device)
    out = Path(args.out)
    report = run_bench(Path(args.psb or default_psb_arg()), out, limit=limit, baseline_every=every,
                       device=device, seed=seed, categories=categories, batch_faces=batch_faces,
                       segment_kwargs={"coarse_faces": coarse} if coarse else None, workers=workers,
                       options={k: v for k, v in vars(args).items() if k not in ("func", "command")})
    for line in summary_lines(report, out):
        print(line)
    failed = any(r.get("failed") for r in report["runs"].values() if r.get("kind") == "torchakvf")
    return 1 if failed else 0
