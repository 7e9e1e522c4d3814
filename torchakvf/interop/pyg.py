"""A ``torch_geometric`` transform that adds AKVF features to a mesh ``Data`` object.

    from torch_geometric.datasets import FAUST            # any dataset with pos and face
    from torchakvf.interop.pyg import AKVFFeatures
    ds = FAUST(root, pre_transform=AKVFFeatures(n=32, coarse_faces=4000))
    data = ds[0]; data.akvf_descriptors                   # [F, 48], the same columns on every mesh

Needs ``torch_geometric`` (``pip install torchakvf[pyg]``). Used as a ``pre_transform``, the
features are computed once and stored with the processed dataset.
"""
from __future__ import annotations

import copy

from torch_geometric.data import Data
from torch_geometric.transforms import BaseTransform

from ..errors import MeshError
from .features import as_tensor_like, face_features


class AKVFFeatures(BaseTransform):
    """Adds per-face AKVF features to a ``Data`` with ``pos`` [V, 3] and ``face`` [3, F]
    (PyG's convention: one column per triangle).

    Adds (on ``pos``'s device, in its dtype):

    * ``akvf_face_features`` [F, n]: |X_i(f)| of the untangled fields, in ``face``'s order
      (0 on faces dropped as degenerate);
    * ``akvf_descriptors`` [F, d]: per-face descriptors invariant to the fields' order and
      sign, comparable across meshes (the columns a per-face model should take): the field
      descriptors (:func:`torchakvf.fields.descriptors.descriptor_names`) then the part
      descriptors (:func:`torchakvf.parts.part_descriptors.part_descriptor_names`; not with
      ``part_descriptors=False``), then, at the default counts (n ≥ 32), the crease cues and
      the boundary probability (:mod:`torchakvf.parts.boundary_probability`), docs/descriptors.md;
    * ``akvf_eigenvalues`` [1, n]: Killing eigenvalues λ·area, ascending (graph-level, so a
      ``Batch`` of B meshes holds [B, n]);
    * with ``raw_norms=True`` also ``akvf_norms`` [F, n], the raw AKVFs' norms.

    Parameters: ``n`` fields; ``coarse_faces`` decimates larger meshes to about that many
    faces before the solve (results still on every input face); ``seed``, ``remedy``,
    ``restarts``, ``tol``, ``part_descriptors`` as in :func:`torchakvf.interop.face_features`.
    ``pos``, ``face`` and every other attribute are left as they are.
    """

    def __init__(self, n: int = 32, *, coarse_faces: int | None = None, seed: int = 0,
                 remedy: str | None = None, restarts: int = 8, tol: float = 1e-6,
                 raw_norms: bool = False, part_descriptors: bool = True):
        self.n, self.coarse_faces, self.seed = int(n), coarse_faces, int(seed)
        self.part_descriptors = bool(part_descriptors)
        self.remedy, self.restarts, self.tol, self.raw_norms = remedy, int(restarts), float(tol), bool(raw_norms)

    def forward(self, data: Data) -> Data:
        from ..mesh import Mesh, MeshBatch

        pos, face = getattr(data, "pos", None), getattr(data, "face", None)
        if pos is None or face is None:
            raise MeshError("<torch_geometric Data>", "AKVFFeatures needs data.pos [V, 3] and "
                            "data.face [3, F] (a mesh; use FaceToEdge only after this transform)")
        if face.dim() != 2 or face.shape[0] != 3:
            raise MeshError("<torch_geometric Data>", f"data.face must be [3, F], got {list(face.shape)}")
        mesh = Mesh(pos.detach().cpu().double().numpy(), face.detach().cpu().t().numpy(),
                    name="<torch_geometric Data>")
        batch = MeshBatch.from_meshes([mesh], coarse_faces=self.coarse_faces)
        ff = face_features(batch, self.n, seed=self.seed, remedy=self.remedy,
                           restarts=self.restarts, tol=self.tol, part_descriptors=self.part_descriptors)[0]
        data.akvf_face_features = as_tensor_like(ff.features, pos)
        data.akvf_descriptors = as_tensor_like(ff.descriptors, pos)
        data.akvf_eigenvalues = as_tensor_like(ff.eigenvalues, pos)[None, :]
        if self.raw_norms:
            data.akvf_norms = as_tensor_like(ff.akvf_norms, pos)
        return data

    def __call__(self, data: Data) -> Data:
        # A shallow copy, as BaseTransform.__call__ does in torch_geometric >= 2.4 (older ones
        # have no forward()): the caller's Data gets no new attributes.
        return self.forward(copy.copy(data))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n={self.n}, coarse_faces={self.coarse_faces})"


__all__ = ["AKVFFeatures"]
