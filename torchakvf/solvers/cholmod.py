"""CHOLMOD's simplicial sparse Cholesky on the CPU, called through ctypes on the CHOLMOD that
``cholespy`` (already a dependency) ships inside its extension module.

Why not cholespy's own constructor on the CPU (see docs/design.md): it fixes CHOLMOD's
ordering to NESDIS (METIS nested dissection with constrained minimum degree). On the Killing
operator's edge graph (about 11 entries per row) that ordering takes most of the factor's time;
AMD orders it several times faster, and its order plus numeric factor cost 0.3-0.7x cholespy's
constructor although its factor has more nonzeros. This module also:

* computes the symbolic analysis once per mesh: a failed shift (R - σS1 not definite) costs a
  numeric refactorization only;
* keeps that analysis apart (:class:`Symbolic`), so that a factor of another matrix with the
  same pattern (the paper's operator and the remedied one) starts from a copy of it;
* can stop a factorization at the first non-positive pivot (:meth:`CholmodFactor.positive_definite_at`),
  which is what a definiteness test needs;
* releases the GIL while CHOLMOD works (ctypes does, cholespy does not), so two factors can
  run on two threads, and one factor's independent subtrees too (:mod:`.cholmod_subtrees`,
  where torch has more than one thread);
* solves on row-stacked right-hand sides ``[k, E]`` without transposing: that is the
  column-major layout CHOLMOD reads.

Only CHOLMOD's LGPL modules (Core, Cholesky, Partition) are used: the supernodal module
(GPL) is never asked for (``supernodal = CHOLMOD_SIMPLICIAL``).

Safety: the structs (:mod:`.cholmod_abi`) are CHOLMOD 3.0's (SuiteSparse 5.x, cholespy 2.x).
:func:`library` accepts the library only if SuiteSparse's version is 5.x *and* every default
that ``cholmod_start`` writes reads back at the offset this layout gives it; after each analysis
the factor's own header is checked too. Anything else (another cholespy build, no cholespy) makes
:func:`library` return None, and the callers use cholespy's constructor instead.
"""
from __future__ import annotations

import contextlib
import ctypes as C
import weakref

import numpy as np
import torch

from ..errors import SolverError
from . import cholmod_subtrees as subtrees
from .cholmod_abi import (
    _AMD,
    _DOUBLE,
    _INT,
    _METIS,
    _NATURAL,
    _NESDIS,
    _PATTERN,
    _REAL,
    _SYS_A,
    _Dense,
    _free,
    _Sparse,
    _start,
    disabled,  # noqa: F401 (cholmod.disabled() switches the direct calls off: tests, benchmarks)
    library,
)

#: Smallest pivot of an indefinite LDLᵀ factor, relative to the largest, that it is solved with
#: (:meth:`CholmodFactor.factorize`). The interior shifts of the Krylov solver gave 2e-7 to 3e-3
#: on PSB meshes, with eigenvalues equal to those of the definite shift to 1e-14; a breakdown is
#: a zero. The solver checks its result anyway (every residual, and the count below the shift).
PIVOT_FLOOR = 1e-12
#: An indefinite factor whose pivots fail :data:`PIVOT_FLOOR` is still solved with where every
#: pivot is at least this fraction of its own row's diagonal entry of the matrix (a pivot that
#: much smaller than its diagonal entry is what a cancellation of 8 of the 16 digits leaves).
#: Some meshes spread their pivots over 13 orders of magnitude even where the factor is
#: definite (PSB 351 decimated: 1e-13 of the largest at σ = -512), so the global ratio rejects
#: every interior shift of theirs; their rows' own ratios at interior shifts were 6e-7 to 3e-6
#: (PSB 1, 21, 121 and 181 decimated: 1e-4 to 1e-1). The solver checks the result as before.
ROW_PIVOT_FLOOR = 1e-8
#: Fill-reducing orderings a :class:`CholmodFactor` can be asked for by name.
ORDERINGS = {"amd": _AMD, "metis": _METIS, "nesdis": _NESDIS}
#: Rows of L computed per call while :meth:`CholmodFactor.positive_definite_at` looks for a
#: non-positive pivot: at least this many, and at least 1/64 of the matrix (the factor's work
#: lies mostly in its last rows, so one step past the first negative pivot costs little).
_ROWS_PER_STEP = 256


class Symbolic:
    """CHOLMOD's symbolic analysis of one lower CSC pattern (fill-reducing ordering, column
    counts of L), kept unfactored: a factor of any matrix with this pattern can start from a copy
    of it (:class:`CholmodFactor` ``symbolic=``) instead of a new analysis. Same pattern, same
    ordering: the numeric factor is the one a fresh analysis would give, bit for bit."""

    def __init__(self, lib, factor, indptr: np.ndarray, indices: np.ndarray, ordering: str,
                 factor_nonzeros: float, factor_flops: float):
        self._lib = lib
        self._common = _start(lib)
        self.factor = lib.cholmod_copy_factor(factor, C.byref(self._common))
        self._finalizer = weakref.finalize(self, _free, lib, self._common, self.factor)
        if not self.factor:
            raise SolverError(f"CHOLMOD could not copy a symbolic factor of order {len(indptr) - 1}")
        self.indptr, self.indices = indptr, indices
        self.ordering, self.factor_nonzeros, self.factor_flops = ordering, factor_nonzeros, factor_flops

    def matches(self, indptr: np.ndarray, indices: np.ndarray) -> bool:
        """Whether a lower CSC pattern is the one analysed."""
        return np.array_equal(self.indptr, indptr) and np.array_equal(self.indices, indices)

    def two_thread_plan(self):
        """The rows two threads factor side by side (:func:`.cholmod_subtrees.two_thread_plan`),
        made once per pattern; None where it would not pay (small, or unbalanced)."""
        if not hasattr(self, "_plan"):
            self._plan = None
            n = len(self.indptr) - 1
            if self.factor_flops >= subtrees.MIN_FLOPS:
                plan = subtrees.two_thread_plan(self._parent(n), np.ctypeslib.as_array(
                    C.cast(self.factor.contents.ColCount, C.POINTER(C.c_int)), shape=(n,)))
                self._plan = plan if plan.speedup >= subtrees.MIN_SPEEDUP else None
        return self._plan

    def _parent(self, n: int) -> np.ndarray:
        """[n] the elimination tree of the permuted pattern (-1 at roots)."""
        lib, c, f = self._lib, C.byref(self._common), self.factor.contents
        matrix = _Sparse(n, n, len(self.indices), self.indptr.ctypes.data, self.indices.ctypes.data, None,
                         None, None, -1, _INT, _PATTERN, _DOUBLE, 1, 1)
        upper = lib.cholmod_ptranspose(C.byref(matrix), 0, None if f.ordering == _NATURAL else f.Perm, None, 0, c)
        if not upper:
            raise SolverError(f"CHOLMOD could not permute a pattern of order {n} (out of memory?)")
        parent = np.empty(n, dtype=np.int32)
        try:
            if not lib.cholmod_etree(upper, parent.ctypes.data, c):
                raise SolverError(f"CHOLMOD could not find the elimination tree of a pattern of order {n}")
        finally:
            lib.cholmod_free_sparse(C.byref(upper), c)
        return parent.astype(np.int64)


class CholmodFactor:
    """Simplicial LDLᵀ factor of a symmetric matrix whose values may change (same pattern).

    n : order; indptr [n+1], indices [nnz] (int32, sorted within columns), values [nnz]
    float64: the *lower* triangle in CSC form, diagonal included. The symbolic analysis
    (ordering, elimination tree) is computed here once; :meth:`factorize` computes the
    numeric factor for new values and says whether the matrix is positive definite.
    ordering : None (CHOLMOD's default choice: AMD, with METIS also tried where AMD fills
    badly) or one of :data:`ORDERINGS` ("nesdis" is what cholespy's constructor uses).
    symbolic : the :attr:`symbolic` analysis of another factor of the same pattern, used instead
    of a new analysis (a :class:`SolverError` if the pattern differs; ``ordering`` is ignored).
    """

    def __init__(self, n: int, indptr: np.ndarray, indices: np.ndarray, values: np.ndarray,
                 lib=None, ordering: str | None = None, symbolic: Symbolic | None = None):
        self._lib = lib if lib is not None else library()
        if self._lib is None:
            raise SolverError("CHOLMOD (through cholespy's library) is not usable here")
        if ordering is not None and ordering not in ORDERINGS:
            raise SolverError(f"ordering must be one of {sorted(ORDERINGS)} or None, got {ordering!r}")
        self.n = int(n)
        self._indptr = np.ascontiguousarray(indptr, dtype=np.int32)
        self._indices = np.ascontiguousarray(indices, dtype=np.int32)
        self._values = np.ascontiguousarray(values, dtype=np.float64).copy()
        self._matrix = _Sparse(self.n, self.n, len(self._values), self._indptr.ctypes.data,
                               self._indices.ctypes.data, None, self._values.ctypes.data, None,
                               -1, _INT, _REAL, _DOUBLE, 1, 1)
        lib = self._lib
        self._common = c = _start(lib)
        # By default nmethods stays 0: CHOLMOD's own choice, AMD (and METIS as well where
        # AMD's fill is poor, keeping the better). A named ordering is for comparisons.
        if ordering is not None and symbolic is None:
            c.nmethods = 1
            c.method[0].ordering = ORDERINGS[ordering]
        self._x = C.POINTER(_Dense)()      # solve2's workspaces, reused across solves
        self._y = C.POINTER(_Dense)()
        self._e = C.POINTER(_Dense)()
        if symbolic is not None and not symbolic.matches(self._indptr, self._indices):
            raise SolverError("internal: a symbolic analysis shared by a factor of another pattern")
        self._factor = (lib.cholmod_copy_factor(symbolic.factor, C.byref(c)) if symbolic is not None
                        else lib.cholmod_analyze(C.byref(self._matrix), C.byref(c)))
        self._finalizer = weakref.finalize(self, _free, lib, c, self._factor, self._x, self._y,
                                           self._e)
        if not self._factor:
            raise SolverError(f"CHOLMOD could not analyse a matrix of order {self.n} (out of memory?)")
        f = self._factor.contents
        if not (f.n == self.n and f.is_super == 0 and f.itype == _INT and f.xtype == _PATTERN):
            raise SolverError("CHOLMOD's factor header does not read as expected")
        if symbolic is None:
            chosen = c.method[c.selected]
            symbolic = Symbolic(lib, self._factor, self._indptr, self._indices,
                                {v: k for k, v in ORDERINGS.items()}.get(f.ordering, str(f.ordering)),
                                float(chosen.lnz), float(chosen.fl))
        #: the analysis, shareable with factors of other matrices of this pattern
        self.symbolic = symbolic
        self.ordering = symbolic.ordering
        #: nonzeros of L and flops of the numeric factor, as CHOLMOD's analysis predicts them
        self.factor_nonzeros, self.factor_flops = symbolic.factor_nonzeros, symbolic.factor_flops
        self.positive_definite = self.usable = self.pivots_finite = False
        self.negative_pivots = self.rows_factored = 0

    def factorize(self, values: np.ndarray, indefinite: bool = False) -> bool:
        """Numeric factor for new values (same pattern, [nnz] float64); True if it can be
        solved with: the matrix is positive definite, or with ``indefinite`` every pivot of D is
        finite and at least :data:`PIVOT_FLOOR` times the largest in magnitude (else the factor
        is unusable until the next successful call).

        Sets ``positive_definite`` and ``negative_pivots``, the number of negative entries of D:
        by Sylvester's law of inertia the number of eigenvalues of the matrix below 0 (for a
        shifted pencil ``R - σS``, the eigenvalues of ``R w = λ S w`` below σ)."""
        self._values[:] = values
        plan = self.symbolic.two_thread_plan() if torch.get_num_threads() > 1 else None
        if plan is not None:
            self._factor_rows(plan)
        elif not self._lib.cholmod_factorize(C.byref(self._matrix), self._factor, C.byref(self._common)):
            raise SolverError(f"CHOLMOD failed to factor a matrix of order {self.n} (out of memory?)")
        self.rows_factored = self.n
        pivots = self._pivots(0, self.n)
        f = self._factor.contents
        # LDLᵀ without pivoting does not stop at a negative pivot, so definiteness is read
        # off D (the first entry of each column of the simplicial factor): A = L D Lᵀ is
        # positive definite iff every D_jj > 0 (a NaN from a breakdown fails the test too).
        self.positive_definite = bool(f.minor == self.n and np.all(pivots > 0))
        self.negative_pivots = int(np.count_nonzero(pivots < 0))
        #: every pivot computed and finite: ``negative_pivots`` is the inertia even where the
        #: factor is not usable for solves
        self.pivots_finite = bool(f.minor == self.n and np.all(np.isfinite(pivots)))
        size = np.abs(pivots)
        # Without pivoting, an LDLᵀ of an indefinite matrix is only as accurate as its smallest
        # pivot allows; a breakdown shows as a zero, an infinity or a NaN.
        self.usable = self.positive_definite or bool(
            indefinite and self.pivots_finite
            and (size.min() >= PIVOT_FLOOR * size.max()
                 or np.all(size >= ROW_PIVOT_FLOOR * self._pivot_diagonal())))
        return self.usable

    def _pivot_diagonal(self) -> np.ndarray:
        """[n] |A_jj| of the matrix's diagonal in the factor's (permuted) row order, the scale
        of each pivot of D."""
        diagonal = np.abs(self._values[self._indptr[:-1]])   # sorted lower CSC: diagonal first
        f = self._factor.contents
        if f.ordering == _NATURAL or not f.Perm:
            return diagonal
        return diagonal[np.ctypeslib.as_array(C.cast(f.Perm, C.POINTER(C.c_int)), shape=(self.n,))]

    def positive_definite_at(self, values: np.ndarray) -> bool:
        """Whether the matrix with ``values`` (same pattern) is positive definite: the answer of
        :meth:`factorize`, bit for bit, for a fraction of its work where it is not.

        The rows of L are computed in steps (CHOLMOD's own row-by-row LDLᵀ, the arithmetic of
        :meth:`factorize`) and the work stops after the first step with a pivot that is not
        positive: a matrix with an eigenvalue below 0 shows one long before the last, expensive
        rows (on PSB meshes at 1-47% of the rows, 0-17% of the work). Where every pivot is
        positive the factor is complete and solves like one from :meth:`factorize`.
        ``rows_factored`` says how many rows of L were computed."""
        self._values[:] = values
        lib, c, f = self._lib, self._common, self._factor.contents
        beta = (C.c_double * 2)(0.0, 0.0)
        step = max(_ROWS_PER_STEP, -(-self.n // 64))
        self.positive_definite = self.usable = self.pivots_finite = False
        with self._upper() as upper:
            for start in range(0, self.n, step):
                stop = min(start + step, self.n)
                if not lib.cholmod_rowfac(upper, None, beta, start, stop, self._factor, C.byref(c)):
                    raise SolverError(f"CHOLMOD failed to factor a matrix of order {self.n} (out of memory?)")
                pivots = self._pivots(start, stop)
                self.rows_factored = stop
                if not (f.minor == self.n and np.all(pivots > 0)):
                    self.negative_pivots = int(np.count_nonzero(pivots < 0))
                    return False
        self.positive_definite = self.usable = self.pivots_finite = True
        self.negative_pivots = 0
        return True

    @contextlib.contextmanager
    def _upper(self):
        """triu(A(p, p)), the matrix cholmod_factorize hands to its row-by-row factorization,
        with the factor made ready to compute rows from 0 as cholmod_factorize makes it: a
        numeric factor's rows reset, a symbolic one allocated (exactly the room its column
        counts need) by an empty first call."""
        lib, c, f = self._lib, self._common, self._factor.contents
        upper = lib.cholmod_ptranspose(C.byref(self._matrix), 2, None if f.ordering == _NATURAL else f.Perm,
                                       None, 0, C.byref(c))
        if not upper:
            raise SolverError(f"CHOLMOD could not permute a matrix of order {self.n} (out of memory?)")
        try:
            f.is_ll = 0
            if f.xtype != _PATTERN:
                np.ctypeslib.as_array(C.cast(f.nz, C.POINTER(C.c_int)), shape=(self.n,))[:] = 1
                f.minor = self.n
            else:
                grow2 = c.grow2
                c.grow2 = 0 if c.final_pack else grow2
                ok = lib.cholmod_rowfac(upper, None, (C.c_double * 2)(0.0, 0.0), 0, 0, self._factor, C.byref(c))
                c.grow2 = grow2
                if not ok:
                    raise SolverError(f"CHOLMOD could not allocate a factor of order {self.n} (out of memory?)")
            yield upper
        finally:
            lib.cholmod_free_sparse(C.byref(upper), C.byref(c))

    def _factor_rows(self, plan) -> None:
        """The numeric factor on two threads (:mod:`.cholmod_subtrees`): the same bits."""
        if not hasattr(self, "_second"):
            self._second = _start(self._lib)
            weakref.finalize(self, self._lib.cholmod_finish, C.byref(self._second))
        with self._upper() as upper:
            subtrees.factor_rows(self._lib, upper, self._factor, [self._common, self._second], plan)

    def _pivots(self, start: int, stop: int) -> np.ndarray:
        """D's entries of rows start..stop-1 (a view; the first entry of each column)."""
        f = self._factor.contents
        if not (f.is_super == 0 and f.is_ll == 0 and f.xtype == _REAL and f.n == self.n):
            raise SolverError("CHOLMOD's factor header does not read as expected")
        colptr = np.ctypeslib.as_array(C.cast(f.p, C.POINTER(C.c_int)), shape=(self.n + 1,))
        x = np.ctypeslib.as_array(C.cast(f.x, C.POINTER(C.c_double)), shape=(int(f.nzmax),))
        return x[colptr[start:stop]]

    def solve_rows(self, rows: torch.Tensor) -> torch.Tensor:
        """A⁻¹ applied to each row of rows [k, n] (float64, CPU): returns [k, n].

        Row-stacked vectors are column-major n x k, what CHOLMOD reads and writes."""
        if not self.usable:
            raise SolverError("solve with a factor that is not usable (not positive definite, "
                              "or an indefinite one with a breakdown)")
        b = np.ascontiguousarray(rows.detach().numpy(), dtype=np.float64)
        if b.ndim != 2 or b.shape[1] != self.n:
            raise SolverError(f"solve_rows takes [k, {self.n}] right-hand sides, got {tuple(b.shape)}")
        k = b.shape[0]
        dense = _Dense(self.n, k, self.n * k, self.n, b.ctypes.data, None, _REAL, _DOUBLE)
        ok = self._lib.cholmod_solve2(_SYS_A, self._factor, C.byref(dense), None,
                                      C.byref(self._x), None, C.byref(self._y), C.byref(self._e),
                                      C.byref(self._common))
        x = self._x.contents if ok and self._x else None
        if x is None or x.nrow != self.n or x.ncol != k or x.d != self.n:
            raise SolverError(f"CHOLMOD's solve failed for {k} right-hand sides of order {self.n}")
        out = np.ctypeslib.as_array(C.cast(x.x, C.POINTER(C.c_double)), shape=(k, self.n))
        return torch.from_numpy(out.copy())
