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
from .clean import CleanMesh, _undirected_edges, _vertex_adjacency, clean_mesh, face_areas, face_cross_products
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
#: Candidate coarse faces (nearest by barycenter) tested for each fine point.
CANDIDATES = 8
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
        corners = vertex_values[faces[self.face]]                         # [P, 3, ...]
        w = self.bary.reshape(self.bary.shape + (1,) * (corners.ndim - 2))
        return (corners * w).sum(axis=1)

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
    v, f = _fill_holes(np.asarray(v, dtype=np.float64), f, clean, max_hole)
    v = _relax_on_surface(v, f, clean, RELAX_STEPS)
    return Mesh(v, f, name=clean.name)


def _fill_holes(v: np.ndarray, f: np.ndarray, surface: CleanMesh, max_edges: int | None):
    """Close each boundary loop (of at most ``max_edges`` edges; None: every loop) with a fan
    around a new vertex: the loop's centroid moved onto ``surface``. Loops through a vertex
    with several boundary edges out of it are left open."""
    half = np.stack([f, np.roll(f, -1, axis=1)], axis=2).reshape(-1, 2)
    n = len(v)
    key = half[:, 0] * n + half[:, 1]
    twin = np.isin(half[:, 1] * n + half[:, 0], key)
    boundary = half[~twin]
    if len(boundary) == 0:
        return v, f
    nxt: dict = {}
    ambiguous = set()
    for a, b in boundary.tolist():
        if a in nxt:
            ambiguous.add(a)
        nxt[a] = b
    seen, loops = set(), []
    for start in list(nxt):
        if start in seen:
            continue
        loop, x, ok = [], start, True
        while x not in seen:
            seen.add(x)
            loop.append(x)
            if x in ambiguous or x not in nxt:
                ok = False
                break
            x = nxt[x]
        if ok and x == start and len(loop) >= 3 and (max_edges is None or len(loop) <= max_edges):
            loops.append(loop)
    if not loops:
        return v, f
    centers = np.array([v[loop].mean(axis=0) for loop in loops])
    centers = locate_on_surface(surface.vertices, surface.faces, centers).on(surface)
    new = []
    for i, loop in enumerate(loops):
        c = n + i
        new += [(b, a, c) for a, b in zip(loop, loop[1:] + loop[:1])]   # against the boundary
    return np.concatenate([v, centers]), np.concatenate([f, np.array(new, dtype=np.int64)])


def _relax_on_surface(v: np.ndarray, f: np.ndarray, surface: CleanMesh, steps: int) -> np.ndarray:
    """Move each vertex halfway to the mean of its neighbours, within its tangent plane, then
    back onto ``surface`` (its closest point); ``steps`` times. Evens out triangle shapes while
    the mesh stays on the original surface."""
    if steps <= 0:
        return v
    adj = _vertex_adjacency(f, len(v))
    adj = ((adj + adj.T) > 0).astype(np.float64).tocsr()
    degree = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)[:, None]
    tree = cKDTree(surface.vertices[surface.faces].mean(axis=1))
    for _ in range(steps):
        before = _unit_normals(v, f)
        normal = np.zeros_like(v)
        np.add.at(normal, f.ravel(), np.repeat(before, 3, axis=0))
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
        step = adj @ v / degree - v
        step -= (step * normal).sum(axis=1, keepdims=True) * normal
        moved = locate_on_surface(surface.vertices, surface.faces, v + 0.5 * step, tree=tree).on(surface)
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
        _, inverse, counts = np.unique(np.sort(f, axis=1), axis=0, return_inverse=True, return_counts=True)
        f = f[counts[inverse.reshape(-1)] == 1]
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


def locate_on_surface(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                      candidates: int = CANDIDATES, tree: cKDTree | None = None) -> SurfacePoints:
    """The closest point of the triangle mesh (vertices [V, 3], faces [F, 3]) to each of
    ``points`` [P, 3], searched among the ``candidates`` faces with the nearest barycenters
    (``tree``: a prebuilt ``cKDTree`` of those barycenters)."""
    tri = vertices[faces]                                                 # [F, 3, 3]
    k = int(min(candidates, len(faces)))
    tree = cKDTree(tri.mean(axis=1)) if tree is None else tree
    _, cand = tree.query(points, k=k)
    cand = cand.reshape(len(points), k)
    a, b, c = (tri[cand, i] for i in range(3))                           # [P, k, 3] each
    bary = _closest_barycentric(points[:, None, :], a, b, c)             # [P, k, 3]
    closest = bary[..., 0:1] * a + bary[..., 1:2] * b + bary[..., 2:3] * c
    dist = np.linalg.norm(closest - points[:, None, :], axis=-1)          # [P, k]
    best = dist.argmin(axis=1)
    rows = np.arange(len(points))
    return SurfacePoints(face=cand[rows, best].astype(np.int64), bary=bary[rows, best],
                         distance=dist[rows, best])


def _closest_barycentric(p, a, b, c):
    """Barycentric coordinates [..., 3] of the point of triangle (a, b, c) closest to p, by the
    Voronoi regions of its vertices, edges and interior (Ericson, Real-Time Collision
    Detection, 5.1.5), every region evaluated and the first that applies kept."""
    dot = lambda x, y: np.einsum("...i,...i->...", x, y)  # noqa: E731
    ab, ac = b - a, c - a
    ap, bp, cp = p - a, p - b, p - c
    d1, d2 = dot(ab, ap), dot(ac, ap)
    d3, d4 = dot(ab, bp), dot(ac, bp)
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        den = va + vb + vc
        v_in, w_in = vb / den, vc / den
    zero, one = np.zeros_like(d1), np.ones_like(d1)
    regions = [
        ((d1 <= 0) & (d2 <= 0), (one, zero, zero)),
        ((d3 >= 0) & (d4 <= d3), (zero, one, zero)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), (1 - t_ab, t_ab, zero)),
        ((d6 >= 0) & (d5 <= d6), (zero, zero, one)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), (1 - t_ac, zero, t_ac)),
        ((va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), (zero, 1 - t_bc, t_bc)),
    ]
    conds = [r[0] for r in regions]
    out = [np.select(conds, [r[1][i] for r in regions], default=d)
           for i, d in enumerate((1 - v_in - w_in, v_in, w_in))]
    return np.nan_to_num(np.stack(out, axis=-1), nan=1.0 / 3.0)


def coarse_mesh(mesh: Mesh | CleanMesh, faces: int) -> CoarseMesh | None:
    """The :class:`CoarseMesh` of ``mesh`` at about ``faces`` faces, or None when the mesh
    has at most :data:`DECIMATE_ABOVE` x ``faces`` faces (it is then solved as it is)."""
    fine = mesh if isinstance(mesh, CleanMesh) else clean_mesh(mesh)
    if len(fine.faces) <= DECIMATE_ABOVE * faces:
        return None
    coarse = clean_mesh(decimate(fine, faces))
    centers = fine.vertices[fine.faces].mean(axis=1)
    return CoarseMesh(coarse=coarse, fine=fine,
                      vertices_on_coarse=locate_on_surface(coarse.vertices, coarse.faces, fine.vertices),
                      faces_on_coarse=locate_on_surface(coarse.vertices, coarse.faces, centers))


__all__ = ["CoarseMesh", "SurfacePoints", "coarse_mesh", "decimate", "locate_on_surface",
           "DEFAULT_COARSE_FACES"]
