"""Approximate Killing vector fields of a batch in one call: :func:`akvf`, a thin wrapper over
:class:`~torchakvf.solvers.akvf_solver.AKVFSolver` (use the solver object to solve one batch
several times: it keeps the operator and the factors)."""
from __future__ import annotations

from ..errors import ParameterError
from ..mesh.batch import MeshBatch
from ..operators.killing import DEFAULT_REMEDY
from ..solvers.akvf_result import AKVFResult
from ..solvers.akvf_solver import (
    KRYLOV_MIN_EDGES,
    ONE_MESH_AT_A_TIME_ON,
    SOLVERS,
    SPURIOUS_BELOW,
    SPURIOUS_MARGIN,
    SPURIOUS_SOLVES,
    AKVFSolver,
    as_batch,
    remedy_advice,
    solver_for,
)


def akvf(meshes, n: int = 32, *, tol: float = 1e-6, seed: int = 0, remedy: str = DEFAULT_REMEDY,
         boundary_correction: bool = True, max_iter: int = 60, solver: str = "auto",
         device=None, batched: bool | None = None, **removed) -> AKVFResult:
    """The n smallest approximate Killing vector fields of each mesh.

    Parameters
    ----------
    meshes : MeshBatch, Mesh, or list of Mesh (a mesh is a batch of one)
    n : number of fields per mesh (a Python or numpy integer; each mesh needs more than n edges)
    tol : eigenpair residual at which a mesh counts as converged (``AKVFResult.converged``;
        a mesh that does not converge is flagged there and warned about, not raised)
    seed : seed of the solver's random start (the same start for every mesh)
    remedy : mesh-quality remedy of the operator (:data:`torchakvf.operators.REMEDIES`, default
        :data:`~torchakvf.operators.killing.DEFAULT_REMEDY`; "none" is the paper's operator);
        any remedy but "none" also skips spurious eigenpairs below :data:`SPURIOUS_BELOW` (the
        n returned are the n smallest of the rest; ``dropped`` counts the skipped ones)
    boundary_correction : use the open-mesh boundary terms (see docs/design.md)
    max_iter : LOBPCG iterations at most
    solver : "lobpcg" (segmented block solver over the batch, any device; a mesh that has
        converged leaves its iteration; on CUDA one block-diagonal factor of the batch serves
        every mesh's solves), "lanczos" (ARPACK shift-invert on the same factor, CPU, one mesh
        at a time), "krylov" (block shift-invert Krylov on the same factor, one mesh at a time)
        or "auto" (:func:`solver_for`, decided per mesh: on CPU Krylov for meshes from
        :data:`KRYLOV_MIN_EDGES` edges, Lanczos below)
    device : device of the batch built from Mesh inputs (a MeshBatch given is moved there);
        default: the batch's own, "cpu" for meshes
    batched : solve the batch as one, as on an accelerator (True), or one mesh at a time
        (False); default: one at a time on the CPU, as one elsewhere (see
        :class:`~torchakvf.solvers.akvf_solver.AKVFSolver`)

    Work runs on the batch's device; the operator and solve are float64 whatever the
    coordinates' dtype, and results are returned in the batch's dtype.

    Each mesh's result depends on that mesh alone: the number of eigenpairs solved (n plus
    room for spurious modes) is decided per mesh, never by its batch mates. On CPU
    (:data:`ONE_MESH_AT_A_TIME_ON`) a batch is solved one mesh at a time, with every solver:
    each mesh gets the bits it gets alone.

    Raises :class:`~torchakvf.errors.SolverError` where a mesh cannot be solved (for a batch of
    decimated meshes, :func:`akvf_falling_back` solves those at full resolution instead).
    """
    if "method" in removed:
        raise ParameterError(f"akvf(method=) was removed; use solver= (one of {SOLVERS})")
    if removed:
        raise TypeError(f"akvf() got an unexpected keyword argument {next(iter(removed))!r}")
    return AKVFSolver(meshes, remedy=remedy, boundary_correction=boundary_correction, solver=solver,
                      device=device, batched=batched, full_resolution_fallback=False).solve(n, tol=tol, seed=seed,
                                                                            max_iter=max_iter)


def akvf_falling_back(batch: MeshBatch, n: int = 32, **kwargs) -> tuple[AKVFResult, list]:
    """:func:`akvf` on a batch of decimated meshes (``MeshBatch.from_meshes(coarse_faces=)``),
    solving at full resolution the meshes whose decimated version cannot be solved.

    A decimated surface can be worse than its original (holes that could not be closed, whose
    boundary terms make R - σS1 indefinite at every shift): a decimated mesh that fails is
    solved alone at full resolution and takes its place in batch order; its mates keep what
    they got (see :class:`~torchakvf.solvers.akvf_solver.AKVFSolver`). Returns (the result,
    [(mesh index, error text)] of the meshes that fell back). A mesh that was not decimated,
    or fails at full resolution too, raises as :func:`akvf` does.
    ``kwargs``: :func:`akvf`'s.
    """
    solve = {k: kwargs.pop(k) for k in ("tol", "seed", "max_iter") if k in kwargs}
    solver = AKVFSolver(batch, full_resolution_fallback=True, **kwargs)
    return solver.solve(n, **solve), solver.fell_back


__all__ = ["AKVFResult", "AKVFSolver", "akvf", "akvf_falling_back", "as_batch", "solver_for", "remedy_advice",
           "SOLVERS", "KRYLOV_MIN_EDGES", "ONE_MESH_AT_A_TIME_ON", "SPURIOUS_BELOW", "SPURIOUS_MARGIN",
           "SPURIOUS_SOLVES"]
