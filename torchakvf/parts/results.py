"""What segmentation returns: one :class:`MeshSegmentation` per mesh, a :class:`Segmentation`
per batch."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..fields.untangle import UntangledFields
from .boundaries import RefinedMesh


@dataclass
class MeshSegmentation:
    """The segmentation of one mesh.

    labels : [F_input] int, part per face of the input (file order); -1 = connecting region
    features : [F_input, n] per-face untangled AKVF norms (0 on faces dropped as degenerate;
        on a decimated mesh, those of the coarse face under each input face)
    eigenvalues : [n] Killing eigenvalues (λ·area) of the raw AKVFs used
    generators : per part, the :class:`~torchakvf.parts.generators.SymmetryGenerator` s
        localized on it
    refined : the mesh cut along the part boundaries (cleaned-mesh vertices, full resolution),
        or None
    cost : spherical k-means cost Σ(1 - cos) of the clustering kept; with method "merge", that of
        the merged parts (:func:`~torchakvf.parts.merge.partition_cost`, in solved-mesh faces)
    converged : whether every eigenpair of the mesh's AKVF solve reached the solve's residual
        tolerance; a False result is usable but not the converged answer (flag it, do not use it
        silently)
    max_residual : the largest relative eigenpair residual of the mesh's AKVFs
    """

    name: str
    k: int
    labels: np.ndarray
    features: np.ndarray
    eigenvalues: np.ndarray
    generators: list
    refined: RefinedMesh | None
    cost: float
    params: dict = field(default_factory=dict)
    converged: bool = True
    max_residual: float = 0.0


@dataclass
class Segmentation:
    """Per-mesh results of :func:`~torchakvf.parts.segment`, in batch order, and the untangled
    fields behind them."""

    meshes: list
    untangled: UntangledFields | None = None

    def face_vectors(self, b: int) -> np.ndarray:
        """[F_input, n_b, 3] untangled Whitney vectors of mesh b on the input's faces (0 on
        dropped faces; on a decimated mesh, those of the coarse face under each input face);
        ``generators[p][i].field`` indexes the second axis."""
        unt = self.untangled
        return unt.batch.to_input_faces(b, unt.mesh_face_vectors(b).detach().cpu().numpy())

    def __len__(self) -> int:
        return len(self.meshes)

    def __getitem__(self, b: int) -> MeshSegmentation:
        return self.meshes[b]

    @property
    def labels(self) -> list:
        return [m.labels for m in self.meshes]

    @property
    def generators(self) -> list:
        return [m.generators for m in self.meshes]


__all__ = ["MeshSegmentation", "Segmentation"]
