"""CHOLMOD called directly (torchakvf.solvers.cholmod) against scipy and against cholespy's own
constructor, the path it replaces on the CPU."""
from __future__ import annotations

import ctypes

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

import torchakvf as ta
from torchakvf import shapes
from torchakvf.solvers import cholmod, cholmod_abi
from torchakvf.solvers.factor import ShiftedFactor

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

needs_cholmod = pytest.mark.skipif(cholmod.library() is None,
                                   reason="cholespy's library has no CHOLMOD 3.0 layout here; "
                                          "the CPU factors then use cholespy's constructor")


def grid_laplacian(m: int, shift: float) -> sp.csc_matrix:
    """The 5-point Laplacian of an m x m grid plus shift·I (eigenvalues in (shift, shift + 8))."""
    one = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    eye = sp.identity(m)
    return (sp.kron(one, eye) + sp.kron(eye, one) + shift * sp.identity(m * m)).tocsc()


def lower_csc(a: sp.csc_matrix):
    low = sp.tril(a).tocsc()
    low.sort_indices()
    return low.indptr, low.indices, low.data


@needs_cholmod
def test_solve_matches_scipy():
    # A definite grid Laplacian (condition number ~ 8 / 0.5 = 16): the solves agree with
    # SuperLU's to a few units of round-off times the condition number.
    a = grid_laplacian(30, 0.5)
    f = cholmod.CholmodFactor(a.shape[0], *lower_csc(a))
    assert f.factorize(lower_csc(a)[2])
    rhs = np.random.default_rng(0).standard_normal((5, a.shape[0]))
    got = f.solve_rows(torch.from_numpy(rhs)).numpy()
    want = spla.splu(a).solve(rhs.T).T
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())
    # One right-hand side, then a different count: the reused workspaces are resized.
    np.testing.assert_allclose(f.solve_rows(torch.from_numpy(rhs[:1])).numpy(), want[:1],
                               rtol=0, atol=1e-12 * np.abs(want).max())


@needs_cholmod
def test_definiteness_is_detected_and_the_analysis_reused():
    a = grid_laplacian(12, 0.0)                       # smallest eigenvalue 2(1 - cos(pi/13))·2 ~ 0.115
    indptr, indices, values = lower_csc(a)
    diag = indptr[:-1]                                 # sorted lower columns start at the diagonal
    f = cholmod.CholmodFactor(a.shape[0], indptr, indices, values)
    for shift, definite in ((-0.2, False), (-0.05, True), (-3.0, False), (1.0, True)):
        v = values.copy()
        v[diag] += shift
        assert f.factorize(v) is definite, shift
        if definite:
            x = f.solve_rows(torch.ones(1, a.shape[0], dtype=torch.float64)).numpy()[0]
            np.testing.assert_allclose((a + shift * sp.identity(a.shape[0])) @ x, 1.0, atol=1e-10)
        else:
            with pytest.raises(ta.SolverError, match="not positive definite"):
                f.solve_rows(torch.ones(1, a.shape[0], dtype=torch.float64))


@needs_cholmod
def test_solve_rows_checks_its_shape():
    a = grid_laplacian(5, 1.0)
    f = cholmod.CholmodFactor(a.shape[0], *lower_csc(a))
    f.factorize(lower_csc(a)[2])
    with pytest.raises(ta.SolverError, match=r"\[k, 25\]"):
        f.solve_rows(torch.ones(25, dtype=torch.float64))
    with pytest.raises(ta.SolverError, match=r"\[k, 25\]"):
        f.solve_rows(torch.ones(2, 24, dtype=torch.float64))


def test_layout_check_rejects_what_is_not_cholmod_defaults():
    # A zeroed struct is what a shifted layout would read back: it must be refused.
    assert not cholmod_abi._defaults_ok(cholmod_abi._Common())


@needs_cholmod
def test_layout_check_accepts_cholmod_start():
    lib = cholmod.library()
    common = cholmod_abi._Common()
    lib.cholmod_start(ctypes.byref(common))
    try:
        assert cholmod_abi._defaults_ok(common)
    finally:
        lib.cholmod_finish(ctypes.byref(common))


@needs_cholmod
def test_shifted_factor_same_shift_and_solution_on_both_paths():
    # A block whose smallest eigenvalue is -5 (λ·area): shift -1 fails and -8 works; both paths
    # must agree on the shift and the solution.
    n = 40
    rng = np.random.default_rng(1)
    q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    lam = np.linspace(-5.0, 50.0, n)
    dense = (q * lam) @ q.T
    rows, cols = np.nonzero(np.ones((n, n)))
    vals = torch.from_numpy(dense[rows, cols])
    mass = torch.ones(n, dtype=torch.float64)
    direct = ShiftedFactor(torch.from_numpy(rows), torch.from_numpy(cols), vals, mass)
    with cholmod.disabled():
        assert cholmod.library() is None
        before = ShiftedFactor(torch.from_numpy(rows), torch.from_numpy(cols), vals, mass)
    assert cholmod.library() is not None
    assert direct.sigma == before.sigma == -8.0
    assert isinstance(direct.backend, cholmod.CholmodFactor)
    assert not isinstance(before.backend, cholmod.CholmodFactor)
    rhs = torch.from_numpy(rng.standard_normal((n, 3)))
    want = np.linalg.solve(dense + 8.0 * np.eye(n), rhs.numpy())     # condition (58 / 3) ~ 20
    for f in (direct, before):
        np.testing.assert_allclose(f.solve(rhs).numpy(), want, atol=1e-11)
        np.testing.assert_allclose(f.solve_rows(rhs.T.contiguous()).numpy(), want.T, atol=1e-11)
        np.testing.assert_allclose(f.solve(rhs[:, 0]).numpy(), want[:, 0], atol=1e-11)


@needs_cholmod
def test_akvf_same_eigenpairs_on_both_factor_paths():
    # Different orderings (AMD against NESDIS) give different round-off only: the eigenvalues
    # agree to the solver's own accuracy (residual 1e-6 bounds them by r² / gap ≪ 1e-8 here),
    # and the spans of the fields match.
    mesh = ta.Mesh(shapes.icosphere(3).vertices, shapes.icosphere(3).faces, "ico3")
    a = ta.akvf(mesh, n=12, solver="krylov")
    with cholmod.disabled():
        b = ta.akvf(mesh, n=12, solver="krylov")
    np.testing.assert_allclose(a.eigenvalues.numpy(), b.eigenvalues.numpy(), rtol=1e-8, atol=1e-8)
    assert bool(a.converged.all()) and bool(b.converged.all())


@needs_cholmod
def test_named_orderings_solve_alike():
    a = grid_laplacian(20, 0.5)
    rhs = torch.from_numpy(np.random.default_rng(2).standard_normal((3, a.shape[0])))
    want = spla.splu(a).solve(rhs.numpy().T).T
    for ordering in (None, "amd", "metis", "nesdis"):
        f = cholmod.CholmodFactor(a.shape[0], *lower_csc(a), ordering=ordering)
        assert f.factorize(lower_csc(a)[2])
        assert f.ordering in cholmod.ORDERINGS and f.factor_nonzeros >= a.shape[0]
        if ordering is not None:
            assert f.ordering == ordering
        np.testing.assert_allclose(f.solve_rows(rhs).numpy(), want, rtol=0,
                                   atol=1e-12 * np.abs(want).max())
    with pytest.raises(ta.SolverError, match="ordering must be one of"):
        cholmod.CholmodFactor(a.shape[0], *lower_csc(a), ordering="colamd")


def grid_laplacian_spectrum(m: int) -> tuple[sp.csc_matrix, np.ndarray]:
    """The 5-point Laplacian of an m x m grid and its eigenvalues (4 - 2cos(iπ/(m+1)) -
    2cos(jπ/(m+1)), all in (0, 8))."""
    one = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(m, m))
    eye = sp.identity(m)
    mu = 2.0 - 2.0 * np.cos(np.arange(1, m + 1) * np.pi / (m + 1))
    return (sp.kron(one, eye) + sp.kron(eye, one)).tocsc(), np.add.outer(mu, mu).ravel()


@needs_cholmod
def test_indefinite_factor_counts_the_eigenvalues_below_and_solves():
    a, lam = grid_laplacian_spectrum(24)
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
def test_indefinite_pivots_are_judged_against_their_own_rows_too():
    """Pivots spread over far more than 1/PIVOT_FLOOR (a row of 1e20 beside a grid Laplacian
    shifted past three of its eigenvalues) still solve where each stays near its row's diagonal;
    a near-breakdown (a pivot 1e-12 of its diagonal) is refused."""
    grid, lam = grid_laplacian_spectrum(12)
    shifted = (grid - 3.1 * sp.identity(grid.shape[0])).tocsc()
    big = sp.csc_matrix(np.array([[1e20]]))
    a = sp.block_diag([big, shifted]).tocsc()
    f = cholmod.CholmodFactor(a.shape[0], *lower_csc(a))
    assert f.factorize(lower_csc(a)[2], indefinite=True) and not f.positive_definite
    assert f.negative_pivots == int((lam < 3.1).sum()) > 0
    rhs = np.random.default_rng(0).standard_normal((2, a.shape[0]))
    want = spla.splu(a).solve(rhs.T).T
    np.testing.assert_allclose(f.solve_rows(torch.from_numpy(rhs)).numpy(), want, rtol=1e-9, atol=1e-30)
    near = sp.csc_matrix(np.array([[1.0, 1.0], [1.0, 1.0 + 1e-12]]))
    b = sp.block_diag([big, near, shifted]).tocsc()
    g = cholmod.CholmodFactor(b.shape[0], *lower_csc(b))
    assert not g.factorize(lower_csc(b)[2], indefinite=True) and g.pivots_finite


@needs_cholmod
def test_indefinite_factor_with_a_zero_pivot_is_refused():
    # [[0, 1], [1, 0]]: nonsingular, but LDLᵀ without pivoting breaks down at the first pivot.
    indptr, indices = np.array([0, 2, 3]), np.array([0, 1, 1])
    f = cholmod.CholmodFactor(2, indptr, indices, np.array([0.0, 1.0, 0.0]))
    assert not f.factorize(np.array([0.0, 1.0, 0.0]), indefinite=True)
    with pytest.raises(ta.SolverError):
        f.solve_rows(torch.ones(1, 2, dtype=torch.float64))


@needs_cholmod
@pytest.mark.parametrize("m", [12, 40])            # 144 rows: one step; 1600: seven steps of 256
def test_stopped_definiteness_test_is_the_whole_factors_answer(m):
    """positive_definite_at says what factorize says, across the bottom of the spectrum (one
    eigenvalue below the shift: the first negative pivot comes late; many: early), stops early
    where many eigenvalues lie below, and where the matrix is definite leaves a factor that
    solves bit for bit as factorize's."""
    a, lam = grid_laplacian_spectrum(m)
    n = a.shape[0]
    indptr, indices, values = lower_csc(a)
    whole = cholmod.CholmodFactor(n, indptr, indices, values)
    fast = cholmod.CholmodFactor(n, indptr, indices, values, symbolic=whole.symbolic)
    rhs = torch.from_numpy(np.random.default_rng(3).standard_normal((2, n)))
    low = np.sort(lam)
    for shift in (-1.0, low[0] - 1e-3, 0.5 * (low[0] + low[1]), 3.0, low[0] - 1e-6):
        v = values.copy()
        v[indptr[:-1]] -= shift
        expect = whole.factorize(v)
        assert expect is bool(shift < low[0])
        assert fast.positive_definite_at(v) is expect, shift
        if expect:
            assert fast.rows_factored == n and fast.positive_definite
            assert torch.equal(fast.solve_rows(rhs), whole.solve_rows(rhs))
        else:
            with pytest.raises(ta.SolverError, match="not positive definite"):
                fast.solve_rows(rhs)
            if shift == 3.0 and m == 40:       # a third of the spectrum below: stops in the first steps
                assert fast.rows_factored < n // 2


@needs_cholmod
def test_a_shared_analysis_factors_bit_for_bit_as_its_own():
    """A factor of another matrix with the same pattern, started from a copy of the first one's
    analysis (no new one), solves bit for bit as one with its own analysis; another pattern is
    refused."""
    a = grid_laplacian(20, 0.5)
    b = (a + sp.diags(np.linspace(0.1, 2.0, a.shape[0]))).tocsc()
    b.data *= 1.7
    first = cholmod.CholmodFactor(a.shape[0], *lower_csc(a))
    shared = cholmod.CholmodFactor(b.shape[0], *lower_csc(b), symbolic=first.symbolic)
    own = cholmod.CholmodFactor(b.shape[0], *lower_csc(b))
    assert shared.symbolic is first.symbolic and own.symbolic is not first.symbolic
    assert shared.factorize(lower_csc(b)[2]) and own.factorize(lower_csc(b)[2])
    rhs = torch.from_numpy(np.random.default_rng(4).standard_normal((3, a.shape[0])))
    assert torch.equal(shared.solve_rows(rhs), own.solve_rows(rhs))
    np.testing.assert_allclose(b @ shared.solve_rows(rhs).numpy().T, rhs.numpy().T, atol=1e-10)
    other = grid_laplacian(21, 0.5)
    with pytest.raises(ta.SolverError, match="another pattern"):
        cholmod.CholmodFactor(other.shape[0], *lower_csc(other), symbolic=first.symbolic)


@needs_cholmod
@pytest.mark.parametrize("shift", [0.5, -3.1])               # definite; 3.1 below: indefinite
def test_two_thread_factor_is_the_one_thread_factor(monkeypatch, shift):
    """With more than one torch thread the numeric factor is computed over two threads (the
    elimination tree's independent subtrees side by side, :mod:`cholmod_subtrees`): the same
    pivots, the same inertia and the same solves, bit for bit, as on one thread."""
    from torchakvf.solvers import cholmod_subtrees
    monkeypatch.setattr(cholmod_subtrees, "MIN_FLOPS", 0.0)
    monkeypatch.setattr(cholmod_subtrees, "MIN_SPEEDUP", 1.0)
    a, lam = grid_laplacian_spectrum(60)
    indptr, indices, values = lower_csc(a)
    values = values.copy()
    values[indptr[:-1]] += shift
    rhs = torch.from_numpy(np.random.default_rng(5).standard_normal((3, a.shape[0])))
    got = {}
    saved = torch.get_num_threads()
    try:
        for threads in (1, 2, 2):
            torch.set_num_threads(threads)
            f = cholmod.CholmodFactor(a.shape[0], indptr, indices, values)
            assert f.factorize(values, indefinite=True)
            assert f.negative_pivots == int((lam + shift < 0).sum())
            got.setdefault(threads, []).append(f.solve_rows(rhs))
            if threads == 2:
                assert f.symbolic.two_thread_plan() is not None     # the two-thread path ran
                assert f.factorize(values, indefinite=True)           # and again on the numeric factor
                got[threads].append(f.solve_rows(rhs))
    finally:
        torch.set_num_threads(saved)
    for x in got[2]:
        assert torch.equal(x, got[1][0])


def test_the_subtree_plan_covers_every_row_once_in_an_order_that_works():
    """The plan's rows: every row once; each thread's ranges are whole subtrees (a row's parent
    is in its range or above it), and the rows above come after their descendants."""
    from torchakvf.solvers import cholmod_subtrees
    rng = np.random.default_rng(6)
    n = 3000
    # a random postordered tree: built by depth-first numbering of a random recursive tree
    kids = {0: []}
    for v in range(1, n):
        kids.setdefault(int(rng.integers(0, v)), []).append(v)
        kids.setdefault(v, [])
    order, parent_of = [], {}
    stack = [(0, False)]
    while stack:
        v, done = stack.pop()
        if done:
            order.append(v)
            continue
        stack.append((v, True))
        for c in kids[v]:
            parent_of[c] = v
            stack.append((c, False))
    post = {v: i for i, v in enumerate(order)}
    parent = np.full(n, -1, dtype=np.int64)
    for c, v in parent_of.items():
        parent[post[c]] = post[v]
    plan = cholmod_subtrees.two_thread_plan(parent, rng.integers(1, 50, n))
    rows = np.concatenate([np.arange(a, b) for ranges in plan.threads + [plan.top] for a, b in ranges])
    assert np.array_equal(np.sort(rows), np.arange(n))
    top = np.zeros(n, dtype=bool)
    for a, b in plan.top:
        top[a:b] = True
    for ranges in plan.threads:
        for a, b in ranges:
            inside = np.arange(a, b)
            p = parent[inside]
            assert np.all((p < 0) | ((p >= a) & (p < b)) | top[np.maximum(p, 0)])
    assert plan.speedup >= 1.0
    # node 2's subtree {0, 2} is not a range of rows; node 2's parent before it
    for bad in ([2, 3, 3, -1], [2, -1, 1]):
        with pytest.raises(ta.SolverError, match="postordered"):
            cholmod_subtrees.subtree_first(np.array(bad))
