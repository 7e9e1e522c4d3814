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
  run on two threads;
* solves on row-stacked right-hand sides ``[k, E]`` without transposing: that is the
  column-major layout CHOLMOD reads.

Only CHOLMOD's LGPL modules (Core, Cholesky, Partition) are used: the supernodal module
(GPL) is never asked for (``supernodal = CHOLMOD_SIMPLICIAL``).

Safety: the structs below are CHOLMOD 3.0's (SuiteSparse 5.x, cholespy 2.x). :func:`library`
accepts the library only if SuiteSparse's version is 5.x *and* every default that
``cholmod_start`` writes reads back at the offset this layout gives it; after each analysis the
factor's own header is checked too. Anything else (another cholespy build, no cholespy) makes
:func:`library` return None, and the callers use cholespy's constructor instead.
"""
from __future__ import annotations

import contextlib
import ctypes as C
import glob
import os
import threading
import weakref

import numpy as np
import torch

from ..errors import SolverError

#: CHOLMOD constants (cholmod_core.h / cholmod_cholesky.h, CHOLMOD 3.0).
_SIMPLICIAL = 0
_AUTO = 1
_NATURAL, _GIVEN, _AMD, _METIS, _NESDIS = 0, 1, 2, 3, 4
_INT, _REAL, _DOUBLE, _PATTERN = 0, 1, 0, 0
_SYS_A = 0
_MAXMETHODS = 9
#: Smallest pivot of an indefinite LDLᵀ factor, relative to the largest, that it is solved with
#: (:meth:`CholmodFactor.factorize`). The interior shifts of the Krylov solver gave 2e-7 to 3e-3
#: on PSB meshes, with eigenvalues equal to those of the definite shift to 1e-14; a breakdown is
#: a zero. The solver checks its result anyway (every residual, and the count below the shift).
PIVOT_FLOOR = 1e-12
#: Fill-reducing orderings a :class:`CholmodFactor` can be asked for by name.
ORDERINGS = {"amd": _AMD, "metis": _METIS, "nesdis": _NESDIS}


class _Method(C.Structure):
    _fields_ = [("lnz", C.c_double), ("fl", C.c_double), ("prune_dense", C.c_double),
                ("prune_dense2", C.c_double), ("nd_oksep", C.c_double), ("other_1", C.c_double * 4),
                ("nd_small", C.c_size_t), ("other_2", C.c_size_t * 4), ("aggressive", C.c_int),
                ("order_for_lu", C.c_int), ("nd_compress", C.c_int), ("nd_camd", C.c_int),
                ("nd_components", C.c_int), ("ordering", C.c_int), ("other_3", C.c_size_t * 4)]


class _Common(C.Structure):
    # The leading fields of cholmod_common; the rest (workspace pointers, statistics) is
    # CHOLMOD's own and only needs room: the tail is far larger than the real struct's.
    _fields_ = [("dbound", C.c_double), ("grow0", C.c_double), ("grow1", C.c_double),
                ("grow2", C.c_size_t), ("maxrank", C.c_size_t), ("supernodal_switch", C.c_double),
                ("supernodal", C.c_int), ("final_asis", C.c_int), ("final_super", C.c_int),
                ("final_ll", C.c_int), ("final_pack", C.c_int), ("final_monotonic", C.c_int),
                ("final_resymbol", C.c_int), ("zrelax", C.c_double * 3), ("nrelax", C.c_size_t * 3),
                ("prefer_zomplex", C.c_int), ("prefer_upper", C.c_int),
                ("quick_return_if_not_posdef", C.c_int), ("prefer_binary", C.c_int),
                ("print", C.c_int), ("precise", C.c_int), ("try_catch", C.c_int),
                ("error_handler", C.c_void_p), ("nmethods", C.c_int), ("current", C.c_int),
                ("selected", C.c_int), ("method", _Method * (_MAXMETHODS + 1)),
                ("postorder", C.c_int), ("default_nesdis", C.c_int), ("_rest", C.c_char * 32768)]


class _Sparse(C.Structure):
    _fields_ = [("nrow", C.c_size_t), ("ncol", C.c_size_t), ("nzmax", C.c_size_t), ("p", C.c_void_p),
                ("i", C.c_void_p), ("nz", C.c_void_p), ("x", C.c_void_p), ("z", C.c_void_p),
                ("stype", C.c_int), ("itype", C.c_int), ("xtype", C.c_int), ("dtype", C.c_int),
                ("sorted", C.c_int), ("packed", C.c_int)]


class _Dense(C.Structure):
    _fields_ = [("nrow", C.c_size_t), ("ncol", C.c_size_t), ("nzmax", C.c_size_t), ("d", C.c_size_t),
                ("x", C.c_void_p), ("z", C.c_void_p), ("xtype", C.c_int), ("dtype", C.c_int)]


class _Factor(C.Structure):
    _fields_ = [("n", C.c_size_t), ("minor", C.c_size_t), ("Perm", C.c_void_p), ("ColCount", C.c_void_p),
                ("IPerm", C.c_void_p), ("nzmax", C.c_size_t), ("p", C.c_void_p), ("i", C.c_void_p),
                ("x", C.c_void_p), ("z", C.c_void_p), ("nz", C.c_void_p), ("next", C.c_void_p),
                ("prev", C.c_void_p), ("nsuper", C.c_size_t), ("ssize", C.c_size_t),
                ("xsize", C.c_size_t), ("maxcsize", C.c_size_t), ("maxesize", C.c_size_t),
                ("super", C.c_void_p), ("pi", C.c_void_p), ("px", C.c_void_p), ("s", C.c_void_p),
                ("ordering", C.c_int), ("is_ll", C.c_int), ("is_super", C.c_int),
                ("is_monotonic", C.c_int), ("itype", C.c_int), ("xtype", C.c_int), ("dtype", C.c_int)]


_P = C.c_void_p
_SIGNATURES = {
    "SuiteSparse_version": (C.c_int, [_P]),
    "cholmod_start": (C.c_int, [_P]),
    "cholmod_finish": (C.c_int, [_P]),
    "cholmod_analyze": (C.POINTER(_Factor), [_P, _P]),
    "cholmod_factorize": (C.c_int, [_P, _P, _P]),
    "cholmod_solve2": (C.c_int, [C.c_int, _P, _P, _P, _P, _P, _P, _P, _P]),
    "cholmod_free_factor": (C.c_int, [_P, _P]),
    "cholmod_free_dense": (C.c_int, [_P, _P]),
    "cholmod_copy_factor": (C.POINTER(_Factor), [_P, _P]),
    "cholmod_ptranspose": (C.POINTER(_Sparse), [_P, C.c_int, _P, _P, C.c_size_t, _P]),
    "cholmod_rowfac": (C.c_int, [_P, _P, _P, C.c_size_t, C.c_size_t, _P, _P]),
    "cholmod_free_sparse": (C.c_int, [_P, _P]),
}
#: Rows of L computed per call while :meth:`CholmodFactor.positive_definite_at` looks for a
#: non-positive pivot: at least this many, and at least 1/64 of the matrix (the factor's work
#: lies mostly in its last rows, so one step past the first negative pivot costs little).
_ROWS_PER_STEP = 256

_lock = threading.Lock()
_library: list = []          # [] before the first look, then [CDLL or None]
_off = threading.local()     # .depth > 0 inside disabled()


def library():
    """The CHOLMOD library inside cholespy's extension module, if its layout is the one this
    module was written for (checked once per process); otherwise None, and None inside
    :func:`disabled`."""
    if getattr(_off, "depth", 0):
        return None
    with _lock:
        if not _library:
            _library.append(_load())
        return _library[0]


@contextlib.contextmanager
def disabled():
    """Within this block (on this thread) CPU factors are made by cholespy's constructor, as
    where the library is not usable: for benchmarks and tests that compare the two paths."""
    _off.depth = getattr(_off, "depth", 0) + 1
    try:
        yield
    finally:
        _off.depth -= 1


def _load():
    try:
        import cholespy
        paths = glob.glob(os.path.join(os.path.dirname(cholespy.__file__), "_cholespy_core*"))
        lib = C.CDLL(paths[0])
        for name, (res, args) in _SIGNATURES.items():
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
    except (ImportError, OSError, IndexError, AttributeError):
        return None
    version = (C.c_int * 3)()
    lib.SuiteSparse_version(version)
    if version[0] != 5:
        return None
    common = _Common()
    if not lib.cholmod_start(C.byref(common)):
        return None
    try:
        ok = _defaults_ok(common)
    finally:
        lib.cholmod_finish(C.byref(common))
    return lib if ok else None


def _defaults_ok(c: _Common) -> bool:
    """Whether every default cholmod_start wrote (CHOLMOD 3.0's cholmod_defaults) reads back at
    this module's offsets: a shifted or resized field would show up in one of them."""
    m = c.method
    return (c.dbound == 0.0 and c.grow0 == 1.2 and c.grow1 == 1.2 and c.grow2 == 5
            and c.maxrank == 8 and c.supernodal_switch == 40.0 and c.supernodal == _AUTO
            and c.final_asis == 1 and c.final_super == 1 and c.final_ll == 0
            and c.final_pack == 1 and c.final_monotonic == 1 and c.final_resymbol == 0
            and list(c.zrelax) == [0.8, 0.1, 0.05] and list(c.nrelax) == [4, 16, 48]
            and c.prefer_upper == 1 and c.quick_return_if_not_posdef == 0
            and c.nmethods == 0 and c.postorder == 1 and c.default_nesdis == 0
            and m[0].ordering == _GIVEN and m[1].ordering == _AMD and m[2].ordering == _METIS
            and m[3].ordering == _NESDIS and m[0].nd_small == 200 and m[0].prune_dense == 10.0
            and m[0].prune_dense2 == -1.0 and m[0].nd_oksep == 1.0 and m[0].aggressive == 1
            and m[0].nd_compress == 1 and m[0].nd_camd == 1)


def _start(lib) -> _Common:
    """A started cholmod_common with the settings every factor here uses."""
    c = _Common()
    lib.cholmod_start(C.byref(c))
    c.print = 0                        # a failed trial shift is handled, not printed
    c.supernodal = _SIMPLICIAL
    # LDLᵀ (final_ll stays 0): 6-10% faster than LLᵀ on PSB meshes; definiteness is then
    # checked on D in CholmodFactor.factorize().
    return c


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
        self.positive_definite = self.usable = False
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
        ok = self._lib.cholmod_factorize(C.byref(self._matrix), self._factor, C.byref(self._common))
        if not ok:
            raise SolverError(f"CHOLMOD failed to factor a matrix of order {self.n} (out of memory?)")
        self.rows_factored = self.n
        pivots = self._pivots(0, self.n)
        f = self._factor.contents
        # LDLᵀ without pivoting does not stop at a negative pivot, so definiteness is read
        # off D (the first entry of each column of the simplicial factor): A = L D Lᵀ is
        # positive definite iff every D_jj > 0 (a NaN from a breakdown fails the test too).
        self.positive_definite = bool(f.minor == self.n and np.all(pivots > 0))
        self.negative_pivots = int(np.count_nonzero(pivots < 0))
        size = np.abs(pivots)
        # Without pivoting, an LDLᵀ of an indefinite matrix is only as accurate as its smallest
        # pivot allows; a breakdown shows as a zero, an infinity or a NaN.
        self.usable = self.positive_definite or bool(
            indefinite and f.minor == self.n and np.all(np.isfinite(pivots))
            and size.min() >= PIVOT_FLOOR * size.max())
        return self.usable

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
        if f.xtype != _PATTERN:
            # A numeric factor restarts at row 0 (what a whole refactorization does first).
            np.ctypeslib.as_array(C.cast(f.nz, C.POINTER(C.c_int)), shape=(self.n,))[:] = 1
            f.minor = self.n
        perm = None if f.ordering == _NATURAL else f.Perm
        # triu(A(p, p)), the matrix cholmod_factorize hands to the row-by-row factorization
        upper = lib.cholmod_ptranspose(C.byref(self._matrix), 2, perm, None, 0, C.byref(c))
        if not upper:
            raise SolverError(f"CHOLMOD could not permute a matrix of order {self.n} (out of memory?)")
        beta = (C.c_double * 2)(0.0, 0.0)
        grow2, step = c.grow2, max(_ROWS_PER_STEP, -(-self.n // 64))
        self.positive_definite = self.usable = False
        try:
            f.is_ll = 0
            if f.xtype == _PATTERN and c.final_pack:
                c.grow2 = 0                # L gets exactly the room its column counts need
            for start in range(0, self.n, step):
                stop = min(start + step, self.n)
                if not lib.cholmod_rowfac(upper, None, beta, start, stop, self._factor, C.byref(c)):
                    raise SolverError(f"CHOLMOD failed to factor a matrix of order {self.n} (out of memory?)")
                c.grow2 = grow2
                pivots = self._pivots(start, stop)
                self.rows_factored = stop
                if not (f.minor == self.n and np.all(pivots > 0)):
                    self.negative_pivots = int(np.count_nonzero(pivots < 0))
                    return False
        finally:
            c.grow2 = grow2
            lib.cholmod_free_sparse(C.byref(upper), C.byref(c))
        self.positive_definite = self.usable = True
        self.negative_pivots = 0
        return True

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


def _free(lib, common, factor, *dense) -> None:
    for d in dense:
        if d:
            lib.cholmod_free_dense(C.byref(d), C.byref(common))
    if factor:
        lib.cholmod_free_factor(C.byref(factor), C.byref(common))
    lib.cholmod_finish(C.byref(common))
