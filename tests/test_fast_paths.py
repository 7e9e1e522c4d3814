"""The segment stage's fast paths give the straightforward computations' answers, bitwise
(issue 13): part ids and sums by bincount against np.unique / np.add.at, the region graph
against a plain loop over the dual edges, barycenter values and surface interpolation against
their [F, 3, ...] gathers, and k-means' single-mesh CPU path against the batched one."""
from __future__ import annotations

import numpy as np
import torch

from torchakvf import shapes
from torchakvf.cluster import spherical_kmeans
from torchakvf.cluster.spherical_kmeans import _lloyd
from torchakvf.mesh.clean import face_areas
from torchakvf.mesh.coarse import SurfacePoints
from torchakvf.parts.boundaries import barycenter_values, vertex_distances
from torchakvf.parts.concavity import crease_weights, dual_edges
from torchakvf.parts.grouping import compact_labels, group_sums
from torchakvf.parts.merge import merged_distances, partition_cost, region_graph


def test_compact_labels_and_group_sums_are_unique_and_add_at():
    rng = np.random.default_rng(0)
    labels = rng.choice([-1, 0, 3, 4, 9], size=500)
    out, k = compact_labels(labels)
    uniq, inv = np.unique(labels[labels >= 0], return_inverse=True)
    assert k == len(uniq)
    np.testing.assert_array_equal(out[labels >= 0], inv)
    assert (out[labels < 0] == -1).all()
    rows = rng.normal(size=(len(inv), 7))
    ref = np.zeros((k, 7))
    np.add.at(ref, inv, rows)
    np.testing.assert_array_equal(group_sums(inv, rows, k), ref)      # bitwise
    assert compact_labels(np.full(4, -1))[1] == 0


def test_region_graph_equals_a_plain_loop_over_the_dual_edges():
    s = shapes.icosphere(2)
    rng = np.random.default_rng(1)
    bary = s.vertices[s.faces].mean(1)
    labels = np.argmax(bary @ rng.normal(size=(6, 3)).T, axis=1) * 2     # ids 0, 2, ..., 10
    labels[:5] = -1
    feats = rng.normal(size=(len(labels), 4))
    area = face_areas(s.vertices, s.faces)
    dual = dual_edges(s.vertices, s.faces)
    g = region_graph(labels, dual, feats, area, crease_angle=1.0)
    ids = sorted(set(labels[labels >= 0].tolist()))
    K = len(ids)
    area_ref, mean_ref = np.zeros(K), np.zeros((K, 4))
    for f, lab in enumerate(labels):
        if lab >= 0:
            p = ids.index(lab)
            area_ref[p] += area[f]
            mean_ref[p] += area[f] * feats[f] / np.linalg.norm(feats[f])
    length, concave, convex = (np.zeros((K, K)) for _ in range(3))
    cav, cvx = crease_weights(dual.dihedral, 1.0)
    for e, (a, b) in enumerate(dual.pairs):
        if labels[a] >= 0 and labels[b] >= 0 and labels[a] != labels[b]:
            i, j = ids.index(labels[a]), ids.index(labels[b])
            for mat, val in ((length, 1.0), (concave, cav[e]), (convex, cvx[e])):
                mat[i, j] += dual.length[e] * val
                mat[j, i] += dual.length[e] * val
    np.testing.assert_array_equal(g.labels[labels >= 0], [ids.index(v) for v in labels[labels >= 0]])
    np.testing.assert_allclose(g.area, area_ref, rtol=1e-14)
    np.testing.assert_allclose(g.mean, mean_ref / area_ref[:, None], rtol=1e-12)
    for got, ref in ((g.length, length), (g.concave, concave), (g.convex, convex)):
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15)
    # partition_cost from a plain loop too
    unit = feats / np.linalg.norm(feats, axis=1, keepdims=True)
    cost = 0.0
    for lab in ids:
        u = unit[labels == lab]
        c = u.sum(0) / np.linalg.norm(u.sum(0))
        cost += float(np.sum(1 - u @ c))
    np.testing.assert_allclose(partition_cost(labels, feats), cost, rtol=1e-12)


def test_merged_distances_and_vertex_distances_equal_their_loops():
    rng = np.random.default_rng(2)
    s = shapes.icosphere(2)
    before = rng.integers(0, 8, len(s.faces))
    after = np.array([0, 1, 0, 2, 1, 2, 0, 1])[before]
    before[:3] = -1
    dist = rng.random((len(s.vertices), 8))
    ref = np.full((len(s.vertices), 3), np.inf)
    for old, new in zip(before, after):
        if old >= 0:
            ref[:, new] = np.minimum(ref[:, new], dist[:, old])
    np.testing.assert_array_equal(merged_distances(dist, before, after), ref)
    feats, area = rng.normal(size=(len(s.faces), 5)), face_areas(s.vertices, s.faces)
    centers = rng.normal(size=(4, 5))
    centers /= np.linalg.norm(centers, axis=1, keepdims=True)
    unit = feats / np.linalg.norm(feats, axis=1, keepdims=True)
    acc = np.zeros((len(s.vertices), 5))
    np.add.at(acc, s.faces.reshape(-1), np.repeat(unit * area[:, None], 3, axis=0))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    np.testing.assert_array_equal(vertex_distances(s.vertices, s.faces, feats, area, centers), 1.0 - acc @ centers.T)


def test_barycenter_values_and_interpolation_equal_the_gathers():
    rng = np.random.default_rng(3)
    faces = rng.integers(0, 40, (70, 3))
    for v in (rng.random((40, 6)), rng.random(40)):
        np.testing.assert_array_equal(barycenter_values(faces, v), v[faces].mean(axis=1))
        bary = rng.random((90, 3))
        bary /= bary.sum(1, keepdims=True)
        pts = SurfacePoints(rng.integers(0, 70, 90), bary, np.zeros(90))
        corners = v[faces[pts.face]]
        ref = (corners * bary.reshape(bary.shape + (1,) * (corners.ndim - 2))).sum(axis=1)
        np.testing.assert_array_equal(pts.interpolate(faces, v), ref)


def test_kmeans_one_mesh_lloyd_equals_the_gathered_batch_path():
    """Lloyd on one mesh (every restart live at first: no per-iteration copies) and on a batch
    of two meshes whose restarts settle at other times (the gathered path CUDA takes): the
    same labels, costs, iteration counts and centers, restart by restart."""
    gen = torch.Generator().manual_seed(4)
    x = torch.randn(2, 300, 6, generator=gen, dtype=torch.float64)
    x[1] += 3 * torch.randn(1, 6, generator=gen, dtype=torch.float64)
    x = torch.nn.functional.normalize(x, dim=-1)
    w = torch.rand(2, 300, generator=gen, dtype=torch.float64)
    seeds = x[:, torch.randperm(300, generator=gen)[:5 * 7]].reshape(2, 5, 7, 6)
    both = _lloyd(x, w, seeds, 100, torch.float32)
    for b in range(2):
        alone = _lloyd(x[b:b + 1], w[b:b + 1], seeds[b:b + 1], 100, torch.float32)
        for got, ref in zip(alone, both):
            assert torch.equal(got[0], ref[b])
    # restart 0 of five is the single-restart run (the same first draws)
    mask = torch.ones(1, 300, dtype=torch.bool)
    five = spherical_kmeans(x[:1], mask, 7, restarts=5, seed=3)
    one = spherical_kmeans(x[:1], mask, 7, restarts=1, seed=3)
    assert torch.equal(one.restart_costs[0, 0], five.restart_costs[0, 0])
