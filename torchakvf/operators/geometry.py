"""Per-face geometry of a packed batch, on unit-area meshes.

Every quantity the DEC operators need is computed here once, vectorized over the whole batch:
each mesh is scaled to unit total area first (eigenvalues scale as 1/area, so the shift and
the tolerances of the solver mean the same on every mesh).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..mesh.batch import MeshBatch


@dataclass
class BatchGeometry:
    """Geometry of a batch scaled to unit area per mesh.

    points : [ΣV, 3] unit-area coordinates
    scale : [B] factor applied to each mesh's coordinates (1/sqrt(area))
    area : [B] original total area (input units^2)
    face_area : [ΣF] areas on the unit-area mesh
    normal : [ΣF, 3] unit normals (from the face orientation)
    cot : [ΣF, 3] cotangent of the corner at v_k (opposite edge k+1: v_{k+1} -> v_{k+2})
    angle : [ΣF, 3] corner angle at v_k (radians)
    grad_bary : [ΣF, 3, 3] gradient of barycentric coordinate l_k in the face
    """

    points: torch.Tensor
    scale: torch.Tensor
    area: torch.Tensor
    face_area: torch.Tensor
    normal: torch.Tensor
    cot: torch.Tensor
    angle: torch.Tensor
    grad_bary: torch.Tensor


def batch_geometry(batch: MeshBatch, dtype: torch.dtype | None = None) -> BatchGeometry:
    """Compute :class:`BatchGeometry`; ``dtype`` defaults to the batch's."""
    dtype = dtype or batch.dtype
    verts = batch.verts.to(dtype)
    f = batch.faces
    p = verts[f]                                             # [F, 3, 3]
    cross = torch.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], dim=1)
    raw_area = 0.5 * torch.linalg.norm(cross, dim=1)
    area = torch.zeros(len(batch), dtype=dtype, device=verts.device)
    area.index_add_(0, batch.face_to_mesh, raw_area)
    scale = area.rsqrt()
    points = verts * scale[batch.vert_to_mesh, None]
    p = points[f]
    face_area = raw_area * (scale ** 2)[batch.face_to_mesh]
    normal = cross / torch.linalg.norm(cross, dim=1, keepdim=True)
    # Corner k: edges to the next two vertices.
    a = p.roll(-1, dims=1) - p                               # v_k -> v_{k+1}
    b = p.roll(-2, dims=1) - p                               # v_k -> v_{k+2}
    dot = (a * b).sum(-1)
    twice_area = (2 * face_area)[:, None]
    cot = dot / twice_area
    angle = torch.atan2(twice_area.expand_as(dot), dot)
    # grad l_k = N x (p_{k+2} - p_{k+1}) / (2A): perpendicular to the opposite edge, pointing at v_k.
    opp = p.roll(-2, dims=1) - p.roll(-1, dims=1)
    grad = torch.cross(normal[:, None, :].expand_as(opp), opp, dim=2) / twice_area[..., None]
    return BatchGeometry(points=points, scale=scale, area=area, face_area=face_area,
                         normal=normal, cot=cot, angle=angle, grad_bary=grad)

