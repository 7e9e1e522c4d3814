"""Approximate Killing vector fields of a batch: operator, eigensolve, Whitney interpolation."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..errors import ParameterError, SolverError
from ..mesh.batch import MeshBatch
from ..mesh.clean import CleanMesh
from ..mesh.mesh import Mesh
from ..operators.killing import KillingSystem, killing_operator
from ..solvers.lanczos import shift_invert_lanczos
from ..solvers.lobpcg import segmented_lobpcg
from .whitney import whitney_face_vectors


@dataclass
class AKVFResult:
    """The n smallest AKVFs of every mesh of a batch (unit-area frame).

    eigenvalues : [B, n] ascending, λ·area (a unit sphere's rotations: 0, then 8π, ...)
    forms : packed [ΣE, n] 1-forms (edge values), S1-orthonormal per mesh
    face_vectors : packed [ΣF, n, 3] Whitney vectors at face barycenters
    residuals : [B, n] relative residual of each eigenpair (see :class:`EigenResult`)
    iterations, shifts, converged : [B] eigensolver diagnostics
    dropped : [B] spurious negative modes (λ·area < SPURIOUS_BELOW) skipped under a remedy
    batch : the :class:`MeshBatch`; ``system``: its :class:`KillingSystem`
    """

    eigenvalues: torch.Tensor
    forms: torch.Tensor
    face_vectors: torch.Tensor
    residuals: torch.Tensor
    iterations: torch.Tensor
    shifts: torch.Tensor
    converged: torch.Tensor
    dropped: torch.Tensor
    batch: MeshBatch
    system: KillingSystem

    @property
    def n(self) -> int:
        return self.eigenvalues.shape[1]

    def mesh_forms(self, b: int) -> torch.Tensor:
        """[E_b, n] forms of mesh b (edges of the cleaned mesh)."""
        return self.forms[int(self.batch.edge_ptr[b]):int(self.batch.edge_ptr[b + 1])]

    def mesh_face_vectors(self, b: int) -> np.ndarray:
        """[F_input, n, 3] face vectors of mesh b on the input's faces (0 on dropped faces)."""
        fv = self.face_vectors[int(self.batch.face_ptr[b]):int(self.batch.face_ptr[b + 1])]
        return self.batch.meshes[b].to_input_faces(fv.detach().cpu().numpy())


def as_batch(meshes, device=None, coarse_faces: int | None = None) -> MeshBatch:
    """A :class:`MeshBatch` from a batch, a mesh or a list of meshes (``coarse_faces``: as in
    :meth:`MeshBatch.from_meshes`; a batch given keeps its own)."""
    if isinstance(meshes, MeshBatch):
        return meshes if device is None else meshes.to(device)
    if isinstance(meshes, (Mesh, CleanMesh)):
        meshes = [meshes]
    return MeshBatch.from_meshes(list(meshes), device=device or "cpu", coarse_faces=coarse_faces)


SOLVERS = ("auto", "lobpcg", "lanczos")

#: Under a mesh-quality remedy, eigenpairs below this (λ·area) are spurious: a Killing energy is
#: >= 0, and good meshes give at worst small negatives (-0.06 on a hemisphere, akvf-math.md);
#: badly shaped vertices give modes localized on a few edges far below zero.
SPURIOUS_BELOW = -1.0
#: Extra eigenpairs computed to make room for spurious ones.
SPURIOUS_MARGIN = 8


def solver_for(device: torch.device) -> str:
    """The eigensolver "auto" picks: Lanczos on CPU, the batched LOBPCG elsewhere.

    Both use the same CHOLMOD shift-invert factor. On CPU the block method's dense
    Rayleigh-Ritz work (bases of 3·(n + guard) columns) costs more than Lanczos' single
    right-hand-side solves (benchmarks/bench_eigensolver.py); on a GPU the block method's
    batched dense work is what the device is good at, and ARPACK does not run there.
    """
    return "lanczos" if torch.device(device).type == "cpu" else "lobpcg"


def akvf(meshes, n: int = 32, *, tol: float = 1e-6, seed: int = 0, remedy: str = "none",
         boundary_correction: bool = True, max_iter: int = 60, method: str = "auto") -> AKVFResult:
    """The n smallest approximate Killing vector fields of each mesh.

    Parameters
    ----------
    meshes : MeshBatch, Mesh, or list of Mesh (a mesh is a batch of one)
    n : number of fields per mesh (each mesh needs at least n edges)
    tol : eigenpair residual at which a mesh counts as converged
    seed : seed of the solver's random start (the same start for every mesh)
    remedy : mesh-quality remedy of the operator (:data:`torchakvf.operators.REMEDIES`); any
        remedy but "none" also skips spurious eigenpairs below :data:`SPURIOUS_BELOW` (the n
        returned are the n smallest of the rest; ``dropped`` counts the skipped ones)
    boundary_correction : use the open-mesh boundary terms (akvf-math.md)
    method : "lobpcg" (segmented block solver over the batch, any device), "lanczos" (ARPACK
        shift-invert on the same factor, CPU, one mesh at a time), or "auto" (:func:`solver_for`)

    Work runs on the batch's device; the operator and solve are float64 whatever the
    coordinates' dtype, and results are returned in the batch's dtype.
    """
    if not isinstance(n, int) or n < 1:
        raise ParameterError(f"n must be a positive integer, got {n!r}")
    if method not in SOLVERS:
        raise ParameterError(f"method must be one of {SOLVERS}, got {method!r}")
    batch = as_batch(meshes)
    system = killing_operator(batch, boundary_correction=boundary_correction, remedy=remedy)
    if method == "auto":
        method = solver_for(batch.device)

    def solve(count: int):
        if method == "lanczos":
            return shift_invert_lanczos(system, count, tol=tol, seed=seed, names=batch.names)
        return segmented_lobpcg(system, count, tol=tol, seed=seed, names=batch.names, max_iter=max_iter)

    drop = remedy != "none"
    max_edges = int((batch.edge_ptr[1:] - batch.edge_ptr[:-1]).min())
    extra = min(SPURIOUS_MARGIN, max(max_edges - n - 1, 0)) if drop else 0
    eig = solve(n + extra)
    dropped = (eig.eigenvalues < SPURIOUS_BELOW).sum(dim=1)
    for _ in range(3):
        # More spurious modes than the margin: solve again with room for all of them.
        short = int(dropped.max()) - extra
        if not drop or short <= 0 or n + extra + 1 >= max_edges:
            break
        extra = min(extra + short + SPURIOUS_MARGIN, max_edges - n - 1)
        eig = solve(n + extra)
        dropped = (eig.eigenvalues < SPURIOUS_BELOW).sum(dim=1)
    # Per mesh, the first n eigenpairs that are not spurious (ascending order kept).
    spurious = eig.eigenvalues < SPURIOUS_BELOW if drop else torch.zeros_like(eig.eigenvalues, dtype=torch.bool)
    keep = torch.argsort(spurious.to(torch.int8), dim=1, stable=True)[:, :n]
    forms = eig.vectors.gather(1, keep[batch.edge_to_mesh])
    fv = whitney_face_vectors(batch, system.geometry, forms)
    out_dt = batch.dtype
    return AKVFResult(eigenvalues=eig.eigenvalues.gather(1, keep).to(out_dt), forms=forms.to(out_dt),
                      face_vectors=fv.to(out_dt), residuals=eig.residuals.gather(1, keep),
                      iterations=eig.iterations, shifts=eig.shifts, converged=eig.converged,
                      dropped=spurious.sum(dim=1), batch=batch, system=system)


def akvf_falling_back(batch: MeshBatch, n: int = 32, **kwargs) -> tuple[AKVFResult, list]:
    """:func:`akvf` on a batch of decimated meshes (``MeshBatch.from_meshes(coarse_faces=)``),
    solving at full resolution the meshes whose decimated version cannot be solved.

    A decimated surface can be worse than its original (holes that could not be closed, whose
    boundary terms make R - σS1 indefinite at every shift): on a :class:`SolverError` each
    decimated mesh is solved alone to find the ones that fail, and the batch is solved again
    with those at full resolution. Returns (the result, [(mesh index, error text)] of the
    meshes that fell back). A batch without decimated meshes raises as :func:`akvf` does.
    """
    try:
        return akvf(batch, n=n, **kwargs), []
    except SolverError as exc:
        decimated = [b for b in range(len(batch)) if batch.coarse_of(b) is not None]
        if not decimated:
            raise
        first = exc
    failed = []
    for b in decimated:
        try:
            akvf(MeshBatch.from_meshes([batch.meshes[b]], device=batch.device, dtype=batch.dtype), n=n, **kwargs)
        except SolverError as exc:
            failed.append((b, str(exc)))
    if not failed:   # no decimated mesh is to blame
        raise first
    return akvf(batch.at_full_resolution([b for b, _ in failed]), n=n, **kwargs), failed
