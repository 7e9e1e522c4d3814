"""Sparse Cholesky factors of the shifted Killing operator, used as the exact shift-invert
preconditioner of the eigensolver.

Why a factorization: slivers put R's largest eigenvalue near 1e7 against ~1 for the smallest,
and no product-only preconditioner (Jacobi, ILU, AMG, Chebyshev) brought LOBPCG under thousands
of iterations; (R - σ S1)^{-1} brings it to a handful. CHOLMOD (through ``cholespy``, the sparse
Cholesky that works on torch tensors on CPU and CUDA) factors it.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import sys

import torch

from ..errors import SolverError

#: Shifts tried in turn (λ·area units): R is only approximately PSD, so the shift must lie
#: below its smallest eigenvalue for R - σ S1 to be positive definite. -1 suffices on good
#: meshes; badly shaped real meshes go down to about -250 (akvf-math.md, pitfall 3).
SHIFTS = (-1.0, -8.0, -64.0, -512.0, -4096.0, -32768.0)


class ShiftedFactor:
    """Cholesky factor of ``R_b - σ diag(S1_b)`` for one mesh, with the first shift that works.

    rows, cols, vals : COO of R_b (local indices, symmetric); mass : [E] S1_b.
    ``solve(rhs)`` returns (R_b - σ S1_b)^{-1} rhs for rhs [E, k] on the factor's device.
    """

    def __init__(self, rows: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor,
                 mass: torch.Tensor, name: str = "mesh", shifts=None):
        import cholespy

        shifts = SHIFTS if shifts is None else tuple(shifts)
        n = len(mass)
        self.device = mass.device
        lower = rows >= cols                       # CHOLMOD reads the lower triangle only
        diag = torch.arange(n, device=mass.device)
        r = torch.cat([rows[lower], diag]).to(torch.int32)
        c = torch.cat([cols[lower], diag]).to(torch.int32)
        base = vals[lower].to(torch.float64)
        last = None
        for sigma in shifts:
            x = torch.cat([base, -sigma * mass.to(torch.float64)])
            try:
                with _quiet_stderr():
                    self._solver = cholespy.CholeskySolverD(n, r.contiguous(), c.contiguous(),
                                                            x.contiguous(), cholespy.MatrixType.COO)
            except ValueError as exc:               # "Matrix is not positive definite!"
                last = exc
                continue
            self.sigma = sigma
            return
        # No advice here: what to try next depends on what was tried (the caller adds it).
        raise SolverError(f"{name}: the Killing operator has eigenvalues below {shifts[-1]} "
                          f"(λ·area); no shift made R - σS1 positive definite ({last}); the mesh "
                          "is likely badly shaped")

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        rhs = rhs.to(torch.float64).contiguous()
        out = torch.empty_like(rhs)
        if self.device.type == "cuda" and rhs.ndim == 2 and rhs.shape[1] > 128:
            # cholespy's CUDA solve takes at most 128 right-hand sides at a time.
            for s in range(0, rhs.shape[1], 128):
                chunk = rhs[:, s:s + 128].contiguous()
                res = torch.empty_like(chunk)
                self._solver.solve(chunk, res)
                out[:, s:s + 128] = res
            return out
        self._solver.solve(rhs, out)
        return out


def mesh_factor(system, b: int, name: str, device=None) -> ShiftedFactor:
    """The :class:`ShiftedFactor` of mesh b of a :class:`~torchakvf.operators.killing.KillingSystem`
    (its block of R and its S1), on ``device`` (default: the system's)."""
    r, c, v, _ = system.block(b)
    lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
    mass = system.mass[lo:hi]
    if device is not None:
        r, c, v, mass = (t.to(device) for t in (r, c, v, mass))
    return ShiftedFactor(r, c, v, mass, name=name)


@contextlib.contextmanager
def _quiet_stderr():
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
            _libc_flush()
    finally:
        for fd, old in zip(fds, saved):
            os.dup2(old, fd)
            os.close(old)


def _libc_flush() -> None:
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass
