"""The result of an AKVF solve: the n smallest fields of every mesh of a batch, packed."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..mesh.batch import MeshBatch
from ..operators.killing import KillingSystem


@dataclass
class AKVFResult:
    """The n smallest AKVFs of every mesh of a batch (unit-area frame).

    Index spaces: "packed" rows are the batch's meshes one after another (``batch.edge_ptr``,
    ``batch.face_ptr``), each mesh as packed, i.e. cleaned and, in a batch built with
    ``coarse_faces``, decimated; :meth:`mesh_face_vectors` maps back to the input faces.

    eigenvalues : [B, n] ascending, λ·area (a unit sphere's rotations: 0, then 8π, ...)
    forms : packed [ΣE, n] 1-forms (edge values), S1-orthonormal per mesh
    face_vectors : packed [ΣF, n, 3] Whitney vectors at face barycenters
    residuals : [B, n] relative residual of each eigenpair (see :class:`EigenResult`)
    converged : [B] bool, every one of the mesh's n residuals <= tol; a mesh where it is False
        was returned with a :class:`~torchakvf.errors.ConvergenceWarning` and must not be used
        as if solved
    iterations, shifts : [B] eigensolver diagnostics: LOBPCG iterations or shift-invert solves
        (Lanczos, Krylov: right-hand sides); the shift σ of the factor, λ·area (-1 or lower: below
        the spectrum; above -1: the Krylov solver's interior shift; see :class:`EigenResult`)
    dropped : [B] spurious negative modes (λ·area < :data:`~torchakvf.solvers.remedy.SPURIOUS_BELOW`)
        skipped under a remedy
    solved : [B] eigenpairs computed per mesh (n + room for spurious modes; decided per mesh)
    batch : the :class:`MeshBatch`; ``system``: its :class:`KillingSystem` (``remedies``: the
        remedy of each mesh)
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
    solved: torch.Tensor | None = None

    @property
    def remedies(self) -> list[str] | None:
        """[B] the mesh-quality remedy each mesh's operator was built with ("none": the paper's
        operator; with ``remedy="auto"`` decided per mesh, see
        :func:`~torchakvf.solvers.remedy.choose_remedies`)."""
        return self.system.remedies

    @property
    def n(self) -> int:
        return self.eigenvalues.shape[1]

    def mesh_forms(self, b: int) -> torch.Tensor:
        """[E_b, n] forms of mesh b on the edges of the packed mesh (``batch.meshes[b]``)."""
        return self.forms[int(self.batch.edge_ptr[b]):int(self.batch.edge_ptr[b + 1])]

    def mesh_face_vectors(self, b: int) -> np.ndarray:
        """[F_input, n, 3] face vectors of mesh b on the faces of the mesh that was packed, in
        its input order (0 on faces cleaning dropped). For a decimated mesh that is the
        decimated mesh; :meth:`Segmentation.face_vectors` reports on the original's faces."""
        fv = self.face_vectors[int(self.batch.face_ptr[b]):int(self.batch.face_ptr[b + 1])]
        return self.batch.meshes[b].to_input_faces(fv.detach().cpu().numpy())

    @classmethod
    def concatenate(cls, parts: list["AKVFResult"], batch: MeshBatch, system: KillingSystem) -> "AKVFResult":
        """One result on ``batch`` from the results of its meshes solved one at a time (in
        batch order; ``system`` the batch's)."""
        cat = lambda name: torch.cat([getattr(p, name) for p in parts])  # noqa: E731
        return cls(eigenvalues=cat("eigenvalues"), forms=cat("forms"), face_vectors=cat("face_vectors"),
                   residuals=cat("residuals"), iterations=cat("iterations"), shifts=cat("shifts"),
                   converged=cat("converged"), dropped=cat("dropped"), batch=batch, system=system,
                   solved=cat("solved"))
