"""pytorch3d ``Meshes`` <-> :class:`~torchakvf.MeshBatch`.

``from_pytorch3d`` reads any object with ``verts_list()`` and ``faces_list()`` (pytorch3d's
documented accessors); ``to_pytorch3d`` needs pytorch3d (``pip install torchakvf[pytorch3d]``;
pytorch3d ships wheels for few torch/CUDA pairs, see its INSTALL.md).
"""
from __future__ import annotations

import torch

from ..errors import ParameterError


def from_pytorch3d(meshes, *, coarse_faces: int | None = None, dtype: torch.dtype = torch.float64):
    """A :class:`~torchakvf.MeshBatch` of the meshes of a pytorch3d ``Meshes``, on its device.

    Each mesh is cleaned as :meth:`MeshBatch.from_meshes` does (duplicate vertices merged,
    degenerate faces dropped; the batch's ``meshes[b].to_input_faces`` maps results back to
    the faces as given). ``coarse_faces``: decimate larger meshes first; ``dtype`` of the
    coordinates (the solves are float64 whatever it is).
    """
    from ..mesh import Mesh, MeshBatch

    verts, faces = meshes.verts_list(), meshes.faces_list()
    if len(verts) == 0:
        raise ParameterError("from_pytorch3d: the Meshes object holds no mesh")
    device = verts[0].device
    items = [Mesh(v.detach().cpu().double().numpy(), f.detach().cpu().long().numpy(),
                  name=f"<pytorch3d mesh {b}>") for b, (v, f) in enumerate(zip(verts, faces))]
    return MeshBatch.from_meshes(items, device=device, dtype=dtype, coarse_faces=coarse_faces)


def to_pytorch3d(batch, *, dtype: torch.dtype | None = None):
    """A pytorch3d ``Meshes`` of the (cleaned, possibly decimated) meshes packed in ``batch``:
    ``Meshes(verts=[V_b, 3] list, faces=[F_b, 3] list)`` with per-mesh vertex indices, on the
    batch's device, coordinates in ``dtype`` (default: the batch's)."""
    from pytorch3d.structures import Meshes

    dtype = batch.dtype if dtype is None else dtype
    verts, faces = [], []
    for b in range(len(batch)):
        v0, v1 = int(batch.vert_ptr[b]), int(batch.vert_ptr[b + 1])
        f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
        verts.append(batch.verts[v0:v1].to(dtype))
        faces.append(batch.faces[f0:f1] - v0)
    return Meshes(verts=verts, faces=faces)


__all__ = ["from_pytorch3d", "to_pytorch3d"]
