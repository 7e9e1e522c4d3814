"""The one AKVF solve of a segmentation, shared by every k of every mesh."""
from __future__ import annotations

from ..fields.akvf import AKVFResult, akvf
from ..mesh import MeshBatch
from ..options import SegmentOptions
from ..solvers.akvf_solver import AKVFSolver

#: The residual tolerance of a segmentation's AKVF solve: :func:`~torchakvf.fields.akvf.akvf`'s
#: default, read from it so the two cannot drift apart.
AKVF_TOL = akvf.__kwdefaults__["tol"]


def solve_akvfs(batch: MeshBatch, n: int, opts: SegmentOptions) -> tuple[AKVFResult, list]:
    """The n smallest AKVFs of every mesh of the batch, once for every k: (result, [(mesh index,
    why it was solved at full resolution)]), by an :class:`~torchakvf.solvers.AKVFSolver` that
    solves at full resolution a decimated mesh that cannot be solved (``fell_back``)."""
    solver = AKVFSolver(batch, remedy=opts.remedy, solver=opts.solver, batched=opts.batched,
                        full_resolution_fallback=True)
    return solver.solve(int(n), tol=AKVF_TOL, seed=opts.seed), solver.fell_back


def solve_quality(fields: AKVFResult, b: int) -> tuple[bool, float]:
    """(converged, max_residual) of mesh b's eigensolve: its largest relative eigenpair residual
    and whether that is within the solve's tolerance (:data:`AKVF_TOL`)."""
    return bool(fields.converged[b]), float(fields.residuals[b].max())


__all__ = ["AKVF_TOL", "solve_akvfs", "solve_quality"]
