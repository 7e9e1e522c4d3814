"""Built-in shapes for failure modes of segmentation, closed, with ground-truth parts: a table and
a mug (k-means on untangled fields cuts flat regions into stripes and boundaries across smooth
surface), a four-legged animal and a fish (protrusions people mark as parts: legs, head, thin
fins).

numpy only. The table is the boundary of a union of voxels (exact flat boxes); the others are
marching-tetrahedra surfaces of a signed distance function (a smooth union of primitives, one
per part), relaxed tangentially and projected back onto the surface so that their triangles
are well shaped.
"""
from __future__ import annotations

import numpy as np

from .shape import Shape

# The 6 tetrahedra of a cube around its diagonal 0-6 (corner c has offset bits x=c&1...,
# numbered as below); every cube splits the same way, so shared faces match (conforming).
_CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                     [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
_TETS = np.array([[0, 1, 2, 6], [0, 2, 3, 6], [0, 3, 7, 6], [0, 7, 4, 6], [0, 4, 5, 6], [0, 5, 1, 6]])


def _voxel_surface(occupied: np.ndarray, h: float, origin) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boundary of a union of voxels: (vertices [V, 3], faces [F, 3] outward, voxel [F] flat
    index of the occupied voxel behind each face). Two triangles per boundary square."""
    occ = np.pad(occupied, 1)
    shape = np.array(occ.shape)
    quads, owner = [], []
    corner_id = lambda p: (p[..., 0] * (shape[1] + 1) + p[..., 1]) * (shape[2] + 1) + p[..., 2]
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        for step in (1, -1):
            nb = np.roll(occ, -step, axis=axis)
            cells = np.argwhere(occ & ~nb)
            base = cells.copy()
            if step == 1:
                base[:, axis] += 1
            du, dv = np.eye(3, dtype=int)[u], np.eye(3, dtype=int)[v]
            ring = np.stack([base, base + du, base + du + dv, base + dv], axis=1)
            # Counter-clockwise seen from outside: (u, v, axis) right-handed for step +1.
            right_handed = (np.cross(du, dv) @ np.eye(3, dtype=int)[axis]) > 0
            if right_handed != (step == 1):
                ring = ring[:, ::-1]
            quads.append(corner_id(ring))
            owner.append(np.ravel_multi_index((cells - 1).T, occupied.shape))
    quads, owner = np.concatenate(quads), np.concatenate(owner)
    used, inv = np.unique(quads, return_inverse=True)
    quads = inv.reshape(-1, 4)
    ijk = np.stack(np.unravel_index(used, tuple(shape + 1)), axis=1) - 1
    vertices = np.asarray(origin, dtype=np.float64) + h * ijk
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    return vertices, faces, np.concatenate([owner, owner])


def table(h: float = 0.05) -> Shape:
    """A table: a 1.6 x 1.0 x 0.1 slab on four 0.15 x 0.15 x 0.7 legs, voxel size ``h``.

    Closed genus-0 mesh (about 4,000 faces); ``part_labels`` 0 = slab, 1..4 = legs;
    ``n_parts`` 5. The slab's flat faces are what k-means cuts into stripes.
    """
    nx, ny, nz_leg, nz_top, w = round(1.6 / h), round(1.0 / h), round(0.7 / h), max(round(0.1 / h), 1), max(round(0.15 / h), 1)
    occ = np.zeros((nx, ny, nz_leg + nz_top), dtype=bool)
    part = np.zeros(occ.shape, dtype=np.int64)
    occ[:, :, nz_leg:] = True
    inset = max(round(0.05 / h), 1)
    for i, (x0, y0) in enumerate([(inset, inset), (nx - inset - w, inset),
                                   (inset, ny - inset - w), (nx - inset - w, ny - inset - w)]):
        occ[x0:x0 + w, y0:y0 + w, :nz_leg] = True
        part[x0:x0 + w, y0:y0 + w, :nz_leg] = i + 1
    v, f, owner = _voxel_surface(occ, h, (-0.8, -0.5, -0.4))
    return Shape("table", v, f, part.reshape(-1)[owner], 5)


def _marching_tetrahedra(sdf, lo, hi, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The zero set of ``sdf`` (vectorized [N, 3] -> [N], negative inside) on a grid of step h
    over the box [lo, hi]: (vertices, faces), faces not yet oriented."""
    axes = [np.arange(a, b + h, h) for a, b in zip(lo, hi)]
    n = np.array([len(a) for a in axes])
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    val = sdf(pts)
    val[val == 0] = 1e-12          # no surface vertex on a grid point: no zero-length edges
    cells = np.stack(np.meshgrid(*[np.arange(m - 1) for m in n], indexing="ij"), axis=-1).reshape(-1, 3)
    corner = np.ravel_multi_index((cells[:, None, :] + _CORNERS[None]).transpose(2, 0, 1), tuple(n))
    tets = corner[:, _TETS].reshape(-1, 4)
    inside = val[tets] < 0
    count = inside.sum(1)
    tets, inside, count = tets[(count > 0) & (count < 4)], inside[(count > 0) & (count < 4)], count[(count > 0) & (count < 4)]
    tris = []
    # One corner apart (1 or 3 inside): a triangle on its three edges.
    one = (count == 1) | (count == 3)
    t1, in1 = tets[one], inside[one]
    odd = np.where((count[one] == 1)[:, None], in1, ~in1)
    apex = np.argmax(odd, axis=1)
    others = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[apex]
    a = t1[np.arange(len(t1)), apex]
    rest = np.take_along_axis(t1, others, axis=1)
    tris.append(np.stack([np.stack([a, rest[:, i]], axis=1) for i in range(3)], axis=1))
    # Two inside (p, q), two outside (r, s): the quad pr, ps, qs, qr as two triangles.
    t2, in2 = tets[count == 2], inside[count == 2]
    order = np.argsort(~in2, axis=1, kind="stable")
    p, q, r, s = np.take_along_axis(t2, order, axis=1).T
    pr, ps, qs, qr = (np.stack(e, axis=1) for e in ((p, r), (p, s), (q, s), (q, r)))
    tris.append(np.stack([pr, ps, qs], axis=1))
    tris.append(np.stack([pr, qs, qr], axis=1))
    edges = np.concatenate(tris)                        # [T, 3, 2] grid-edge endpoints
    edges = np.sort(edges, axis=2)
    key = edges[..., 0] * len(pts) + edges[..., 1]
    ukey, inv = np.unique(key, return_inverse=True)
    i, j = ukey // len(pts), ukey % len(pts)
    t = val[i] / (val[i] - val[j])
    vertices = pts[i] + t[:, None] * (pts[j] - pts[i])
    return vertices, inv.reshape(-1, 3)


def _gradient(sdf, x: np.ndarray, d: float = 1e-5) -> np.ndarray:
    return np.stack([(sdf(x + d * e) - sdf(x - d * e)) / (2 * d) for e in np.eye(3)], axis=1)


def _relax_onto(sdf, vertices: np.ndarray, faces: np.ndarray, iterations: int = 15) -> np.ndarray:
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
        g = _gradient(sdf, v)
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        move -= np.einsum("ij,ij->i", move, g)[:, None] * g
        v = v + 0.5 * move
        for _ in range(2):
            g = _gradient(sdf, v)
            v = v - (sdf(v) / np.maximum(np.einsum("ij,ij->i", g, g), 1e-12))[:, None] * g
    return v


def _mug_sdfs(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # Body: a closed can, radius 0.5, height 1.2, edges rounded by 0.1.
    rad = np.hypot(x[:, 0], x[:, 1])
    q = np.stack([rad - 0.4, np.abs(x[:, 2]) - 0.5], axis=1)
    body = np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0) - 0.1
    # Handle: a torus (major 0.3, tube 0.08) in the xz-plane through the body's side.
    c = x - np.array([0.5, 0.0, 0.0])
    ring = np.hypot(c[:, 0], c[:, 2]) - 0.3
    handle = np.hypot(ring, c[:, 1]) - 0.08
    return body, handle


def _mug_sdf(x: np.ndarray) -> np.ndarray:
    return np.minimum(*_mug_sdfs(x))


def _implicit_shape(name: str, parts, lo, hi, h: float, blend: float, relax: int = 15) -> Shape:
    """The zero set of the smooth union of the signed distance functions ``parts`` (a function
    [N, 3] -> [P, N], negative inside) over the box [lo, hi] at grid step h: marching
    tetrahedra, relaxed onto the surface, faces turned outward; the part of a face is the
    primitive nearest its centroid. ``blend`` (length units; 0: a plain union) rounds the
    creases where primitives meet; ``relax``: steps of tangential relaxation (thin parts need
    more to lose the slivers marching tetrahedra leaves across them)."""
    def sdf(x):
        return _smooth_union(parts(x), blend)
    v, f = _marching_tetrahedra(sdf, lo, hi, h)
    v = _relax_onto(sdf, v, f, iterations=relax)
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = np.einsum("ij,ij->i", normal, _gradient(sdf, tri.mean(1))) > 0
    f = np.where(outward[:, None], f, f[:, ::-1])
    labels = np.argmin(parts(v[f].mean(1)), axis=0).astype(np.int64)
    return Shape(name, v, f, labels, int(labels.max()) + 1)


def _smooth_union(d: np.ndarray, blend: float) -> np.ndarray:
    """[P, N] distances -> [N]: min over the primitives, its creases rounded over ``blend``
    (the polynomial smooth minimum, applied pairwise in order)."""
    out = d[0]
    for other in d[1:]:
        if blend <= 0:
            out = np.minimum(out, other)
            continue
        mix = np.maximum(blend - np.abs(out - other), 0.0) / blend
        out = np.minimum(out, other) - mix * mix * blend / 4
    return out


def _ellipsoid_sdf(x: np.ndarray, center, axes) -> np.ndarray:
    """Approximate signed distance to an axis-aligned ellipsoid (exact zero set; distances
    scaled by the smallest semi-axis)."""
    q = (x - np.asarray(center)) / np.asarray(axes)
    return (np.linalg.norm(q, axis=1) - 1.0) * min(axes)


def _capsule_sdf(x: np.ndarray, a, b, radius: float) -> np.ndarray:
    """Signed distance to the capsule of ``radius`` around the segment a-b."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ab = b - a
    t = np.clip((x - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(x - a - t[:, None] * ab, axis=1) - radius


def _mug_parts(x: np.ndarray) -> np.ndarray:
    return np.stack(_mug_sdfs(x))


def mug(h: float = 0.06) -> Shape:
    """A mug: a closed rounded can (radius 0.5, height 1.2) with a ring handle on its side.

    Closed genus-1 mesh (about 10,000 faces at the default grid step ``h``), meeting the
    handle at concave creases; ``part_labels`` 0 = body, 1 = handle; ``n_parts`` 2.
    """
    return _implicit_shape("mug", _mug_parts, (-0.65, -0.65, -0.7), (0.95, 0.65, 0.7), h, blend=0.0)


#: The quadruped's legs: hip points (x, y) under the body, each leg straight down to z = -1.0.
_LEG_XY = ((0.55, 0.22), (0.55, -0.22), (-0.55, 0.22), (-0.55, -0.22))


def _quadruped_parts(x: np.ndarray) -> np.ndarray:
    body = _ellipsoid_sdf(x, (0.0, 0.0, 0.0), (0.95, 0.4, 0.38))
    head = np.minimum(_ellipsoid_sdf(x, (1.25, 0.0, 0.42), (0.3, 0.2, 0.2)),
                      _capsule_sdf(x, (0.8, 0.0, 0.12), (1.1, 0.0, 0.38), 0.14))
    legs = [_capsule_sdf(x, (lx, ly, -0.1), (lx, ly, -0.92), 0.12) for lx, ly in _LEG_XY]
    return np.stack([body, head, *legs])


def quadruped(h: float = 0.1) -> Shape:
    """A four-legged animal: an ellipsoidal body (1.9 long), a head on a short neck in front
    and four straight legs (radius 0.12, 0.8 below the body) at its corners.

    Closed genus-0 mesh (about 5,700 faces at the default grid step ``h``), the parts
    joined by rounded creases; ``part_labels`` 0 = body, 1 = head (with the neck), 2..5 = legs
    (front left, front right, hind left, hind right); ``n_parts`` 6. People cut the legs and
    the head off the body: protrusions, which a segmentation must separate before it halves
    the body.
    """
    return _implicit_shape("quadruped", _quadruped_parts, (-1.1, -0.55, -1.1), (1.65, 0.55, 0.7), h,
                           blend=0.08, relax=30)


#: Half the thickness of the fish's fins (its body is 0.6 wide and 0.9 high).
_FIN = 0.09


def _fish_parts(x: np.ndarray) -> np.ndarray:
    body = _ellipsoid_sdf(x, (0.0, 0.0, 0.0), (1.0, 0.3, 0.45))
    tail = _ellipsoid_sdf(x, (-1.2, 0.0, 0.0), (0.35, _FIN, 0.45))
    dorsal = _ellipsoid_sdf(x, (0.0, 0.0, 0.5), (0.4, _FIN, 0.25))
    fins = [_ellipsoid_sdf(x, (0.3, side * 0.35, -0.15), (0.25, 0.22, _FIN)) for side in (1, -1)]
    return np.stack([body, tail, dorsal, *fins])


def fish(h: float = 0.08) -> Shape:
    """A fish: an ellipsoidal body (2.0 long), a tail fin behind it, a dorsal fin on top and
    two pectoral fins on its sides; the fins are thin (0.18 thick).

    Closed genus-0 mesh (about 7,700 faces at the default grid step ``h``); ``part_labels``
    0 = body, 1 = tail, 2 = dorsal fin, 3 and 4 = pectoral fins (left, right); ``n_parts`` 5.
    The fins are thin protrusions that people mark as parts.
    """
    return _implicit_shape("fish", _fish_parts, (-1.7, -0.65, -0.6), (1.1, 0.65, 0.85), h, blend=0.06,
                           relax=30)


__all__ = ["table", "mug", "quadruped", "fish"]
