"""Shift-invert factors (torchakvf.solvers.factor): the block-diagonal factor of a batch, and
the block Krylov solver's interior shift (InteriorFactor): the same eigenpairs as at a definite
shift, and a fallback to the definite shift wherever its own check fails."""
from __future__ import annotations

import logging

import numpy as np
import pytest
import torch
from helpers.eigen_checks import batch_with_a_low_mesh

import torchakvf as ta
from torchakvf import shapes
from torchakvf.solvers import akvf_solver, cholmod, group_solver
from torchakvf.solvers.factor import INTERIOR_SHIFT_PER_PAIR, InteriorFactor

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

needs_cholmod = pytest.mark.skipif(cholmod.library() is None,
                                   reason="cholespy's library has no CHOLMOD 3.0 layout here; "
                                          "interior shifts need CHOLMOD called directly")


def test_block_diagonal_factor_is_each_mesh_own_factor():
    """One factor of the block-diagonal batch: each mesh gets the shift its own ladder finds (a
    trial at -1 fails because of one mesh, and the ladder runs per mesh), and the solve is each
    block's exact solve: backward error at round-off level per mesh (a conditioning-free
    check), and the same solution as the mesh's own factor within cond · eps."""
    from torchakvf.solvers.factor import BlockDiagonalFactor, mesh_factor
    system = batch_with_a_low_mesh()
    block = BlockDiagonalFactor(system)
    alone = [mesh_factor(system, b, f"mesh {b}") for b in range(system.n_meshes)]
    assert block.sigma.tolist() == [f.sigma for f in alone] == [-1.0, -8.0, -1.0]
    rhs = torch.randn(len(system.mass), 5, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    x = block.solve(rhs)
    shifted = system.stiffness - torch.sparse_coo_tensor(
        torch.arange(len(system.mass)).repeat(2, 1),
        torch.repeat_interleave(block.sigma, system.edge_ptr[1:] - system.edge_ptr[:-1]) * system.mass,
        system.stiffness.shape, check_invariants=False)
    for b, f in enumerate(alone):
        lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
        a = shifted.to_dense()[lo:hi, lo:hi]          # small test meshes (< 1000 edges)
        r = a @ x[lo:hi] - rhs[lo:hi]
        backward = float(r.abs().max() / (a.abs().sum(1).max() * x[lo:hi].abs().max()))
        assert backward < 1e-13, (b, backward)
        cond = float(torch.linalg.cond(a))
        gap = float((f.solve(rhs[lo:hi]) - x[lo:hi]).abs().max() / x[lo:hi].abs().max())
        assert gap < 100 * cond * 2.2e-16, (b, gap, cond)


def test_block_diagonal_factor_shifts_given_and_unsolvable():
    from torchakvf.solvers.factor import BlockDiagonalFactor
    system = batch_with_a_low_mesh()
    assert BlockDiagonalFactor(system, shifts=[-2.0, -8.0, -1.0]).sigma.tolist() == [-2.0, -8.0, -1.0]
    with pytest.raises(ta.SolverError) as exc:
        BlockDiagonalFactor(system, names=["a", "b", "c"], shifts=[-1.0, -1.0, -1.0])
    assert "a, b, c" in str(exc.value)
    with pytest.raises(ta.ParameterError):
        BlockDiagonalFactor(system, shifts=[-1.0])


def table_mesh() -> ta.Mesh:
    s = shapes.table()            # 6,480 edges: the Krylov solver's size, no symmetric repeats
    return ta.Mesh(s.vertices, s.faces, "table")


def definite_only(monkeypatch):
    monkeypatch.setattr(group_solver, "interior_factor", lambda system, b, need, definite, **kw: definite())


@needs_cholmod
def test_akvf_at_the_interior_shift_equals_the_definite_shift(monkeypatch):
    n = 16
    mesh = table_mesh()
    inner = ta.akvf(mesh, n=n)
    assert akvf_solver.solver_for(torch.device("cpu"), len(inner.batch.edges)) == "krylov"
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
    real = group_solver.interior_factor

    def spoiled(system, b, need, definite, **kw):
        f = real(system, b, need, definite, **kw)
        assert isinstance(f, InteriorFactor)
        if spoil == "count":
            f.below += 1
        else:
            f.floor = 1e9
        return f

    monkeypatch.setattr(group_solver, "interior_factor", spoiled)
    with caplog.at_level(logging.INFO, logger="torchakvf.solvers.krylov"):
        got = ta.akvf(mesh, n=n)
    assert "solving again at a definite shift" in caplog.text
    assert float(got.shifts[0]) == -1.0
    # the solve again is the definite-only solve's calls on the same factor and start: its bits
    np.testing.assert_array_equal(got.eigenvalues.numpy(), want.eigenvalues.numpy())
    assert bool(got.converged.all())


@needs_cholmod
def test_no_definite_shift_still_raises(monkeypatch):
    """A mesh with an eigenvalue below every definite shift raised a SolverError (so that a
    decimated one is solved at full resolution): at the interior shift it still does."""
    mesh = table_mesh()
    real = group_solver.interior_factor

    def no_definite(system, b, need, definite, **kw):
        def raising():
            raise ta.SolverError("mesh: no shift made R - σS1 positive definite")
        f = real(system, b, need, raising, **kw)
        f.floor = 1e9                     # every eigenvalue counts as below the last shift
        return f

    monkeypatch.setattr(group_solver, "interior_factor", no_definite)
    with pytest.raises(ta.SolverError, match="no shift made"):
        ta.akvf(mesh, n=16)


#: The table's eigenvalues (λ·area, remedy "smooth") start 23.4, 38.4, 43.7, 44.0, 44.0, 44.3,
#: 62.5, 67.0, 78.4, 88.7, 92.8, 122.3; every count below is asserted against its solve.
def _table_system_and_eigenvalues():
    from torchakvf.operators.killing import killing_operator

    batch = ta.MeshBatch.from_meshes([table_mesh()])
    system = killing_operator(batch, remedy="smooth")
    return batch, system, ta.akvf(batch, n=24, remedy="smooth").eigenvalues[0].numpy()


@needs_cholmod
@pytest.mark.parametrize("per_pair, need, tries, sigma", [
    (5.0, 16, 4, 80.0), (20.0, 6, 4, 60.0), (30.0, 4, 4, "lower"), (30.0, 4, 0, None)])
def test_too_many_eigenvalues_below_moves_the_shift_down(monkeypatch, per_pair, need, tries, sigma):
    """interior_factor takes σ = per_pair · need where at most ``need`` eigenvalues lie below
    it, else σ/2, else up to INTERIOR_RETRIES lower shifts, else the definite factor: 9 below
    80 (need 16: the first try), 11 below 120 then 6 below 60 (need 6: the second), the same
    for need 4 (neither: a lower σ, or with no retries the definite factor)."""
    from torchakvf.solvers import factor as factor_module
    from torchakvf.solvers.factor import ShiftedFactor, interior_factor, mesh_factor

    _, system, lam = _table_system_and_eigenvalues()
    monkeypatch.setattr(factor_module, "INTERIOR_SHIFT_PER_PAIR", per_pair)
    monkeypatch.setattr(factor_module, "INTERIOR_RETRIES", tries)
    f = interior_factor(system, 0, need, lambda: mesh_factor(system, 0, "table"))
    if sigma is None:
        assert isinstance(f, ShiftedFactor) and f.sigma == -1.0
        assert int((lam < per_pair * need).sum()) > need and int((lam < per_pair * need / 2).sum()) > need
        return
    assert isinstance(f, InteriorFactor) and f.skipped is None
    if sigma == "lower":
        assert -1.0 < f.sigma < per_pair * need / 2
    else:
        assert f.sigma == sigma
    assert f.below == int((lam < f.sigma).sum()) <= need


@needs_cholmod
def test_an_interior_shift_that_counts_the_skipped_eigenvalues_apart(monkeypatch):
    """With ``skip_below``, the retries count only the eigenvalues in [skip_below, σ): here the
    two below 40 stand for spurious modes. Need 4 at 30 per pair: 11 below 120, then 6 below 60
    (too many for the plain count), of which 2 below 40, so σ = 60 holds 4 wanted ones."""
    from torchakvf.solvers import factor as factor_module
    from torchakvf.solvers.factor import interior_factor, mesh_factor

    _, system, lam = _table_system_and_eigenvalues()
    monkeypatch.setattr(factor_module, "INTERIOR_SHIFT_PER_PAIR", 30.0)
    f = interior_factor(system, 0, 4, lambda: mesh_factor(system, 0, "table"), skip_below=40.0)
    assert isinstance(f, InteriorFactor) and f.sigma == 60.0
    assert f.skipped == int((lam < 40.0).sum()) == 2
    assert f.below == int((lam < 60.0).sum()) == 6


@needs_cholmod
def test_the_krylov_solver_leaves_the_counted_spurious_pairs_out(monkeypatch):
    """At an interior shift that counted them, the Krylov solver neither waits for nor returns
    the pairs below the spurious threshold (here 40, with the table's 23.4 and 38.4 below it):
    the same n pairs above it as the definite factor's solve that returns them all, to the
    solve's tolerance, and ``dropped`` counts them from the inertia."""
    from torchakvf.solvers import factor as factor_module

    batch, _, lam = _table_system_and_eigenvalues()
    monkeypatch.setattr(group_solver, "SPURIOUS_BELOW", 40.0)
    monkeypatch.setattr(factor_module, "INTERIOR_SHIFT_PER_PAIR", 30.0)
    windowed = ta.akvf(batch, n=4, remedy="smooth", solver="krylov")
    monkeypatch.setattr(factor_module, "INTERIOR_RETRIES", 0)     # the definite factor
    definite = ta.akvf(batch, n=4, remedy="smooth", solver="krylov")
    assert float(windowed.shifts[0]) == 60.0 and float(definite.shifts[0]) == -1.0
    assert bool(windowed.converged.all()) and bool(definite.converged.all())
    assert int(windowed.dropped[0]) == int(definite.dropped[0]) == int((lam < 40.0).sum()) == 2
    want = lam[lam >= 40.0][:4]
    for got in (windowed, definite):
        np.testing.assert_allclose(got.eigenvalues[0].numpy(), want, rtol=1e-8)
    # The solver itself: the count it returned holds no pair below the threshold.
    from torchakvf.operators.killing import killing_operator
    from torchakvf.solvers.factor import interior_factor, mesh_factor
    from torchakvf.solvers.krylov import block_krylov
    system = killing_operator(batch, remedy="smooth")
    monkeypatch.setattr(factor_module, "INTERIOR_RETRIES", 4)
    f = interior_factor(system, 0, 4, lambda: mesh_factor(system, 0, "table"), skip_below=40.0)
    eig = block_krylov(system, 12, need=4, skip_below=40.0, factors=[f])
    assert int(eig.left_out[0]) == 2 and bool((eig.eigenvalues[0] >= 40.0).all())
    np.testing.assert_allclose(eig.eigenvalues[0, :4].numpy(), want, rtol=1e-8)


# ---------------------------------------------------------------------------------------------
# errors that surface: the device cholespy can use, a failed solve on the device
# ---------------------------------------------------------------------------------------------

def test_a_cuda_device_other_than_the_first_is_refused(monkeypatch):
    """cholespy always factors on the first visible GPU: cuda:1 is refused in one line naming
    the device and the fix (no GPU needed: the check reads the device's index only)."""
    from torchakvf.solvers.factor import check_factor_device
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert check_factor_device("cpu") == torch.device("cpu")
    assert check_factor_device("cuda:0") == torch.device("cuda:0")
    with pytest.raises(ta.ParameterError, match="cuda:1") as exc:
        check_factor_device("cuda:1")
    assert "CUDA_VISIBLE_DEVICES=1" in str(exc.value) and "\n" not in str(exc.value)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "current_device", lambda: 2)
    with pytest.raises(ta.ParameterError, match="CUDA_VISIBLE_DEVICES=2"):
        check_factor_device("cuda")


class _PrintsInsteadOfRaising:
    """A cholespy solver whose device call failed: like cholespy, it prints the error and
    leaves the output as it was (here: zeros, or NaN)."""

    def __init__(self, fill: float):
        self.fill = fill

    def solve(self, rhs, out):
        out.fill_(self.fill)


@pytest.mark.parametrize("fill", [0.0, float("nan")])
def test_a_failed_device_solve_raises_naming_the_mesh(monkeypatch, fill):
    """The first solve of a new cholespy factor is checked on a known right-hand side: a solve
    that leaves zeros or NaN raises a SolverError naming the mesh (the batch's meshes for a
    block factor), for a factor of one mesh and for the block factor of a batch solved as one."""
    from torchakvf.solvers import cholesky as chol
    from torchakvf.solvers import factor
    system = batch_with_a_low_mesh()
    monkeypatch.setattr(chol, "cholesky", lambda pattern, diagonal, engine=None:
                        (_PrintsInsteadOfRaising(fill), None))
    with pytest.raises(ta.SolverError, match="mesh 1: the sparse factor's solve on cpu failed its check"):
        factor.mesh_factor(system, 1, "mesh 1")
    with pytest.raises(ta.SolverError, match="a, b, c: the sparse factor"):
        factor.BlockDiagonalFactor(system, names=["a", "b", "c"], shifts=[-1.0, -8.0, -1.0])


def test_a_working_cholespy_factor_passes_its_check():
    """cholespy's own CPU factor (where it is installed) passes the first-solve check, whose
    backward error is at round-off level (far below BACKWARD_ERROR_MAX) at every shift."""
    cholespy = pytest.importorskip("cholespy")
    from torchakvf.solvers import cholesky as chol
    system = batch_with_a_low_mesh()
    idx, vals = system.stiffness.indices(), system.stiffness.values()
    pattern = chol.lower_pattern(idx[0], idx[1], vals, len(system.mass))
    diagonal = 8.0 * system.mass.to(torch.float64)
    solver, err = chol.cholesky(pattern, diagonal, engine=None)
    assert isinstance(solver, cholespy.CholeskySolverD)
    chol.check_first_solve(solver, torch.device("cpu"), pattern, diagonal, "batch")


@needs_cholmod
def test_a_factor_shares_an_analysis_only_of_its_own_pattern():
    """CpuFactor(like=) copies another factor's analysis where the lower pattern is the same
    (the same factor bit for bit as with its own analysis), and analyses its own otherwise."""
    from torchakvf.operators import killing_operator
    from torchakvf.solvers.cholesky import CpuFactor, lower_pattern

    def pattern(mesh, remedy):
        system = killing_operator(ta.MeshBatch.from_meshes([mesh]), remedy=remedy)
        r, c, v, size = system.block(0)
        return lower_pattern(r, c, v, size), system.mass.double()

    ellipsoid = shapes.ellipsoid((1.0, 1.3, 1.7), level=3)
    ellipsoid = ta.Mesh(ellipsoid.vertices, ellipsoid.faces, "ellipsoid")
    (paper, _), (smooth, mass) = pattern(ellipsoid, "none"), pattern(ellipsoid, "smooth")
    first = CpuFactor(paper)
    shared, own = CpuFactor(smooth, like=first.symbolic), CpuFactor(smooth)
    assert shared.symbolic is first.symbolic and own.symbolic is not first.symbolic
    assert shared.factorize(mass) and own.factorize(mass)
    rhs = torch.from_numpy(np.random.default_rng(0).standard_normal((2, len(mass))))
    assert torch.equal(shared.factor.solve_rows(rhs), own.factor.solve_rows(rhs))
    # The table's right angles give its paper operator exact zeros that the product DᵀS0⁻¹D
    # drops, where the remedy's floored weights do not: another pattern, its own analysis.
    (paper, _), (smooth, _) = pattern(table_mesh(), "none"), pattern(table_mesh(), "smooth")
    assert paper[1].shape != smooth[1].shape
    table = CpuFactor(paper)
    assert CpuFactor(smooth, like=table.symbolic).symbolic is not table.symbolic


@needs_cholmod
def test_psb_mesh_with_82_spurious_modes_is_solved_at_an_interior_shift(psb):
    """PSB 351 decimated (a bearing: 82 spurious modes down to -512 under "smooth", and λ₁₆ =
    9.6 where a unit-area surface has about 140) has more eigenvalues below 5n and 5n/2 than n;
    at its definite shift, -512, the wanted pairs crowd within 4% of each other. A lower
    interior shift that counts the spurious modes apart solves it: the same eigenvalues as
    scipy's eigsh at the definite shift, and the same number dropped."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    from helpers.eigen_checks import scipy_matrices

    from torchakvf.solvers.remedy import SPURIOUS_BELOW

    mesh = ta.load_mesh(psb / "meshes" / "351.off.gz")
    n = 16
    res = ta.akvf(ta.MeshBatch.from_meshes([mesh], coarse_faces=4000), n=n)
    assert -1.0 < float(res.shifts[0]) < 5.0 * n / 2 and bool(res.converged.all())
    R, s1 = scipy_matrices(res.system)
    v0 = np.random.default_rng(0).standard_normal(R.shape[0])
    lam = np.sort(spla.eigsh(R, k=n + int(res.dropped[0]) + 4, M=sp.diags(s1).tocsc(), sigma=-512.0,
                             which="LM", v0=v0, tol=1e-12)[0])
    assert int((lam < SPURIOUS_BELOW).sum()) == int(res.dropped[0]) == 82
    want = lam[lam >= SPURIOUS_BELOW][:n]
    np.testing.assert_allclose(res.eigenvalues[0].numpy(), want, rtol=1e-8, atol=1e-8)
