"""Crease patches: the regions a surface's sharp creases cut it into.

Where the untangled fields cannot tell two parts apart (coaxial cylinders share their rotation,
coplanar slabs their translations, a box leg its neighbour's), the crease between them is the only
cue left, and the over-segmentation the merge starts from must have a boundary on it: k-means
pieces follow isolines of the fields, which run anywhere on such shapes. :func:`crease_patches`
finds the patches, and the over-segmentation is cut along them
(:func:`~torchakvf.parts.cut.over_segmentation`).

A crease is a change of the surface normal by more than ``angle`` within ``rings`` dual rings (a
few triangles), not between two neighbouring faces: meshed creases are rounded or chamfered over
a triangle or two (marching cubes, fillets), so a threshold on single dihedral angles leaks
through the gaps of a rounded crease. Faces near a crease form a band; the patches are the
connected pieces of the other faces, and each band face joins the patch nearest it (in dual
hops), so a patch boundary runs along the middle of its crease. The segmentation's default cuts
along concave creases only (``OverSegmentation.crease_concave``, ``concave_only`` here): people cut a
shape where its surface turns inward, and a convex crease is most often the edge of one part.
A patch that k-means cut into fragments all too small to keep is made one piece again
(:func:`unite_patch_fragments`), so a thin part the creases delimit reaches the merge.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra

from ..mesh.clean import face_cross_products
from .concavity import DualEdges
from .topology import labelled_pieces

#: Normal change (radians) that makes a crease: well above the bending of smooth surface over a
#: few triangles, well below the right angles where primitives meet.
CREASE_SPLIT_ANGLE = math.radians(60.0)
#: Dual rings within which a crease's normal change is measured: creases rounded over up to
#: about this many triangles are found.
CREASE_RINGS = 3


def unit_face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[F, 3] unit normals of the faces [F, 3] of ``vertices`` [V, 3] (zero for degenerate faces)."""
    n = face_cross_products(np.asarray(vertices, dtype=np.float64), np.asarray(faces))
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def dual_graph(adjacency: np.ndarray, n_faces: int) -> sp.csr_matrix:
    """[F, F] symmetric 0/1 matrix of the face pairs ``adjacency`` [P, 2] sharing an edge."""
    a, b = adjacency[:, 0], adjacency[:, 1]
    return sp.coo_matrix((np.ones(2 * len(a)), (np.r_[a, b], np.r_[b, a])), shape=(n_faces, n_faces)).tocsr()


def dual_ball(adjacency: np.ndarray, n_faces: int, rings: int) -> sp.csr_matrix:
    """[F, F] 0/1 pattern (CSR, sorted) of the face pairs at most ``rings`` dual hops apart,
    each face with itself included: the pattern of (I + A)^rings, A the dual adjacency of
    ``adjacency`` [P, 2]."""
    a, b = adjacency[:, 0], adjacency[:, 1]
    self_loops = np.arange(n_faces)
    step = sp.csr_matrix((np.ones(2 * len(a) + n_faces, dtype=np.int32),
                          (np.r_[a, b, self_loops], np.r_[b, a, self_loops])), shape=(n_faces, n_faces))
    step.data[:] = 1
    ball = step
    for _ in range(int(rings) - 1):
        ball = ball @ step
        ball.data[:] = 1                 # a pattern, not path counts
    ball.sum_duplicates()
    ball.sort_indices()
    return ball


def least_cosine(normals: np.ndarray, adjacency: np.ndarray, rings: int, centroids: np.ndarray | None = None,
                 dtype=np.float32) -> np.ndarray:
    """[F] the least n_f·n_g of each face f over the faces g at most ``rings`` dual hops away,
    1 where none is less (f itself counts: n_f·n_f = 1). normals : [F, 3] unit face normals;
    adjacency : [P, 2] face pairs sharing an edge; centroids : [F, 3] face centroids, or None.
    With centroids only concave bends count: faces f, g bend concavely where
    ``(c_g - c_f)·(n_g - n_f) < 0`` (each lies on the normal side of the other's plane; > 0 on a
    convex sphere). dtype : the arithmetic's float type.

    Each pair of faces at most ``rings`` hops apart is compared once (the upper triangle of
    :func:`dual_ball`; the test is symmetric in f and g, to the bit) and the least taken at both
    faces."""
    n_faces = len(normals)
    least = np.ones(n_faces, dtype=dtype)
    if n_faces == 0:
        return least
    pairs = sp.triu(dual_ball(adjacency, n_faces, rings), k=1, format="csr")
    counts = np.diff(pairs.indptr)
    cols = pairs.indices
    unit = np.asarray(normals, dtype=dtype)
    u_row, u_col = np.repeat(unit, counts, axis=0), unit[cols]
    dots = np.einsum("pk,pk->p", u_row, u_col)
    if centroids is not None:
        centers = np.asarray(centroids, dtype=dtype)
        bend = np.einsum("pk,pk->p", centers[cols] - np.repeat(centers, counts, axis=0), u_col - u_row)
        dots = np.where(bend < 0, dots, dtype(1.0))
    rows = counts > 0
    if len(dots):
        least[rows] = np.minimum(np.minimum.reduceat(dots, pairs.indptr[:-1][rows]), dtype(1.0))
        np.minimum.at(least, cols, dots)
    return least


def crease_band(normals: np.ndarray, adjacency: np.ndarray, angle: float = CREASE_SPLIT_ANGLE,
                rings: int = CREASE_RINGS, centroids: np.ndarray | None = None) -> np.ndarray:
    """[F] whether a face lies within ``rings`` dual rings of a face whose normal differs from its
    own by more than ``angle`` radians (:func:`least_cosine`; with centroids, concave bends
    only), tested in float32 (far from its round-off)."""
    return least_cosine(normals, adjacency, rings, centroids, np.float32) < math.cos(angle)


def crease_band_of(vertices: np.ndarray, faces: np.ndarray, dual: DualEdges,
                   angle: float = CREASE_SPLIT_ANGLE, rings: int = CREASE_RINGS,
                   concave_only: bool = False) -> np.ndarray:
    """[F] bool, the band of rounded creases :func:`crease_patches` cuts along (the same
    arguments): it depends on the mesh alone, so a caller cutting several labellings along it
    makes it once."""
    centroids = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)].mean(axis=1) if concave_only else None
    return crease_band(unit_face_normals(vertices, faces), dual.pairs, angle, rings, centroids)


def crease_patches(vertices: np.ndarray, faces: np.ndarray, dual: DualEdges,
                   angle: float = CREASE_SPLIT_ANGLE, rings: int = CREASE_RINGS,
                   concave_only: bool = False, cut: np.ndarray | None = None,
                   band: np.ndarray | None = None) -> np.ndarray:
    """[F] int64 patch of each face.

    Creases are found at two scales. A dual edge whose faces' normals differ by more than
    ``angle`` is a crease by itself (a crisp crease: it is never crossed). A rounded crease is
    a band (:func:`crease_band`): the patches are the connected pieces of the faces off the band,
    and each band face joins the patch nearest it in dual hops without crossing a crisp crease
    (ties as scipy's multi-source search breaks them, the same on every run), so a boundary runs
    along the middle of its band. Band faces that reach no patch that way (a region enclosed by
    crisp creases and narrower than the band: a thin leg of a low-poly chair) are patches of their
    own, one per such region.

    vertices : [V, 3]; faces : [F, 3]; dual : :func:`~torchakvf.parts.concavity.dual_edges` of
    the mesh; angle : radians; rings : >= 1; concave_only : only concave creases cut (where
    people cut a shape into parts, the minima rule; a convex crease is the edge of one part).
    cut : [P] bool, dual edges also never crossed, as a crisp crease is: where a labelling's
    labels differ, the patches are then those of each label's faces, so a crease splits a piece
    it crosses even where it encloses no patch of the whole surface (the crease round a hub on a
    bored disc: the bore's wall joins the hub to the disc past it). band : [F]
    :func:`crease_band_of` of the same arguments, if at hand.
    """
    n_faces = len(faces)
    crisp = (dual.dihedral if concave_only else np.abs(dual.dihedral)) > angle
    if cut is not None:
        crisp = crisp | np.asarray(cut, dtype=bool)
    if band is None:
        band = crease_band_of(vertices, faces, dual, angle, rings, concave_only)
    a, b = dual.pairs[~crisp, 0], dual.pairs[~crisp, 1]
    smooth = dual_graph(np.stack([a, b], axis=1), n_faces)           # crisp creases cut
    keep = ~band[a] & ~band[b]
    off_band = sp.coo_matrix((np.ones(int(keep.sum())), (a[keep], b[keep])), shape=(n_faces, n_faces))
    n_off, patch = connected_components(off_band, directed=False)
    if not band.any():
        return patch.astype(np.int64)
    nearest = np.full(n_faces, -1)
    if not band.all():
        _, _, nearest = dijkstra(smooth, directed=False, indices=np.flatnonzero(~band), unweighted=True,
                                 min_only=True, return_predecessors=True)
    lost = band & (nearest < 0)
    _, region = connected_components(smooth, directed=False)
    patch = np.where(band, np.where(lost, n_off + region, patch[np.maximum(nearest, 0)]), patch)
    return np.unique(patch, return_inverse=True)[1].astype(np.int64)


def split_by_patches(labels: np.ndarray, patches: np.ndarray) -> tuple[np.ndarray, int]:
    """(labels [F] int64, P): each (label, patch) pair of ``labels`` [F] (>= 0) and ``patches`` [F]
    its own label ``label * P + patch``, P the patch count, so ``label`` is ``split // P``."""
    n_patches = int(patches.max()) + 1 if len(patches) else 1
    return np.asarray(labels, dtype=np.int64) * n_patches + patches, n_patches


def unite_patch_fragments(labels: np.ndarray, patches: np.ndarray, adjacency: np.ndarray,
                          face_area: np.ndarray, floor: float) -> np.ndarray:
    """[F] ``labels`` (split by ``patches``, :func:`split_by_patches`) where every crease patch of
    at least ``floor`` of the area (a share) that k-means cut into pieces all below ``floor`` is
    one piece, labelled as its largest piece.

    A thin part delimited by creases (a table's leg, a spoke, a fin) is a few percent of the
    surface, and k-means may cut it across into pieces each below the small-piece floor; removed
    one by one, they would join the large piece across the crease, and the part would be lost
    before the merge sees it. United, the patch is a piece of its own size. A patch with a piece
    above the floor, or one below the floor as a whole (its pieces are removed either way), is
    left as it is.

    labels, patches : [F] int; adjacency : [P, 2] face pairs sharing an edge; face_area : [F].
    """
    labels = np.asarray(labels)
    patches = np.asarray(patches)
    if len(labels) == 0:
        return labels
    n_pieces, piece = labelled_pieces(labels, adjacency)
    area = np.asarray(face_area, dtype=np.float64)
    threshold = floor * area.sum()
    piece_area = np.bincount(piece, weights=area, minlength=n_pieces)
    piece_patch = np.empty(n_pieces, dtype=np.int64)
    piece_patch[piece] = patches
    n_patches = int(patches.max()) + 1
    large = piece_area >= threshold
    has_large = np.zeros(n_patches, dtype=bool)
    has_large[piece_patch[large]] = True
    # each patch's largest piece (the first of equal ones), and its label
    order = np.lexsort((np.arange(n_pieces), -piece_area, piece_patch))
    first = order[np.r_[True, piece_patch[order][1:] != piece_patch[order][:-1]]]
    piece_label = np.empty(n_pieces, dtype=labels.dtype)
    piece_label[piece] = labels
    patch_label = np.full(n_patches, -1, dtype=labels.dtype)
    patch_label[piece_patch[first]] = piece_label[first]
    patch_area = np.bincount(patches, weights=area, minlength=n_patches)
    unite = ~has_large & (patch_area >= threshold)
    return np.where(unite[patches], patch_label[patches], labels)


__all__ = ["CREASE_SPLIT_ANGLE", "CREASE_RINGS", "unit_face_normals", "dual_graph", "dual_ball", "least_cosine",
           "crease_band", "crease_band_of", "crease_patches", "split_by_patches", "unite_patch_fragments"]
