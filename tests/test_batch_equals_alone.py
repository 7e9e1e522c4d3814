"""A mesh segmented in a batch gets the bits it gets alone (batching must not change answers):
meshes of one round at different field counts and cluster counts, so the round's arrays are
padded past each mesh's own."""
import numpy as np
import pytest
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.cluster import spherical_kmeans
from torchakvf.options import SegmentOptions
from torchakvf.parts.field_counts import akvf_count
from torchakvf.parts.rounds import segment_rounds


@pytest.fixture(scope="module")
def solved():
    ms = [ta.Mesh(s.vertices, s.faces, name=s.name)
          for s in (shapes.three_blobs(n_around=20), shapes.dumbbell(), shapes.sphere_with_two_ellipsoids())]
    n = akvf_count([[9]])                       # 32 fields + spare: every k below fits
    batch = ta.akvf(ta.MeshBatch.from_meshes(ms), n=n, remedy="smooth")
    alone = [ta.akvf(m, n=n, remedy="smooth") for m in ms]
    return ms, batch, alone


def test_batched_rounds_equal_each_mesh_alone(solved):
    ms, batch, alone = solved
    for b, f in enumerate(alone):   # the batched eigensolve's fields are each mesh's own
        e0, e1 = int(batch.batch.edge_ptr[b]), int(batch.batch.edge_ptr[b + 1])
        assert torch.equal(batch.forms[e0:e1], f.forms)
    # round 0: n 32 / 24 / 24 and k' 27 / 24 / 24; round 1: mesh 1 sits out; round 2: mesh 0 alone
    ks = [[9, 3, 10], [2], [5, 12]]
    opts = SegmentOptions(seed=0, refine=False)
    together = {}
    for rnd in segment_rounds(batch, ks, opts):
        assert rnd.untangled.n == max(int(v) for v in rnd.untangled.n_fields)
        for b in rnd.active:
            together[(b, rnd.ks[b])] = rnd.meshes[b]
    for b, f in enumerate(alone):
        for rnd in segment_rounds(f, [ks[b]], opts):
            one, many = rnd.meshes[0], together[(b, rnd.ks[0])]
            np.testing.assert_array_equal(many.labels, one.labels)
            assert many.cost == one.cost
            assert many.features.shape == one.features.shape
            assert np.array_equal(many.features, one.features)
            assert many.generators == one.generators     # from the untangled fields' energies


def test_kmeans_seeding_per_mesh_equals_the_batched_seeding():
    """On CPU each mesh of a batch seeds its own k centers; the centers, and so the clustering,
    are those of the batched seeding (which the other devices keep)."""
    from torchakvf.cluster.spherical_kmeans import kmeanspp
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
        assert torch.equal(own[0], batched[b, :, :k])
    mask = w > 0
    km = spherical_kmeans(x, mask, ks, restarts=4, seed=0)
    for b, k in enumerate(ks):
        one = spherical_kmeans(x[b:b + 1], mask[b:b + 1], [k], restarts=4, seed=0)
        assert torch.equal(km.labels[b], one.labels[0]) and torch.equal(km.cost[b], one.cost[0])
