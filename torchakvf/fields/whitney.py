"""Whitney interpolation of 1-forms to tangent vectors at face barycenters."""
from __future__ import annotations

import torch

from ..mesh.batch import MeshBatch
from ..operators.geometry import BatchGeometry


def whitney_face_vectors(batch: MeshBatch, geo: BatchGeometry, forms: torch.Tensor) -> torch.Tensor:
    """Vectors at face barycenters of packed 1-forms.

    X_f = (1/3) Σ_{e=(i->j) in f} w_e (∇l_j - ∇l_i)  (akvf-math.md, Sec. 2), exact for the
    gradient of a linear function.

    forms : packed [ΣE, n] (edge values, edges oriented i -> j, i < j)
    Returns [ΣF, n, 3], in the unit-area frame of ``geo``.
    """
    fe, sign = batch.face_edges, batch.face_edge_sign.to(forms.dtype)
    w = forms[fe] * sign[..., None]                             # [F, 3(edge k: v_k->v_k+1), n]
    g = geo.grad_bary.to(forms.dtype)                           # [F, 3(l_k), 3]
    dgrad = g.roll(-1, dims=1) - g                              # ∇l_{k+1} - ∇l_k for edge k
    return torch.einsum("fkn,fkc->fnc", w, dgrad) / 3.0


def face_norms(face_vectors: torch.Tensor) -> torch.Tensor:
    """[ΣF, n, 3] -> [ΣF, n]: the per-face feature |X_f| of each field."""
    return torch.linalg.norm(face_vectors, dim=-1)
