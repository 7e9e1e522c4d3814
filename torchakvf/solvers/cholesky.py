"""One sparse Cholesky factor of R + diag(d) (R the Killing operator's lower triangle): CHOLMOD
called directly on the CPU (:class:`CpuFactor`: one symbolic analysis, a diagonal refilled per
trial shift), else cholespy (CPU or CUDA); its solves, and the check of a new cholespy factor's
first solve. :mod:`.factor` builds the eigensolver's shifted factors from these."""
from __future__ import annotations

import contextlib
import ctypes
import os
import sys

import numpy as np
import torch

from ..errors import SolverError
from . import cholmod


def lower_pattern(rows: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor, n: int):
    """(n, rows, cols, values) of the lower triangle of R (CHOLMOD reads only that one) with
    the n diagonal entries appended (for the shift), as cholespy takes them."""
    lower = rows >= cols
    diag = torch.arange(n, device=rows.device)
    r = torch.cat([rows[lower], diag]).to(torch.int32).contiguous()
    c = torch.cat([cols[lower], diag]).to(torch.int32).contiguous()
    return n, r, c, vals[lower].to(torch.float64)


class CpuFactor:
    """R + diag(d) for changing d, factored by CHOLMOD directly: the lower CSC pattern and the
    symbolic analysis are built once, each :meth:`factorize` only refills the diagonal.

    like : a :class:`~torchakvf.solvers.cholmod.Symbolic` analysis of another matrix (the
    paper's operator of the same mesh), used where its pattern is this one's (else a new one)."""

    def __init__(self, pattern, ordering: str | None = None, like=None):
        import scipy.sparse as sp

        n, r, c, base = pattern
        slots = torch.cat([base.cpu(), base.new_zeros(n).cpu()])     # the diagonal slots: 0 here
        lower = sp.csc_matrix((slots.numpy(), (r.cpu().numpy(), c.cpu().numpy())), shape=(n, n))
        lower.sum_duplicates()          # R's own diagonal and the appended slots merge
        lower.sort_indices()
        self._base = lower.data.copy()
        # In a sorted lower-triangular column the diagonal comes first (always stored: the
        # pattern appends every diagonal slot, kept even where R's entry is 0).
        self._diag = lower.indptr[:-1].copy()
        if not np.array_equal(lower.indices[self._diag], np.arange(n)):
            raise SolverError("internal: a diagonal slot is missing from R's lower pattern")
        shared = like if like is not None and like.matches(lower.indptr, lower.indices) else None
        self.factor = cholmod.CholmodFactor(n, lower.indptr, lower.indices, self._base,
                                             ordering=ordering, symbolic=shared)

    @property
    def symbolic(self):
        """The symbolic analysis of this pattern (shareable: ``like=`` of another factor)."""
        return self.factor.symbolic

    def _values(self, diagonal: torch.Tensor) -> np.ndarray:
        values = self._base.copy()
        values[self._diag] += diagonal.detach().cpu().numpy()
        return values

    def factorize(self, diagonal: torch.Tensor, indefinite: bool = False):
        return self.factor.factorize(self._values(diagonal), indefinite=indefinite)

    def positive_definite_at(self, diagonal: torch.Tensor) -> bool:
        """Whether R + diag(diagonal) is positive definite (what :meth:`factorize` says, stopped
        at the first non-positive pivot; where it is, the factor is complete)."""
        return self.factor.positive_definite_at(self._values(diagonal))


def cpu_engine(pattern, device: torch.device, like=None):
    """A :class:`CpuFactor` on the CPU where CHOLMOD can be called directly (sharing ``like``'s
    analysis where the pattern is the same), else None (cholespy then factors each trial shift
    from scratch)."""
    if device.type != "cpu" or cholmod.library() is None:
        return None
    return CpuFactor(pattern, like=like)


def cholesky(pattern, diagonal: torch.Tensor, engine=None):
    """(solver of R + diag(diagonal), None) or (None, the error) where it is not positive
    definite. The solver is ``engine``'s CHOLMOD factor if given, else a cholespy solver."""
    if engine is not None:
        if engine.factorize(diagonal):
            return engine.factor, None
        return None, "CHOLMOD: not positive definite"
    import cholespy

    n, r, c, base = pattern
    x = torch.cat([base, diagonal.to(base.device)]).contiguous()
    # CHOLMOD's "not positive definite" of a trial shift is muted on the CPU only: on a GPU the
    # same channel carries CUDA errors, which must be seen.
    quiet = quiet_stdio() if x.device.type == "cpu" else contextlib.nullcontext()
    try:
        with quiet:
            return cholespy.CholeskySolverD(n, r, c, x, cholespy.MatrixType.COO), None
    except ValueError as exc:               # "Matrix is not positive definite!"
        return None, exc


def solve(solver, device: torch.device, rhs: torch.Tensor) -> torch.Tensor:
    if isinstance(solver, cholmod.CholmodFactor):
        if rhs.ndim == 1:
            return solver.solve_rows(rhs.to(torch.float64)[None])[0]
        return contiguous_transpose(solver.solve_rows(contiguous_transpose(rhs.to(torch.float64))))
    rhs = rhs.to(torch.float64).contiguous()
    out = torch.empty_like(rhs)
    if device.type == "cuda" and rhs.ndim == 2 and rhs.shape[1] > 128:
        # cholespy's CUDA solve takes at most 128 right-hand sides at a time.
        for s in range(0, rhs.shape[1], 128):
            chunk = rhs[:, s:s + 128].contiguous()
            res = torch.empty_like(chunk)
            solver.solve(chunk, res)
            out[:, s:s + 128] = res
        return out
    solver.solve(rhs, out)
    return out


def solve_rows(solver, device: torch.device, rows: torch.Tensor) -> torch.Tensor:
    if isinstance(solver, cholmod.CholmodFactor):
        return solver.solve_rows(rows.to(torch.float64))
    return contiguous_transpose(solve(solver, device, contiguous_transpose(rows)))


def contiguous_transpose(x: torch.Tensor) -> torch.Tensor:
    """x.T as a contiguous array (on the CPU numpy's transposing copy: 5x torch's for
    [6, 45594])."""
    if x.device.type == "cpu":
        return torch.from_numpy(np.ascontiguousarray(x.numpy().T))
    return x.T.contiguous()


#: Largest normwise backward error ||A x - b|| / (||A|| ||x|| + ||b||) (max norms) of the known
#: right-hand side's solve (:func:`check_first_solve`). A Cholesky solve is backward stable: its
#: backward error is a small multiple of eps (1e-16) whatever the conditioning, so this is met
#: with room by any working factor, while a failed device call leaves zeros, garbage or NaN
#: (backward error of order 1).
BACKWARD_ERROR_MAX = 1e-10


def check_first_solve(solver, device: torch.device, pattern, diagonal: torch.Tensor, name: str) -> None:
    """Solve A x = b for a known b (A = R + diag(diagonal), b = A·1) with a new cholespy factor
    and raise a :class:`SolverError` naming ``name`` where the result is not finite or its
    backward error exceeds :data:`BACKWARD_ERROR_MAX`. cholespy prints CUDA errors instead of
    raising them (a failed allocation or launch leaves the output unwritten): this is where they
    surface. CHOLMOD called directly raises its own errors and is not checked."""
    if isinstance(solver, cholmod.CholmodFactor):
        return
    n, r, c, base = pattern
    vals = torch.cat([base.to(device), diagonal.to(device, torch.float64)])
    r, c = r.to(device).long(), c.to(device).long()

    def times(x: torch.Tensor) -> torch.Tensor:          # A x from A's lower triangle
        off = r != c
        y = torch.zeros_like(x).index_add_(0, r, vals * x[c])
        return y.index_add_(0, c[off], vals[off] * x[r[off]])

    b = times(torch.ones(n, dtype=torch.float64, device=device))
    x = solve(solver, device, b[:, None])[:, 0]
    norm_a = torch.zeros(n, dtype=torch.float64, device=device).index_add_(0, r, vals.abs())
    norm_a = norm_a.index_add_(0, c[r != c], vals[r != c].abs()).max()
    err = (times(x) - b).abs().max() / (norm_a * x.abs().max() + b.abs().max())
    if not bool(torch.isfinite(x).all()) or not float(err) <= BACKWARD_ERROR_MAX:
        raise SolverError(f"{name}: the sparse factor's solve on {device} failed its check (backward "
                          f"error {float(err):.1e} > {BACKWARD_ERROR_MAX:.0e}, or not finite): a "
                          "device error (out of memory?) was printed above; free memory or make the "
                          "batch smaller")


@contextlib.contextmanager
def quiet_stdio():
    """Silence CHOLMOD's C-level "not positive definite" warning during a trial factorization
    (the failure is handled: the next shift is tried). CHOLMOD prints through C stdio to
    stdout, buffered, so both descriptors are redirected and C buffers flushed before restoring."""
    try:
        fds = [sys.stdout.fileno(), sys.stderr.fileno()]
    except (AttributeError, OSError, ValueError):
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(fd) for fd in fds]
    try:
        with open(os.devnull, "w") as null:
            for fd in fds:
                os.dup2(null.fileno(), fd)
            yield
            libc_flush()
    finally:
        for fd, old in zip(fds, saved):
            os.dup2(old, fd)
            os.close(old)


def libc_flush() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass
