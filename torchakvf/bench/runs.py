"""The runs of ``torchakvf bench`` (see :mod:`torchakvf.bench.run`): torchakvf through the
evaluation's batching and prediction, the scipy baseline one mesh at a time, the warm-up, and
what each measures (seconds per stage, memory)."""
from __future__ import annotations

import collections
import logging
import shutil
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from .. import shapes
from ..evaluate.plan import PredictionPlan
from ..evaluate.predict import PredictSettings, predict_in_worker
from ..io import load_mesh
from ..io.outputs import OutputSpaceError, write_seg
from ..mesh import Mesh, MeshBatch, clean_mesh
from ..parts.segment import segment_each_k
from ..pipeline.batches import prediction_batches
from ..pipeline.parallel import error_text, is_programming_error, map_batches
from ..progress import progress

log = logging.getLogger("torchakvf.bench")

__all__ = ["STAGES", "BenchMesh", "load_scipy_reference", "run_torchakvf", "run_scipy", "warm_up",
           "rss_mib", "cpu_seconds"]

#: Stage names of a run, in report order.
STAGES = ("load", "pack", "akvf", "segment", "write", "other")
_MIB = 2.0 ** 20


def load_scipy_reference():
    """(module, None) or (None, why it is skipped): scipy's sparse eigensolver stack can be
    missing pieces on exotic builds, and the bench must still run without its baseline."""
    try:
        from .. import scipy_reference
    except Exception as exc:  # noqa: BLE001 - any import problem means: no baseline, said so
        return None, f"scipy baseline skipped: importing torchakvf.scipy_reference failed ({type(exc).__name__}: {exc})"
    return scipy_reference, None


class BenchMesh:
    """One selected PSB mesh: its entry, human segment counts, protocol k's and face count."""

    def __init__(self, entry, counts, ks, faces):
        self.entry, self.counts, self.ks, self.faces = entry, list(counts), list(ks), int(faces)

    @property
    def mesh_id(self) -> int:
        return self.entry.mesh_id


def rss_mib(children: bool = False) -> float | None:
    """Peak resident memory so far (ru_maxrss), MiB, of this process or (``children``) of the
    largest of its finished child processes (the worker processes); None where unavailable."""
    try:
        import resource
    except ImportError:  # not on Windows
        return None
    peak = resource.getrusage(resource.RUSAGE_CHILDREN if children else resource.RUSAGE_SELF).ru_maxrss
    return peak / _MIB if sys.platform == "darwin" else peak * 1024 / _MIB  # bytes vs KiB


def cpu_seconds() -> float:
    """User + system CPU seconds so far of this process and its finished (reaped) child
    processes: a run's difference is its CPU time, which other processes' load on a shared
    machine does not inflate as it does wall time (worker pools end with each run, so their
    time is in by the run's end)."""
    try:
        import resource
    except ImportError:  # not on Windows
        return time.process_time()
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


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
    run["ru_maxrss_mib"] = rss_mib()
    if run.get("workers", 1) > 1:
        # The work ran in the workers: each is at most the largest child's peak, and the run's
        # resident total at most this process's peak plus workers x that.
        run["worker_maxrss_mib"] = rss_mib(children=True)
        run["total_rss_bound_mib"] = run["ru_maxrss_mib"] + run["workers"] * run["worker_maxrss_mib"]
    run["cuda_max_memory_allocated_mib"] = _cuda_peak_mib(device)
    return run


def run_torchakvf(name: str, meshes, work: Path, predict: PredictSettings, *, batch_faces: int,
                  workers: int = 1) -> dict:
    """Segment ``meshes`` at every k through the evaluation's batching and prediction
    (``predict``: options, field count, decimation, device), predictions written under ``work``.

    As ``evaluate_psb`` does: batched by
    :func:`~torchakvf.pipeline.batches.prediction_batches`; a failing batch of several meshes is retried
    one mesh at a time, a failing single mesh is recorded in ``failed`` and the run goes on; a
    mesh whose eigensolve did not converge is recorded in ``unconverged`` ({id: max residual}).
    Returns the run's dict (see the module notes).
    """
    device = predict.device
    run = {"name": name, "kind": "torchakvf", "device": device, "batch_faces": int(batch_faces),
           "workers": int(workers),
           "meshes": len(meshes), "faces": sum(m.faces for m in meshes),
           "mesh_ids": [m.mesh_id for m in meshes], "failed": {}, "unconverged": {}, "batches": 0, "per_mesh": {}}
    pred_root = work / name
    plans = [PredictionPlan(m.entry, m.counts, m.ks, pred_root / str(m.mesh_id), faces=m.faces)
             for m in meshes]
    faces_of = {m.mesh_id: m.faces for m in meshes}
    n_k = {m.mesh_id: len(m.ks) for m in meshes}
    prog = progress(sum(faces_of.values()), f"bench {name}", "faces")
    stages: dict = {}
    by_k: dict = {}
    _cuda_reset(device)
    log.info("bench %s: %d meshes, %d faces, batches of <= %d faces, device %s", name, len(meshes),
             run["faces"], batch_faces, device)
    t_start, cpu_start = time.perf_counter(), cpu_seconds()
    batches = prediction_batches(plans, faces_of, n_k, batch_faces, coarse_faces=predict.coarse_faces,
                                 workers=workers, device=device)
    for res in map_batches(batches, predict_in_worker, (predict,), workers=workers,
                           fatal=(OutputSpaceError,)):
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
        prog.update(int(sum(faces_of[p.mesh_id] for p in batch)), note=msg)
        for p in batch:
            meta = p.meta()
            if meta.get("converged") is False:
                run["unconverged"][p.mesh_id] = meta.get("max_residual")
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
    run["cpu_seconds"] = cpu_seconds() - cpu_start
    prog.close()
    shutil.rmtree(pred_root, ignore_errors=True)  # after the clock: predictions are scratch
    return _finish_run(run, meshes, wall, stages, by_k, device)


def _scipy_segment_mesh(ref, mesh, pred_dir: Path, seed: int, n_akvf: int, stages: dict,
                        by_k: dict) -> None:
    """The plain pipeline on one mesh, its stages added to ``stages`` / ``by_k`` (seconds):
    torchakvf's loader and clean-up (the reference needs a clean, oriented mesh), the reference's
    operator + ``eigsh`` once (``n_akvf`` fields, as torchakvf computes), then per k: Algorithm 1
    on the first clamp(2k, 16, 32) fields (``segment_scipy``'s default), Whitney face vectors,
    their norms and spherical k-means (the reference's default restarts), and one ``.seg``."""
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
        S1 = ref.clamp_mass(S1)
        _, forms = ref.solve_akvf(R, S1, min(int(n_akvf), R.shape[0] - 1), -1.0)
    tick("akvf")
    for k in mesh.ks:
        n = min(int(np.clip(2 * k, 16, 32)), forms.shape[1])
        U, _ = ref.untangle_numpy(forms[:, :n], S1, seed=seed)
        feats = np.linalg.norm(ref.whitney_face_vectors_scipy(meta["V"], clean.faces, edges, U), axis=2)
        labels, _ = ref.spherical_kmeans_numpy(feats, min(int(k), len(feats)), seed=seed)
        tick("segment", k)
        write_seg(pred_dir / f"{mesh.mesh_id}_k{k}.seg", clean.labels_to_input_faces(labels))
        tick("write")


def run_scipy(ref, meshes, work: Path, *, seed: int, n_akvf: int) -> dict:
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
        except Exception as exc:  # noqa: BLE001 - a bad mesh fails alone; a bug surfaces
            if is_programming_error(exc):
                raise
            run["failed"][m.mesh_id] = error_text(exc)
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


def warm_up(predict: PredictSettings, n_akvf: int) -> float:
    """Untimed: a small built-in shape through AKVFs + segmentation on ``predict.device`` (lazy
    imports, CUDA context and libraries). Returns its seconds (reported, charged to no run)."""
    device = predict.device
    t0 = time.perf_counter()
    try:
        s = shapes.dumbbell(n_around=12)
        batch = MeshBatch.from_meshes([Mesh(s.vertices, s.faces, name="warm-up")], device=device)
        segment_each_k(batch, 2, predict.options.replace(refine=False), n_akvf=n_akvf)
    except Exception as exc:  # noqa: BLE001 - a warm-up problem shows up in the runs anyway
        log.warning("bench: warm-up failed (%s: %s); timing without it", type(exc).__name__, exc)
    _cuda_reset(device)
    return time.perf_counter() - t0
