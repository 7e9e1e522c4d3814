"""Coarse-to-fine: solve on a decimated mesh, answer on the full-resolution one.

Intrinsic symmetries are coarse-scale structure: the AKVFs of a PSB mesh decimated to a few
thousand faces localize on the same parts as those of the 20k-face original, at a fraction of
the cost of every stage (eigensolve, untangling, k-means all scale with the mesh). A
:class:`CoarseMesh` is the decimated mesh a batch solves on, together with its full-resolution
source and where every fine vertex and fine face barycenter lies on the coarse surface, so that
results (vertex fields, per-face values) can be carried back to the source's faces.

Decimation is quadric edge collapse (Garland-Heckbert) by ``fast_simplification``, the backend
of ``trimesh.Trimesh.simplify_quadric_decimation``. It can leave a few edges shared by three
faces and doubled faces; those faces are removed, as are the tiny components that removal can
cut off, the holes it opens are closed again, and a few steps of tangential relaxation even out
the triangles (see :func:`decimate`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..errors import MeshError, ParameterError
from .clean import (CleanMesh, _half_edges, _undirected_edges, _vertex_adjacency, clean_mesh, face_areas,
                    face_cross_products, unique_rows)
from .mesh import Mesh

#: Face count the CLI commands that segment decimate to by default (see README: measured on
#: the PSB against full resolution).
DEFAULT_COARSE_FACES = 4000
#: Meshes with at most this many times the target face count are solved as they are: the
#: saving would be small and the transfer not free.
DECIMATE_ABOVE = 1.25
#: Components of a decimated mesh with fewer faces are dropped (cut off by the repair; a
#: near-flat scrap of a few faces has spurious zero-energy modes).
MIN_COMPONENT_FACES = 8
#: Sample spacing of :class:`SurfaceIndex`, in units of the median face's radius (the
#: distance from its barycenter to its farthest corner): faces larger than this are sampled
#: at the centers of a subdivision. Smaller: more samples, fewer candidate faces per point.
SAMPLE_SPACING = 0.5
#: ... but no face is cut into more than MAX_SPLIT^2 sub-triangles (a huge sliver raises the
#: spacing instead).
MAX_SPLIT = 8
#: Samples asked for first in each ball query (more where a ball holds more). 16: the fewest
#: tree walks in all on PSB meshes decimated to 4000 faces (1.2x less search time than 8;
#: the answer is the exact closest face either way).
QUERY_K = 16
#: Ratio between the search radii of two successive query groups.
REACH_STEP = 1.25
#: The AABB search measures the faces around a closest point whose smallest barycentric
#: coordinate is at most this (on an edge or corner, or within round-off of one).
TIE_BARY = 1e-9
#: The relaxation projects onto the fine surface with the exact search (True) or with the
#: former nearest-barycenter search (False, the default): exact projections change the
#: decimated meshes (vertices moved by up to 6% of the bounding box on PSB 21) and with them
#: the segmentations (69-87% matched agreement on PSB 1, 21, 301 at k 3-5), a change to be
#: scored on the benchmark before it is taken (benchmarks/results/pack_stage.md).
EXACT_RELAXATION = False
#: Tangential relaxation steps after decimation. Edge collapse leaves long thin triangles,
#: and the mesh-quality remedy then loses the Killing fields themselves: a unit sphere
#: decimated to 1500 faces kept its rotations at λ·area = 31 (0.3 after 3 steps, against
#: 25 for the next eigenvalue; tests/test_coarse.py).
RELAX_STEPS = 3
#: On an input with boundaries, decimation holes up to this many edges are closed (larger
#: loops are taken for the input's own boundaries).
SMALL_HOLE_EDGES = 12
#: Largest turn of a face's normal a relaxation move may cause (radians).
FOLD_LIMIT = np.pi / 4


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


@dataclass(frozen=True)
class CoarseMesh:
    """A decimated mesh to solve on, and the full-resolution mesh its results belong to.

    coarse : the cleaned decimated mesh (what a :class:`MeshBatch` packs; its ``name`` is the
        source's, so errors still name the file)
    fine : the cleaned full-resolution mesh; results are reported on its input faces
    vertices_on_coarse : the fine vertices located on ``coarse`` ([V_fine] points)
    faces_on_coarse : the fine face barycenters located on ``coarse`` ([F_fine] points)
    """

    coarse: CleanMesh
    fine: CleanMesh
    vertices_on_coarse: SurfacePoints
    faces_on_coarse: SurfacePoints

    @property
    def name(self) -> str:
        return self.fine.name

    def vertex_field(self, coarse_vertex_values: np.ndarray) -> np.ndarray:
        """[V_fine, ...] a per-coarse-vertex field, linearly interpolated at the fine vertices."""
        return self.vertices_on_coarse.interpolate(self.coarse.faces, coarse_vertex_values)

    @cached_property
    def fine_area(self) -> np.ndarray:
        """[F_fine] face areas of the fine mesh scaled to unit total area."""
        a = face_areas(self.fine.vertices, self.fine.faces)
        return a / a.sum()

    def face_values(self, coarse_face_values: np.ndarray) -> np.ndarray:
        """[F_fine, ...] per-coarse-face values at the fine faces (the coarse face under each
        fine barycenter)."""
        return np.asarray(coarse_face_values)[self.faces_on_coarse.face]


def decimate(mesh: Mesh | CleanMesh, faces: int) -> Mesh:
    """Quadric edge collapse of ``mesh`` to about ``faces`` faces, repaired to be edge-manifold.

    Returns a :class:`Mesh` (named like the input) for :func:`clean_mesh`. Raises
    :class:`MeshError` when nothing usable is left, :class:`ParameterError` for faces < 4.
    """
    if not isinstance(faces, (int, np.integer)) or isinstance(faces, bool) or faces < 4:
        raise ParameterError(f"the coarse face count must be an integer >= 4, got {faces!r}")
    try:
        import fast_simplification
    except ImportError:  # pragma: no cover - a dependency, absent only in a broken install
        raise ParameterError("coarse-to-fine solving needs the fast-simplification package "
                             "(pip install fast-simplification), or pass coarse_faces=None") from None
    clean = mesh if isinstance(mesh, CleanMesh) else clean_mesh(mesh)
    if len(clean.faces) <= faces:
        return Mesh(clean.vertices, clean.faces, name=clean.name)
    v, f = fast_simplification.simplify(np.ascontiguousarray(clean.vertices, dtype=np.float64),
                                        np.ascontiguousarray(clean.faces, dtype=np.int32),
                                        target_count=int(faces))
    f = _drop_small_components(_drop_non_manifold(np.asarray(f, dtype=np.int64)))
    if len(f) == 0:
        raise MeshError(clean.name, f"decimation to {faces} faces left nothing usable; "
                                    "solve at full resolution (coarse_faces=None)")
    # Holes the collapse or the repair opened are closed again (all of them when the input is
    # closed): the open-mesh boundary terms on a spurious hole of a few edges made R - σS1
    # indefinite at every shift on 9 of 300 PSB meshes.
    max_hole = None if clean.report.get("boundary_edges", 0) == 0 else SMALL_HOLE_EDGES
    surface = _BarycenterSearch(clean.vertices, clean.faces) if not EXACT_RELAXATION \
        else SurfaceIndex(clean.vertices, clean.faces)
    v, f = _fill_holes(np.asarray(v, dtype=np.float64), f, surface, max_hole)
    v = _relax_on_surface(v, f, surface, RELAX_STEPS)
    return Mesh(v, f, name=clean.name)


def _fill_holes(v: np.ndarray, f: np.ndarray, surface, max_edges: int | None):
    """Close each boundary loop (of at most ``max_edges`` edges; None: every loop) with a fan
    around a new vertex: the loop's centroid moved onto ``surface``.

    A boundary that passes a vertex twice (two holes touching at a corner, which the collapse
    and the removal of non-manifold faces leave) is cut there into simple loops
    (:func:`_boundary_loops`), each closed by its own fan: left open, its boundary terms made
    R - σS1 indefinite at every shift on 5 of the 380 PSB meshes, which were then solved at
    full resolution (up to 20x the time)."""
    half = _half_edges(f)
    n = len(v)
    key = half[:, 0] * n + half[:, 1]
    twin = np.isin(half[:, 1] * n + half[:, 0], key)
    boundary = half[~twin]
    if len(boundary) == 0:
        return v, f
    loops = [loop for loop in _boundary_loops(boundary)
             if len(loop) >= 3 and (max_edges is None or len(loop) <= max_edges)]
    if not loops:
        return v, f
    centers = np.array([v[loop].mean(axis=0) for loop in loops])
    centers = surface.locate(centers).on(surface)
    new = []
    for i, loop in enumerate(loops):
        c = n + i
        new += [(b, a, c) for a, b in zip(loop, loop[1:] + loop[:1])]   # against the boundary
    return np.concatenate([v, centers]), np.concatenate([f, np.array(new, dtype=np.int64)])


def _boundary_loops(boundary: np.ndarray) -> list:
    """The boundary half-edges [H, 2] (a -> b) as simple closed loops (lists of vertices, in
    order), in a fixed order (by first half-edge).

    Each walk follows the half-edges out of each vertex in their given order; when it comes
    back to a vertex already on its path, the part of the path since that vertex is a simple
    loop and is cut off (so a boundary through a vertex twice gives two loops). A path that
    ends where no half-edge leaves (not a closed boundary) is dropped."""
    out: dict = {}
    for a, b in boundary.tolist():
        out.setdefault(a, []).append(b)
    for nexts in out.values():
        nexts.reverse()                    # popped from the end: the given order
    loops = []
    for start in [int(a) for a in boundary[:, 0]]:
        if not out.get(start):
            continue
        path, at = [start], {start: 0}
        while True:
            nexts = out.get(path[-1])
            if not nexts:                  # back at start with no edge left, or an open end
                break
            y = nexts.pop()
            if y in at:
                cut = at[y]
                loops.append(path[cut:])
                for z in path[cut + 1:]:
                    del at[z]
                del path[cut + 1:]
            else:
                at[y] = len(path)
                path.append(y)
    return loops


def _relax_on_surface(v: np.ndarray, f: np.ndarray, surface, steps: int) -> np.ndarray:
    """Move each vertex halfway to the mean of its neighbours, within its tangent plane, then
    back onto ``surface`` (its closest point); ``steps`` times. Evens out triangle shapes while
    the mesh stays on the original surface."""
    if steps <= 0:
        return v
    adj = _vertex_adjacency(f, len(v))
    adj = ((adj + adj.T) > 0).astype(np.float64).tocsr()
    degree = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)[:, None]
    for _ in range(steps):
        before = _unit_normals(v, f)
        normal = np.zeros_like(v)
        np.add.at(normal, f.ravel(), np.repeat(before, 3, axis=0))
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        step = adj @ v / degree - v
        step -= (step * normal).sum(axis=1, keepdims=True) * normal
        moved = surface.locate(v + 0.5 * step).on(surface)
        for _ in range(8):
            # A move that turns a face by more than FOLD_LIMIT (a fold, or a sliver about to
            # become one) is undone for the face's corners; repeated until none is left.
            bad = (_unit_normals(moved, f) * before).sum(axis=1) < np.cos(FOLD_LIMIT)
            if not bad.any():
                break
            corners = np.unique(f[bad].ravel())
            moved[corners] = v[corners]
        v = moved
    return v


def _unit_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    n = face_cross_products(v, f)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _drop_non_manifold(f: np.ndarray) -> np.ndarray:
    """Remove faces on edges shared by more than two faces, until there are none, and both
    copies of a face repeated on the same three vertices (a flattened pocket)."""
    if len(f):
        _, _, inverse, counts = unique_rows(np.sort(f, axis=1))
        f = f[counts[inverse] == 1]
    for _ in range(16):
        if len(f) == 0:
            break
        edge_of_half = _undirected_edges(f).inverse                       # [3F], face-major
        bad = (np.bincount(edge_of_half)[edge_of_half] > 2).reshape(-1, 3).any(axis=1)
        if not bad.any():
            break
        f = f[~bad]
    return f


def _drop_small_components(f: np.ndarray) -> np.ndarray:
    if len(f) == 0:
        return f
    _, comp = connected_components(_vertex_adjacency(f, int(f.max()) + 1), directed=False)
    face_comp = comp[f[:, 0]]
    size = np.bincount(face_comp)
    return f[size[face_comp] >= MIN_COMPONENT_FACES]


class SurfaceIndex:
    """Exact closest points on a triangle mesh (vertices [V, 3], faces [F, 3]).

    Two searches give the closest face (among faces at the same distance the lowest index),
    with the barycentric coordinates and distance of :meth:`_closest`; they give the same bits
    except where two faces are equally near, within round-off, at two different points of the
    surface (a symmetric configuration), which each may settle its own way:

    * **AABB** (``search="aabb"``, the default where libigl imports): libigl's
      ``point_mesh_squared_distance`` (a bounding-box tree in C++) finds a closest face; a
      point whose closest point lies on an edge or corner of that face is as close to the faces
      around it, so those are measured too and the lowest index among the nearest kept.
      2.99x faster than the sample search over the PSB meshes decimated to 4000 faces
      (2.2-3.7x per mesh; the same bits at all but 30 of 11.5 million points;
      benchmarks/results/surface_map_aabb.md).
    * **samples** (``search="samples"``; the fallback without libigl, and the reference the
      tests hold the AABB search to): a ``cKDTree`` of sample points on the faces, each face
      sampled at the centers of a uniform L x L subdivision (L^2 sub-triangles, L by face
      size), so that every point of a face lies within ``rho`` of one of its own samples. That
      gives the bound the search rests on: a face none of whose samples is within ``u + rho``
      of a point is farther than ``u`` from it. It takes ``u`` from the nearest sample's face
      and measures the exact point-triangle distance to every face with a sample inside the
      ball, so it returns the true closest face (brute force's answer), where the
      nearest-barycenter candidates of a fixed count missed it for ~0.5% of the points on
      decimated PSB meshes (up to a third of an edge farther).
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
        same distance go to the lower face index)."""
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

    def _nearest_pairs(self, points: np.ndarray, pair_point: np.ndarray, pair_face: np.ndarray) -> SurfacePoints:
        """For each point of ``pair_point`` (ascending once sorted), the nearest of its candidate
        faces (pairs [M] with repeats allowed), the lowest face index among equal distances;
        one row per distinct point, in ascending point order."""
        n_faces = len(self.faces)
        key = np.sort(pair_point * n_faces + pair_face)
        key = key[np.r_[True, key[1:] != key[:-1]]]        # (np.unique: a slow hash in numpy 2.4)
        point, face = key // n_faces, key % n_faces       # by point, then by face
        bary, dist = self._closest(points[point], face)
        start = np.flatnonzero(np.r_[True, point[1:] != point[:-1]])      # each point's pairs
        lowest = np.repeat(np.minimum.reduceat(dist, start), np.diff(np.r_[start, len(point)]))
        at_min = np.flatnonzero(dist == lowest)
        best = at_min[np.r_[True, point[at_min][1:] != point[at_min][:-1]]]  # lowest face of the ties
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
        and the distance [N]: :func:`_closest_barycentric`'s Voronoi regions, with the six dot
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


class _BarycenterSearch:
    """The former closest-point search, kept for the relaxation (:data:`EXACT_RELAXATION`):
    the closest point among the ``candidates`` faces with the nearest barycenters. Not exact (on
    decimated PSB meshes it misses the closest face for ~0.5% of the points), but the decimated
    meshes, and so every result, stay those the benchmark scores were measured with."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, candidates: int = 8):
        self.vertices, self.faces, self.candidates = vertices, faces, candidates
        self.tri = vertices[faces]                                        # [F, 3, 3]
        self.tree = cKDTree(self.tri.mean(axis=1))

    def locate(self, points: np.ndarray) -> SurfacePoints:
        k = int(min(self.candidates, len(self.faces)))
        _, cand = self.tree.query(points, k=k)
        cand = cand.reshape(len(points), k)
        a, b, c = (self.tri[cand, i] for i in range(3))                  # [P, k, 3] each
        bary = _closest_barycentric(points[:, None, :], a, b, c)          # [P, k, 3]
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


def _subtriangle_centers(n: int) -> np.ndarray:
    """[n^2, 2] (u, v) of the centers of the n x n subdivision of a triangle
    (point a + u (b - a) + v (c - a)): n(n+1)/2 upward and n(n-1)/2 downward sub-triangles."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    up = (i + j) <= n - 1
    down = (i + j) <= n - 2
    uv = np.concatenate([np.stack([i[up] + 1 / 3, j[up] + 1 / 3], axis=1),
                         np.stack([i[down] + 2 / 3, j[down] + 2 / 3], axis=1)])
    return uv / n


def _point_triangle(points: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric coordinates [N, 3] of the closest point of triangle tri[i] ([N, 3, 3]) to
    points[i] ([N, 3]), and the distance [N]."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    bary = _closest_barycentric(points, a, b, c)
    closest = bary[..., 0:1] * a + bary[..., 1:2] * b + bary[..., 2:3] * c
    return bary, np.linalg.norm(closest - points, axis=-1)


def locate_on_surface(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                      index: SurfaceIndex | None = None) -> SurfacePoints:
    """The closest point of the triangle mesh (vertices [V, 3], faces [F, 3]) to each of
    ``points`` [P, 3], exact (see :class:`SurfaceIndex`; ``index``: one prebuilt for this
    mesh, to reuse over several calls)."""
    index = SurfaceIndex(vertices, faces) if index is None else index
    return index.locate(points)


def _closest_barycentric(p, a, b, c):
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


def coarse_mesh(mesh: Mesh | CleanMesh, faces: int) -> CoarseMesh | None:
    """The :class:`CoarseMesh` of ``mesh`` at about ``faces`` faces, or None when the mesh
    has at most :data:`DECIMATE_ABOVE` x ``faces`` faces (it is then solved as it is)."""
    fine = mesh if isinstance(mesh, CleanMesh) else clean_mesh(mesh)
    if len(fine.faces) <= DECIMATE_ABOVE * faces:
        return None
    coarse = clean_mesh(decimate(fine, faces))
    centers = fine.vertices[fine.faces].mean(axis=1)
    on_coarse = SurfaceIndex(coarse.vertices, coarse.faces).locate(np.concatenate([fine.vertices, centers]))
    nv = len(fine.vertices)
    part = lambda sl: SurfacePoints(on_coarse.face[sl], on_coarse.bary[sl], on_coarse.distance[sl])  # noqa: E731
    return CoarseMesh(coarse=coarse, fine=fine, vertices_on_coarse=part(slice(0, nv)),
                      faces_on_coarse=part(slice(nv, None)))


__all__ = ["CoarseMesh", "SurfaceIndex", "SurfacePoints", "coarse_mesh", "decimate", "locate_on_surface",
           "DEFAULT_COARSE_FACES"]
