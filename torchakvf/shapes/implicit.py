"""Built-in shapes for failure modes of segmentation, closed, with ground-truth parts: a table and
a mug (k-means on untangled fields cuts flat regions into stripes and boundaries across smooth
surface), a four-legged animal and a fish (protrusions people mark as parts: legs, head, thin
fins).

numpy only. The table is the boundary of a union of voxels (exact flat boxes); the others are
marching-tetrahedra surfaces (:mod:`.marching`) of a signed distance function (:mod:`.sdf`: a
smooth union of primitives, one per part), relaxed tangentially and projected back onto the
surface so that their triangles are well shaped.
"""
from __future__ import annotations

import numpy as np

from .marching import gradient, marching_tetrahedra, relax_onto
from .sdf import capsule_sdf, ellipsoid_sdf, smooth_union
from .shape import Shape


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
    nx, ny, nz_leg = round(1.6 / h), round(1.0 / h), round(0.7 / h)
    nz_top, w = max(round(0.1 / h), 1), max(round(0.15 / h), 1)
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
        return smooth_union(parts(x), blend)
    v, f = marching_tetrahedra(sdf, lo, hi, h)
    v = relax_onto(sdf, v, f, iterations=relax)
    tri = v[f]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = np.einsum("ij,ij->i", normal, gradient(sdf, tri.mean(1))) > 0
    f = np.where(outward[:, None], f, f[:, ::-1])
    labels = np.argmin(parts(v[f].mean(1)), axis=0).astype(np.int64)
    return Shape(name, v, f, labels, int(labels.max()) + 1)


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
    body = ellipsoid_sdf(x, (0.0, 0.0, 0.0), (0.95, 0.4, 0.38))
    head = np.minimum(ellipsoid_sdf(x, (1.25, 0.0, 0.42), (0.3, 0.2, 0.2)),
                      capsule_sdf(x, (0.8, 0.0, 0.12), (1.1, 0.0, 0.38), 0.14))
    legs = [capsule_sdf(x, (lx, ly, -0.1), (lx, ly, -0.92), 0.12) for lx, ly in _LEG_XY]
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
    body = ellipsoid_sdf(x, (0.0, 0.0, 0.0), (1.0, 0.3, 0.45))
    tail = ellipsoid_sdf(x, (-1.2, 0.0, 0.0), (0.35, _FIN, 0.45))
    dorsal = ellipsoid_sdf(x, (0.0, 0.0, 0.5), (0.4, _FIN, 0.25))
    fins = [ellipsoid_sdf(x, (0.3, side * 0.35, -0.15), (0.25, 0.22, _FIN)) for side in (1, -1)]
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
