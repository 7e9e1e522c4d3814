"""Batched spherical k-means (cosine distance) with k-means++ seeding and restarts.

Every mesh of a batch, with its own k, and every restart run as one set of padded tensor ops:
rows [B, N_max, d] with a mask, centers [B·R, k_max, d] with a mask for meshes whose k < k_max.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..errors import ParameterError

_NEG = -4.0   # below any cosine: marks centers that do not exist for a mesh


@dataclass
class KMeansResult:
    """labels : [B, N_max] (-1 on padding); centers : [B, k_max, d] unit vectors (0 when unused);
    cost : [B] Σ (1 - cos) of the restart kept; iterations : [B]."""

    labels: torch.Tensor
    centers: torch.Tensor
    cost: torch.Tensor
    iterations: torch.Tensor


def spherical_kmeans(x: torch.Tensor, mask: torch.Tensor, k, *, restarts: int = 20,
                     max_iter: int = 100, seed: int = 0, weights: torch.Tensor | None = None
                     ) -> KMeansResult:
    """Cluster the rows of each mesh by cosine similarity.

    x : [B, N_max, d] padded feature rows (normalized here); mask : [B, N_max] bool
    k : int or sequence of B ints (each 1 <= k_b <= number of rows of mesh b)
    restarts : independent k-means++ starts per mesh; the lowest cost is kept
    seed : each mesh's random draws come from ``torch.Generator().manual_seed(seed)`` alone
    weights : optional [B, N_max] row weights of the cost (e.g. face areas); default 1 per row
    """
    nb, n_max, d = x.shape
    ks = [int(k)] * nb if isinstance(k, int) else [int(v) for v in k]
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

    # Uniform draws for seeding, per mesh from its own generator.
    draws = torch.stack([torch.rand(r, k_max, generator=torch.Generator().manual_seed(seed), dtype=dt)
                         for _ in range(nb)]).to(dev)                             # [B, R, k_max]
    xr = x[:, None].expand(nb, r, n_max, d).reshape(nb * r, n_max, d)
    wr = w[:, None].expand(nb, r, n_max).reshape(nb * r, n_max)
    ok_r = center_ok[:, None].expand(nb, r, k_max).reshape(nb * r, k_max)
    centers = _kmeanspp(xr, wr, draws.reshape(nb * r, k_max), ok_r)

    labels = torch.full((nb * r, n_max), -1, dtype=torch.long, device=dev)
    iters = torch.zeros(nb * r, dtype=torch.long, device=dev)
    active = torch.ones(nb * r, dtype=torch.bool, device=dev)
    for _ in range(max_iter):
        idx = torch.nonzero(active).reshape(-1)
        if len(idx) == 0:
            break
        sim = xr[idx] @ centers[idx].transpose(1, 2)
        sim = sim.masked_fill(~ok_r[idx, None, :], _NEG)
        new = sim.argmax(-1)
        changed = (new != labels[idx]).any(dim=1)
        labels[idx] = new
        iters[idx] += 1
        onehot = torch.nn.functional.one_hot(new, k_max).to(dt) * wr[idx, :, None]
        sums = onehot.transpose(1, 2) @ xr[idx]                                   # [n, k_max, d]
        norm = sums.norm(dim=-1, keepdim=True)
        # An emptied cluster keeps its previous center rather than vanishing.
        centers[idx] = torch.where(norm > 0, sums / norm.clamp(min=1e-300), centers[idx])
        active[idx[~changed]] = False

    sim = (xr @ centers.transpose(1, 2)).masked_fill(~ok_r[:, None, :], _NEG)
    best_sim, labels = sim.max(-1)
    cost = ((1 - best_sim) * wr).sum(-1).reshape(nb, r)
    pick = cost.argmin(dim=1)
    sel = torch.arange(nb, device=dev) * r + pick
    labels = labels[sel].masked_fill(~mask, -1)
    return KMeansResult(labels=labels, centers=centers[sel] * center_ok[..., None],
                        cost=cost.min(dim=1).values, iterations=iters[sel])


def _kmeanspp(x: torch.Tensor, w: torch.Tensor, u: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """k-means++ seeding by inverse-CDF sampling with the pre-drawn uniforms u [M, k_max].

    Rows are drawn with probability ∝ weight · (1 - cos to the nearest chosen center)^2.
    """
    m, n_max, d = x.shape
    k_max = u.shape[1]
    centers = x.new_zeros(m, k_max, d)
    prob = w.clone()
    nearest = torch.full((m, n_max), 2.0, dtype=x.dtype, device=x.device)
    ar = torch.arange(m, device=x.device)
    for j in range(k_max):
        cdf = prob.cumsum(1)
        total = cdf[:, -1:]
        pick = torch.searchsorted(cdf, (u[:, j:j + 1] * total).contiguous()).clamp(max=n_max - 1)[:, 0]
        # Fall back to uniform over valid rows where every remaining row has zero weight.
        degenerate = total[:, 0] <= 0
        if degenerate.any():
            valid = (w > 0).to(x.dtype).cumsum(1)
            fb = torch.searchsorted(valid, (u[:, j:j + 1] * valid[:, -1:]).contiguous())[:, 0]
            pick = torch.where(degenerate, fb.clamp(max=n_max - 1), pick)
        centers[:, j] = torch.where(ok[:, j:j + 1], x[ar, pick], centers[:, j])
        nearest = torch.minimum(nearest, 1 - (x * centers[:, j:j + 1]).sum(-1))
        prob = w * nearest.clamp(min=0) ** 2
    return centers
