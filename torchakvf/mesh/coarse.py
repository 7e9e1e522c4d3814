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

from ..errors import MeshError, ParameterError
from .clean import (
    CleanMesh,
    clean_mesh,
    face_areas,
    face_cross_products,
    half_edges,
    undirected_edges,
    unique_rows,
    vertex_adjacency,
)
from .mesh import Mesh
from .surface_map import BarycenterSearch, SurfaceIndex, SurfacePoints, locate_on_surface

#: Face count the CLI commands that segment decimate to by default (the PSB scores against
#: full resolution: see docs/design.md).
DEFAULT_COARSE_FACES = 4000
#: Meshes with at most this many times the target face count are solved as they are: the
#: saving would be small and the transfer not free.
DECIMATE_ABOVE = 1.25
#: Components of a decimated mesh with fewer faces are dropped (cut off by the repair; a
#: near-flat scrap of a few faces has spurious zero-energy modes).
MIN_COMPONENT_FACES = 8
#: Tangential relaxation steps after decimation. Edge collapse leaves long thin triangles,
#: and the mesh-quality remedy then loses the Killing fields themselves: unrelaxed, a unit
#: sphere decimated to 1500 faces has its rotations at λ·area = 31, above the next eigenvalue
#: (25); after 3 steps at 0.3 (tests/test_coarse.py).
RELAX_STEPS = 3
#: On an input with boundaries, decimation holes up to this many edges are closed (larger
#: loops are taken for the input's own boundaries).
SMALL_HOLE_EDGES = 12
#: A decimation that folds the surface over (edge collapse checks no self-intersection: the
#: flat cap of a thin flange collapses into a fan of long triangles that cuts through the hub
#: on it) puts part of the fine surface above coarse faces pointing the other way. Where that
#: share of the fine area (:func:`folded_share`) is above this, the mesh is decimated again to
#: twice the face count, up to :data:`DECIMATE_RETRIES` times (past 1.25x the fine face count:
#: solved as it is). On the PSB the share is 0 on the median mesh, 2.3 % at the 99th
#: percentile (thin-walled cups, inner and outer walls collapsed together, where more faces did
#: not help: experiments/results/generality_decimation.md).
FOLDED_SHARE = 0.05
DECIMATE_RETRIES = 2
#: Coordinate grid of the canonical frame (:func:`canonical_frame`), relative to its size
#: (:data:`FRAME_SIZE`): far below a face width of any mesh worth decimating.
FRAME_GRID = 2.0 ** -24
#: The square root of the surface's area in the canonical frame: every copy of a shape, in any
#: unit of length, is collapsed at this one size. The collapse's error thresholds are absolute,
#: so at a small size they pass many edges at once and it collapses less evenly: an icosphere of
#: 5,120 faces decimated to 1,000 keeps its three rotations from size 3 up, not at 2 or below.
#: The smallest such size, nearest the sizes the descriptors' boundary model and evidence were
#: made at (medians: the PSB 1.6, the procedural corpus 1.9); at 8 the coarse meshes' faces are
#: less even and the PSB's Mech meshes lost most of their boundary precision (docs/descriptors.md,
#: Units of length).
FRAME_SIZE = 3.0
#: Largest turn of a face's normal a relaxation move may cause (radians).
FOLD_LIMIT = np.pi / 4
#: The collapse's error thresholds are absolute (squared lengths), so how a shape decimates
#: depends on its unit of length. The defaults were chosen on meshes whose square root of the
#: area lies between these bounds (all but one of the 380 PSB meshes, the procedural corpus but
#: its largest pipe fittings, the built-in shapes); a mesh outside them is collapsed scaled by a
#: power of two to a size in [1, 2), where the PSB's meshes are typical (:func:`decimation_scale`),
#: so a part modelled in metres or in micrometres decimates as it would in the units of those
#: meshes, and a copy 1/1000 and one 1000 times the size decimate alike.
DECIMATE_SIZE = (0.25, 8.0)


@dataclass(frozen=True)
class CoarseMesh:
    """A decimated mesh to solve on, and the full-resolution mesh its results belong to.

    coarse : the cleaned decimated mesh (what a :class:`MeshBatch` packs; its ``name`` is the
        source's, so errors still name the file)
    fine : the cleaned full-resolution mesh; results are reported on its input faces
    vertices_on_coarse : the fine vertices located on ``coarse`` ([V_fine] points)
    faces_on_coarse : the fine face barycenters located on ``coarse`` ([F_fine] points)
    faces_asked : the face count the decimation aimed at (None: not recorded)
    canonical : whether ``coarse`` was collapsed in the surface's canonical frame
        (:func:`decimate`)
    """

    coarse: CleanMesh
    fine: CleanMesh
    vertices_on_coarse: SurfacePoints
    faces_on_coarse: SurfacePoints
    faces_asked: int | None = None
    canonical: bool = False

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


def decimate(mesh: Mesh | CleanMesh, faces: int, *, canonical: bool = False) -> Mesh:
    """Quadric edge collapse of ``mesh`` to about ``faces`` faces, repaired to be edge-manifold.

    canonical : run the collapse in :func:`canonical_frame` (numbering, pose and size made
        from the surface alone: :data:`FRAME_SIZE`), so that a moved or renumbered copy, or one
        in another unit of length, decimates to the same surface (its coarse mesh is this one
        moved and scaled, vertex for vertex). The default collapses the input as
        numbered: its sweep follows the face order and breaks exact ties on the coordinates'
        round-off, so such a copy decimates to another surface. The per-face descriptors use
        the canonical collapse; segmentations use the default (their defaults were chosen on it).
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
    size = decimation_scale(clean.vertices, clean.faces)
    v = None
    if canonical:
        u, g, to_input = canonical_frame(clean.vertices, clean.faces)     # at FRAME_SIZE already
        v, f = fast_simplification.simplify(u, g, target_count=int(faces))
        v = to_input(np.asarray(v, dtype=np.float64))
        # The collapse is not rotation-invariant: on some meshes (PSB 141, any rotation of which
        # collapses less evenly than its modelling frame) it stalls in the principal frame above
        # the target, leaving faces of 100x the mean area. There the input's own collapse is the
        # better surface, at the price of invariance.
        if len(f) > DECIMATE_ABOVE * faces:
            v = None
    if v is None:
        v, f = fast_simplification.simplify(np.ascontiguousarray(clean.vertices, dtype=np.float64) * size,
                                            np.ascontiguousarray(clean.faces, dtype=np.int32),
                                            target_count=int(faces))
        v = np.asarray(v, dtype=np.float64) / size
    f = _drop_small_components(drop_non_manifold(np.asarray(f, dtype=np.int64)))
    if len(f) == 0:
        raise MeshError(clean.name, f"decimation to {faces} faces left nothing usable; "
                                    "solve at full resolution (coarse_faces=None)")
    # Holes the collapse or the repair opened are closed again (all of them when the input is
    # closed): the open-mesh boundary terms on a spurious hole of a few edges make R - σS1
    # indefinite at every shift (on 9 of the 300 labelled PSB meshes).
    max_hole = None if clean.report.get("boundary_edges", 0) == 0 else SMALL_HOLE_EDGES
    surface = BarycenterSearch(clean.vertices, clean.faces)
    v, f = fill_holes(np.asarray(v, dtype=np.float64), f, surface, max_hole)
    v = _relax_on_surface(v, f, surface, RELAX_STEPS)
    return Mesh(v, f, name=clean.name)


def decimation_scale(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The power of two the collapse scales the mesh by: 1.0 where the square root of its area
    lies in :data:`DECIMATE_SIZE` [lo, hi), else the one that brings it into [1, 2).
    vertices : [V, 3]; faces : [F, 3]."""
    size = float(np.sqrt(face_areas(np.asarray(vertices, dtype=np.float64), np.asarray(faces)).sum()))
    lo, hi = DECIMATE_SIZE
    if not np.isfinite(size) or size <= 0.0 or lo <= size < hi:
        return 1.0
    return float(2.0 ** -np.floor(np.log2(size)))


def canonical_frame(vertices: np.ndarray, faces: np.ndarray):
    """(u [V, 3] float64, g [F, 3] int32, to_input): the mesh in a frame and numbering made
    from the surface alone, so that a moved or renumbered copy gives the same arrays.

    The frame: centred on the area centroid, rotated onto the principal axes of the area (each
    axis pointing where the third moment is positive, the third making a rotation), scaled to
    the area :data:`FRAME_SIZE` squared (so a copy in another unit of length gets the same frame
    up to round-off), coordinates rounded to :data:`FRAME_GRID` times that size (the collapse then
    sees the same bits, not a rotation's rounding noise, which flips its many exact ties on flat
    regions). Vertices are numbered in lexicographic order of their coordinates there, faces
    by their vertices' numbers (each face starting at its lowest, orientation kept).
    ``to_input(points)`` maps [P, 3] points of the frame back. Where the axes are not unique
    (equal principal moments, a symmetric third moment) another copy may get another frame: the
    same surface, differently sampled.
    """
    u, to_input = _principal_frame(vertices, faces)
    order, g, face_order = _canonical_numbering(u, faces)
    return np.ascontiguousarray(u[order]), np.ascontiguousarray(g[face_order], dtype=np.int32), to_input


def canonical_numbering(vertices: np.ndarray, faces: np.ndarray):
    """(vertex order [V], new faces [F, 3], face order [F], frame vertices [V, 3]) of
    :func:`canonical_frame`: ``vertices[vertex order]`` with ``new faces`` (in that numbering,
    each starting at its lowest vertex, orientation kept) is the mesh numbered from its surface
    alone; new face i is input face ``face order[i]``; ``frame vertices`` are the new vertices
    in the canonical frame."""
    u, _ = _principal_frame(vertices, faces)
    order, g, face_order = _canonical_numbering(u, faces)
    return order, g[face_order], face_order, np.ascontiguousarray(u[order])


def _sum(terms: np.ndarray) -> np.ndarray:
    """Σ over axis 0 in an order set by the values alone: the same bits for any order of the
    faces (their round-off decides the frame of a shape whose principal moments are equal)."""
    return np.sort(terms, axis=0).sum(axis=0)


def _principal_frame(vertices: np.ndarray, faces: np.ndarray):
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    # each face's corners in lexicographic order: its area and centroid do not depend on where
    # its vertex list starts, nor on the numbering
    corners = v[f].reshape(-1, 3)
    order = np.lexsort((corners[:, 2], corners[:, 1], corners[:, 0], np.repeat(np.arange(len(f)), 3)))
    vf = corners[order].reshape(-1, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(vf[:, 1] - vf[:, 0], vf[:, 2] - vf[:, 0]), axis=1)
    centroid = (vf[:, 0] + vf[:, 1] + vf[:, 2]) / 3.0
    total = max(float(_sum(area)), 1e-300)
    center = _sum(area[:, None] * centroid) / total
    c = (centroid - center) / np.sqrt(total)
    second = _sum(area[:, None, None] * c[:, :, None] * c[:, None, :]) / total
    _, axes = np.linalg.eigh(0.5 * (second + second.T))
    third = _sum(area[:, None] * (c @ axes) ** 3)
    axes = axes * np.where(third < 0, -1.0, 1.0)
    # a rotation, not a mirror, so that the frame keeps the faces' orientation
    axes[:, 2] = np.cross(axes[:, 0], axes[:, 1])
    # one size for every copy: the collapse's error thresholds are absolute, so a copy in
    # another unit would otherwise decimate to another surface (not unit area: an icosphere
    # of area 4π scaled to it decimates less evenly and loses its rotations)
    scale = FRAME_SIZE / np.sqrt(total)
    grid = FRAME_GRID * FRAME_SIZE
    u = np.round(((v - center) @ axes) * scale / grid) * grid

    def to_input(points: np.ndarray) -> np.ndarray:
        return (np.asarray(points, dtype=np.float64) / scale) @ axes.T + center
    return u, to_input


def _canonical_numbering(u: np.ndarray, faces: np.ndarray):
    """(vertex order [V], faces [F, 3] renumbered and rolled, face order [F]) from frame
    coordinates u."""
    order = np.lexsort((u[:, 2], u[:, 1], u[:, 0]))
    rank = np.empty(len(u), dtype=np.int64)
    rank[order] = np.arange(len(u))
    g = rank[np.asarray(faces, dtype=np.int64)]
    first = g.argmin(axis=1)
    g = np.take_along_axis(g, (first[:, None] + np.arange(3)) % 3, axis=1)
    return order, g, np.lexsort((g[:, 2], g[:, 1], g[:, 0]))


def fill_holes(v: np.ndarray, f: np.ndarray, surface, max_edges: int | None):
    """Close each boundary loop (of at most ``max_edges`` edges; None: every loop) with a fan
    around a new vertex: the loop's centroid moved onto ``surface``.

    A boundary that passes a vertex twice (two holes touching at a corner, which the collapse
    and the removal of non-manifold faces leave) is cut there into simple loops
    (:func:`boundary_loops`), each closed by its own fan: left open, its boundary terms make
    R - σS1 indefinite at every shift on a few PSB meshes, which must then be solved at full
    resolution (up to 20x the time)."""
    half = half_edges(f)
    n = len(v)
    key = half[:, 0] * n + half[:, 1]
    twin = np.isin(half[:, 1] * n + half[:, 0], key)
    boundary = half[~twin]
    if len(boundary) == 0:
        return v, f
    loops = [loop for loop in boundary_loops(boundary)
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


def boundary_loops(boundary: np.ndarray) -> list:
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
    adj = vertex_adjacency(f, len(v))
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


def drop_non_manifold(f: np.ndarray) -> np.ndarray:
    """Remove faces on edges shared by more than two faces, until there are none, and both
    copies of a face repeated on the same three vertices (a flattened pocket)."""
    if len(f):
        _, _, inverse, counts = unique_rows(np.sort(f, axis=1))
        f = f[counts[inverse] == 1]
    for _ in range(16):
        if len(f) == 0:
            break
        edge_of_half = undirected_edges(f).inverse                       # [3F], face-major
        bad = (np.bincount(edge_of_half)[edge_of_half] > 2).reshape(-1, 3).any(axis=1)
        if not bad.any():
            break
        f = f[~bad]
    return f


def _drop_small_components(f: np.ndarray) -> np.ndarray:
    if len(f) == 0:
        return f
    _, comp = connected_components(vertex_adjacency(f, int(f.max()) + 1), directed=False)
    face_comp = comp[f[:, 0]]
    size = np.bincount(face_comp)
    return f[size[face_comp] >= MIN_COMPONENT_FACES]


def coarse_mesh(mesh: Mesh | CleanMesh, faces: int, *, canonical: bool = False) -> CoarseMesh | None:
    """The :class:`CoarseMesh` of ``mesh`` at about ``faces`` faces, or None when the mesh
    has at most :data:`DECIMATE_ABOVE` x ``faces`` faces (it is then solved as it is).
    A decimation that folds more than :data:`FOLDED_SHARE` of the surface over is made again
    at 2x, then 4x the faces (the least folded is kept; ``faces_asked`` records its count; None
    where the count passes the fine mesh's). ``canonical``: :func:`decimate`'s (the per-face
    descriptors' coarse mesh)."""
    fine = mesh if isinstance(mesh, CleanMesh) else clean_mesh(mesh)
    asked, best = int(faces), None
    for _ in range(DECIMATE_RETRIES + 1):
        if len(fine.faces) <= DECIMATE_ABOVE * asked:
            return None
        made = coarse_mesh_at(fine, asked, canonical)
        share = folded_share(made)
        if best is None or share < best[0]:
            best = (share, made)
        if share <= FOLDED_SHARE:
            break
        asked *= 2
    return best[1]


def coarse_mesh_at(fine: CleanMesh, faces: int, canonical: bool = False) -> CoarseMesh:
    """The :class:`CoarseMesh` of the cleaned ``fine`` decimated once to about ``faces`` faces,
    folded or not (:func:`coarse_mesh` makes it again where it folds)."""
    # the decimated surface is not welded: a few of its vertices lie within round-off of each
    # other after the collapse (1 of 362 decimated PSB meshes), and the segmentation's defaults
    # were chosen on the surface as collapsed
    coarse = clean_mesh(decimate(fine, faces, canonical=True) if canonical else decimate(fine, faces), weld=False)
    centers = fine.vertices[fine.faces].mean(axis=1)
    on_coarse = SurfaceIndex(coarse.vertices, coarse.faces).locate(np.concatenate([fine.vertices, centers]))
    nv = len(fine.vertices)
    part = lambda sl: SurfacePoints(on_coarse.face[sl], on_coarse.bary[sl], on_coarse.distance[sl])  # noqa: E731
    return CoarseMesh(coarse=coarse, fine=fine, vertices_on_coarse=part(slice(0, nv)),
                      faces_on_coarse=part(slice(nv, None)), faces_asked=int(faces), canonical=canonical)


def folded_share(cm: CoarseMesh, cos_below: float = 0.0) -> float:
    """The share of the fine surface's area whose faces point against the coarse face under
    their barycentre (the cosine between their normals below ``cos_below``; at 0: where the
    decimation folded the surface over or collapsed a part thinner than its edges into a
    sheet, 0 on a faithful decimation)."""
    nf = face_cross_products(cm.fine.vertices, cm.fine.faces)
    nc = face_cross_products(cm.coarse.vertices, cm.coarse.faces)[cm.faces_on_coarse.face]
    area = np.linalg.norm(nf, axis=1)
    total = float(area.sum())
    cos = (nf * nc).sum(axis=1) / np.maximum(area * np.linalg.norm(nc, axis=1), 1e-300)
    return float(area[cos < cos_below].sum()) / total if total > 0 else 0.0


__all__ = ["CoarseMesh", "SurfaceIndex", "SurfacePoints", "canonical_frame", "canonical_numbering", "coarse_mesh",
           "coarse_mesh_at", "decimate", "decimation_scale", "folded_share", "locate_on_surface",
           "DEFAULT_COARSE_FACES", "DECIMATE_ABOVE", "DECIMATE_RETRIES", "DECIMATE_SIZE", "FOLDED_SHARE", "FRAME_GRID",
           "FRAME_SIZE"]
