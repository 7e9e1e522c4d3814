"""The Krylov solver (torchakvf.solvers.krylov): multiplicities against scipy, the crowding
guard, room for spurious modes, a mesh smaller than its basis, the Gram-Schmidt pass."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
from helpers.eigen_checks import PAPER, clusters, mesh_of, s1_principal_cosines, scipy_matrices

import torchakvf as ta
from torchakvf import scipy_reference as ref
from torchakvf import shapes

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)


def _eigen_bounds(lam_ref: np.ndarray, res: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per pair: the a-posteriori bound on |Δλ| / max(|λ|, 1) of a symmetric pencil with relative
    residual ``res`` (min(r, r² / relgap), Kato-Temple), and on the sine of the angle between
    the computed and exact eigenspace of its cluster (r / relgap, Davis-Kahan), relgap being
    the distance to the nearest eigenvalue outside the pair's cluster."""
    scale = np.maximum(np.abs(lam_ref), 1.0)
    gaps = np.empty(len(lam_ref))
    for i in range(len(lam_ref)):
        d = np.abs(np.delete(lam_ref, i) - lam_ref[i])
        d = d[d > 1e-6 * scale[i]]
        gaps[i] = (d.min() if len(d) else np.inf) / scale[i]
    return np.minimum(res, res ** 2 / gaps), res / gaps


@pytest.mark.parametrize("remedy", ["none", "smooth"])
def test_krylov_matches_scipy_with_multiplicities(remedy):
    """icosphere(3), n = 40: clusters of multiplicity 3, 4 and 5 (block 4 alone can miss a
    fifth copy; the solver, at block 4, solves again at block 8 when 4 eigenvalues crowd
    together). Eigenvalues and cluster spans of the Krylov solver agree with the
    independent scipy solve within the bounds their residuals and the eigen-gaps give."""
    n = 40
    res = ta.akvf(mesh_of(shapes.icosphere(3)), n=n, remedy=remedy, solver="krylov")
    assert bool(res.converged.all()) and float(res.residuals.max()) <= 1e-6
    cm = res.batch.meshes[0]
    R, S1, _, _ = ref.killing_operator_scipy(cm.vertices, cm.faces, remedy=remedy)
    S1 = ref.clamp_mass(S1)
    lam_ref, w_ref = ref.solve_akvf(R, S1, n + 6, -1.0)
    lam, w = res.eigenvalues[0].numpy(), res.forms.numpy()
    r_ref = np.linalg.norm((R @ w_ref - S1[:, None] * w_ref * lam_ref) / np.sqrt(S1)[:, None],
                           axis=0) / np.maximum(np.abs(lam_ref), 1.0)
    r = np.maximum(res.residuals[0].numpy(), r_ref[:n])
    lam_bound, sin_bound = _eigen_bounds(lam_ref, np.r_[r, r_ref[n:]])
    runs = [b - a for a, b in clusters(lam_ref[:n])]
    assert max(runs) >= 5, runs                        # the test sees a multiplicity above 4
    scale = np.maximum(np.abs(lam_ref[:n]), 1.0)
    # 1e-12: round-off of two different assemblies of the same operator.
    assert np.all(np.abs(lam - lam_ref[:n]) / scale <= lam_bound[:n] + 1e-12), \
        np.c_[np.abs(lam - lam_ref[:n]) / scale, lam_bound[:n]]
    for a, b in clusters(lam_ref):
        if b > n:
            break
        cos = s1_principal_cosines(w[:, a:b], w_ref[:, a:b], S1)
        sin = np.sqrt(np.clip(1 - cos ** 2, 0, None))
        assert np.all(sin <= 2 * sin_bound[a:b].max() + 1e-7), (a, b, sin, sin_bound[a:b])


def test_krylov_crowding_guard():
    """A repeated eigenvalue with as many copies as the block is flagged (and solved again at
    the wide block); fewer copies or well separated values are not."""
    from torchakvf.solvers.krylov import crowded
    lam = torch.tensor([0.0, 1.0, 5.0, 5.0, 5.0 + 1e-9, 5.0 + 2e-9, 9.0], dtype=torch.float64)
    assert crowded(lam, 4)
    assert not crowded(lam, 5)
    assert not crowded(torch.tensor([0.0, 1.0, 5.0, 5.0, 5.0, 9.0, 12.0], dtype=torch.float64), 4)
    # Near zero the spread is absolute (1e-3), elsewhere relative to |λ|.
    assert crowded(torch.tensor([1e-4, 2e-4, 3e-4, 4e-4, 7.0], dtype=torch.float64), 4)
    assert not crowded(torch.tensor([100.0, 100.2, 100.4, 100.6], dtype=torch.float64), 4)


def test_krylov_makes_room_for_spurious_modes():
    """Pairs below ``skip_below`` do not count towards ``need``: with the threshold above the
    sphere's first 6 eigenvalues and room for 2, grow=False gives up early (inf residuals, for
    its caller to solve again) and grow=True returns the 6 and the ``need`` after them,
    converged and equal to scipy's."""
    from torchakvf.operators.killing import killing_operator
    from torchakvf.solvers.krylov import KrylovBasis, block_krylov
    mesh = mesh_of(shapes.icosphere(3))
    system = killing_operator(ta.MeshBatch.from_meshes([mesh]), remedy=PAPER)
    R, S1 = scipy_matrices(system)
    lam_all = np.sort(spla.eigsh(R, k=24, M=sp.diags(S1).tocsc(), sigma=-1.0, which="LM",
                                 v0=np.random.default_rng(0).standard_normal(R.shape[0]))[0])
    below = 0.5 * (lam_all[5] + lam_all[6])            # 6 "spurious" pairs below it
    assert lam_all[6] - lam_all[5] > 1.0
    short = block_krylov(system, 12, need=10, skip_below=below)
    assert torch.isinf(short.residuals).all() and not bool(short.converged[0])
    grown = block_krylov(system, 12, need=10, skip_below=below, basis=KrylovBasis(grow=True))
    lam = grown.eigenvalues[0].numpy()
    assert len(lam) == 6 + 10 + 2 and bool(grown.converged[0])
    assert float(grown.residuals[0, :16].max()) <= 1e-6
    np.testing.assert_allclose(lam[:16], lam_all[:16], rtol=1e-8, atol=1e-9)


def test_krylov_on_a_mesh_smaller_than_its_basis():
    """icosphere(1) has 120 edges: the Krylov basis fills the whole space (the invariant
    subspace / exhausted basis path), and the result is still the scipy one."""
    mesh = mesh_of(shapes.icosphere(1))
    res = ta.akvf(mesh, n=30, remedy=PAPER, solver="krylov")
    assert bool(res.converged.all())
    R, S1 = scipy_matrices(res.system)
    lam_ref = np.sort(spla.eigsh(R, k=30, M=sp.diags(S1).tocsc(), sigma=-1.0, which="LM",
                                 v0=np.random.default_rng(0).standard_normal(R.shape[0]))[0])
    np.testing.assert_allclose(res.eigenvalues[0].numpy(), lam_ref, rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize("rows", [3, 8, 21, 64])
def test_krylov_gram_schmidt_pass_equals_the_two_whole_products(rows):
    """The chunked Gram-Schmidt pass (basis read once, 8 rows at a time) gives the coefficients
    and the vector of the two whole-basis products, and leaves w S-orthogonal to the basis."""
    from torchakvf.solvers.krylov_kernels import orthonormal, project_out

    gen = torch.Generator().manual_seed(3)
    e = 500
    mass = torch.rand(e, generator=gen, dtype=torch.float64) + 0.5
    start = torch.randn(rows, e, generator=gen, dtype=torch.float64)
    basis, _ = orthonormal(start, start[:0], mass)
    assert basis.shape == (rows, e)
    # S-orthonormal to round-off: the Gram matrix of rows orthonormalized once from random data
    assert torch.allclose((basis * mass) @ basis.T, torch.eye(rows, dtype=torch.float64), atol=1e-13)
    w = torch.randn(4, e, generator=gen, dtype=torch.float64)
    wm = w * mass
    out, coef = project_out(w, wm, basis)
    want_coef = wm @ basis.T
    assert coef.shape == (4, rows)
    # Each coefficient is one dot product of length 500 (entries ~1): round-off ~1e-14.
    assert torch.allclose(coef, want_coef, rtol=0, atol=1e-12)
    assert torch.allclose(out, w - want_coef @ basis, rtol=0, atol=1e-12)
    # One classical pass against an orthonormal basis leaves only round-off inside its span.
    assert float(((out * mass) @ basis.T).abs().max()) < 1e-12 * float(w.abs().max()) * e ** 0.5
    # w itself is untouched (the pass works on a copy).
    assert torch.equal(wm, w * mass)
