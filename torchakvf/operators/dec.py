"""Discrete exterior calculus operators over a packed batch, as block-diagonal torch sparse matrices.

Conventions (docs/akvf_operator.md, Sec. 2.1): edge e = (i, j), i < j, oriented i -> j;
a 1-form is one value per edge, w_e = integral of w along e. Diagonal Hodge stars are returned
as vectors. All quantities are on unit-area meshes (see :mod:`.geometry`).
"""
from __future__ import annotations

import math
import warnings

import numpy as np
import scipy.sparse as sp
import torch

from ..mesh.batch import MeshBatch
from .geometry import BatchGeometry


def sparse_coo(rows, cols, vals, shape) -> torch.Tensor:
    """Coalesced sparse COO matrix (duplicates summed).

    On CPU the duplicates are summed by scipy (a counting sort by row, then each short row
    sorted): 3x faster than torch's coalesce (a global sort of the keys) on the Killing
    operator's ~10⁶ entries, the same entries up to the order of the sums' round-off."""
    rows, cols, vals = rows.reshape(-1), cols.reshape(-1), vals.reshape(-1)
    if rows.device.type == "cpu":
        mat = sp.coo_matrix((vals.numpy(), (rows.numpy(), cols.numpy())), shape=shape).tocsr()
        mat.sum_duplicates()
        return csr_to_coo(mat, vals.dtype)
    idx = torch.stack([rows, cols])
    return torch.sparse_coo_tensor(idx, vals, shape, check_invariants=False).coalesce()


def csr_to_coo(mat: "sp.csr_matrix", dtype=torch.float64) -> torch.Tensor:
    """A torch COO tensor (flagged coalesced) from a scipy CSR matrix in canonical format
    (sorted, no duplicates)."""
    n_rows = mat.shape[0]
    row = np.repeat(np.arange(n_rows, dtype=np.int64), np.diff(mat.indptr))
    idx = torch.from_numpy(np.stack([row, mat.indices.astype(np.int64)]))
    return torch.sparse_coo_tensor(idx, torch.from_numpy(mat.data).to(dtype), mat.shape,
                                   is_coalesced=True, check_invariants=False)


def weighted_gram(dmat: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Dᵀ diag(weights) D as a coalesced COO tensor, for a coalesced COO D [m, n] and
    weights [m] (scipy's sparse product on CPU, torch's elsewhere)."""
    if dmat.device.type == "cpu":
        idx = dmat.indices().numpy()
        d = sp.csr_matrix((dmat.values().numpy(), (idx[0], idx[1])), shape=dmat.shape)
        gram = (d.T.tocsr() @ sp.diags(weights.numpy()) @ d).tocsr()
        gram.sum_duplicates()
        gram.sort_indices()
        return csr_to_coo(gram, dmat.dtype)
    scaled = torch.sparse_coo_tensor(dmat.indices(), dmat.values() * weights[dmat.indices()[0]],
                                     dmat.shape, check_invariants=False).coalesce()
    with warnings.catch_warnings():
        # torch routes sparse @ sparse through its (beta-flagged) CSR kernels.
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return torch.sparse.mm(dmat.t().coalesce(), scaled).coalesce()


def d0(batch: MeshBatch, dtype=torch.float64) -> torch.Tensor:
    """Exterior derivative on 0-forms, sparse [ΣE, ΣV]: (d0 f)_e = f_j - f_i."""
    e = batch.edges
    n_e, n_v = len(e), len(batch.verts)
    rows = torch.arange(n_e, device=e.device).repeat_interleave(2)
    vals = torch.tensor([-1.0, 1.0], dtype=dtype, device=e.device).repeat(n_e)
    return sparse_coo(rows, e.reshape(-1), vals, (n_e, n_v))


def d1(batch: MeshBatch, dtype=torch.float64) -> torch.Tensor:
    """Exterior derivative on 1-forms, sparse [ΣF, ΣE]: signed sum around each ccw face."""
    n_f = len(batch.faces)
    rows = torch.arange(n_f, device=batch.faces.device).repeat_interleave(3)
    return sparse_coo(rows, batch.face_edges, batch.face_edge_sign.to(dtype), (n_f, len(batch.edges)))


def edge_face_count(batch: MeshBatch) -> torch.Tensor:
    """[ΣE] number of faces at each edge (1 on a boundary, 2 inside)."""
    return torch.bincount(batch.face_edges.reshape(-1), minlength=len(batch.edges))


def boundary_vertex_mask(batch: MeshBatch) -> torch.Tensor:
    """[ΣV] bool, True on vertices of boundary edges."""
    mask = torch.zeros(len(batch.verts), dtype=torch.bool, device=batch.verts.device)
    mask[batch.edges[edge_face_count(batch) == 1].reshape(-1)] = True
    return mask


def star0(batch: MeshBatch, geo: BatchGeometry) -> torch.Tensor:
    """[ΣV] barycentric vertex areas A_v (a third of each adjacent face's area)."""
    out = geo.face_area.new_zeros(len(batch.verts))
    out.index_add_(0, batch.faces.reshape(-1), (geo.face_area / 3).repeat_interleave(3))
    return out


def star1(batch: MeshBatch, geo: BatchGeometry) -> torch.Tensor:
    """[ΣE] cotangent weights (cot a + cot b) / 2; one cotangent on boundary edges.

    Can be zero or negative on obtuse triangles (see :func:`..killing.killing_operator`'s remedy).
    """
    out = geo.cot.new_zeros(len(batch.edges))
    # Edge k of a face (v_k -> v_{k+1}) is opposite the corner at v_{k+2}.
    out.index_add_(0, batch.face_edges.reshape(-1), 0.5 * geo.cot.roll(-2, dims=1).reshape(-1))
    return out


def star2(geo: BatchGeometry) -> torch.Tensor:
    """[ΣF] 1 / A_f."""
    return 1.0 / geo.face_area


def angle_sum(batch: MeshBatch, geo: BatchGeometry) -> torch.Tensor:
    """[ΣV] sum of the corner angles at each vertex."""
    out = geo.angle.new_zeros(len(batch.verts))
    out.index_add_(0, batch.faces.reshape(-1), geo.angle.reshape(-1))
    return out


def angle_defect(batch: MeshBatch, geo: BatchGeometry) -> torch.Tensor:
    """[ΣV] 2 pi - angle sum at interior vertices, 0 on boundary vertices.

    The boundary's pi - angle sum is geodesic turning and belongs to the boundary term.
    """
    theta = 2 * math.pi - angle_sum(batch, geo)
    return torch.where(boundary_vertex_mask(batch), torch.zeros_like(theta), theta)
