"""Smooth part boundaries from isolines of feature distances.

Vertex features are area-weighted averages of the adjacent faces' features; each vertex gets
its cosine distance d(C_i, φ) to every cluster center. Between two parts i and j the boundary
is the zero isoline of g_ij = d(C_i, φ) - d(C_j, φ), linear inside each face.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .grouping import group_sums


def vertex_distances(vertices: np.ndarray, faces: np.ndarray, face_features: np.ndarray,
                     face_area: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """[V, k] cosine distance of each vertex's averaged feature to each (unit) center.

    face_features : [F, d]; face_area : [F]; centers : [k, d] unit vectors.
    """
    unit = face_features / np.maximum(np.linalg.norm(face_features, axis=1, keepdims=True), 1e-300)
    acc = group_sums(faces.reshape(-1), np.repeat(unit * face_area[:, None], 3, axis=0), len(vertices))
    acc /= np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)
    return 1.0 - acc @ centers.T


#: Faces per block of :func:`barycenter_values` times its k: a block's sum and gather buffer
#: (2 x 512 KiB) stay in cache, where [F, k] gathers of the whole mesh go through memory.
_BARYCENTER_BLOCK_VALUES = 2 ** 16


def barycenter_values(faces: np.ndarray, vdist: np.ndarray) -> np.ndarray:
    """[F, k] mean of the corners' rows of ``vdist`` [V, k] (or [V]) per face: bitwise
    ``vdist[faces].mean(axis=1)`` ((a + b) + c) / 3, without the [F, 3, k] gather, by blocks of
    faces (same sums, ~2x faster than whole-mesh gathers at k >= 15 on 50k faces)."""
    n_faces, row = len(faces), vdist.shape[1:]
    out = np.empty((n_faces,) + row, dtype=vdist.dtype)
    block = max(256, _BARYCENTER_BLOCK_VALUES // max(int(np.prod(row)), 1))
    corner = np.empty((min(block, n_faces),) + row, dtype=vdist.dtype)
    for s in range(0, n_faces, block):
        e = min(s + block, n_faces)
        o, c = out[s:e], corner[:e - s]
        np.take(vdist, faces[s:e, 0], axis=0, out=o)
        np.take(vdist, faces[s:e, 1], axis=0, out=c)
        o += c
        np.take(vdist, faces[s:e, 2], axis=0, out=c)
        o += c
    out /= 3.0
    return out


def isoline_face_labels(faces: np.ndarray, vdist: np.ndarray) -> np.ndarray:
    """[F] label of the part whose isoline region holds each face's barycenter.

    g_ij is linear in a face, so its value at the barycenter is the mean of the corners'.
    """
    return barycenter_values(faces, vdist).argmin(axis=1)


def face_margins(faces: np.ndarray, vdist: np.ndarray) -> np.ndarray:
    """[F] at each barycenter, g between the second-closest and the closest part (>= 0)."""
    d = np.sort(barycenter_values(faces, vdist), axis=1)
    return d[:, 1] - d[:, 0] if d.shape[1] > 1 else np.full(len(faces), np.inf)


@dataclass
class RefinedMesh:
    """The mesh cut along the part boundaries.

    vertices : [V', 3] (the input vertices first, then the cut points)
    faces : [F', 3]; labels : [F'] part of each new face; parent : [F'] face it was cut from
    """

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray
    parent: np.ndarray


def refine_along_isolines(vertices: np.ndarray, faces: np.ndarray, vdist: np.ndarray) -> RefinedMesh:
    """Cut every face whose corners belong to different parts along the isolines g_ij = 0.

    vertices : [V, 3]; faces : [F, 3]; vdist : [V, k] distance of each vertex to each part
    (:func:`vertex_distances`); a vertex belongs to its closest part.

    Cut points sit on edges, shared by both faces of an edge, so the refined mesh stays
    watertight. A face with two parts is cut by a straight segment; one with three parts is
    split around its barycenter. Row order: the uniform faces first (in face order), then the
    triangles of each cut face in face order (3 for two parts, 6 for three); vertices: the
    input's, then one cut point per cut edge (edges in (i, j), i < j, lexicographic order),
    then the barycenters of the three-part faces in face order.
    """
    vlab = vdist.argmin(axis=1)
    flab = vlab[faces]                                   # [F, 3] part of each corner
    uniform = (flab[:, 0] == flab[:, 1]) & (flab[:, 1] == flab[:, 2])
    cut_faces = np.flatnonzero(~uniform)
    v, lab = faces[cut_faces], flab[cut_faces]           # [C, 3]
    # Half-edge k of a face joins v_k -> v_{k+1}; it is cut where its ends' parts differ. Only
    # cut edges get a point, so the edge numbering is that of the cut edges alone (sorted like
    # every edge of the mesh would be, lexicographically by (i, j), i < j).
    head = np.roll(v, -1, axis=1)
    half_cut = lab != np.roll(lab, -1, axis=1)           # [C, 3]
    lo, hi = np.minimum(v, head)[half_cut], np.maximum(v, head)[half_cut]
    n = int(faces.max()) + 1 if len(faces) else 1
    ukey, point = np.unique(lo.astype(np.int64) * n + hi, return_inverse=True)
    i, j = ukey // n, ukey % n
    # Zero of g = d_a - d_b along the edge, a = label(i), b = label(j).
    gi = vdist[i, vlab[i]] - vdist[i, vlab[j]]
    gj = vdist[j, vlab[i]] - vdist[j, vlab[j]]
    t = np.clip(gi / (gi - gj), 0.0, 1.0)
    new_points = vertices[i] * (1 - t[:, None]) + vertices[j] * t[:, None]
    n_verts = len(vertices) + len(new_points)
    m = np.full(v.shape, -1, dtype=np.int64)             # cut point on half-edge k, or -1
    m[half_cut] = len(vertices) + point.reshape(-1)

    three = (lab[:, 0] != lab[:, 1]) & (lab[:, 1] != lab[:, 2]) & (lab[:, 0] != lab[:, 2])
    n_tris = np.where(three, 6, 3)
    n_uniform = len(faces) - len(cut_faces)
    first = n_uniform + np.cumsum(n_tris) - n_tris       # first output row of each cut face
    n_out = n_uniform + int(n_tris.sum())
    out_f = np.empty((n_out, 3), dtype=np.int64)
    out_l = np.empty(n_out, dtype=np.int64)
    out_f[:n_uniform], out_l[:n_uniform] = faces[uniform], flab[uniform, 0]
    parent = np.concatenate([np.flatnonzero(uniform), np.repeat(cut_faces, n_tris)])

    # Two parts: the lone corner k is the one whose two edges (k and k - 1) are both cut.
    two = np.flatnonzero(~three)
    k = np.argmax(half_cut[two] & np.roll(half_cut[two], 1, axis=1), axis=1)
    k1, k2 = (k + 1) % 3, (k + 2) % 3
    a, b, c = v[two, k], v[two, k1], v[two, k2]
    mab, mca = m[two, k], m[two, k2]
    rows = first[two][:, None] + np.arange(3)
    out_f[rows] = np.stack([np.stack([a, mab, mca], 1), np.stack([mab, b, c], 1),
                            np.stack([mab, c, mca], 1)], axis=1)
    out_l[rows] = np.stack([lab[two, k], lab[two, k1], lab[two, k1]], axis=1)

    # Three parts: two triangles per corner around the face's barycenter.
    tri = np.flatnonzero(three)
    centre = n_verts + np.arange(len(tri))
    vt, mt, lt = v[tri], m[tri], lab[tri]
    rows = first[tri][:, None] + np.arange(6)
    out_f[rows] = np.stack([np.stack(pair, 1) for kk in range(3) for pair in
                            ((vt[:, kk], mt[:, kk], centre), (vt[:, kk], centre, mt[:, (kk + 2) % 3]))], axis=1)
    out_l[rows] = np.repeat(lt, 2, axis=1)
    verts = [vertices, new_points]
    if len(tri):
        verts.append(vertices[vt].mean(axis=1))
    return RefinedMesh(vertices=np.concatenate(verts), faces=out_f, labels=out_l, parent=parent.astype(np.int64))
