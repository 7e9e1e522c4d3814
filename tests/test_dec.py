"""DEC operators (torchakvf.operators.dec): exactness, Gauss-Bonnet with boundary turning, the
Hodge stars on unit-area meshes, against the independent numpy/scipy reference."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from helpers.operator_meshes import EULER, SHAPES, as_scipy, per_mesh_sum, shape_meshes

import torchakvf as ta
from torchakvf import scipy_reference as ref
from torchakvf.operators import angle_defect, angle_sum, batch_geometry, d0, d1, star0, star1, star2

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)


@pytest.fixture(scope="module")
def meshes():
    return shape_meshes()


@pytest.fixture(scope="module")
def batch(meshes):
    return ta.MeshBatch.from_meshes([meshes[k] for k in SHAPES])


def test_d0_d1_structure_and_exactness(batch):
    D0, D1 = as_scipy(d0(batch)), as_scipy(d1(batch))
    e = batch.edges.numpy()
    assert D0.shape == (len(e), len(batch.verts)) and D1.shape == (len(batch.faces), len(e))
    # (d0 f)_e = f_j - f_i for e = (i -> j)
    f = np.random.default_rng(0).standard_normal(len(batch.verts))
    np.testing.assert_array_equal(D0 @ f, f[e[:, 1]] - f[e[:, 0]])
    # every face row holds three +-1 entries, every interior edge is in two faces
    assert np.all(np.diff(D1.indptr) == 3) and set(np.unique(D1.data)) <= {-1.0, 1.0}
    # d1 d0 = 0 exactly (integer arithmetic in floats)
    assert abs(D1 @ D0).max() == 0
    dd = torch.sparse.mm(d1(batch), d0(batch)).coalesce()
    assert torch.all(dd.values() == 0)
    # within each mesh: edges are i < j, sorted, and never cross meshes
    for b in range(len(batch)):
        lo, hi = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
        eb = e[lo:hi]
        assert np.all(eb[:, 0] < eb[:, 1])
        assert np.all(np.diff(eb[:, 0] * 10 ** 7 + eb[:, 1]) > 0)
        assert eb.min() >= int(batch.vert_ptr[b]) and eb.max() < int(batch.vert_ptr[b + 1])


def test_gauss_bonnet_and_boundary_defect(batch):
    geo = batch_geometry(batch)
    theta = angle_defect(batch, geo)
    asum = angle_sum(batch, geo)
    nf = torch.zeros(len(batch.edges), dtype=torch.long)
    nf.index_add_(0, batch.face_edges.reshape(-1), torch.ones(batch.face_edges.numel(), dtype=torch.long))
    bverts = torch.zeros(len(batch.verts), dtype=torch.bool)
    bverts[batch.edges[nf == 1].reshape(-1)] = True
    assert torch.all(theta[bverts] == 0)                         # boundary vertices: 0 defect
    turning = torch.where(bverts, math.pi - asum, torch.zeros_like(asum))
    total = per_mesh_sum(theta + turning, batch.vert_ptr)
    for b, name in enumerate(batch.names):
        nv = int(batch.vert_ptr[b + 1] - batch.vert_ptr[b])
        ne = int(batch.edge_ptr[b + 1] - batch.edge_ptr[b])
        nfc = int(batch.face_ptr[b + 1] - batch.face_ptr[b])
        chi = nv - ne + nfc
        assert chi == EULER[name], name
        assert abs(total[b] - 2 * math.pi * chi) < 1e-11, (name, total[b])
        if not bverts[int(batch.vert_ptr[b]):int(batch.vert_ptr[b + 1])].any():
            tb = per_mesh_sum(theta, batch.vert_ptr)[b]
            assert abs(tb - 2 * math.pi * chi) < 1e-11, (name, tb)


def test_hodge_stars_on_unit_area(batch, meshes):
    geo = batch_geometry(batch)
    np.testing.assert_allclose(per_mesh_sum(star0(batch, geo), batch.vert_ptr), 1.0, rtol=1e-13)
    np.testing.assert_allclose(per_mesh_sum(1.0 / star2(geo), batch.face_ptr), 1.0, rtol=1e-13)
    assert torch.all(star0(batch, geo) > 0)
    # the unit-area scale: area * scale^2 = 1, and the input area is kept
    np.testing.assert_allclose((geo.area * geo.scale ** 2).numpy(), 1.0, rtol=1e-13)
    s1 = star1(batch, geo).numpy()
    for b, name in enumerate(batch.names):
        cm = batch.meshes[b]
        _, S1, edges, meta = ref.killing_operator_scipy(cm.vertices, cm.faces)
        lo, hi = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
        np.testing.assert_array_equal(batch.edges[lo:hi].numpy() - int(batch.vert_ptr[b]), edges)
        np.testing.assert_allclose(s1[lo:hi], S1, rtol=0, atol=1e-12)
        np.testing.assert_allclose(float(geo.area[b]), meta["area_input"], rtol=1e-13)
        np.testing.assert_allclose(
            star0(batch, geo)[int(batch.vert_ptr[b]):int(batch.vert_ptr[b + 1])].numpy(),
            meta["star0"], rtol=1e-12)
        theta = angle_defect(batch, geo)[int(batch.vert_ptr[b]):int(batch.vert_ptr[b + 1])].numpy()
        np.testing.assert_allclose(theta, meta["angle_defect"], rtol=0, atol=1e-12)
