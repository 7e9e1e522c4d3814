"""DEC identities and the Killing operator, checked entry by entry against the independent
numpy/scipy reference (torchakvf/scipy_reference.py) on closed and open meshes."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.operators import (angle_defect, angle_sum, batch_geometry, d0, d1, killing_operator,
                                 star0, star1, star2)

from torchakvf import scipy_reference as ref

from planar_meshes import golden_disk
from threads import one_torch_thread  # noqa: F401 - autouse fixture




SHAPES = {
    "icosphere3": lambda: (shapes.icosphere(3).vertices, shapes.icosphere(3).faces),
    "torus": lambda: (shapes.torus(n_major=48).vertices, shapes.torus(n_major=48).faces),
    "open_tube": lambda: (shapes.open_tube(n_around=36).vertices, shapes.open_tube(n_around=36).faces),
    "golden_disk": golden_disk,
    "hemisphere3": lambda: (shapes.hemisphere(3).vertices, shapes.hemisphere(3).faces),
    "square_patch": lambda: (shapes.square_patch(14).vertices, shapes.square_patch(14).faces),
    "flat_disk": lambda: (shapes.flat_disk(n_boundary=60).vertices, shapes.flat_disk(n_boundary=60).faces),
}
EULER = {"icosphere3": 2, "torus": 0, "open_tube": 0, "golden_disk": 1, "hemisphere3": 1,
         "square_patch": 1, "flat_disk": 1}


@pytest.fixture(scope="module")
def meshes():
    return {k: ta.Mesh(*f(), name=k) for k, f in SHAPES.items()}


@pytest.fixture(scope="module")
def batch(meshes):
    return ta.MeshBatch.from_meshes([meshes[k] for k in SHAPES])


def _per_mesh_sum(x: torch.Tensor, ptr: torch.Tensor) -> np.ndarray:
    return np.array([float(x[int(ptr[b]):int(ptr[b + 1])].sum()) for b in range(len(ptr) - 1)])


def _scipy(a: torch.Tensor) -> sp.csr_matrix:
    a = a.coalesce()
    i = a.indices().cpu().numpy()
    return sp.csr_matrix((a.values().cpu().numpy(), (i[0], i[1])), shape=tuple(a.shape))


# ---------------------------------------------------------------------------------------------
# DEC identities
# ---------------------------------------------------------------------------------------------

def test_d0_d1_structure_and_exactness(batch):
    D0, D1 = _scipy(d0(batch)), _scipy(d1(batch))
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
    total = _per_mesh_sum(theta + turning, batch.vert_ptr)
    for b, name in enumerate(batch.names):
        nv = int(batch.vert_ptr[b + 1] - batch.vert_ptr[b])
        ne = int(batch.edge_ptr[b + 1] - batch.edge_ptr[b])
        nfc = int(batch.face_ptr[b + 1] - batch.face_ptr[b])
        chi = nv - ne + nfc
        assert chi == EULER[name], name
        assert abs(total[b] - 2 * math.pi * chi) < 1e-11, (name, total[b])
        if not bverts[int(batch.vert_ptr[b]):int(batch.vert_ptr[b + 1])].any():
            tb = _per_mesh_sum(theta, batch.vert_ptr)[b]
            assert abs(tb - 2 * math.pi * chi) < 1e-11, (name, tb)


def test_hodge_stars_on_unit_area(batch, meshes):
    geo = batch_geometry(batch)
    np.testing.assert_allclose(_per_mesh_sum(star0(batch, geo), batch.vert_ptr), 1.0, rtol=1e-13)
    np.testing.assert_allclose(_per_mesh_sum(1.0 / star2(geo), batch.face_ptr), 1.0, rtol=1e-13)
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


# ---------------------------------------------------------------------------------------------
# Killing operator vs the scipy reference
# ---------------------------------------------------------------------------------------------

EXACT_SHAPES = ["icosphere3", "open_tube", "golden_disk", "hemisphere3", "square_patch"]


@pytest.mark.parametrize("bc", [True, False], ids=["bc", "naive"])
@pytest.mark.parametrize("name", EXACT_SHAPES)
def test_stiffness_matches_scipy_reference(meshes, name, bc):
    b = ta.MeshBatch.from_meshes([meshes[name]])
    system = killing_operator(b, boundary_correction=bc, remedy="none")
    cm = b.meshes[0]
    R, S1, edges, meta = ref.killing_operator_scipy(cm.vertices, cm.faces, boundary_correction=bc)
    assert meta["n_nonpositive_S1"] == 0        # precondition: no mass floor anywhere
    np.testing.assert_array_equal(b.edges.numpy(), edges)
    Rt = _scipy(system.stiffness)
    scale = abs(R).max()
    assert abs(Rt - R).max() <= 1e-9 * scale, abs(Rt - R).max() / scale
    # exactly symmetric up to round-off
    assert abs(Rt - Rt.T).max() <= 1e-14 * scale
    np.testing.assert_allclose(system.mass.numpy(), S1, rtol=1e-12)
    np.testing.assert_allclose(system.star1_raw.numpy(), S1, rtol=1e-12)
    # the boundary correction changes an open mesh's operator, and is a no-op on a closed one
    R_other, *_ = ref.killing_operator_scipy(cm.vertices, cm.faces, boundary_correction=not bc)
    if meta["n_boundary_edges"]:
        assert abs(Rt - R_other).max() > 1e-3 * scale
    else:
        assert abs(Rt - R_other).max() <= 1e-12 * scale


def test_stiffness_symmetric_whole_batch(batch):
    for bc in (True, False):
        R = _scipy(killing_operator(batch, boundary_correction=bc, remedy="none").stiffness)
        assert abs(R - R.T).max() <= 1e-14 * abs(R).max()


def test_stiffness_matches_reference_with_negative_cotans():
    s = shapes.ellipsoid(level=3)                 # 4 edges with star1 < 0 (down to -0.028)
    b = ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)])
    cm = b.meshes[0]
    R, S1, _, meta = ref.killing_operator_scipy(cm.vertices, cm.faces)
    assert meta["n_nonpositive_S1"] > 0
    Rt = _scipy(killing_operator(b, remedy="none").stiffness)
    assert abs(Rt - R).max() <= 1e-9 * abs(R).max(), abs(Rt - R).max() / abs(R).max()


@pytest.mark.parametrize("remedy", ["clamp", "smooth"])
@pytest.mark.parametrize("name", ["ellipsoid3", "hemisphere3", "square_patch"])
def test_remedy_operators_match_independent_reference(meshes, name, remedy):
    """The remedies against the scipy reference's own statement of them (floored star1 in
    every term, ring-averaged curvature written with scipy.sparse), on meshes with negative
    cotans (ellipsoid3), a boundary (hemisphere3) and a jittered open patch."""
    if name == "ellipsoid3":
        s = shapes.ellipsoid(level=3)
        mesh = ta.Mesh(s.vertices, s.faces)
    else:
        mesh = meshes[name]
    b = ta.MeshBatch.from_meshes([mesh])
    cm = b.meshes[0]
    system = killing_operator(b, remedy=remedy)
    R, S1, edges, _ = ref.killing_operator_scipy(cm.vertices, cm.faces, remedy=remedy)
    np.testing.assert_array_equal(b.edges.numpy(), edges)
    Rt, scale = _scipy(system.stiffness), abs(R).max()
    assert abs(Rt - R).max() <= 1e-9 * scale, abs(Rt - R).max() / scale
    np.testing.assert_allclose(system.mass.numpy(), S1, rtol=1e-12)
    # The remedy does change the operator (so the comparison above can fail).
    R_none, *_ = ref.killing_operator_scipy(cm.vertices, cm.faces, remedy="none")
    if remedy == "smooth" or bool((system.star1_raw < system.mass).any()):
        assert abs(Rt - R_none).max() > 1e-6 * scale


def test_batch_is_block_diagonal_of_each_alone(meshes):
    names = ["icosphere3", "golden_disk", "open_tube", "hemisphere3"]
    for bc in (True, False):
        batch = ta.MeshBatch.from_meshes([meshes[k] for k in names])
        system = killing_operator(batch, boundary_correction=bc, remedy="none")
        idx = system.stiffness.indices()
        owner = batch.edge_to_mesh
        assert torch.equal(owner[idx[0]], owner[idx[1]])         # nothing couples two meshes
        for b, k in enumerate(names):
            alone = killing_operator(ta.MeshBatch.from_meshes([meshes[k]]), boundary_correction=bc, remedy="none")
            r, c, v, size = system.block(b)
            assert size == len(alone.mass)
            Rb = sp.csr_matrix((v.numpy(), (r.numpy(), c.numpy())), shape=(size, size))
            Ra = _scipy(alone.stiffness)
            assert abs(Rb - Ra).max() <= 1e-13 * abs(Ra).max()
            lo, hi = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
            np.testing.assert_allclose(system.mass[lo:hi].numpy(), alone.mass.numpy(), rtol=1e-14)
        # the blocks' nonzeros add up to the whole matrix
        total = sum(len(system.block(b)[2]) for b in range(len(names)))
        assert total == system.stiffness.values().numel()


# ---------------------------------------------------------------------------------------------
# what the operator means: rigid motions are (nearly) in its kernel
# ---------------------------------------------------------------------------------------------

def _rayleigh(system, w: np.ndarray) -> np.ndarray:
    R = _scipy(system.stiffness)
    s = system.mass.numpy()
    return np.einsum("en,en->n", w, R @ w) / np.einsum("en,e,en->n", w, s, w)


def test_disk_rigid_motions_need_boundary_correction(meshes):
    b = ta.MeshBatch.from_meshes([meshes["golden_disk"]])
    p = batch_geometry(b).points.numpy()
    e = b.edges.numpy()
    vec = p[e[:, 1]] - p[e[:, 0]]
    mid = 0.5 * (p[e[:, 0]] + p[e[:, 1]])
    rot = np.einsum("ec,ec->e", np.cross([0.0, 0.0, 1.0], mid), vec)
    w = np.stack([vec[:, 0], vec[:, 1], rot], axis=1)     # x, y translations; rotation about z
    rq_bc = _rayleigh(killing_operator(b, boundary_correction=True, remedy="none"), w)
    rq_naive = _rayleigh(killing_operator(b, boundary_correction=False, remedy="none"), w)
    assert np.all(np.abs(rq_bc[:2]) < 1e-8), rq_bc
    assert abs(rq_bc[2]) < 0.1, rq_bc
    assert np.all(rq_naive > 1.0), rq_naive


def test_sphere_rotations_nearly_killing(meshes):
    b = ta.MeshBatch.from_meshes([meshes["icosphere3"]])
    system = killing_operator(b, remedy="none")
    p = system.geometry.points.numpy()
    e = b.edges.numpy()
    vec = p[e[:, 1]] - p[e[:, 0]]
    mid = 0.5 * (p[e[:, 0]] + p[e[:, 1]])
    w = np.stack([np.einsum("ec,ec->e", np.cross(a, mid), vec) for a in np.eye(3)], axis=1)
    rq = _rayleigh(system, w)
    # O(h^2): 0.0165 on icosphere(3) (docs/akvf_operator.md, Sec. 3), far below the next mode (~25)
    assert np.all((rq > 0.005) & (rq < 0.03)), rq
    # a generic (non-Killing) gradient field costs much more
    g = (p[e[:, 1]] - p[e[:, 0]]) @ np.array([1.0, 2.0, 3.0])
    assert _rayleigh(system, g[:, None])[0] > 10


def test_remedy_validation_and_clamp(meshes):
    b = ta.MeshBatch.from_meshes([meshes["icosphere3"], meshes["flat_disk"]])
    with pytest.raises(ta.ParameterError, match="remedy"):
        killing_operator(b, remedy="bogus")
    none = killing_operator(b, remedy="none")
    clamp = killing_operator(b, remedy="clamp")
    for bi in range(2):
        lo, hi = int(b.edge_ptr[bi]), int(b.edge_ptr[bi + 1])
        raw = none.star1_raw[lo:hi]
        floor = 0.1 * raw.abs().mean()
        torch.testing.assert_close(clamp.mass[lo:hi], torch.maximum(raw, floor), rtol=1e-14, atol=0)
        assert torch.all(none.mass[lo:hi] > 0)
    # flat_disk has exact right angles (star1 ~ 0): it is counted
    assert int(none.negative_star1_counts()[1]) > 0
    assert int(none.negative_star1_counts()[0]) == 0


def test_meshbatch_to_dtype_keeps_index_tensors():
    b = ta.MeshBatch.from_meshes([ta.Mesh(shapes.icosphere(1).vertices, shapes.icosphere(1).faces)])
    for moved in (b.to(torch.float32), b.to("cpu", torch.float32), b.to(dtype=torch.float32)):
        assert moved.verts.dtype == torch.float32 and moved.face_edge_sign.dtype == torch.float32
        for name in ("faces", "edges", "face_edges", "vert_ptr", "face_ptr", "edge_ptr"):
            assert getattr(moved, name).dtype == torch.int64, name
            assert torch.equal(getattr(moved, name), getattr(b, name)), name
    assert b.to("cpu").dtype == torch.float64
    with pytest.raises(ta.ParameterError):
        b.to(torch.int32)


def test_owner_index_matches_batch_maps():
    from torchakvf.mesh import owner_index
    ptr = torch.tensor([0, 3, 3, 5])
    assert owner_index(ptr).tolist() == [0, 0, 0, 2, 2]
    s = [shapes.icosphere(1), shapes.icosphere(2)]
    b = ta.MeshBatch.from_meshes([ta.Mesh(x.vertices, x.faces) for x in s])
    assert torch.equal(b.face_to_mesh, owner_index(b.face_ptr))
    assert b.edge_to_mesh.tolist() == [0] * 120 + [1] * 480


def test_single_threaded_restores_the_thread_count_also_when_overlapping():
    import threading

    from torchakvf._threads import single_threaded
    saved = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        with single_threaded():
            assert torch.get_num_threads() == 1
            with single_threaded():
                assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        # Two threads whose blocks overlap (A enters, B enters, A leaves, B leaves): the process
        # ends with its thread count, not with the 1 that B would have saved.
        a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

        def first():
            with single_threaded():
                a_in.set()
                b_in.wait(5)
            a_out.set()

        def second():
            a_in.wait(5)
            with single_threaded():
                b_in.set()
                a_out.wait(5)

        ts = [threading.Thread(target=first), threading.Thread(target=second)]
        for t in ts:
            t.start()
        for t in ts:
            t.join(10)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)
