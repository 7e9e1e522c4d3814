"""k-means++ seeding (:mod:`torchakvf.cluster.kmeanspp`): each mesh's own seeding on the CPU is
the batched seeding's, and so is its clustering."""
from __future__ import annotations

import torch

from torchakvf.cluster import spherical_kmeans
from torchakvf.cluster.kmeanspp import kmeanspp


def test_kmeans_seeding_per_mesh_equals_the_batched_seeding():
    """On CPU each mesh of a batch seeds its own k centers; the centers, and so the clustering,
    are those of the batched seeding (which the other devices keep)."""
    g = torch.Generator().manual_seed(3)
    x = torch.nn.functional.normalize(torch.randn(3, 50, 4, generator=g, dtype=torch.float64), dim=-1)
    w = torch.ones(3, 50, dtype=torch.float64)
    w[1, 40:] = 0                                                     # a shorter mesh
    x = x * (w > 0)[..., None]
    ks = [5, 2, 9]
    u = torch.rand(3, 4, 9, generator=g, dtype=torch.float64)
    ok = torch.arange(9)[None, :] < torch.tensor(ks)[:, None]
    batched = kmeanspp(x, w, u, ok)
    for b, k in enumerate(ks):
        own = kmeanspp(x[b:b + 1], w[b:b + 1], u[b:b + 1, :, :k], ok[b:b + 1, :k])
        # Centers are rows of x picked by comparing a uniform draw with cumulative weights: other
        # products' round-off (1e-16 relative) moves a pick only for a draw that close to a step
        # of them, so the picks, and the rows copied, are compared exactly.
        assert torch.equal(own[0], batched[b, :, :k])
    mask = w > 0
    km = spherical_kmeans(x, mask, ks, restarts=4, seed=0)
    for b, k in enumerate(ks):
        one = spherical_kmeans(x[b:b + 1], mask[b:b + 1], [k], restarts=4, seed=0)
        assert torch.equal(km.labels[b], one.labels[0]) and torch.equal(km.cost[b], one.cost[0])
