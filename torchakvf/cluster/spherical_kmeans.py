"""Batched spherical k-means (cosine distance) with k-means++ seeding and restarts.

Every mesh of a batch, with its own k, and every restart run as one set of padded tensor ops:
rows [B, N_max, d] with a mask, centers [B, R, k_max, d] with a mask for meshes whose k < k_max.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import ParameterError
from ..restarts import best_restart
from .kmeanspp import seeded_centers

_NEG = -4.0   # below any cosine: marks centers that do not exist for a mesh

#: k-means++ restarts of :func:`spherical_kmeans` called by itself (a segmentation uses
#: :data:`~torchakvf.options.KMEANS_RESTARTS_BY_METHOD`): many, since k-means has many
#: near-equal local optima and a caller with no other knowledge wants the best.
DEFAULT_RESTARTS = 20
#: Lloyd iterations per precision phase of :func:`spherical_kmeans` called by itself (a
#: segmentation uses :data:`~torchakvf.options.KMEANS_MAX_ITER`).
DEFAULT_MAX_ITER = 100


@dataclass
class KMeansResult:
    """labels : [B, N_max] per padded row (rows as given to :func:`spherical_kmeans`, -1 on
    padding); centers : [B, k_max, d] unit vectors (0 when unused); cost : [B] Σ w (1 - cos) of
    the restart kept; iterations : [B] Lloyd iterations (float32 and float64 phases together);
    restart_costs : [B, R] the cost every restart ended at (the kept one is the lowest; of
    costs equal to round-off, the first: :func:`~torchakvf.restarts.best_restart`)."""

    labels: torch.Tensor
    centers: torch.Tensor
    cost: torch.Tensor
    iterations: torch.Tensor
    restart_costs: torch.Tensor | None = None


def spherical_kmeans(x: torch.Tensor, mask: torch.Tensor, k, *, restarts: int = DEFAULT_RESTARTS,
                     max_iter: int = DEFAULT_MAX_ITER, seed: int = 0, weights: torch.Tensor | None = None,
                     iteration_dtype: torch.dtype = torch.float32, init=None) -> KMeansResult:
    """Cluster the rows of each mesh by cosine similarity.

    x : [B, N_max, d] padded feature rows (normalized here); mask : [B, N_max] bool
    k : int or sequence of B ints (each 1 <= k_b <= number of rows of mesh b)
    restarts : independent k-means++ starts per mesh; the lowest cost is kept (the first of
        those within round-off of it, so the pick does not depend on the BLAS's rounding)
    seed : each mesh's random draws come from ``torch.Generator().manual_seed(seed)`` alone, so
        a mesh gets the same clustering in any batch (with any other meshes and k's)
    weights : optional [B, N_max] row weights of the cost (e.g. face areas); default 1 per row
    iteration_dtype : float type of the similarities [B, N, R·k] of the Lloyd iterations (the
        largest products). With float32, Lloyd iterations go on in float64 from where the
        float32 ones stopped until no label changes, so the partition returned is a float64
        fixed point; seeding, cluster sums, the final assignment and the cost that picks the
        restart are float64. tests/test_precision.py checks float32 against float64.
    init : optional [B] list, each None or a [j_b, d] tensor of 1 <= j_b <= k_b seed centers
        (normalized here) for mesh b: its LAST restart starts from them, the other k_b - j_b
        centers chosen k-means++-style (given the seeds) with that restart's own draws; the
        other restarts, and meshes with None, are seeded as without ``init``. E.g. the previous
        k's clustering of the same mesh (:func:`~torchakvf.parts.rounds.segment_rounds`).
    """
    nb = x.shape[0]
    ks = [int(k)] * nb if isinstance(k, numbers.Integral) else [int(v) for v in k]
    counts = mask.sum(1).tolist()
    if len(ks) != nb:
        raise ParameterError(f"k has {len(ks)} values for {nb} meshes")
    for b, (kb, nrows) in enumerate(zip(ks, counts)):
        if kb < 1 or kb > nrows:
            raise ParameterError(f"k = {kb} is out of range for mesh {b} with {nrows} faces")
    k_max, r, dev = max(ks), restarts, x.device
    dt = torch.float64
    x = torch.nn.functional.normalize(x.to(dt), dim=-1) * mask[..., None]
    w = (mask.to(dt) if weights is None else weights.to(dt) * mask)
    kvec = torch.tensor(ks, device=dev)
    center_ok = torch.arange(k_max, device=dev)[None, :] < kvec[:, None]          # [B, k_max]

    centers = seeded_centers(x, w, mask, ks, r, seed, center_ok, init)             # [B, R, k_max, d]
    labels, cost, iters, centers = _lloyd_each(x, w, mask, ks, centers, max_iter, iteration_dtype, center_ok)
    pick = best_restart(cost, largest=False)
    ar = torch.arange(nb, device=dev)
    labels = labels[ar, :, pick].masked_fill(~mask, -1)
    return KMeansResult(labels=labels, centers=centers[ar, pick] * center_ok[..., None],
                        cost=cost[ar, pick], iterations=iters[ar, pick], restart_costs=cost)


def _lloyd_each(x: torch.Tensor, w: torch.Tensor, mask: torch.Tensor, ks: list, centers: torch.Tensor,
                max_iter: int, iteration_dtype: torch.dtype, center_ok: torch.Tensor):
    """:func:`lloyd` of every restart of every mesh: (labels [B, N_max, R], cost [B, R],
    iterations [B, R], centers [B, R, k_max, d])."""
    nb, n_max, d = x.shape
    r, k_max, dev, dt = centers.shape[1], max(ks), x.device, x.dtype
    if dev.type == "cpu":
        # On CPU each mesh iterates alone with its own k: no padded centers (computed, masked and
        # searched by max on every iteration when the k's differ), and no mesh computes as many
        # restarts as the slowest one in the batch still has. The draws, and so the answer, are
        # those of the batched run.
        # Rows past a mesh's last one are padding (weight 0; the same label on every iteration).
        ends = [int(torch.nonzero(mask[b]).max()) + 1 for b in range(nb)]
        parts = [lloyd(x[b:b + 1, :ends[b]], w[b:b + 1, :ends[b]], centers[b:b + 1, :, :ks[b]], max_iter,
                       iteration_dtype) for b in range(nb)]
        labels = torch.full((nb, n_max, r), -1, dtype=torch.long, device=dev)
        cost = torch.cat([p[1] for p in parts])
        iters = torch.cat([p[2] for p in parts])
        centers = torch.zeros(nb, r, k_max, d, dtype=dt, device=dev)
        for b, p in enumerate(parts):
            labels[b, :ends[b]] = p[0][0]
            centers[b, :, :ks[b]] = p[3]
    else:
        labels, cost, iters, centers = lloyd(x, w, centers, max_iter, iteration_dtype, center_ok)
    return labels, cost, iters, centers


def lloyd(x: torch.Tensor, w: torch.Tensor, centers: torch.Tensor, max_iter: int,
          iteration_dtype: torch.dtype, center_ok: torch.Tensor | None = None):
    """Lloyd iterations of every restart from seeded centers, then the final float64 assignment.

    x : [B, N, d] unit rows (0 on padding); w : [B, N] weights (0 on padding)
    centers : [B, R, k, d] seeds; center_ok : [B, k] which centers exist (None: all of them)
    Returns labels [B, N, R], cost [B, R] = Σ w (1 - cos), iterations [B, R], centers [B, R, k, d].

    One mesh on CPU with all its centers (every call of :func:`spherical_kmeans` there) takes
    :func:`lloyd_one_mesh`, the same arithmetic without the batch's bookkeeping; any other
    call :func:`lloyd_batched`.
    """
    if len(x) == 1 and x.device.type == "cpu" and (center_ok is None or bool(center_ok.all())):
        return lloyd_one_mesh(x, w, centers, max_iter, iteration_dtype)
    return lloyd_batched(x, w, centers, max_iter, iteration_dtype, center_ok)


def lloyd_one_mesh(x: torch.Tensor, w: torch.Tensor, centers: torch.Tensor, max_iter: int,
                   iteration_dtype: torch.dtype):
    """:func:`lloyd_batched` for one mesh (x [1, N, d], w [1, N], centers [1, R, k, d]) with
    every center present, on CPU, bitwise.

    The same products of the same shapes and layouts, the same cluster sums in the same order:
    each iteration's active restarts, in index order, side by side (the batched path's slots
    for one mesh, which has no padding restarts). What goes is the per-iteration bookkeeping on
    small tensors (slot gathers of centers and labels, scatters back, boolean-mask writes):
    which restarts are active is a Python list, read back once per iteration, and while all of
    them are, labels and centers are replaced, not written into.
    """
    _, n_rows, d = x.shape
    r, k = centers.shape[1], centers.shape[2]
    centers = centers.clone(memory_format=torch.contiguous_format)  # as the batched path's slot copies
    labels = torch.full((1, n_rows, r), -1, dtype=torch.long)
    iters = [0] * r
    phases = [iteration_dtype] if iteration_dtype == torch.float64 else [iteration_dtype, torch.float64]
    xw = (x * w[..., None]).reshape(n_rows, d)
    sim_buf = x_it = None
    for phase in phases:
        sim_buf = x_it = None   # free the previous phase's buffers before this phase allocates its own
        act = list(range(r))                                                       # active restarts
        x_it = x.to(phase)
        sim_buf = x_it.new_empty(1, n_rows, r * k)
        for _ in range(max_iter):
            if not act:
                break
            q = len(act)
            every = q == r
            cl = centers if every else centers[:, act]                             # [1, q, k, d]
            new = _nearest(x_it, cl, None, sim_buf)[1]                             # [1, N, q]
            old = labels if every else labels[:, :, act]
            changed = (new != old).any(dim=1)[0].tolist()
            if every:
                labels = new
            else:
                labels[:, :, act] = new
            for j in act:
                iters[j] += 1
            # the batched path's sums for one mesh: restart j's clusters at rows j k .. j k + k - 1
            sums = x.new_zeros(q * k, d)
            for j in range(q):
                sums.index_add_(0, j * k + new[0, :, j], xw)
            sums = sums.reshape(1, q, k, d)
            norm = sums.norm(dim=-1, keepdim=True)
            # An emptied cluster keeps its previous center rather than vanishing.
            moved = torch.where(norm > 0, sums / norm.clamp(min=1e-300), cl)
            if every:
                centers = moved
            else:
                centers[:, act] = moved
            act = [j for j, moving in zip(act, changed) if moving]
    del sim_buf, x_it
    labels, cost = _final_assignment(x, w, centers, None)
    return labels, cost, torch.tensor([iters], dtype=torch.long), centers


def _nearest(xb: torch.Tensor, cb: torch.Tensor, absent_b: torch.Tensor | None, out: torch.Tensor | None = None):
    """(cosine to the nearest center [b, N, q], its index [b, N, q]) for rows xb [b, N, d] and
    the centers cb [b, q, k, d] of q restarts, side by side in one GEMM (the rows are never
    copied q times). absent_b [b, 1, 1, k]: centers that do not exist (None: all do); out: a
    buffer of at least b·N·q·k elements of xb's dtype for the similarities. Ties go to the
    lowest center index.

    The similarities are laid out [b, q, k, N] (centers by rows): the max over k then reduces
    whole rows of N, which vectorizes; over the last axis of [b, N, q, k] it reduced k at a
    time (2-5x the GEMM at k = 24). On CPU the lowest index attaining the max is found with
    numpy (:func:`_first_max`); torch's comparisons into bool tensors cost 5x numpy's there.
    """
    m, n_max = xb.shape[:2]
    q, k_max, d = cb.shape[1:]
    if out is not None:
        out = out.view(-1)[:m * n_max * q * k_max].view(m, q * k_max, n_max)
    sim = torch.matmul(cb.reshape(m, q * k_max, d).to(xb.dtype), xb.transpose(1, 2), out=out)
    sim = sim.view(m, q, k_max, n_max)
    if absent_b is not None:
        sim.masked_fill_(absent_b.reshape(m, 1, k_max, 1), _NEG)
    if sim.device.type == "cpu":
        found = _first_max(sim.numpy())
        if found is not None:
            best, index = found
            return (torch.from_numpy(best).permute(0, 2, 1), torch.from_numpy(index).permute(0, 2, 1))
    best, index = sim.max(2)
    return best.permute(0, 2, 1), index.permute(0, 2, 1)


def _first_max(sim):
    """(max [b, q, N], lowest index attaining it [b, q, N] int64) over axis 2 of a numpy
    [b, q, k, N] array, or None if the array holds NaN (left to torch's max)."""
    k = sim.shape[2]
    best = sim.max(axis=2)
    at_max = sim == best[:, :, None, :]
    # The lowest index j attaining the max holds the largest weight k - j.
    wt = np.uint8 if k < 256 else (np.uint16 if k < 65536 else np.int64)
    weight = np.arange(k, 0, -1, dtype=wt)[None, None, :, None]
    top = np.multiply(at_max, weight, dtype=wt).max(axis=2)
    if not top.all():      # a NaN row: no index equals its max
        return None
    return best, k - top.astype(np.int64)


def _final_assignment(x: torch.Tensor, w: torch.Tensor, centers: torch.Tensor, absent: torch.Tensor | None):
    """Labels [B, N, R] and cost [B, R] = Σ w (1 - cos) of the float64 assignment to centers
    [B, R, k, d], one restart at a time ([B, N, k], not [B, N, R·k])."""
    nb, n_max = x.shape[:2]
    r = centers.shape[1]
    labels = torch.empty(nb, n_max, r, dtype=torch.long, device=x.device)
    cost = x.new_empty(nb, r)
    for j in range(r):
        best_sim, labels[:, :, j] = (t[..., 0] for t in _nearest(x, centers[:, j:j + 1], absent))
        cost[:, j] = ((1 - best_sim) * w).sum(1)                                    # [B]
    return labels, cost


def lloyd_batched(x: torch.Tensor, w: torch.Tensor, centers: torch.Tensor, max_iter: int,
                  iteration_dtype: torch.dtype, center_ok: torch.Tensor | None = None):
    """:func:`lloyd` for any batch on any device: each iteration the live meshes' active
    restarts are gathered into slots, the results scattered back."""
    nb, n_max, d = x.shape
    r, k_max = centers.shape[1], centers.shape[2]
    dev = x.device
    centers = centers.clone()
    ragged = center_ok is not None and not bool(center_ok.all())
    absent = None if center_ok is None else ~center_ok[:, None, None, :]          # [B, 1, 1, k]


    def assign(xb, cb, absent_b, out=None):
        return _nearest(xb, cb, absent_b if ragged else None, out)

    labels = torch.full((nb, n_max, r), -1, dtype=torch.long, device=dev)
    iters = torch.zeros(nb, r, dtype=torch.long, device=dev)
    # float32 Lloyd iterations, then float64 ones from where they stopped (usually one
    # iteration that changes nothing): the fixed point reached, and so the labels, is a float64
    # one, whatever round-off the float32 similarities had on this BLAS, thread count or padding.
    phases = [iteration_dtype] if iteration_dtype == torch.float64 else [iteration_dtype, torch.float64]
    sim_buf = x_it = None
    for phase in phases:
        sim_buf = x_it = None   # free the previous phase's buffers before this phase allocates its own
        active = torch.ones(nb, r, dtype=torch.bool, device=dev)
        # The similarities [B, N, R·k] are the largest array (260 MB at k = 81 on a 20k-face
        # mesh): one buffer for every iteration, since allocating it afresh costs as much as the GEMM.
        x_it = x.to(phase)
        sim_buf = x_it.new_empty(nb, n_max, r * k_max)
        xw_all = x * w[..., None]                                                   # [B, N, d]
        for _ in range(max_iter):
            # Only restarts still moving iterate: settled ones (and meshes whose restarts have all
            # settled) drop out, so a slow restart does not make the others pay for its iterations.
            # Each live mesh's q active restarts go first; shorter lists are padded with settled
            # restarts, which are computed but not written back.
            live = torch.nonzero(active.any(dim=1)).reshape(-1)
            if len(live) == 0:
                break
            m = len(live)
            # every mesh live (always so for one mesh): views, not copies, of the per-mesh arrays
            every = m == nb
            pick = (lambda t: t) if every else (lambda t: t[live])
            act = pick(active)                                                          # [m, R]
            q = int(act.sum(dim=1).max())
            rows = torch.arange(m, device=dev)[:, None]
            if q == r and bool(act.all()):
                slot = torch.arange(r, device=dev)[None, :].expand(m, r)                # [m, q]
                valid = act
            else:
                slot = torch.argsort((~act).to(torch.int8), dim=1, stable=True)[:, :q]  # [m, q]
                valid = torch.gather(act, 1, slot)                                      # [m, q]
            cent = pick(centers)
            cl = cent[rows, slot]                                                       # [m, q, k, d]
            new = assign(pick(x_it), cl, None if absent is None else pick(absent), sim_buf)[1]   # [m, N, q]
            lab = pick(labels)
            idx = slot[:, None, :].expand(m, n_max, q)
            old = torch.gather(lab, 2, idx)
            changed = (new != old).any(dim=1) & valid                                  # [m, q]
            lab = lab.scatter(2, idx, torch.where(valid[:, None, :], new, old))
            if every:
                labels = lab
                iters += act.long()
            else:
                labels[live] = lab
                iters[live] += act.long()
            # Weighted sums per (mesh, restart, cluster) by index_add, one restart at a time: a
            # one-hot GEMM would build [m, N, q, k] (260 MB at k = 81 on a 20k-face mesh).
            xw = pick(xw_all).reshape(m * n_max, d)
            base = (torch.arange(m, device=dev)[:, None] * (q * k_max)).expand(m, n_max).reshape(-1)
            sums = x.new_zeros(m * q * k_max, d)
            for j in range(q):
                sums.index_add_(0, base + j * k_max + new[:, :, j].reshape(-1), xw)
            sums = sums.reshape(m, q, k_max, d)
            norm = sums.norm(dim=-1, keepdim=True)
            # An emptied cluster keeps its previous center rather than vanishing.
            moved = torch.where(norm > 0, sums / norm.clamp(min=1e-300), cl)
            cent[rows.expand(m, q)[valid], slot[valid]] = moved[valid]
            if every:
                active = act.scatter(1, slot, changed)
            else:
                centers[live] = cent
                active[live] = act.scatter(1, slot, changed)

    del sim_buf, x_it
    labels, cost = _final_assignment(x, w, centers, absent if ragged else None)
    return labels, cost, iters, centers
