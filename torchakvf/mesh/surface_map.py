"""Closest points on a triangle mesh: where the fine vertices and face barycenters of a
decimated mesh's source lie on it (:class:`SurfaceIndex`, exact), and the approximate search
the decimation's relaxation projects with (:class:`BarycenterSearch`)."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ParameterError
from .clean import CleanMesh

#: Sample spacing of :class:`SurfaceIndex`, in units of the median face's radius (the
#: distance from its barycenter to its farthest corner): faces larger than this are sampled
#: at the centers of a subdivision. Smaller: more samples, fewer candidate faces per point.
SAMPLE_SPACING = 0.5
#: ... but no face is cut into more than MAX_SPLIT^2 sub-triangles (a huge sliver raises the
#: spacing instead).
MAX_SPLIT = 8
#: Samples asked for first in each ball query (more where a ball holds more): 16 needs the
#: fewest tree walks in all on meshes decimated to 4000 faces (the answer is the exact closest
#: face at any value).
QUERY_K = 16
#: Ratio between the search radii of two successive query groups.
REACH_STEP = 1.25
#: The AABB search measures the faces around a closest point whose smallest barycentric
#: coordinate is at most this (on an edge or corner, or within round-off of one).
TIE_BARY = 1e-9
#: Distances within this fraction of the mesh's bounding-box diagonal count as equal. A point
#: whose closest point lies on an edge is exactly as near both faces of that edge; which of the
#: two computed distances comes out smaller is round-off, and a rigid motion of the input
#: changes it, so such ties are settled by geometry instead (:meth:`SurfaceIndex._nearest_pairs`).
TIE_DISTANCE = 1e-10


@dataclass(frozen=True)
class SurfacePoints:
    """Points located on a triangle mesh: point p = Σ_c bary[p, c] · V[faces[face[p], c]].

    face : [P] int64, index of the (cleaned) coarse face holding each point's closest point
    bary : [P, 3] float64, barycentric coordinates of that closest point (>= 0, sum 1)
    distance : [P] float64, distance from the point to the coarse surface (input units)
    """

    face: np.ndarray
    bary: np.ndarray
    distance: np.ndarray

    def interpolate(self, faces: np.ndarray, vertex_values: np.ndarray) -> np.ndarray:
        """[P, ...] linear interpolation of per-coarse-vertex values [V_coarse, ...]."""
        vertex_values = np.asarray(vertex_values)
        corner = faces[self.face]                                         # [P, 3]
        shape = (len(corner),) + (1,) * (vertex_values.ndim - 1)
        # Σ_c bary_c · value_c, added in corner order as (corners * w).sum(axis=1) adds them,
        # without the [P, 3, ...] gather
        out = vertex_values[corner[:, 0]] * self.bary[:, 0].reshape(shape)
        for c in (1, 2):
            out += vertex_values[corner[:, c]] * self.bary[:, c].reshape(shape)
        return out

    def on(self, surface: CleanMesh) -> np.ndarray:
        """[P, 3] the located points themselves, on the mesh they were located on."""
        return self.interpolate(surface.faces, surface.vertices)


class SurfaceIndex:
    """Exact closest points on a triangle mesh (vertices [V, 3], faces [F, 3]).

    Two searches give the closest face (faces equally near up to round-off: the one the point
    lies most squarely above, see :meth:`_nearest_pairs`),
    with the barycentric coordinates and distance of :meth:`_closest`; they give the same bits
    except where two faces are equally near, within round-off, at two different points of the
    surface (a symmetric configuration), which each may settle its own way:

    * **AABB** (``search="aabb"``, the default where libigl imports): libigl's
      ``point_mesh_squared_distance`` (a bounding-box tree in C++) finds a closest face; a
      point whose closest point lies on an edge or corner of that face is as close to the faces
      around it, so those are measured too and their tie settled as the sample search does.
      About 3x faster than the sample search on meshes decimated to 4000 faces, with the same
      bits at all but a few points in a million (see docs/design.md).
    * **samples** (``search="samples"``; the fallback without libigl, and the reference the
      tests hold the AABB search to): a ``cKDTree`` of sample points on the faces, each face
      sampled at the centers of a uniform L x L subdivision (L^2 sub-triangles, L by face
      size), so that every point of a face lies within ``rho`` of one of its own samples. That
      gives the bound the search rests on: a face none of whose samples is within ``u + rho``
      of a point is farther than ``u`` from it. It takes ``u`` from the nearest sample's face
      and measures the exact point-triangle distance to every face with a sample inside the
      ball, so it returns the true closest face (brute force's answer), which the
      nearest-barycenter candidates of :class:`BarycenterSearch` do not always find.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, search: str = "auto"):
        if search not in ("auto", "aabb", "samples"):
            raise ParameterError(f"search must be 'auto', 'aabb' or 'samples', got {search!r}")
        have_igl = _igl() is not None
        if search == "aabb" and not have_igl:
            raise ParameterError("search='aabb' needs libigl: pip install libigl")
        self.search = "samples" if search == "samples" or not have_igl else "aabb"
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.tri = self.vertices[self.faces]                              # [F, 3, 3]
        # Per face, what the point-triangle distance needs besides the point (see _closest).
        self.a = self.tri[:, 0]
        self.ab, self.ac = self.tri[:, 1] - self.a, self.tri[:, 2] - self.a
        self.gram = np.stack([(self.ab * self.ab).sum(1), (self.ab * self.ac).sum(1),
                              (self.ac * self.ac).sum(1)], axis=1)          # [F, 3]
        span = self.vertices.max(axis=0) - self.vertices.min(axis=0) if len(self.vertices) else np.ones(3)
        self.tie_distance = TIE_DISTANCE * max(float(np.linalg.norm(span)), 1e-300)
        if self.search == "samples":
            self._build_samples()

    def _build_samples(self) -> None:
        """The sample points and their tree (the "samples" search)."""
        center = self.tri.mean(axis=1)
        # Largest distance from a face's barycenter to its points (attained at a corner).
        radius = np.linalg.norm(self.tri - center[:, None], axis=-1).max(axis=1)   # [F]
        big = float(radius.max()) if len(radius) else 0.0
        self.rho = max(SAMPLE_SPACING * float(np.median(radius)) if len(radius) else 0.0,
                       big / MAX_SPLIT, 1e-300)
        # A sub-triangle of an L-subdivision is the face scaled by 1/L (or its point
        # reflection), so its points lie within radius / L of its center.
        level = np.maximum(np.ceil(radius / self.rho - 1e-9).astype(np.int64), 1)
        samples, owner = [], []
        for n in np.unique(level):
            sel = np.flatnonzero(level == n)
            uv = _subtriangle_centers(int(n))                             # [n^2, 2]
            a = self.tri[sel, 0]
            e0, e1 = self.tri[sel, 1] - a, self.tri[sel, 2] - a
            pts = a[:, None] + uv[None, :, :1] * e0[:, None] + uv[None, :, 1:] * e1[:, None]
            samples.append(pts.reshape(-1, 3))
            owner.append(np.repeat(sel, len(uv)))
        self.level = level
        self.owner = np.concatenate(owner) if owner else np.zeros(0, dtype=np.int64)
        self.sample_radius = (radius / level)[self.owner]                  # [S] <= rho
        # An unbalanced tree builds 2-3x faster and queries about as fast here.
        self.tree = cKDTree(np.concatenate(samples) if samples else np.zeros((0, 3)),
                            balanced_tree=False, compact_nodes=False)

    def locate(self, points: np.ndarray) -> SurfacePoints:
        """The closest point of the mesh to each of ``points`` [P, 3] (ties between faces at the
        same distance: see :meth:`_nearest_pairs`)."""
        points = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        if not len(points):
            return SurfacePoints(face=np.zeros(0, dtype=np.int64), bary=np.zeros((0, 3)), distance=np.zeros(0))
        bad = ~np.isfinite(points).all(axis=1)
        if bad.any():
            raise ParameterError(f"{int(bad.sum())} of {len(points)} points to locate are not finite "
                                 f"(NaN or inf; the first is row {int(np.flatnonzero(bad)[0])})")
        if self.search == "aabb" and len(self.faces):
            return self._locate_aabb(points)
        if not hasattr(self, "tree"):
            self._build_samples()
        return self._locate_samples(points)

    def _locate_aabb(self, points: np.ndarray) -> SurfacePoints:
        """:meth:`locate` by libigl's AABB tree, ties resolved over the faces around the
        closest point's edge or corner."""
        _, face, _ = _igl().point_mesh_squared_distance(points, self.vertices, self.faces)
        face = np.array(face, dtype=np.int64)                             # our own: written below
        bary, dist = self._closest(points, face)
        # A closest point on (or within round-off of) an edge or corner of its face: the faces
        # around the corners that span it are as close, up to round-off; all of them are
        # measured, as the sample search measures every face near the point.
        edge = np.flatnonzero(bary.min(axis=1) <= TIE_BARY)
        if not len(edge):
            return SurfacePoints(face=face, bary=bary, distance=dist)
        ring_ptr, ring_face = self._vertex_faces
        corner = self.faces[face[edge]]                                   # [m, 3]
        span = bary[edge] > TIE_BARY                                      # corners spanning it
        row, col = np.nonzero(span)
        v = corner[row, col]
        count = ring_ptr[v + 1] - ring_ptr[v]
        first = np.repeat(ring_ptr[v], count)
        offset = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
        pair_point = np.concatenate([edge, np.repeat(edge[row], count)])
        pair_face = np.concatenate([face[edge], ring_face[first + offset]])
        best = self._nearest_pairs(points, pair_point, pair_face)
        face[edge], bary[edge], dist[edge] = best.face, best.bary, best.distance
        return SurfacePoints(face=face, bary=bary, distance=dist)

    @cached_property
    def _vertex_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """(ptr [V + 1], faces [3F]): the faces around vertex v are faces[ptr[v]:ptr[v + 1]]."""
        flat = self.faces.ravel()
        order = np.argsort(flat, kind="stable")
        ptr = np.zeros(len(self.vertices) + 1, dtype=np.int64)
        ptr[1:] = np.cumsum(np.bincount(flat, minlength=len(self.vertices)))
        return ptr, order // 3

    @cached_property
    def _unit_normals(self) -> np.ndarray:
        """[F, 3] unit face normals (zero for a degenerate face)."""
        n = np.cross(self.ab, self.ac)
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, length, out=np.zeros_like(n), where=length > 0)

    def _nearest_pairs(self, points: np.ndarray, pair_point: np.ndarray, pair_face: np.ndarray) -> SurfacePoints:
        """For each point of ``pair_point`` (ascending once sorted), the nearest of its candidate
        faces (pairs [M] with repeats allowed); one row per distinct point, in ascending point
        order.

        Faces within :data:`TIE_DISTANCE` of the nearest are tied (a closest point on their
        shared edge or corner): of those, the face whose plane the point lies most squarely
        above (the offset from its closest point most nearly along the face's normal) is kept,
        which a rigid motion or a renumbering of the mesh does not change; the lowest face index
        only where that is equal too (a point on the surface, or on the bisector of an edge)."""
        n_faces = len(self.faces)
        key = np.sort(pair_point * n_faces + pair_face)
        key = key[np.r_[True, key[1:] != key[:-1]]]        # (np.unique: a slow hash in numpy 2.4)
        point, face = key // n_faces, key % n_faces       # by point, then by face
        bary, dist = self._closest(points[point], face)
        start = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])      # each point's pairs
        lowest = np.repeat(np.minimum.reduceat(dist, start), np.diff(np.r_[start, len(point)]))
        tied = dist <= lowest + self.tie_distance
        at_min = np.flatnonzero(tied)
        offset = points[point[at_min]] - (self.a[face[at_min]] + bary[at_min, 1:2] * self.ab[face[at_min]]
                                          + bary[at_min, 2:3] * self.ac[face[at_min]])
        square = np.abs(np.einsum("ij,ij->i", offset, self._unit_normals[face[at_min]]))
        square = np.divide(square, dist[at_min], out=np.zeros_like(square), where=dist[at_min] > 0)
        # by point, then the squarest first, then the lowest face
        at_min = at_min[np.lexsort((face[at_min], -square, point[at_min]))]
        best = at_min[np.r_[True, point[at_min][1:] != point[at_min][:-1]]]
        return SurfacePoints(face=face[best].astype(np.int64), bary=bary[best], distance=dist[best])

    def _locate_samples(self, points: np.ndarray) -> SurfacePoints:
        """:meth:`locate` by the sample tree (see the class notes)."""
        n_points, n_samples = len(points), len(self.owner)
        slack = lambda r: r * (1 + 1e-9) + 1e-12 * self.rho              # noqa: E731 (round-off)
        k = min(QUERY_K, n_samples)
        # Bounded to 2 rho (the ball a point within rho of the surface needs): prunes the tree
        # walk; a point with no sample that near is asked again without a bound.
        d, idx = self.tree.query(points, k=k, distance_upper_bound=2 * self.rho)
        d, idx = d.reshape(n_points, k), idx.reshape(n_points, k)
        far = np.flatnonzero(~np.isfinite(d[:, 0]))
        if len(far):
            d_far, idx_far = self.tree.query(points[far], k=k)
            d[far], idx[far] = d_far.reshape(len(far), k), idx_far.reshape(len(far), k)
        # The distance to the nearest sample's face bounds the distance to the surface.
        first = self.owner[idx[:, 0]]
        upper = self._closest(points, first)[1]
        pair_point, pair_face = [np.arange(n_points)], [first]

        def keep(rows, d, idx):
            # A face can hold the closest point only if one of its samples lies within
            # upper + (that sample's sub-triangle radius).
            near = d <= slack(upper[rows, None] + self.sample_radius[np.minimum(idx, n_samples - 1)])
            r, c = np.nonzero(near)
            pair_point.append(rows[r])
            pair_face.append(self.owner[idx[r, c]])

        keep(np.arange(n_points), d, idx)
        # Where the k samples do not reach upper + rho, the ball may hold more: asked again
        # with a larger k, bounded, in a few groups of similar radius (one bound per call).
        reach = slack(upper + self.rho)
        todo = np.flatnonzero((d[:, -1] <= reach) | (reach > 2 * self.rho)) if k < n_samples \
            else np.zeros(0, dtype=np.int64)
        while len(todo):
            k = min(4 * k, n_samples)
            group = np.floor(np.log(reach[todo] / reach[todo].min()) / np.log(REACH_STEP)).astype(np.int64)
            again = []
            for g in np.unique(group):
                rows = todo[group == g]
                d, idx = self.tree.query(points[rows], k=k, distance_upper_bound=reach[rows].max())
                d, idx = d.reshape(len(rows), k), idx.reshape(len(rows), k)
                keep(rows, d, idx)
                again.append(rows[d[:, -1] <= reach[rows]])
            todo = np.concatenate(again) if k < n_samples else todo[:0]
        return self._nearest_pairs(points, np.concatenate(pair_point), np.concatenate(pair_face))

    def _closest(self, points: np.ndarray, face: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Barycentric coordinates [N, 3] of the point of face[i] closest to points[i] ([N, 3])
        and the distance [N]: :func:`closest_barycentric`'s Voronoi regions, with the six dot
        products taken from two per point and the face's Gram matrix (bp = ap - ab, ...)."""
        a, ab, ac = self.a[face], self.ab[face], self.ac[face]
        g = self.gram[face]
        ap = points - a
        d1 = np.einsum("ij,ij->i", ab, ap)
        d2 = np.einsum("ij,ij->i", ac, ap)
        d3, d4 = d1 - g[:, 0], d2 - g[:, 1]
        d5, d6 = d1 - g[:, 1], d2 - g[:, 2]
        bary = _regions(d1, d2, d3, d4, d5, d6)
        closest = a + bary[:, 1:2] * ab + bary[:, 2:3] * ac
        return bary, np.linalg.norm(points - closest, axis=1)


class BarycenterSearch:
    """Approximate closest points on a triangle mesh: the closest point among the ``candidates``
    faces with the nearest barycenters. Not exact (on decimated meshes it misses the closest
    face for ~0.5% of the points, by up to a third of an edge), and it is what the relaxation
    of :func:`~torchakvf.mesh.coarse.decimate` projects with: the exact search moves the
    decimated vertices, and with them every segmentation, a change not scored on the benchmark
    (see docs/design.md)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, candidates: int = 8):
        self.vertices, self.faces, self.candidates = vertices, faces, candidates
        self.tri = vertices[faces]                                        # [F, 3, 3]
        self.tree = cKDTree(self.tri.mean(axis=1))

    def locate(self, points: np.ndarray) -> SurfacePoints:
        k = int(min(self.candidates, len(self.faces)))
        _, cand = self.tree.query(points, k=k)
        cand = cand.reshape(len(points), k)
        a, b, c = (self.tri[cand, i] for i in range(3))                  # [P, k, 3] each
        bary = closest_barycentric(points[:, None, :], a, b, c)          # [P, k, 3]
        closest = bary[..., 0:1] * a + bary[..., 1:2] * b + bary[..., 2:3] * c
        dist = np.linalg.norm(closest - points[:, None, :], axis=-1)       # [P, k]
        best = dist.argmin(axis=1)
        rows = np.arange(len(points))
        return SurfacePoints(face=cand[rows, best].astype(np.int64), bary=bary[rows, best],
                             distance=dist[rows, best])


def _igl():
    """libigl's Python module, or None where it is not installed (the sample search then).

    Its threads follow IGL_NUM_THREADS, read once per process (default: every core); the
    worker processes of :mod:`torchakvf.pipeline.parallel` get 1."""
    try:
        import igl
    except (ImportError, OSError):     # not installed, or its compiled library does not load
        return None
    return igl


def libigl_available() -> bool:
    """Whether libigl imports (the AABB search of :class:`SurfaceIndex` needs it)."""
    return _igl() is not None


def _subtriangle_centers(n: int) -> np.ndarray:
    """[n^2, 2] (u, v) of the centers of the n x n subdivision of a triangle
    (point a + u (b - a) + v (c - a)): n(n+1)/2 upward and n(n-1)/2 downward sub-triangles."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = (i + j) <= n - 1
    down = (i + j) <= n - 2
    uv = np.concatenate([np.stack([i[up] + 1 / 3, j[up] + 1 / 3], axis=1),
                         np.stack([i[down] + 2 / 3, j[down] + 2 / 3], axis=1)])
    return uv / n


def locate_on_surface(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                      index: SurfaceIndex | None = None) -> SurfacePoints:
    """The closest point of the triangle mesh (vertices [V, 3], faces [F, 3]) to each of
    ``points`` [P, 3], exact (see :class:`SurfaceIndex`; ``index``: one prebuilt for this
    mesh, to reuse over several calls)."""
    index = SurfaceIndex(vertices, faces) if index is None else index
    return index.locate(points)


def closest_barycentric(p, a, b, c):
    """Barycentric coordinates [..., 3] of the point of triangle (a, b, c) closest to p, by the
    Voronoi regions of its vertices, edges and interior (Ericson, Real-Time Collision
    Detection, 5.1.5), every region evaluated and the first that applies kept."""
    dot = lambda x, y: np.einsum("...i,...i->...", x, y)  # noqa: E731
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c
    return _regions(dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp))


def _regions(d1, d2, d3, d4, d5, d6):
    """Barycentric coordinates [..., 3] of the closest point from Ericson's six dot products
    (d1 = ab.ap, d2 = ac.ap, d3 = ab.bp, d4 = ac.bp, d5 = ab.cp, d6 = ac.cp)."""
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        den = va + vb + vc
        v_in, w_in = vb / den, vc / den
    out = np.stack([1 - v_in - w_in, v_in, w_in], axis=-1)              # the interior
    # The first region that applies wins: written last to first, each over the ones after it.
    regions = [
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), lambda m: (0.0, 1 - t_bc[m], t_bc[m])),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), lambda m: (1 - t_ac[m], 0.0, t_ac[m])),
        ((d6 >= 0) & (d5 <= d6), lambda m: (0.0, 0.0, 1.0)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), lambda m: (1 - t_ab[m], t_ab[m], 0.0)),
        ((d3 >= 0) & (d4 <= d3), lambda m: (0.0, 1.0, 0.0)),
        ((d1 <= 0) & (d2 <= 0), lambda m: (1.0, 0.0, 0.0)),
    ]
    for mask, values in regions:
        if mask.any():
            for i, x in enumerate(values(mask)):
                out[..., i][mask] = x
    return np.nan_to_num(out, nan=1.0 / 3.0)


__all__ = ["BarycenterSearch", "SurfaceIndex", "SurfacePoints", "closest_barycentric", "libigl_available",
           "locate_on_surface"]
