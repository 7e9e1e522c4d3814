"""Signed distance functions of solids (negative inside, in length units) and the operations that
combine them: the building blocks of the implicit shapes (:mod:`.implicit`, :mod:`.procedural`).

Two forms. Plain functions of points (``capsule_sdf``, ``ellipsoid_sdf``, ``smooth_union``) for
hand-written shapes; and small primitive objects, each a callable ``x [N, 3] -> [N]`` with
``bounds()`` (a world-space box that contains the solid), placed by a rigid frame (``center``
and ``rotation``, whose columns are the primitive's local axes in world coordinates) so that one
formula serves any axis. Rigid motions keep distances, so a primitive's distance is exact when
its local formula is; :class:`Ellipsoid` is the one approximation (a bound, exact on the surface
and along the axes). :class:`Union` and :class:`Difference` make compound solids of primitives.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def smooth_union(d: np.ndarray, blend: float) -> np.ndarray:
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


def ellipsoid_sdf(x: np.ndarray, center, axes) -> np.ndarray:
    """Approximate signed distance to an axis-aligned ellipsoid (exact zero set; distances
    scaled by the smallest semi-axis)."""
    q = (x - np.asarray(center)) / np.asarray(axes)
    return (np.linalg.norm(q, axis=1) - 1.0) * min(axes)


def capsule_sdf(x: np.ndarray, a, b, radius: float) -> np.ndarray:
    """Signed distance to the capsule of ``radius`` around the segment a-b."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ab = b - a
    t = np.clip((x - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(x - a - t[:, None] * ab, axis=1) - radius


def polygon_sdf(p: np.ndarray, poly, skip=None) -> np.ndarray:
    """Exact signed distance of 2-D points p [N, 2] to a simple polygon (vertices [M, 2] in
    order, either winding): negative inside. skip : [M] bool, edges (edge i joins vertex
    i - 1 to vertex i) that bound the region without being surface (a profile's axis): they
    count for inside and outside, not for the distance."""
    poly = np.asarray(poly, dtype=np.float64)
    skip = np.zeros(len(poly), dtype=bool) if skip is None else np.asarray(skip)
    d = np.full(len(p), np.inf)
    sign = np.ones(len(p))
    for i in range(len(poly)):
        vi, vj = poly[i], poly[i - 1]
        e, w = vj - vi, p - vi
        if not skip[i]:
            b = w - e * np.clip(w @ e / (e @ e), 0.0, 1.0)[:, None]
            d = np.minimum(d, np.sum(b * b, axis=1))
        c = np.stack([p[:, 1] >= vi[1], p[:, 1] < vj[1], e[0] * w[:, 1] > e[1] * w[:, 0]])
        sign[c.all(0) | (~c).all(0)] *= -1      # crossing-number parity: the point is inside
    return sign * np.sqrt(d)


def rotation(axis, angle: float) -> np.ndarray:
    """The rotation by ``angle`` radians about ``axis`` (Rodrigues), [3, 3]."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def frame(z_axis, x_hint=(1.0, 0.0, 0.0)) -> np.ndarray:
    """A rotation whose third column is ``z_axis`` (normalized) and whose first is as close to
    ``x_hint`` as that allows, [3, 3]."""
    z = np.asarray(z_axis, dtype=np.float64)
    z = z / np.linalg.norm(z)
    x = np.asarray(x_hint, dtype=np.float64) - (np.asarray(x_hint) @ z) * z
    if np.linalg.norm(x) < 1e-6:
        x = np.eye(3)[np.argmin(np.abs(z))] - z[np.argmin(np.abs(z))] * z
    x = x / np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A rotation drawn uniformly (a normalized Gaussian quaternion), [3, 3]."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _box_bounds(center, rotation_, half) -> tuple[np.ndarray, np.ndarray]:
    """World box around a local box of half extents ``half`` placed by (center, rotation)."""
    ext = np.abs(np.asarray(rotation_)) @ np.asarray(half, dtype=np.float64)
    return np.asarray(center) - ext, np.asarray(center) + ext


def _segment_bounds(a, b, r: float) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return np.minimum(a, b) - r, np.maximum(a, b) + r


@dataclass(frozen=True, eq=False)   # array fields: no element-wise __eq__
class Placed:
    """A primitive with a local frame: ``local(x)`` maps world points [N, 3] to local ones."""
    center: tuple = (0.0, 0.0, 0.0)
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    def local(self, x: np.ndarray) -> np.ndarray:
        return (x - np.asarray(self.center)) @ np.asarray(self.rotation)


@dataclass(frozen=True, eq=False)
class Box(Placed):
    """A box of half extents ``half`` (local x, y, z), its edges rounded by ``rounding``."""
    half: tuple = (1.0, 1.0, 1.0)
    rounding: float = 0.0

    def __call__(self, x):
        q = np.abs(self.local(x)) - (np.asarray(self.half) - self.rounding)
        return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0) - self.rounding

    def bounds(self):
        return _box_bounds(self.center, self.rotation, self.half)


@dataclass(frozen=True, eq=False)
class Ellipsoid(Placed):
    """An ellipsoid of semi-axes ``axes`` along its local x, y, z. The distance is the
    first-order bound k0 (k0 - 1) / k1 (k0 = |p / a|, k1 = |p / a^2|): exact on the surface
    and along the axes, and unlike a distance scaled by one semi-axis it stays close to the
    true one beside a thin ellipsoid (a fin), so the nearest-part labels stay right."""
    axes: tuple = (1.0, 1.0, 1.0)

    def __call__(self, x):
        a = np.asarray(self.axes, dtype=np.float64)
        p = self.local(x)
        k0 = np.linalg.norm(p / a, axis=1)
        k1 = np.linalg.norm(p / (a * a), axis=1)
        return np.where(k1 > 0, k0 * (k0 - 1) / np.maximum(k1, 1e-300), -a.min())

    def bounds(self):
        return _box_bounds(self.center, self.rotation, self.axes)


@dataclass(frozen=True, eq=False)
class _AlongSegment:
    """A solid of revolution about the segment a-b, of radius ``ra`` at ``a`` and ``rb`` at
    ``b``."""
    a: tuple
    b: tuple
    ra: float
    rb: float

    def axis(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(b - a [3], x - a [N, 3])."""
        a, b = np.asarray(self.a, dtype=np.float64), np.asarray(self.b, dtype=np.float64)
        return b - a, x - a

    def bounds(self):
        return _segment_bounds(self.a, self.b, max(self.ra, self.rb))


@dataclass(frozen=True, eq=False)
class RoundCone(_AlongSegment):
    """Spheres of radius ``ra`` at ``a`` and ``rb`` at ``b`` and the cone tangent to both
    (a capsule when the radii are equal): exact distance."""

    def __call__(self, x):
        ba, pa = self.axis(x)
        l2 = ba @ ba
        rr = self.ra - self.rb
        a2 = l2 - rr * rr
        y = pa @ ba
        z = y - l2
        x2 = np.sum((pa * l2 - y[:, None] * ba) ** 2, axis=1)
        y2, z2 = y * y * l2, z * z * l2
        k = np.sign(rr) * rr * rr * x2
        middle = (np.sqrt(x2 * a2 / l2) + y * rr) / l2 - self.ra
        out = np.where(np.sign(y) * a2 * y2 < k, np.sqrt(x2 + y2) / l2 - self.ra, middle)
        return np.where(np.sign(z) * a2 * z2 > k, np.sqrt(x2 + z2) / l2 - self.rb, out)


def capsule(a, b, radius: float) -> RoundCone:
    """The capsule of ``radius`` around the segment a-b."""
    return RoundCone(tuple(a), tuple(b), radius, radius)


@dataclass(frozen=True, eq=False)
class Frustum(_AlongSegment):
    """A capped cone from the disc of radius ``ra`` at ``a`` to that of ``rb`` at ``b`` (a
    cylinder when the radii are equal), flat ends: exact distance."""

    def __call__(self, x):
        ba, pa = self.axis(x)
        baba = ba @ ba
        paba = pa @ ba / baba
        r = np.sqrt(np.maximum(np.sum(pa * pa, axis=1) - paba * paba * baba, 0.0))
        rba = self.rb - self.ra
        cax = np.maximum(0.0, r - np.where(paba < 0.5, self.ra, self.rb))
        cay = np.abs(paba - 0.5) - 0.5
        f = np.clip((rba * (r - self.ra) + paba * baba) / (rba * rba + baba), 0.0, 1.0)
        cbx, cby = r - self.ra - f * rba, paba - f
        s = np.where((cbx < 0) & (cay < 0), -1.0, 1.0)
        return s * np.sqrt(np.minimum(cax * cax + cay * cay * baba, cbx * cbx + cby * cby * baba))


def cylinder(a, b, radius: float) -> Frustum:
    """The solid cylinder of ``radius`` whose axis is the segment a-b (flat ends)."""
    return Frustum(tuple(a), tuple(b), radius, radius)


@dataclass(frozen=True, eq=False)
class Torus(Placed):
    """A tube of radius ``minor`` around the circle of radius ``major`` in the local xy-plane,
    or around its arc from local +x through ``arc`` radians counter-clockwise about local z,
    with rounded ends or (``flat_ends``, arcs up to pi) flat ones: exact distance."""
    major: float = 1.0
    minor: float = 0.25
    arc: float = 2 * np.pi
    flat_ends: bool = False

    def __call__(self, x):
        p = self.local(x)
        rho = np.hypot(p[:, 0], p[:, 1])
        ring = np.hypot(rho - self.major, p[:, 2]) - self.minor
        if self.arc >= 2 * np.pi:
            return ring
        phi = np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * np.pi)
        ends, planes = [], []
        for t in (0.0, self.arc):
            centre = self.major * np.array([np.cos(t), np.sin(t), 0.0])
            if self.flat_ends:      # distance to the end disc, and to its plane
                normal = np.array([-np.sin(t), np.cos(t), 0.0])
                off = (p - centre) @ normal
                radial = np.linalg.norm(p - centre - off[:, None] * normal, axis=1)
                ends.append(np.hypot(np.maximum(radial - self.minor, 0.0), off))
                planes.append(np.abs(off))
            else:
                ends.append(np.linalg.norm(p - centre, axis=1) - self.minor)
        within = np.maximum(ring, -np.minimum(*planes)) if self.flat_ends else ring
        return np.where(phi <= self.arc, within, np.minimum(*ends))

    def bounds(self):
        m = self.major + self.minor
        return _box_bounds(self.center, self.rotation, (m, m, self.minor))


@dataclass(frozen=True, eq=False)
class Extrusion(Placed):
    """A prism: the local-xy polygon ``polygon`` [M, 2] extruded over |z| <= ``half_height``
    (a hexagonal nut, a gusset): exact distance."""
    polygon: tuple = ((1, 0), (0, 1), (-1, 0), (0, -1))
    half_height: float = 0.5

    def __call__(self, x):
        p = self.local(x)
        w = np.stack([polygon_sdf(p[:, :2], self.polygon), np.abs(p[:, 2]) - self.half_height], axis=1)
        return np.linalg.norm(np.maximum(w, 0), axis=1) + np.minimum(w.max(1), 0)

    def bounds(self):
        poly = np.abs(np.asarray(self.polygon, dtype=np.float64)).max(0)
        return _box_bounds(self.center, self.rotation, (poly[0], poly[1], self.half_height))


@dataclass(frozen=True, eq=False)
class Revolved(Placed):
    """A solid of revolution about local z: the profile [M, 2] of (radius >= 0, z) points, a
    polygon that closes along the axis (a chamfered turned section): exact distance (the
    edges on the axis are not surface)."""
    profile: tuple = ((0, -1), (1, -1), (1, 1), (0, 1))

    def __call__(self, x):
        p = self.local(x)
        prof = np.asarray(self.profile, dtype=np.float64)
        on_axis = (prof[:, 0] == 0) & (np.roll(prof[:, 0], 1) == 0)
        return polygon_sdf(np.stack([np.hypot(p[:, 0], p[:, 1]), p[:, 2]], axis=1), prof, on_axis)

    def bounds(self):
        prof = np.asarray(self.profile, dtype=np.float64)
        r, z0, z1 = prof[:, 0].max(), prof[:, 1].min(), prof[:, 1].max()
        lo, hi = _box_bounds(np.asarray(self.center) + np.asarray(self.rotation)[:, 2] * (z0 + z1) / 2,
                             self.rotation, (r, r, (z1 - z0) / 2))
        return lo, hi


@dataclass(frozen=True, eq=False)
class Union:
    """The union of solids, its creases rounded over ``blend`` (0: a plain union)."""
    parts: tuple
    blend: float = 0.0

    def __call__(self, x):
        return smooth_union(np.stack([p(x) for p in self.parts]), self.blend)

    def bounds(self):
        return union_bounds(self.parts)


@dataclass(frozen=True, eq=False)
class Difference:
    """``solid`` with ``cut`` taken away (max(d, -d_cut): exact outside the cut's shadow)."""
    solid: object
    cut: object

    def __call__(self, x):
        return np.maximum(self.solid(x), -self.cut(x))

    def bounds(self):
        return self.solid.bounds()


def union_bounds(solids) -> tuple[np.ndarray, np.ndarray]:
    """The world box around all of ``solids`` (each with ``bounds()``)."""
    b = [s.bounds() for s in solids]
    return np.min([lo for lo, _ in b], axis=0), np.max([hi for _, hi in b], axis=0)


__all__ = ["smooth_union", "ellipsoid_sdf", "capsule_sdf", "polygon_sdf", "rotation", "frame", "random_rotation",
           "Box", "Ellipsoid", "RoundCone", "capsule", "Frustum", "cylinder", "Torus", "Extrusion", "Revolved",
           "Union", "Difference", "union_bounds"]
