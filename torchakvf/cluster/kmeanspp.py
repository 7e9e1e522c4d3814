"""k-means++ seeding of spherical k-means (cosine distance): every restart of every mesh of a
padded batch from pre-drawn uniforms, each mesh from its own seeded generator and of its own k,
and a warm start grown from given centers (:func:`kmeanspp_from`)."""
from __future__ import annotations

import torch

from ..errors import ParameterError


def seeded_centers(x: torch.Tensor, w: torch.Tensor, mask: torch.Tensor, ks: list, r: int, seed: int,
                   center_ok: torch.Tensor, init) -> torch.Tensor:
    """[B, R, k_max, d] k-means++ centers of every restart of every mesh (x [B, N_max, d] unit
    rows, w [B, N_max] weights, ks [B], center_ok [B, k_max]); with ``init``, each listed mesh's
    last restart grown from its given seeds (see :func:`spherical_kmeans`)."""
    nb, _, d = x.shape
    k_max, dev, dt = max(ks), x.device, x.dtype
    # Uniform draws for seeding, per mesh from its own generator and of its own k (padded), so a
    # mesh's clustering does not depend on the k's of the meshes beside it in the batch.
    draws = torch.zeros(nb, r, k_max, dtype=dt)
    for b in range(nb):
        draws[b, :, :ks[b]] = torch.rand(r, ks[b], generator=torch.Generator().manual_seed(seed), dtype=dt)
    draws = draws.to(dev)                                                          # [B, R, k_max]
    if dev.type == "cpu" and nb > 1:
        # Each mesh seeds its own k centers: batched, every mesh takes k_max sequential steps (a
        # round with one mesh at k' = 97 made the others' seeding 5x dearer); the same products
        # per mesh, so the same centers.
        centers = x.new_zeros(nb, r, k_max, d)
        for b in range(nb):
            centers[b:b + 1, :, :ks[b]] = kmeanspp(x[b:b + 1], w[b:b + 1], draws[b:b + 1, :, :ks[b]],
                                                  center_ok[b:b + 1, :ks[b]])
    else:
        centers = kmeanspp(x, w, draws, center_ok)                                # [B, R, k_max, d]
    if init is not None:
        if len(init) != nb:
            raise ParameterError(f"init has {len(init)} entries for {nb} meshes")
        for b, seeds in enumerate(init):
            if seeds is not None:
                end = int(torch.nonzero(mask[b]).max()) + 1   # the same rows in any batch
                centers[b, r - 1, :ks[b]] = kmeanspp_from(x[b, :end], w[b, :end], seeds,
                                                          draws[b, r - 1, :ks[b]], b)
    return centers


def kmeanspp_from(x: torch.Tensor, w: torch.Tensor, seeds: torch.Tensor, u: torch.Tensor,
                  b: int) -> torch.Tensor:
    """One mesh's k centers: the given seeds, then k-means++ draws for the rest.

    x : [N, d] unit rows (0 on padding); w : [N] weights; seeds : [j, d] (normalized here,
    1 <= j <= k); u : [k] uniforms (u[c] picks center c, so u[:j] go unused).
    Returns [k, d]: the seeds, then rows drawn with probability ∝ weight · (1 - cos to the
    nearest center so far)^2 (uniform over the rows of positive weight where that is 0).
    """
    k = len(u)
    if seeds.dim() != 2 or seeds.shape[1] != x.shape[1] or not 1 <= len(seeds) <= k:
        raise ParameterError(f"init of mesh {b} must be [j, {x.shape[1]}] with 1 <= j <= {k}, "
                             f"got {list(seeds.shape)}")
    seeds = torch.nn.functional.normalize(seeds.to(x.dtype).to(x.device), dim=-1)
    out = x.new_zeros(k, x.shape[1])
    out[:len(seeds)] = seeds
    nearest = (1 - x @ seeds.T).min(dim=1).values                                  # [N]
    for c in range(len(seeds), k):
        prob = w * nearest.clamp(min=0) ** 2
        cdf = prob.cumsum(0)
        if float(cdf[-1]) > 0:
            pick = int(torch.searchsorted(cdf, (u[c] * cdf[-1]).reshape(1)).clamp(max=len(x) - 1))
        else:
            valid = (w > 0).to(x.dtype).cumsum(0)
            pick = int(torch.searchsorted(valid, (u[c] * valid[-1]).reshape(1)).clamp(max=len(x) - 1))
        out[c] = x[pick]
        nearest = torch.minimum(nearest, 1 - x @ out[c])
    return out


def kmeanspp(x: torch.Tensor, w: torch.Tensor, u: torch.Tensor, ok: torch.Tensor) -> torch.Tensor:
    """k-means++ seeding of every restart by inverse-CDF sampling with pre-drawn uniforms.

    x : [B, N, d] unit rows; w : [B, N] weights; u : [B, R, k_max] uniforms; ok : [B, k_max].
    Rows are drawn with probability ∝ weight · (1 - cos to the nearest chosen center)^2.
    Returns centers [B, R, k_max, d] (0 where ``ok`` is False).
    """
    nb, n_max, d = x.shape
    r, k_max = u.shape[1], u.shape[2]
    centers = x.new_zeros(nb, r, k_max, d)
    prob = w[:, None, :].expand(nb, r, n_max).clone()                               # [B, R, N]
    nearest = torch.full((nb, r, n_max), 2.0, dtype=x.dtype, device=x.device)
    ar = torch.arange(nb, device=x.device)[:, None]
    valid = None
    for j in range(k_max):
        cdf = prob.cumsum(2)
        total = cdf[..., -1:]
        pick = torch.searchsorted(cdf, (u[..., j:j + 1] * total).contiguous()).clamp(max=n_max - 1)[..., 0]
        # Fall back to uniform over valid rows where every remaining row has zero weight.
        degenerate = total[..., 0] <= 0                                             # [B, R]
        if degenerate.any():
            if valid is None:
                valid = (w > 0).to(x.dtype).cumsum(1)[:, None, :].expand(nb, r, n_max).contiguous()
            fb = torch.searchsorted(valid, (u[..., j:j + 1] * valid[..., -1:]).contiguous())[..., 0]
            pick = torch.where(degenerate, fb.clamp(max=n_max - 1), pick)
        chosen = x[ar, pick]                                                        # [B, R, d]
        centers[:, :, j] = torch.where(ok[:, None, j:j + 1], chosen, centers[:, :, j])
        nearest = torch.minimum(nearest, 1 - centers[:, :, j] @ x.transpose(1, 2))
        prob = w[:, None, :] * nearest.clamp(min=0) ** 2
    return centers
