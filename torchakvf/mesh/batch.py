"""Many meshes packed into one set of tensors (pytorch3d's packed layout, PyG's vocabulary).

Packed tensors hold every mesh's rows one after another with *global* indices: ``faces`` of
mesh b are shifted by ``vert_ptr[b]``. ``(B+1,)`` offset vectors ``vert_ptr``, ``face_ptr``,
``edge_ptr`` delimit the meshes, and ``*_to_mesh`` vectors give each row's mesh, so
``index_add_``/segment reductions work directly on the batch. Per-mesh dense work uses padded
views from :func:`pad_packed`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from ..devices import resolve_device
from ..errors import MeshError, ParameterError
from .clean import CleanMesh, clean_mesh, undirected_edges
from .coarse import CoarseMesh, coarse_mesh
from .mesh import Mesh

log = logging.getLogger("torchakvf.mesh")


def owner_index(ptr: torch.Tensor) -> torch.Tensor:
    """[ΣN] index of the mesh owning each packed row, from offsets ``ptr`` [B+1]
    (``owner_index(batch.face_ptr)`` is ``batch.face_to_mesh``)."""
    return torch.repeat_interleave(torch.arange(len(ptr) - 1, device=ptr.device), ptr[1:] - ptr[:-1])


def mesh_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Undirected edges of a triangle mesh and each face's edges.

    Returns
    -------
    edges : [E, 2] int64, (i, j) with i < j, sorted lexicographically; edge e is oriented i -> j
    face_edges : [F, 3] int64, edge k of face (v0, v1, v2) joins v_k -> v_{k+1}
    face_edge_sign : [F, 3] float64, +1 where v_k -> v_{k+1} agrees with the edge's orientation
    """
    table = undirected_edges(faces)     # half-edge k of face f is row 3f + k
    sign = np.where(faces < np.roll(faces, -1, axis=1), 1.0, -1.0)
    return table.unique, table.inverse.reshape(-1, 3), sign


@dataclass
class MeshBatch:
    """B cleaned meshes as packed tensors on one device.

    Attributes
    ----------
    verts : [ΣV, 3] float, coordinates as given (units of the input)
    faces : [ΣF, 3] int64, global vertex indices, consistently oriented
    edges : [ΣE, 2] int64, global vertex indices, i < j within each mesh, oriented i -> j
    face_edges : [ΣF, 3] int64, global edge index of edge v_k -> v_{k+1} of each face
    face_edge_sign : [ΣF, 3] float, +1/-1: that half-edge's direction relative to its edge
    vert_ptr, face_ptr, edge_ptr : [B+1] int64 offsets
    meshes : list of the B :class:`CleanMesh` that were packed (host-side maps back to the
        input faces)
    coarse : list of B entries, the :class:`~torchakvf.mesh.coarse.CoarseMesh` mesh b was
        decimated from (its results belong to ``coarse[b].fine``) or None where mesh b is the
        input at full resolution; empty when the batch was built without ``coarse_faces``
    """

    verts: torch.Tensor
    faces: torch.Tensor
    edges: torch.Tensor
    face_edges: torch.Tensor
    face_edge_sign: torch.Tensor
    vert_ptr: torch.Tensor
    face_ptr: torch.Tensor
    edge_ptr: torch.Tensor
    meshes: list
    coarse: list = field(default_factory=list)

    @classmethod
    def from_meshes(cls, meshes: Sequence[Mesh | CleanMesh] | Mesh | CleanMesh,
                    device: str | torch.device = "cpu",
                    dtype: torch.dtype = torch.float64,
                    coarse_faces: int | None = None) -> "MeshBatch":
        """Clean (if needed) and pack meshes. ``dtype`` is the coordinates' float type.

        coarse_faces : if given, each mesh with more than 1.25x this many faces is decimated to
            about this many (:func:`~torchakvf.mesh.coarse.coarse_mesh`) and the coarse mesh is
            packed; :func:`~torchakvf.parts.segment` then reports its results on the original
            faces. A mesh whose decimation fails is packed at full resolution (logged).
        """
        if isinstance(meshes, (Mesh, CleanMesh)):
            meshes = [meshes]
        meshes = [m if isinstance(m, CleanMesh) else clean_mesh(m) for m in meshes]
        if not meshes:
            raise ParameterError("MeshBatch.from_meshes needs at least one mesh")
        coarse = []
        if coarse_faces is not None:
            coarse = [coarse_or_none(m, coarse_faces) for m in meshes]
            meshes = [m if c is None else c.coarse for m, c in zip(meshes, coarse)]
        if dtype not in (torch.float32, torch.float64):
            raise ParameterError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        verts, faces, edges, fe, fs = [], [], [], [], []
        nv = nf = ne = 0
        vptr, fptr, eptr = [0], [0], [0]
        for m in meshes:
            e, f_e, f_s = mesh_edges(m.faces)
            verts.append(m.vertices)
            faces.append(m.faces + nv)
            edges.append(e + nv)
            fe.append(f_e + ne)
            fs.append(f_s)
            nv, nf, ne = nv + len(m.vertices), nf + len(m.faces), ne + len(e)
            vptr.append(nv), fptr.append(nf), eptr.append(ne)
        dev = resolve_device(device)   # one ParameterError for a device this machine lacks
        t = lambda a, dt: torch.as_tensor(np.concatenate(a), dtype=dt, device=dev)  # noqa: E731
        return cls(verts=t(verts, dtype), faces=t(faces, torch.int64), edges=t(edges, torch.int64),
                   face_edges=t(fe, torch.int64), face_edge_sign=t(fs, dtype),
                   vert_ptr=torch.tensor(vptr, device=dev), face_ptr=torch.tensor(fptr, device=dev),
                   edge_ptr=torch.tensor(eptr, device=dev), meshes=list(meshes), coarse=coarse)

    # ---- sizes and index maps ------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.meshes)

    @property
    def device(self) -> torch.device:
        return self.verts.device

    @property
    def dtype(self) -> torch.dtype:
        return self.verts.dtype

    @property
    def names(self) -> list[str]:
        return [m.name for m in self.meshes]

    @property
    def vert_to_mesh(self) -> torch.Tensor:
        """[ΣV] mesh index of each packed vertex."""
        return owner_index(self.vert_ptr)

    @property
    def face_to_mesh(self) -> torch.Tensor:
        """[ΣF] mesh index of each packed face."""
        return owner_index(self.face_ptr)

    @property
    def edge_to_mesh(self) -> torch.Tensor:
        """[ΣE] mesh index of each packed edge."""
        return owner_index(self.edge_ptr)

    _FLOAT_FIELDS = ("verts", "face_edge_sign")
    _INDEX_FIELDS = ("faces", "edges", "face_edges", "vert_ptr", "face_ptr", "edge_ptr")

    def to(self, device=None, dtype: torch.dtype | None = None) -> "MeshBatch":
        """The same batch on another device and/or with another float type, like
        ``Tensor.to``: ``batch.to("cuda")``, ``batch.to(torch.float32)``,
        ``batch.to("cuda", torch.float32)``. Index tensors stay int64 (only the coordinates and
        the half-edge signs take ``dtype``)."""
        if isinstance(device, torch.dtype):
            device, dtype = None, device
        if dtype is not None and dtype not in (torch.float32, torch.float64):
            raise ParameterError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        if device is not None:
            device = resolve_device(device)
        mv = {k: getattr(self, k).to(device=device, dtype=dtype) for k in self._FLOAT_FIELDS}
        mv.update({k: getattr(self, k).to(device=device) for k in self._INDEX_FIELDS})
        return MeshBatch(meshes=self.meshes, coarse=self.coarse, **mv)

    def coarse_of(self, b: int) -> CoarseMesh | None:
        """The :class:`CoarseMesh` behind mesh b, or None when mesh b is at full resolution."""
        return self.coarse[b] if self.coarse else None

    def at_full_resolution(self, indices) -> "MeshBatch":
        """The same batch with meshes ``indices`` packed at full resolution instead of decimated."""
        full = set(int(i) for i in indices)
        meshes = [self.input_mesh(b) if b in full else m for b, m in enumerate(self.meshes)]
        out = MeshBatch.from_meshes(meshes, device=self.device, dtype=self.dtype)
        out.coarse = [None if b in full else c for b, c in enumerate(self.coarse)] if self.coarse else []
        return out

    def input_mesh(self, b: int) -> CleanMesh:
        """The cleaned mesh whose input faces mesh b's results are reported on (the
        full-resolution mesh when b was decimated)."""
        c = self.coarse_of(b)
        return self.meshes[b] if c is None else c.fine

    def to_input_faces(self, b: int, values: np.ndarray) -> np.ndarray:
        """[F_input, ...] per-face ``values`` [F_b, ...] of packed mesh b on its input file's
        faces: on a decimated mesh, those of the coarse face under each input face's
        barycenter; 0 on faces dropped as degenerate."""
        coarse = self.coarse_of(b)
        if coarse is not None:
            values = coarse.face_values(values)
        return self.input_mesh(b).to_input_faces(values)

    def mesh(self, b: int) -> "MeshBatch":
        """Mesh b as a batch of its own (slices of this batch's tensors, local indices): the
        batch :meth:`from_meshes` makes of that mesh alone."""
        v0, v1 = int(self.vert_ptr[b]), int(self.vert_ptr[b + 1])
        f0, f1 = int(self.face_ptr[b]), int(self.face_ptr[b + 1])
        e0, e1 = int(self.edge_ptr[b]), int(self.edge_ptr[b + 1])
        ptr = lambda n: torch.tensor([0, n], device=self.device)  # noqa: E731
        return MeshBatch(verts=self.verts[v0:v1], faces=self.faces[f0:f1] - v0, edges=self.edges[e0:e1] - v0,
                         face_edges=self.face_edges[f0:f1] - e0, face_edge_sign=self.face_edge_sign[f0:f1],
                         vert_ptr=ptr(v1 - v0), face_ptr=ptr(f1 - f0), edge_ptr=ptr(e1 - e0),
                         meshes=[self.meshes[b]], coarse=[self.coarse[b]] if self.coarse else [])

    def split(self, packed: torch.Tensor, ptr: torch.Tensor) -> list[torch.Tensor]:
        """Split a packed tensor into per-mesh pieces along dim 0 using offsets ``ptr``."""
        sizes = (ptr[1:] - ptr[:-1]).tolist()
        return list(torch.split(packed, sizes, dim=0))


def coarse_or_none(mesh: CleanMesh, faces: int | None) -> CoarseMesh | None:
    """The decimation of ``mesh`` to about ``faces`` faces that :meth:`MeshBatch.from_meshes`
    solves on (None: none asked, the mesh is small enough, or decimation failed)."""
    if faces is None:
        return None
    try:
        return coarse_mesh(mesh, faces)
    except MeshError as exc:
        # The decimated surface is unusable (e.g. collapses made it non-orientable): the full
        # mesh is still a correct input, only slower.
        log.warning("%s: solving at full resolution, decimation to %d faces failed: %s",
                    mesh.name, faces, exc.problem)
        return None


def pad_packed(x: torch.Tensor, ptr: torch.Tensor, fill: float = 0.0
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Padded view of a packed tensor.

    x : [ΣN, ...] packed rows; ptr : [B+1] offsets.
    Returns ``padded`` [B, N_max, ...] (``fill`` in the padding) and ``mask`` [B, N_max] bool.
    """
    counts = ptr[1:] - ptr[:-1]
    b = len(counts)
    n_max = int(counts.max()) if b else 0
    owner = owner_index(ptr.to(x.device))
    pos = torch.arange(x.shape[0], device=x.device) - ptr[:-1][owner]
    padded = x.new_full((b, n_max) + tuple(x.shape[1:]), fill)
    padded[owner, pos] = x
    mask = torch.zeros(b, n_max, dtype=torch.bool, device=x.device)
    mask[owner, pos] = True
    return padded, mask
