"""Triangle meshes of the zero set of a signed distance function (:mod:`.sdf`): marching
tetrahedra or marching cubes on a grid, and tangential relaxation back onto the surface.

Marching tetrahedra (numpy) (six per grid cube, split the same way in every cube, so the
surface is conforming) gives the zero set of the piecewise-linear interpolant of the sampled
distance: a closed manifold wherever no sample is exactly zero, each vertex on one grid edge.
Its raw triangles are poorly shaped (slivers where the surface passes near a grid point);
:func:`relax_onto` evens them out while keeping every vertex on the surface.
"""
from __future__ import annotations

import numpy as np

# The 6 tetrahedra of a cube around its diagonal 0-6 (corner c has offset bits x=c&1...,
# numbered as below); every cube splits the same way, so shared faces match (conforming).
_CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                     [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
_TETS = np.array([[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]])


def _crossing_cells(inside: np.ndarray) -> np.ndarray:
    """[C, 3] grid indices (C order) of the cubes with corners on both sides of the surface:
    the only cubes with a tetrahedron that the surface crosses (every corner is in a
    tetrahedron with corners 0 and 6), so skipping the others changes nothing."""
    sl = [(slice(0, -1), slice(1, None))[c] for c in range(2)]
    views = [inside[sl[i], sl[j], sl[k]] for i, j, k in _CORNERS]
    any_in, all_in = np.logical_or.reduce(views), np.logical_and.reduce(views)
    return np.argwhere(any_in & ~all_in)


def marching_tetrahedra(sdf, lo, hi, h: float, clamp: float = 0.0,
                        orient: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The zero set of ``sdf`` (vectorized [N, 3] -> [N], negative inside) on a grid of step h
    over the box [lo, hi]: (vertices [V, 3], faces [F, 3]).

    clamp : keep each vertex at least this fraction of its grid edge away from the edge's ends
        (0: the exact linear crossing). With clamp > 0 no triangle degenerates: each has its
        corners on three distinct edges of one tetrahedron, clamp away from their shared ends.
    orient : turn each face outward, its normal toward the tetrahedron's outside corners
        (consistent by construction); otherwise faces are not yet oriented.
    """
    axes = [np.arange(a, b + h, h) for a, b in zip(lo, hi)]
    n = np.array([len(a) for a in axes])
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    val = sdf(pts)
    val[val == 0] = 1e-12          # no surface vertex on a grid point: no zero-length edges
    cells = _crossing_cells((val < 0).reshape(tuple(n)))
    corner = np.ravel_multi_index((cells[:, None, :] + _CORNERS[None]).transpose(2, 0, 1), tuple(n))
    tets = corner[:, _TETS].reshape(-1, 4)
    inside = val[tets] < 0
    count = inside.sum(1)
    crossed = (count > 0) & (count < 4)
    tets, inside, count = tets[crossed], inside[crossed], count[crossed]
    tris, outward = [], []
    # One corner apart (1 or 3 inside): a triangle on its three edges.
    one = (count == 1) | (count == 3)
    t1, in1 = tets[one], inside[one]
    odd = np.where((count[one] == 1)[:, None], in1, ~in1)
    apex = np.argmax(odd, axis=1)
    others = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[apex]
    a = t1[np.arange(len(t1)), apex]
    rest = np.take_along_axis(t1, others, axis=1)
    tris.append(np.stack([np.stack([a, rest[:, i]], axis=1) for i in range(3)], axis=1))
    away = pts[rest].mean(1) - pts[a]                   # from an inside apex to the outside
    outward.append(np.where((count[one] == 1)[:, None], away, -away))
    # Two inside (p, q), two outside (r, s): the quad pr, ps, qs, qr as two triangles.
    t2, in2 = tets[count == 2], inside[count == 2]
    order = np.argsort(~in2, axis=1, kind="stable")
    p, q, r, s = np.take_along_axis(t2, order, axis=1).T
    pr, ps, qs, qr = (np.stack(e, axis=1) for e in ((p, r), (p, s), (q, s), (q, r)))
    tris.append(np.stack([pr, ps, qs], axis=1))
    tris.append(np.stack([pr, qs, qr], axis=1))
    out2 = pts[r] + pts[s] - pts[p] - pts[q]
    outward += [out2, out2]
    edges = np.concatenate(tris)                        # [T, 3, 2] grid-edge endpoints
    edges = np.sort(edges, axis=2)
    key = edges[..., 0] * len(pts) + edges[..., 1]
    ukey, inv = np.unique(key, return_inverse=True)
    i, j = ukey // len(pts), ukey % len(pts)
    t = val[i] / (val[i] - val[j])
    if clamp > 0:
        t = np.clip(t, clamp, 1.0 - clamp)
    vertices = pts[i] + t[:, None] * (pts[j] - pts[i])
    faces = inv.reshape(-1, 3)
    if orient:
        tri = vertices[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        flip = np.einsum("ij,ij->i", normal, np.concatenate(outward)) < 0
        faces = np.where(flip[:, None], faces[:, ::-1], faces)
    return vertices, faces


def marching_cubes(sdf, lo, hi, h: float, clamp: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The zero set of ``sdf`` (vectorized [N, 3] -> [N], negative inside) on a grid of step h
    over the box [lo, hi] by marching cubes (libigl's 256-case table): (vertices [V, 3],
    faces [F, 3] int64), closed and outward; about 3 triangles per h^2 of surface, a third of
    what marching tetrahedra makes.

    clamp : keep each vertex at least this fraction of its grid edge from the edge's ends (0:
        the linear crossing). Three points inside distinct edges of a cube are never collinear,
        so with clamp > 0 no triangle degenerates.
    """
    import igl
    axes = [np.arange(a, b + h, h) for a, b in zip(lo, hi)]
    n = [len(a) for a in axes]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")        # x fastest, as igl reads
    pts = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    val = np.ascontiguousarray(sdf(pts), dtype=np.float64)
    val[val == 0] = 1e-12          # no surface vertex on a grid point
    vertices, faces, edge_vertex = igl.marching_cubes(val, pts, n[0], n[1], n[2], 0.0)
    if clamp > 0 and len(edge_vertex):
        key = np.fromiter(edge_vertex.keys(), dtype=np.int64, count=len(edge_vertex))
        vid = np.fromiter(edge_vertex.values(), dtype=np.int64, count=len(edge_vertex))
        i, j = key & 0xFFFFFFFF, key >> 32
        t = np.clip(val[i] / (val[i] - val[j]), clamp, 1.0 - clamp)
        vertices = np.array(vertices)
        vertices[vid] = pts[i] + t[:, None] * (pts[j] - pts[i])
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def gradient(sdf, x: np.ndarray, d: float = 1e-5) -> np.ndarray:
    """Central differences of ``sdf`` at x [N, 3]: [N, 3]."""
    return np.stack([(sdf(x + d * e) - sdf(x - d * e)) / (2 * d) for e in np.eye(3)], axis=1)


def relax_onto(sdf, vertices: np.ndarray, faces: np.ndarray, iterations: int = 15) -> np.ndarray:
    """Tangential umbrella smoothing, each step projected back onto sdf = 0 (Newton)."""
    v = vertices.copy()
    nv = len(v)
    i = faces.reshape(-1)
    j = np.roll(faces, -1, axis=1).reshape(-1)
    deg = np.bincount(i, minlength=nv) + np.bincount(j, minlength=nv)
    for _ in range(iterations):
        acc = np.zeros_like(v)
        np.add.at(acc, i, v[j])
        np.add.at(acc, j, v[i])
        move = acc / deg[:, None] - v
        g = gradient(sdf, v)
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        move -= np.einsum("ij,ij->i", move, g)[:, None] * g
        v = v + 0.5 * move
        for _ in range(2):
            g = gradient(sdf, v)
            v = v - (sdf(v) / np.maximum(np.einsum("ij,ij->i", g, g), 1e-12))[:, None] * g
    return v


def _value_and_gradient(sdf, x: np.ndarray, d: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """sdf at x [N, 3] and its forward-difference gradient [N, 3], in one call of sdf."""
    n = len(x)
    out = sdf(np.concatenate([x, x + [d, 0, 0], x + [0, d, 0], x + [0, 0, d]]))
    val = out[:n]
    return val, (out[n:].reshape(3, n).T - val[:, None]) / d


#: Faces a relaxation step may not make: shape quality (see _face_measures) under this (a
#: needle: smallest angle under about 2.5 degrees) ...
MIN_QUALITY = 0.05
#: ... or an area under this fraction of the starting mean.
MIN_AREA = 0.005


def _face_measures(v: np.ndarray, faces: np.ndarray, g: np.ndarray):
    """Per face [F]: area, shape quality 4 sqrt(3) area / (sum of squared edges) (1 for an
    equilateral triangle) and the alignment of its normal with the surface's (the sum of its
    vertices' sdf gradients g [V, 3]; <= 0: folded)."""
    tri = v[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    squares = np.sum((tri - np.roll(tri, 1, axis=1)) ** 2, axis=(1, 2))
    return area, 4 * np.sqrt(3) * area / np.maximum(squares, 1e-300), np.einsum("ij,ij->i", cross, g[faces].sum(1))


def relax(sdf, vertices: np.ndarray, faces: np.ndarray, iterations: int = 15) -> np.ndarray:
    """:func:`relax_onto` at 1/5 of its cost, and safe: each step one Newton projection, the
    distance and its (forward-difference) gradient in one call of ``sdf``; a step moves each
    vertex half way to the mean of its neighbours within the surface's tangent plane, then
    back onto it. Where a step would fold a face (turn it against the surface's normal) or
    take its area or shape quality under MIN_AREA of the starting mean area or MIN_QUALITY
    (or under half its own starting value, for a face that starts below), its vertices keep
    their previous positions (at a thin part's rim, at a crease)."""
    import scipy.sparse as sp
    v = vertices.copy()
    nv = len(v)
    i = faces.reshape(-1)
    j = np.roll(faces, -1, axis=1).reshape(-1)
    ring = sp.coo_matrix((np.ones(2 * len(i)), (np.r_[i, j], np.r_[j, i])), shape=(nv, nv)).tocsr()
    ring = sp.diags(1.0 / np.asarray(ring.sum(1)).ravel()) @ ring
    val, g = _value_and_gradient(sdf, v)
    area, quality, align = _face_measures(v, faces, g)
    min_area = np.minimum(MIN_AREA * area.mean(), 0.5 * area)
    min_quality = np.minimum(MIN_QUALITY, 0.5 * quality)
    folded = align <= 0                          # a crease face may start so: left to itself

    def bad(x, gx):
        a, q, al = _face_measures(x, faces, gx)
        return (a < min_area) | (q < min_quality) | ((al <= 0) & ~folded)

    for _ in range(iterations):
        move = ring @ v - v
        n = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        move -= np.einsum("ij,ij->i", move, n)[:, None] * n
        new = v + 0.5 * move
        val, gn = _value_and_gradient(sdf, new)        # gn: the normal here and for the next step
        new = new - (val / np.maximum(np.einsum("ij,ij->i", gn, gn), 1e-12))[:, None] * gn
        for _ in range(3):
            b = bad(new, gn)
            if not b.any():
                break
            keep = np.unique(faces[b])
            new[keep], gn[keep] = v[keep], g[keep]
        else:
            if bad(new, gn).any():
                break               # the reverts spread: stop at the last good step
        v, g = new, gn
    return v


__all__ = ["marching_tetrahedra", "marching_cubes", "gradient", "relax_onto", "relax"]
