"""Validation and clean-up of one mesh, with index maps back to the input's faces.

What is repaired (and counted in ``CleanMesh.report``): exact duplicate vertices are merged,
distinct vertices within round-off of each other (:data:`WELD_DISTANCE`) are welded, faces with
a repeated vertex index, faces reaching an outlier vertex (:data:`OUTLIER_DISTANCE`),
zero-area faces and repeated faces are dropped (with
``zip_cracks=True`` the crack a dropped needle face leaves is zipped shut), edges shared by two
sheets touching along them (an even number of faces, alternating in direction around the edge)
are split into edges of two faces (:func:`split_non_manifold_edges`), faces are re-oriented
consistently per component and closed components turned to face outward
(:func:`orient_outward`), unreferenced vertices are removed.
What is refused (``MeshError``): other non-manifold edges (an odd number of faces on them, or
faces that do not pair into sheets), non-orientable surfaces, and meshes with nothing left
after clean-up.
Open boundaries and several connected components are supported as they are.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import MeshError
from .mesh import Mesh

#: Faces with area below this fraction of the mean face area are treated as degenerate:
#: their cotangents are unbounded and their star2 = 1/A is infinite.
DEGENERATE_AREA_FRACTION = 1e-10

#: Distinct vertices closer than this fraction of the mesh's spread (:data:`OUTLIER_DISTANCE`)
#: are welded into one. Marching cubes puts two vertices 1e-16..1e-14 apart where the surface
#: passes through a grid point (a slab's face on a grid plane); the faces between them have zero
#: area and are dropped, and without the weld the drop cuts the surface apart along the plane (a
#: disc's top from its rim: two components with open boundaries). No PSB mesh nor procedural corpus shape
#: has two vertices within 1e-8 of its bounding-box diagonal (a few spreads), so the weld touches
#: only such meshes. Decimated meshes are not welded (:func:`clean_mesh`'s ``weld``).
WELD_DISTANCE = 1e-10

#: A face with an edge longer than this many times the mesh's spread (the median distance of
#: its vertices from their coordinate-wise median) reaches an outlier vertex (a stray
#: coordinate such as 1e12), and is dropped: its area would dwarf the mesh's (every other face
#: would then look degenerate) and its edges would set the mesh's scale. The measure is
#: scale-free and robust (a median, which no handful of vertices moves), and it keeps a small
#: part far from the rest, whose own edges are short. On the 380 Princeton Segmentation
#: Benchmark meshes the longest edge is 1.3 spreads (mesh 30), so none loses a face.
OUTLIER_DISTANCE = 1000.0


@dataclass(frozen=True)
class CleanMesh:
    """A validated, cleaned mesh and the maps back to the input it came from.

    Attributes
    ----------
    vertices : [V, 3] float64
    faces : [F, 3] int64, consistently oriented
    face_index : [F] int64, for each kept face the index of the input face it is
    n_input_faces : int, face count of the input (file order is 0..n_input_faces-1)
    face_component : [F] int64, connected component of each face (0..n_components-1)
    name : str
    report : dict, counts of what clean-up changed
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_index: np.ndarray
    n_input_faces: int
    face_component: np.ndarray
    name: str
    input_faces: np.ndarray = field(repr=False)
    report: dict = field(default_factory=dict)

    @property
    def n_components(self) -> int:
        return int(self.face_component.max()) + 1

    def to_input_faces(self, values: np.ndarray, fill=0) -> np.ndarray:
        """Scatter per-face ``values`` [F, ...] onto the input's faces [n_input_faces, ...].

        Dropped (degenerate) input faces get ``fill``.
        """
        values = np.asarray(values)
        out = np.full((self.n_input_faces,) + values.shape[1:], fill, dtype=values.dtype)
        out[self.face_index] = values
        return out

    def labels_to_input_faces(self, labels: np.ndarray) -> np.ndarray:
        """Per-face integer labels [F] onto the input's faces [n_input_faces].

        A dropped face takes the most common label among the kept faces sharing a vertex with
        it (a degenerate sliver belongs to the part around it; ties go to the smaller label);
        clusters of dropped faces fill in from the outside over a few passes; -1 where no
        labelled face is near.
        """
        out = self.to_input_faces(np.asarray(labels, dtype=np.int64), fill=-1)
        kept = np.zeros(self.n_input_faces, dtype=bool)
        kept[self.face_index] = True
        dropped = np.flatnonzero(~kept)           # np.setdiff1d's answer, without its sorts
        if len(dropped) == 0:
            return out
        n_vertices = int(self.input_faces.max()) + 1
        # Vertex-face incidence of the input; (incidence^T incidence) links faces sharing a vertex.
        inc = sp.csr_matrix((np.ones(3 * self.n_input_faces), (self.input_faces.ravel(),
                             np.repeat(np.arange(self.n_input_faces), 3))),
                            shape=(n_vertices, self.n_input_faces))
        near = (inc[:, dropped].T @ inc).tocsr()                      # [D, F_input]
        for _ in range(3):
            todo = np.flatnonzero(out[dropped] < 0)
            if len(todo) == 0:
                break
            filled = out.copy()
            for row in todo:
                nb = near.indices[near.indptr[row]:near.indptr[row + 1]]
                lab = out[nb]
                lab = lab[lab >= 0]
                if len(lab):
                    filled[dropped[row]] = np.bincount(lab).argmax()
            out = filled
        return out


def face_cross_products(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[F, 3] (p1 - p0) x (p2 - p0) per triangle: twice the area times the unit normal
    (the one place numpy code gets face areas and normals from; the torch operators compute
    theirs in :func:`torchakvf.operators.geometry.batch_geometry`)."""
    p = vertices[faces]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangle areas [F] (units of length^2)."""
    return 0.5 * np.linalg.norm(face_cross_products(vertices, faces), axis=1)


def clean_mesh(mesh: Mesh, zip_cracks: bool = True, weld: bool = True) -> CleanMesh:
    """Validate and clean ``mesh``; see the module docstring for what is repaired or refused.

    zip_cracks : close the crack that dropping a needle face (zero area, one vertex on the
        opposite edge) opens, by splitting the face across it (:func:`_zip_cracks`).
        A crack is a zero-area hole whose open-boundary terms cost Killing modes (a sphere with
        one loses a rotation) or make R - σS1 indefinite at every shift (PSB 351, the only PSB
        mesh with such faces: 20 of them; zipped, it solves at full resolution). False: the
        faces are just dropped.
    weld : weld distinct vertices within :data:`WELD_DISTANCE` of each other (an input's
        round-off pairs). False: only exact duplicates are merged (a decimated mesh, whose
        close vertices are the collapse's own, is cleaned so).
    """
    name = mesh.name
    report = {}
    # Merge exact duplicate vertices (STL and many exporters write one copy per face).
    verts, first_input, inverse, _ = unique_rows(mesh.vertices)
    report["merged_vertices"] = mesh.n_vertices - len(verts)
    root = weld_roots(verts) if weld else None
    report["welded_vertices"] = 0 if root is None else int((root != np.arange(len(verts))).sum())
    if root is not None:
        reps = np.flatnonzero(root == np.arange(len(verts)))
        number = np.full(len(verts), -1, dtype=np.int64)
        number[reps] = np.arange(len(reps))
        verts, first_input, inverse = verts[reps], first_input[reps], number[root][inverse]
    faces = inverse[mesh.faces]
    keep = np.arange(mesh.n_faces)

    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    report["repeated_index_faces"] = int(repeated.sum())
    faces, keep = faces[~repeated], keep[~repeated]
    if len(faces) == 0:
        raise MeshError(name, "every face repeats a vertex index; nothing is left to process")

    outlier = faces_at_outliers(verts, faces)
    report["outlier_faces"] = int(outlier.sum())
    faces, keep = faces[~outlier], keep[~outlier]
    if len(faces) == 0:
        raise MeshError(name, "every face touches an outlier vertex (a coordinate far from all "
                              "the others); nothing is left to process")

    area = face_areas(verts, faces)
    degenerate = area <= DEGENERATE_AREA_FRACTION * area.mean()
    report["zero_area_faces"] = int(degenerate.sum())
    if zip_cracks and degenerate.any():
        faces, keep, report["zipped_cracks"] = _zip_cracks(verts, faces, keep, degenerate)
    else:
        faces, keep = faces[~degenerate], keep[~degenerate]
    if len(faces) == 0:
        raise MeshError(name, "every face has zero area; nothing is left to process")

    first = np.sort(unique_rows(np.sort(faces, axis=1))[1])
    report["repeated_faces"] = len(faces) - len(first)
    faces, keep = faces[first], keep[first]

    edge_faces = undirected_edges(faces)
    counts = np.bincount(edge_faces.inverse)
    report["split_edges"] = 0
    if counts.max() > 2:
        split = split_non_manifold_edges(verts, faces, edge_faces, counts)
        if split is None:
            e = int(np.argmax(counts))
            i, j = sorted(int(first_input[v]) for v in edge_faces.unique[e])   # the file's vertex numbers
            raise MeshError(name, f"non-manifold edge ({i}, {j}) is shared by "
                                  f"{int(counts[e])} faces ({int((counts > 2).sum())} such edges) that do not "
                                  "pair into sheets; repair the mesh (e.g. split it into manifold pieces) first")
        report["split_edges"] = int((counts > 2).sum())
        faces, source = split
        verts, first_input = verts[source], first_input[source]
        edge_faces = undirected_edges(faces)
        counts = np.bincount(edge_faces.inverse)

    # Renumber the vertices the faces use, in their order (np.unique(faces, return_inverse)'s
    # numbering, by a count instead of a sort). The renumbering keeps the order of vertex pairs,
    # so the edge table carries over with its pairs renumbered.
    referenced = np.bincount(faces.ravel(), minlength=len(verts)) > 0
    report["unreferenced_vertices"] = len(verts) - int(referenced.sum())
    if not referenced.all():
        rank = np.cumsum(referenced) - 1
        faces = rank[faces]
        edge_faces = EdgeTable(rank[edge_faces.unique], edge_faces.inverse)
        verts = verts[referenced]

    faces, flipped = orient_consistently(faces, name, edge_faces)
    report["flipped_faces"] = flipped

    n_comp, vertex_comp = connected_components(vertex_adjacency(faces, len(verts)), directed=False)
    face_comp = vertex_comp[faces[:, 0]].astype(np.int64)
    open_face = (counts[edge_faces.inverse] == 1).reshape(-1, 3).any(axis=1)
    faces, report["turned_outward"] = orient_outward(verts, faces, face_comp, open_face)
    report["components"] = int(n_comp)
    report["boundary_edges"] = int((counts == 1).sum())
    return CleanMesh(vertices=verts, faces=faces, face_index=keep, n_input_faces=mesh.n_faces,
                     face_component=face_comp, name=name, input_faces=mesh.faces, report=report)


def split_non_manifold_edges(vertices: np.ndarray, faces: np.ndarray, table: EdgeTable,
                             counts: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(faces [F, 3], source [V']) with every edge shared by more than two faces split into
    edges of two, or None where one cannot be (an odd number of faces on it, or faces whose
    directions along it do not alternate around it).

    Where two sheets of a surface touch along an edge (marching cubes leaves such edges where a
    part is about a grid cell thin: scikit-image's as well), the faces around the edge,
    taken in angular order about it, alternate in the direction they traverse it. Each face
    is paired with its angular neighbour across the wedge its orientation puts inside the solid
    (the wedge after a face traversing the edge backwards, counter-clockwise about it), so each
    solid wedge keeps its own two faces. The edge's two vertices are then copied once per fan of
    faces around them (faces joined across edges of two faces or across a pairing): the sheets
    touch where they did, as separate surfaces there, with no opening. ``source`` gives the
    vertex each new vertex copies (the first V are the input's own, in order).
    vertices : [V, 3]; faces : [F, 3]; table : :func:`undirected_edges` of faces;
    counts : [E] faces on each edge."""
    half = half_edges(faces)
    by_edge = np.argsort(table.inverse, kind="stable")          # half-edges grouped by edge
    start = np.concatenate([[0], np.cumsum(counts)])
    two = start[:-1][counts == 2]
    joined = [np.stack([by_edge[two], by_edge[two + 1]], axis=1)]    # half-edge pairs, one per sheet
    for e in np.flatnonzero(counts > 2):
        hs = by_edge[start[e]:start[e + 1]]
        if len(hs) % 2:
            return None
        a, b = table.unique[e]
        u = vertices[b] - vertices[a]
        u = u / np.linalg.norm(u)
        third = faces[hs // 3, (hs % 3 + 2) % 3]
        w = vertices[third] - vertices[a]
        w = w - np.outer(w @ u, u)
        ref = w[0] / np.linalg.norm(w[0])
        ring = hs[np.argsort(np.arctan2(w @ np.cross(u, ref), w @ ref), kind="stable")]
        backward = half[ring, 0] == b                           # traverses b -> a
        if np.any(backward == np.roll(backward, -1)):
            return None
        lead = 0 if backward[0] else 1
        joined.append(np.stack([ring[lead::2], np.roll(ring, -1)[lead::2]], axis=1))
    joined = np.concatenate(joined)
    # The corners (3f + k: face f at its k-th vertex) of a pair's two faces at each end of their
    # edge lie in one fan; a vertex's fans are the components of those links.
    ends = half[joined[:, 0]]                                   # [P, 2] each pair's edge

    def corner(f, v):
        return 3 * f + np.argmax(faces[f] == v[:, None], axis=1)

    i = np.concatenate([corner(joined[:, 0] // 3, ends[:, k]) for k in (0, 1)])
    j = np.concatenate([corner(joined[:, 1] // 3, ends[:, k]) for k in (0, 1)])
    n_corners = faces.size
    _, fan = connected_components(sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n_corners, n_corners)),
                                  directed=False)
    # Each vertex of a split edge keeps the fan of its lowest corner; its other fans, in the order
    # of their lowest corners, get copies numbered after the vertices.
    corners = faces.ravel()
    by_vertex = np.argsort(corners, kind="stable")
    first = np.searchsorted(corners[by_vertex], np.arange(len(vertices) + 1))
    faces = faces.copy()
    source = list(range(len(vertices)))
    for v in np.unique(table.unique[counts > 2]):
        at = by_vertex[first[v]:first[v + 1]]                   # its corners, ascending
        fans = fan[at]
        for f in fans[np.sort(np.unique(fans, return_index=True)[1])][1:]:      # by lowest corner
            faces.flat[at[fans == f]] = len(source)
            source.append(int(v))
    return faces, np.asarray(source, dtype=np.int64)


def orient_outward(vertices: np.ndarray, faces: np.ndarray, face_component: np.ndarray,
                   open_face: np.ndarray) -> tuple[np.ndarray, int]:
    """(faces [F, 3], faces turned): every closed component turned to face outward (its signed
    volume positive), except one inside another closed component's bounding box, which may bound
    a cavity (it keeps its orientation). A closed surface oriented inward (some exporters and
    marching-cubes codes write them so) would read its concave creases as convex and cast the
    lines of sight and the thickness rays outside the solid. Open components are left as they
    are (an open surface has no inside). face_component : [F]; open_face : [F] bool, faces on
    a boundary edge."""
    n = int(face_component.max()) + 1 if len(faces) else 0
    closed = np.bincount(face_component[open_face], minlength=n) == 0
    p = vertices[faces]
    # signed volume of each component (the divergence theorem; about each one's own first
    # vertex, so that coordinates far from the origin lose no digits)
    origin = np.zeros((n, 3))
    origin[face_component[::-1]] = p[::-1, 0]
    q = p - origin[face_component][:, None]
    volume = np.bincount(face_component, weights=np.einsum("ij,ij->i", q[:, 0], np.cross(q[:, 1], q[:, 2])),
                         minlength=n) / 6.0
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    np.minimum.at(lo, face_component, p.min(axis=1))
    np.maximum.at(hi, face_component, p.max(axis=1))
    # a closed surface of no volume (two sheets on each other) has no inside to face away from:
    # its sign is round-off, so it is kept
    size = np.linalg.norm(hi - lo, axis=1)
    turn = np.zeros(n, dtype=bool)
    for c in np.flatnonzero(closed & (volume < -1e-9 * size ** 3)):
        others = closed.copy()
        others[c] = False
        inside = others & np.all(lo <= lo[c], axis=1) & np.all(hi >= hi[c], axis=1)
        turn[c] = not inside.any()
    flip = turn[face_component]
    if not flip.any():
        return faces, 0
    out = faces.copy()
    out[flip] = out[flip][:, ::-1]
    return out, int(flip.sum())


def weld_roots(vertices: np.ndarray, distance: float = WELD_DISTANCE) -> np.ndarray | None:
    """[V] the vertex each of ``vertices`` [V, 3] is welded into: the lowest index of its
    cluster of vertices linked by distances below ``distance`` times their spread (the median
    distance from their coordinate-wise median; itself where none is that close); None where
    no two vertices are that close."""
    if len(vertices) < 2:
        return None
    # the scale is the vertices' spread (as for the outliers), which a stray coordinate such as
    # 1e12 does not move: on the diagonal it would weld every vertex of the mesh into one
    spread = point_spread(vertices)
    if not np.isfinite(spread) or spread <= 0:
        return None
    from scipy.spatial import cKDTree

    pairs = cKDTree(vertices).query_pairs(distance * spread, output_type="ndarray")
    if len(pairs) == 0:
        return None
    n = len(vertices)
    link = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, cluster = connected_components(link, directed=False)
    lowest = np.full(int(cluster.max()) + 1, n, dtype=np.int64)
    np.minimum.at(lowest, cluster, np.arange(n))
    return lowest[cluster]


def point_spread(points: np.ndarray) -> float:
    """The spread of ``points`` [P, 3]: the median distance from their coordinate-wise median (a
    scale no handful of stray points moves; :data:`OUTLIER_DISTANCE`, :data:`WELD_DISTANCE`)."""
    return float(np.median(np.linalg.norm(points - np.median(points, axis=0), axis=1)))


def faces_at_outliers(vertices: np.ndarray, faces: np.ndarray,
                      factor: float = OUTLIER_DISTANCE) -> np.ndarray:
    """[F] bool: the faces with an edge longer than ``factor`` spreads (see
    :data:`OUTLIER_DISTANCE`). vertices : [V, 3]; faces : [F, 3]; the spread is measured on the
    vertices the faces use."""
    used = np.flatnonzero(np.bincount(faces.ravel(), minlength=len(vertices)))
    p = vertices[used]
    spread = point_spread(p)
    if not spread > 0:
        return np.zeros(len(faces), dtype=bool)
    with np.errstate(over="ignore", invalid="ignore"):
        edges = np.linalg.norm(vertices[faces] - vertices[faces[:, [1, 2, 0]]], axis=2)   # [F, 3]
        return ~(edges <= factor * spread).all(axis=1)


def _zip_cracks(verts: np.ndarray, faces: np.ndarray, keep: np.ndarray, degenerate: np.ndarray):
    """Drop the degenerate faces, closing the crack each needle face (A, B, C), B on segment
    AC, leaves: the face across AC, (C, A, D), is split at B into (C, B, D) and (B, A, D) (both
    keep its input face index). Where the needle sat in a flattened pocket, a new face repeats
    an existing one on the same three vertices; both copies are dropped (the pocket had no area).

    Returns (faces, keep, number of needles zipped). Degenerate faces that are not needles
    with kept faces across all three edges are just dropped.
    """
    faces, keep = faces.copy(), keep.copy()
    out_faces, out_keep, zipped = [], [], 0
    alive = ~degenerate
    # Directed half-edge (u, v) -> face, of the faces that stay.
    half = {(int(u), int(v)): i for i in np.flatnonzero(alive)
            for u, v in zip(faces[i], faces[i][[1, 2, 0]])}
    for d in np.flatnonzero(degenerate):
        tri = faces[d]
        length = np.linalg.norm(verts[tri[[1, 2, 0]]] - verts[tri], axis=1)
        k = int(length.argmax())
        a, c, b = int(tri[k]), int(tri[(k + 1) % 3]), int(tri[(k + 2) % 3])
        i = half.get((c, a))
        if i is None or not alive[i]:
            continue
        if (b, c) not in half or (a, b) not in half:
            # Not a crack: B is on no face beside the needle's short edges, so dropping the
            # needle opens no hole (and splitting the face across AC would make one).
            continue
        t = faces[i].tolist()
        j = t.index(c)
        dv = t[(j + 2) % 3]
        for u, v in zip(t, t[1:] + t[:1]):
            half.pop((u, v), None)
        alive[i] = False
        for new in ((c, b, dv), (b, a, dv)):
            out_faces.append(new)
            out_keep.append(keep[i])
        zipped += 1
    faces = np.concatenate([faces[alive], np.array(out_faces, dtype=faces.dtype).reshape(-1, 3)])
    keep = np.concatenate([keep[alive], np.array(out_keep, dtype=keep.dtype)])
    # A zipped pocket: a new face on the same three vertices as another face (opposite
    # orientation): drop both copies. Repeats among the input's own faces are left to the
    # repeated-face step (one copy kept).
    new = np.zeros(len(faces), dtype=bool)
    new[len(faces) - len(out_faces):] = True
    _, _, inverse, counts = unique_rows(np.sort(faces, axis=1))
    pocket = np.zeros(len(counts), dtype=bool)
    pocket[inverse[new & (counts[inverse] > 1)]] = True
    stay = ~pocket[inverse]
    return faces[stay], keep[stay], zipped


@dataclass
class EdgeTable:
    """The undirected edges of a face list and the edge of each half-edge."""

    unique: np.ndarray   # [E, 2] sorted vertex pairs
    inverse: np.ndarray  # [3F] half-edge -> undirected edge


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``np.unique(a, axis=0, return_index=True, return_inverse=True, return_counts=True)`` of
    a [N, C] array, by one ``np.lexsort`` of its columns (numpy sorts rows as a structured
    dtype, 5-10x slower).

    Returns (unique rows [U, C] in lexicographic order, index of each one's first occurrence
    [U], inverse [N] (a == unique[inverse]), counts [U]); equal values are equal rows (-0.0 is
    0.0), as in numpy.
    """
    a = np.asarray(a)
    if len(a) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return a[:0], empty, empty, empty
    order = np.lexsort(a.T[::-1])                      # stable: first occurrences stay first
    rows = a[order]
    new = np.empty(len(a), dtype=bool)
    new[0] = True
    np.any(rows[1:] != rows[:-1], axis=1, out=new[1:])
    group = np.cumsum(new) - 1
    inverse = np.empty(len(a), dtype=np.int64)
    inverse[order] = group
    starts = np.flatnonzero(new)
    counts = np.diff(np.append(starts, len(a)))
    return rows[new], order[new].astype(np.int64), inverse, counts


def half_edges(faces: np.ndarray) -> np.ndarray:
    """[3F, 2] the half-edges (v_k, v_{k+1}) of each face, face-major."""
    return np.stack([faces, faces[:, [1, 2, 0]]], axis=2).reshape(-1, 2)


def undirected_edges(faces: np.ndarray) -> EdgeTable:
    """The :class:`EdgeTable` of faces [F, 3]: edges sorted by (lower, higher) vertex."""
    half = half_edges(faces)
    lo, hi = half.min(axis=1), half.max(axis=1)
    # One int64 key per edge sorts like the (lo, hi) pair: a 1-D unique instead of a row unique.
    n = int(hi.max()) + 1 if len(hi) else 1
    keys, inverse = np.unique(lo * n + hi, return_inverse=True)
    return EdgeTable(np.stack([keys // n, keys % n], axis=1), inverse.reshape(-1))


def vertex_adjacency(faces: np.ndarray, n: int) -> sp.csr_matrix:
    """[n, n] sparse matrix, nonzero at (u, v) for each half-edge u -> v of faces [F, 3]."""
    i = faces.ravel()
    j = faces[:, [1, 2, 0]].ravel()
    return sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n)).tocsr()


def orient_consistently(faces: np.ndarray, name: str, table: EdgeTable | None = None) -> tuple[np.ndarray, int]:
    """Flip faces so that each interior edge is traversed once in each direction.

    Returns the oriented faces and how many were flipped. Each component keeps the orientation
    of its lowest-numbered face. Raises on non-orientable surfaces (e.g. a Moebius strip).
    table : ``undirected_edges(faces)`` if at hand.
    """
    half = half_edges(faces)
    table = undirected_edges(faces) if table is None else table
    forward = half[:, 0] < half[:, 1]
    # An interior edge is consistent when its two half-edges point opposite ways.
    n_fwd = np.bincount(table.inverse, weights=forward, minlength=len(table.unique))
    n_all = np.bincount(table.inverse, minlength=len(table.unique))
    if np.all((n_all == 1) | (n_fwd == 1)):
        return faces, 0

    # Face adjacency through shared edges, breadth first.
    he_face = np.repeat(np.arange(len(faces)), 3)
    order = np.argsort(table.inverse, kind="stable")
    edge_sorted = table.inverse[order]
    pair_start = np.flatnonzero(np.r_[True, edge_sorted[1:] != edge_sorted[:-1]])
    neighbours = [[] for _ in range(len(faces))]
    for s in pair_start:
        if s + 1 < len(order) and edge_sorted[s + 1] == edge_sorted[s]:
            a, b = order[s], order[s + 1]
            same = forward[a] == forward[b]  # same direction => the two faces disagree
            fa, fb = he_face[a], he_face[b]
            neighbours[fa].append((fb, same))
            neighbours[fb].append((fa, same))
    flip = np.full(len(faces), -1, dtype=np.int8)
    for seed in range(len(faces)):
        if flip[seed] >= 0:
            continue
        flip[seed] = 0
        queue = deque([seed])
        while queue:
            f = queue.popleft()
            for g, same in neighbours[f]:
                want = flip[f] ^ int(same)
                if flip[g] < 0:
                    flip[g] = want
                    queue.append(g)
                elif flip[g] != want:
                    raise MeshError(name, "the surface is not orientable (faces cannot be "
                                          "ordered consistently); torchakvf needs an orientable mesh")
    out = faces.copy()
    out[flip == 1] = out[flip == 1][:, ::-1]
    return out, int((flip == 1).sum())
