"""The block Krylov solver at an interior shift (torchakvf.solvers.factor.InteriorFactor).

The factor: an LDLᵀ of an indefinite matrix counts its eigenvalues below the shift (inertia)
and solves as accurately as the matrix's conditioning allows. The solver: the same eigenpairs
as at a definite shift, and a fallback to the definite shift wherever its own check fails."""
from __future__ import annotations

import importlib
import logging

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.solvers import cholmod
from torchakvf.solvers.factor import INTERIOR_SHIFT_PER_PAIR, InteriorFactor

from threads import one_torch_thread  # noqa: F401 - autouse fixture

needs_cholmod = pytest.mark.skipif(cholmod.library() is None,
                                   reason="cholespy's library has no CHOLMOD 3.0 layout here; "
                                          "interior shifts need CHOLMOD called directly")
akvf_module = importlib.import_module("torchakvf.fields.akvf")


def grid_laplacian(m: int) -> tuple[sp.csc_matrix, np.ndarray]:
    """The 5-point Laplacian of an m x m grid and its eigenvalues (4 - 2cos(iπ/(m+1)) -
    2cos(jπ/(m+1)), all in (0, 8))."""
    one = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    eye = sp.identity(m)
    mu = 2.0 - 2.0 * np.cos(np.arange(1, m + 1) * np.pi / (m + 1))
    return (sp.kron(one, eye) + sp.kron(eye, one)).tocsc(), np.add.outer(mu, mu).ravel()


def lower_csc(a: sp.csc_matrix):
    low = sp.tril(a).tocsc()
    low.sort_indices()
    return low.indptr, low.indices, low.data.copy()


@needs_cholmod
def test_indefinite_factor_counts_the_eigenvalues_below_and_solves():
    a, lam = grid_laplacian(24)
    indptr, indices, values = lower_csc(a)
    f = cholmod.CholmodFactor(a.shape[0], indptr, indices, values)
    for shift in (3.1, 5.7):
        v = values.copy()
        v[indptr[:-1]] -= shift
        assert not f.factorize(v)                        # indefinite: refused by default
        assert not f.positive_definite
        with pytest.raises(ta.SolverError, match="not positive definite"):
            f.solve_rows(torch.ones(1, a.shape[0], dtype=torch.float64))
        assert f.factorize(v, indefinite=True)
        assert f.negative_pivots == int((lam < shift).sum())   # Sylvester's law of inertia
        shifted = (a - shift * sp.identity(a.shape[0])).tocsc()
        rhs = np.random.default_rng(0).standard_normal((3, a.shape[0]))
        want = spla.splu(shifted).solve(rhs.T).T
        cond = np.abs(lam - shift).max() / np.abs(lam - shift).min()
        got = f.solve_rows(torch.from_numpy(rhs)).numpy()
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * cond * np.abs(want).max())
    # a definite matrix: no negative pivot, usable either way
    assert f.factorize(values, indefinite=True) and f.positive_definite and f.negative_pivots == 0


@needs_cholmod
def test_indefinite_factor_with_a_zero_pivot_is_refused():
    # [[0, 1], [1, 0]]: nonsingular, but LDLᵀ without pivoting breaks down at the first pivot.
    indptr, indices = np.array([0, 2, 3]), np.array([0, 1, 1])
    f = cholmod.CholmodFactor(2, indptr, indices, np.array([0.0, 1.0, 0.0]))
    assert not f.factorize(np.array([0.0, 1.0, 0.0]), indefinite=True)
    with pytest.raises(ta.SolverError):
        f.solve_rows(torch.ones(1, 2, dtype=torch.float64))


def table_mesh() -> ta.Mesh:
    s = shapes.table()            # 6,480 edges: the Krylov solver's size, no symmetric repeats
    return ta.Mesh(s.vertices, s.faces, "table")


def definite_only(monkeypatch):
    monkeypatch.setattr(akvf_module, "interior_factor", lambda system, b, need, definite: definite())


@needs_cholmod
def test_akvf_at_the_interior_shift_equals_the_definite_shift(monkeypatch):
    n = 16
    mesh = table_mesh()
    inner = ta.akvf(mesh, n=n)
    assert akvf_module.solver_for(torch.device("cpu"), len(inner.batch.edges)) == "krylov"
    assert float(inner.shifts[0]) == INTERIOR_SHIFT_PER_PAIR * n
    definite_only(monkeypatch)
    outer = ta.akvf(mesh, n=n)
    assert float(outer.shifts[0]) == -1.0
    for r in (inner, outer):
        assert bool(r.converged.all()) and float(r.residuals.max()) <= 1e-6
    # Each eigenvalue is within r·max(|λ|, 1) of the true one (r <= 1e-6 its relative residual):
    # the two solves agree to twice that; a missed or extra eigenvalue would be off by O(1).
    lam_i, lam_o = inner.eigenvalues[0].numpy(), outer.eigenvalues[0].numpy()
    np.testing.assert_array_less(np.abs(lam_i - lam_o), 2e-6 * np.maximum(np.abs(lam_o), 1.0))
    # ... and the fewer right-hand sides are the point of it
    assert int(inner.iterations[0]) < int(outer.iterations[0])


@needs_cholmod
@pytest.mark.parametrize("spoil", ["count", "floor"])
def test_a_failed_check_solves_again_at_the_definite_shift(monkeypatch, caplog, spoil):
    """If the pairs found below the interior shift are not the ν its factor counts (spoiled
    here by a wrong count), or an eigenvalue lies at or below the last definite shift (spoiled
    here by raising that floor), the mesh is solved again at the definite shift."""
    n = 16
    mesh = table_mesh()
    definite_only(monkeypatch)
    want = ta.akvf(mesh, n=n)
    monkeypatch.undo()
    real = akvf_module.interior_factor

    def spoiled(system, b, need, definite):
        f = real(system, b, need, definite)
        assert isinstance(f, InteriorFactor)
        if spoil == "count":
            f.below += 1
        else:
            f.floor = 1e9
        return f

    monkeypatch.setattr(akvf_module, "interior_factor", spoiled)
    with caplog.at_level(logging.INFO, logger="torchakvf.solvers.krylov"):
        got = ta.akvf(mesh, n=n)
    assert "solving again at a definite shift" in caplog.text
    assert float(got.shifts[0]) == -1.0
    np.testing.assert_array_equal(got.eigenvalues.numpy(), want.eigenvalues.numpy())
    assert bool(got.converged.all())


@needs_cholmod
def test_no_definite_shift_still_raises(monkeypatch):
    """A mesh with an eigenvalue below every definite shift raised a SolverError (so that a
    decimated one is solved at full resolution): at the interior shift it still does."""
    mesh = table_mesh()
    real = akvf_module.interior_factor

    def no_definite(system, b, need, definite):
        def raising():
            raise ta.SolverError("mesh: no shift made R - σS1 positive definite")
        f = real(system, b, need, raising)
        f.floor = 1e9                     # every eigenvalue counts as below the last shift
        return f

    monkeypatch.setattr(akvf_module, "interior_factor", no_definite)
    with pytest.raises(ta.SolverError, match="no shift made"):
        ta.akvf(mesh, n=16)


@needs_cholmod
@pytest.mark.parametrize("per_pair, need, sigma", [(5.0, 16, 80.0), (20.0, 6, 60.0), (20.0, 4, None)])
def test_too_many_eigenvalues_below_halves_then_gives_up(monkeypatch, per_pair, need, sigma):
    """interior_factor takes σ = per_pair · need where at most ``need`` eigenvalues lie below
    it, else σ/2, else the definite factor. The table's eigenvalues (λ·area) start 24.3, 33.8,
    33.8, 34.2, 34.4, 39.5, 65.0, 68.5, 80.5, ..., 121.2: 8 below 80 (accepted for need 16),
    11 below 120 then 6 below 60 (need 6: the second try), 8 below 80 then 6 below 40 (need 4:
    neither, the definite factor)."""
    from torchakvf.operators.killing import killing_operator
    from torchakvf.solvers import factor as factor_module
    from torchakvf.solvers.factor import ShiftedFactor, interior_factor, mesh_factor

    batch = ta.MeshBatch.from_meshes([table_mesh()])
    system = killing_operator(batch)
    lam = ta.akvf(batch, n=24).eigenvalues[0].numpy()
    monkeypatch.setattr(factor_module, "INTERIOR_SHIFT_PER_PAIR", per_pair)
    f = interior_factor(system, 0, need, lambda: mesh_factor(system, 0, "table"))
    if sigma is None:
        assert isinstance(f, ShiftedFactor) and f.sigma == -1.0
        assert int((lam < per_pair * need).sum()) > need and int((lam < per_pair * need / 2).sum()) > need
    else:
        assert isinstance(f, InteriorFactor) and f.sigma == sigma
        assert f.below == int((lam < sigma).sum()) <= need
