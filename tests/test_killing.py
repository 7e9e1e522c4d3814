"""The Killing operator (torchakvf.operators.killing), checked entry by entry against the
independent numpy/scipy reference (torchakvf/scipy_reference.py) on closed and open meshes; its
remedies; a batch block-diagonal of its meshes; rigid motions nearly in its kernel."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import torch
from helpers.operator_meshes import SHAPES, as_scipy, shape_meshes

import torchakvf as ta
from torchakvf import scipy_reference as ref
from torchakvf import shapes
from torchakvf.operators import batch_geometry, killing_operator
from torchakvf.operators.killing import KillingAssembly

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)


@pytest.fixture(scope="module")
def meshes():
    return shape_meshes()


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
    Rt = as_scipy(system.stiffness)
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


def test_stiffness_symmetric_whole_batch(meshes):
    batch = ta.MeshBatch.from_meshes([meshes[k] for k in SHAPES])
    for bc in (True, False):
        R = as_scipy(killing_operator(batch, boundary_correction=bc, remedy="none").stiffness)
        assert abs(R - R.T).max() <= 1e-14 * abs(R).max()


def test_stiffness_matches_reference_with_negative_cotans():
    s = shapes.ellipsoid(level=3)                 # 4 edges with star1 < 0 (down to -0.028)
    b = ta.MeshBatch.from_meshes([ta.Mesh(s.vertices, s.faces)])
    cm = b.meshes[0]
    R, S1, _, meta = ref.killing_operator_scipy(cm.vertices, cm.faces)
    assert meta["n_nonpositive_S1"] > 0
    Rt = as_scipy(killing_operator(b, remedy="none").stiffness)
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
    Rt, scale = as_scipy(system.stiffness), abs(R).max()
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
            Ra = as_scipy(alone.stiffness)
            assert abs(Rb - Ra).max() <= 1e-13 * abs(Ra).max()
            lo, hi = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
            np.testing.assert_allclose(system.mass[lo:hi].numpy(), alone.mass.numpy(), rtol=1e-14)
        # the blocks' nonzeros add up to the whole matrix
        total = sum(len(system.block(b)[2]) for b in range(len(names)))
        assert total == system.stiffness.values().numel()


def test_a_remedy_per_mesh_is_each_mesh_alone_with_its_remedy(meshes):
    """A list of remedies (what remedy="auto" decides) assembles each mesh's block as that mesh
    alone under its own remedy: floors, curvature rings and raw weights stay within a mesh."""
    names = ["icosphere3", "hemisphere3", "square_patch", "ellipsoid3"]
    remedies = ["smooth", "none", "clamp", "smooth"]
    meshes = dict(meshes, ellipsoid3=ta.Mesh(shapes.ellipsoid(level=3).vertices, shapes.ellipsoid(level=3).faces))
    batch = ta.MeshBatch.from_meshes([meshes[k] for k in names])
    system = killing_operator(batch, remedy=remedies)
    assert system.remedies == remedies
    for b, (k, remedy) in enumerate(zip(names, remedies)):
        alone = killing_operator(ta.MeshBatch.from_meshes([meshes[k]]), remedy=remedy)
        r, c, v, size = system.block(b)
        Rb = sp.csr_matrix((v.numpy(), (r.numpy(), c.numpy())), shape=(size, size))
        Ra = as_scipy(alone.stiffness)
        assert abs(Rb - Ra).max() <= 1e-13 * abs(Ra).max()
        lo, hi = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
        np.testing.assert_allclose(system.mass[lo:hi].numpy(), alone.mass.numpy(), rtol=1e-14)
        # and the remedy did change this block (so the comparison can fail)
        other = killing_operator(ta.MeshBatch.from_meshes([meshes[k]]), remedy="none" if remedy != "none" else "smooth")
        assert abs(as_scipy(other.stiffness) - Ra).max() > 1e-9 * abs(Ra).max()
    sub = system.select([3, 1])
    assert sub.remedies == ["smooth", "none"]


@pytest.mark.parametrize("bc", [True, False], ids=["bc", "naive"])
def test_one_assembly_gives_every_remedys_operator_bit_for_bit(meshes, bc):
    """KillingAssembly computes the parts no remedy changes once; each system it then builds
    (the paper's first, as remedy "auto" does, then others) is a fresh assembly's exactly:
    nothing the first one made leaks into the next."""
    names = ["hemisphere3", "icosphere3", "open_tube"]
    batch = ta.MeshBatch.from_meshes([meshes[k] for k in names])
    assembly = KillingAssembly(batch, boundary_correction=bc)
    for remedies in (["none"] * 3, ["smooth", "none", "clamp"], ["smooth"] * 3, ["none"] * 3):
        got = assembly.system(remedies)
        want = killing_operator(batch, boundary_correction=bc, remedy=remedies)
        assert got.remedies == want.remedies == remedies
        assert torch.equal(got.stiffness.indices(), want.stiffness.indices())
        assert torch.equal(got.stiffness.values(), want.stiffness.values())
        assert torch.equal(got.mass, want.mass) and torch.equal(got.star1_raw, want.star1_raw)


# ---------------------------------------------------------------------------------------------
# what the operator means: rigid motions are (nearly) in its kernel
# ---------------------------------------------------------------------------------------------

def _rayleigh(system, w: np.ndarray) -> np.ndarray:
    R = as_scipy(system.stiffness)
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
