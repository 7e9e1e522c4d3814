"""Predicting one batch of PSB meshes: load, pack, one AKVF solve, every missing k (or the
automatic-k scan), prediction and meta files. The work is
:mod:`torchakvf.parts`'; this module adds the files, the timings and the resume logic.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass

import numpy as np

from ..io import load_mesh
from ..io.outputs import atomic_write_bytes, write_seg
from ..mesh import MeshBatch
from ..options import SPARE_FIELDS, SegmentOptions
from ..parts.field_counts import default_n_fields
from ..parts.rounds import segment_rounds
from ..parts.solve import solve_akvfs, solve_quality
from . import metrics as M
from . import psb as P
from .k_auto import RULES, pick_k, scan_k

__all__ = ["PredictSettings", "predict_batch", "predict_in_worker", "stage_clock", "eval_akvf_count",
           "solve_meta", "write_meta"]


@dataclass(frozen=True)
class PredictSettings:
    """How a batch is predicted (picklable: it travels to worker processes).

    auto : k chosen per mesh (:mod:`torchakvf.evaluate.k_auto`) instead of the plan's k's
    n_fields : fields untangled per mesh (None: the engine's default per k)
    k_range, k_rule : the scan, with ``auto``
    coarse_faces : decimate meshes above about this many faces (None: full resolution)
    options : the :class:`~torchakvf.options.SegmentOptions` (seed, remedy, solver, ...)
    device : torch device of the computation
    """

    auto: bool
    n_fields: int | None
    k_range: tuple | None
    k_rule: str | None
    coarse_faces: int | None
    options: SegmentOptions
    device: str = "cpu"


def eval_akvf_count(settings: PredictSettings) -> int:
    """AKVFs per mesh: a fixed n per run (not the batch's largest need), so that a mesh's fields
    do not depend on which meshes share its batch: ``n_fields``, else the largest default field
    count (32; the scan's n with k auto) plus the engine's spare fields."""
    if settings.n_fields is not None:
        return int(settings.n_fields)
    if settings.auto:
        return default_n_fields(settings.k_range[1]) + SPARE_FIELDS
    return default_n_fields(10 ** 6) + SPARE_FIELDS


def predict_in_worker(batch, settings: PredictSettings):
    """:func:`predict_batch` (it may run in a worker process); returns (its loaded meshes, its
    one-line summary, its stage timings)."""
    timings: dict = {}
    meshes, note = predict_batch(batch, settings, timings=timings)
    try:  # the process's peak so far (MiB): where it jumps, this batch set a new peak
        import resource
        timings["process_maxrss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    except ImportError:  # pragma: no cover - not on Windows
        pass
    return meshes, note, timings


def predict_batch(batch, settings: PredictSettings, *, timings=None, loaded=None):
    """AKVFs once for the batch of :class:`~torchakvf.evaluate.plan.PredictionPlan` s, then every
    missing k; writes predictions and meta files (a round's predictions as soon as it is done).

    timings : optional dict the stage seconds of this batch are added to (``torchakvf bench``):
        "load", "pack" (clean + pack), "akvf", "segment" (with k auto: the scan) and, given k,
        "segment_by_k" ({k: seconds}, each round charged to its meshes' k's by face share),
        "write" (predictions + meta files). CUDA is synchronized before each reading.
    loaded : {mesh id: (mesh as read, its :func:`~torchakvf.mesh.clean_mesh`)} where the
        caller loaded them (the corpus runner's :class:`~torchakvf.evaluate.eval_task.EvalTask`);
        None: loaded here

    Returns ({mesh_id: Mesh} (the loaded input meshes, for scoring), a one-line summary)."""
    opts = settings.options
    tick = stage_clock(timings, settings.device)
    t0 = time.perf_counter()
    if loaded is None:
        loaded = {p.mesh_id: (m, m) for p in batch for m in [load_mesh(p.entry.mesh_path)]}
    meshes = {i: m for i, (m, _) in loaded.items()}
    tick("load")
    # packing cleans a mesh as read, and keeps one cleaned already
    mb = MeshBatch.from_meshes([loaded[p.mesh_id][1] for p in batch], device=settings.device,
                               coarse_faces=settings.coarse_faces)
    tick("pack")
    faces = np.array([len(m.faces) for m in mb.meshes], dtype=np.float64)
    share = faces / faces.sum()
    seconds = np.zeros(len(batch))
    fields, fell_back = solve_akvfs(mb, eval_akvf_count(settings), opts)
    tick("akvf")
    t_akvf = time.perf_counter() - t0
    seconds += t_akvf * share
    costs = [dict() for _ in batch]
    extra = [dict() for _ in batch]
    if settings.auto:
        t1 = time.perf_counter()
        extra = _scan_and_write(batch, fields, settings, costs)
        seconds += (time.perf_counter() - t1) * share
        tick("segment")
        n_rounds = settings.k_range[1] - settings.k_range[0] + 1
    else:
        missing = [sorted(p.missing(False)) for p in batch]
        n_rounds = max(len(m) for m in missing)
        t1 = time.perf_counter()
        # labels and costs are what the eval keeps: no generators nor next merge's costs
        for rnd in segment_rounds(fields, missing, opts, n_fields=settings.n_fields, extras=False):
            tick("segment", [(rnd.ks[b], faces[b]) for b in rnd.active])
            for b in rnd.active:
                write_seg(batch[b].pred_path(rnd.ks[b]), rnd.meshes[b].labels)
                costs[b][str(rnd.ks[b])] = float(rnd.meshes[b].cost)
            tick("write")
            t2 = time.perf_counter()
            act_faces = faces[rnd.active]
            seconds[rnd.active] += (t2 - t1) * act_faces / act_faces.sum()
            t1 = t2
    for b, p in enumerate(batch):
        meta = solve_meta(fields, b, fell_back, meshes[p.mesh_id].n_faces)
        write_meta(p, {**meta, **extra[b], "costs": costs[b], "seconds": float(seconds[b])})
    tick("write")
    note = (f"{len(batch)} meshes, {int(faces.sum())} faces, akvf {t_akvf:.1f}s, {n_rounds} "
            f"k-rounds {time.perf_counter() - t0 - t_akvf:.1f}s")
    return meshes, note


def solve_meta(fields, b: int, fell_back: list, faces: int) -> dict:
    """What the meta file records of mesh ``b``'s solve: its input faces, Killing eigenvalues,
    convergence, remedy, decimation (and why it fell back to full resolution)."""
    coarse = fields.batch.coarse_of(b)
    meta = {"faces": int(faces), "eigenvalues": fields.eigenvalues[b].detach().cpu().numpy().astype(float).tolist()}
    meta["converged"], meta["max_residual"] = solve_quality(fields, b)
    meta["remedy"] = fields.remedies[b]
    meta["coarse_faces"] = None if coarse is None else len(coarse.coarse.faces)
    why = [w for i, w in fell_back if i == b]
    if why:
        meta["full_resolution_because"] = why[0]
    return meta


def write_meta(plan, meta: dict) -> None:
    """Merge this run's ``meta`` into the mesh's meta file: its ``costs`` added to the earlier
    runs', its ``seconds`` to theirs."""
    old = plan.meta()
    meta = {**old, **meta, "costs": {**old.get("costs", {}), **meta.get("costs", {})},
            "seconds": float(old.get("seconds", 0.0)) + float(meta.get("seconds", 0.0))}
    atomic_write_bytes(plan.meta_path, json.dumps(meta, indent=1).encode())


def _scan_and_write(batch, fields, settings: PredictSettings, costs: list) -> list:
    """k auto: the scan of k_range on the batch's AKVFs; writes each mesh's chosen k and returns
    the meta entries ("auto": the choice, every rule's, and 1-RI per k where there is gt)."""
    scan = scan_k(fields, settings.k_range, settings.options, rule=settings.k_rule,
                  n_fields=settings.n_fields, keep=True)
    extra = []
    for b, p in enumerate(batch):
        k = scan.chosen[b]
        write_seg(p.pred_path(k), scan.segmentations[k].meshes[b].labels)
        costs[b] = {str(kk): float(c) for kk, c in zip(scan.ks, scan.costs[b])}
        by_rule = {r: pick_k(scan.ks, scan.costs[b], r, scan.eigenvalues[b], scan.next_costs[b]) for r in RULES}
        ri_by_k = {}
        if p.entry.has_gt:  # 1-RI of every k tried (cheap), to compare the choice with an oracle
            gts = [P.read_seg(s) for s in p.entry.seg_paths]
            for kk in scan.ks:
                lab = scan.segmentations[kk].meshes[b].labels
                ri_by_k[str(kk)] = float(np.mean([M.rand_index_error(lab, g) for g in gts]))
        extra.append({"auto": dict(chosen=k, rule=settings.k_rule, ks=scan.ks, n_fields=scan.n_fields,
                                   by_rule=by_rule, rand_index_error_by_k=ri_by_k)})
    return extra


def stage_clock(timings, device):
    """``tick(stage, by_k=None)``: adds the seconds since the previous tick to ``timings[stage]``
    (and, with ``by_k`` = [(k, faces), ...], splits them over ``timings["segment_by_k"]`` by
    face share); a no-op when ``timings`` is None."""
    if timings is None:
        return lambda stage, by_k=None: None
    import torch

    sync = torch.cuda.synchronize if str(device).startswith("cuda") else (lambda: None)
    last = [time.perf_counter()]

    def tick(stage, by_k=None):
        sync()
        now = time.perf_counter()
        dt, last[0] = now - last[0], now
        timings[stage] = timings.get(stage, 0.0) + dt
        if by_k:
            per = timings.setdefault("segment_by_k", {})
            total = float(sum(f for _, f in by_k)) or 1.0
            for k, f in by_k:
                per[int(k)] = per.get(int(k), 0.0) + dt * float(f) / total
    return tick
