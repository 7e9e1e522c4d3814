"""Smooth part boundaries from isolines of feature distances.

Vertex features are area-weighted averages of the adjacent faces' features; each vertex gets
its cosine distance d(C_i, φ) to every cluster center. Between two parts i and j the boundary
is the zero isoline of g_ij = d(C_i, φ) - d(C_j, φ), linear inside each face.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh.batch import mesh_edges
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


def barycenter_values(faces: np.ndarray, vdist: np.ndarray) -> np.ndarray:
    """[F, k] mean of the corners' rows of ``vdist`` [V, k] per face: bitwise
    ``vdist[faces].mean(axis=1)`` ((a + b) + c) / 3, without the [F, 3, k] gather."""
    out = vdist[faces[:, 0]]
    out += vdist[faces[:, 1]]
    out += vdist[faces[:, 2]]
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

    Cut points sit on edges, shared by both faces of an edge, so the refined mesh stays
    watertight. A face with two parts is cut by a straight segment; one with three parts is
    split around its barycenter.
    """
    vlab = vdist.argmin(axis=1)
    edges, face_edges, _ = mesh_edges(faces)
    i, j = edges[:, 0], edges[:, 1]
    cut = vlab[i] != vlab[j]
    # Zero of g = d_a - d_b along the edge, a = label(i), b = label(j).
    gi = vdist[i, vlab[i]] - vdist[i, vlab[j]]
    gj = vdist[j, vlab[i]] - vdist[j, vlab[j]]
    t = np.clip(np.where(cut, gi / np.where(cut, gi - gj, 1.0), 0.5), 0.0, 1.0)
    new_points = vertices[i[cut]] * (1 - t[cut, None]) + vertices[j[cut]] * t[cut, None]
    point_of_edge = np.full(len(edges), -1)
    point_of_edge[cut] = len(vertices) + np.arange(int(cut.sum()))
    verts = [vertices, new_points]
    n_verts = len(vertices) + len(new_points)

    out_f, out_l, out_p = [], [], []
    flab = vlab[faces]
    uniform = (flab[:, 0] == flab[:, 1]) & (flab[:, 1] == flab[:, 2])
    out_f.append(faces[uniform]), out_l.append(flab[uniform, 0]), out_p.append(np.flatnonzero(uniform))
    centroids = []
    for f in np.flatnonzero(~uniform):
        v = faces[f]
        lab = flab[f]
        m = point_of_edge[face_edges[f]]                 # cut point on edge k (v_k -> v_k+1) or -1
        if len(set(lab.tolist())) == 2:
            # The lone corner k is the one whose two edges are both cut.
            k = int(np.flatnonzero((m >= 0) & (np.roll(m, 1) >= 0))[0])
            a, b, c = v[k], v[(k + 1) % 3], v[(k + 2) % 3]
            mab, mca = m[k], m[(k + 2) % 3]
            tris = [(a, mab, mca), (mab, b, c), (mab, c, mca)]
            labs = [lab[k], lab[(k + 1) % 3], lab[(k + 1) % 3]]
        else:
            centre = n_verts + len(centroids)
            centroids.append(vertices[v].mean(axis=0))
            tris, labs = [], []
            for k in range(3):
                tris += [(v[k], m[k], centre), (v[k], centre, m[(k + 2) % 3])]
                labs += [lab[k], lab[k]]
        out_f.append(np.array(tris)), out_l.append(np.array(labs)), out_p.append(np.full(len(tris), f))
    if centroids:
        verts.append(np.array(centroids))
    return RefinedMesh(vertices=np.concatenate(verts), faces=np.concatenate(out_f).astype(np.int64),
                       labels=np.concatenate(out_l).astype(np.int64),
                       parent=np.concatenate(out_p).astype(np.int64))
