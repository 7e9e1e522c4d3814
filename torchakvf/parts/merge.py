"""The right parts: merge an over-segmentation's adjacent parts until k remain.

k-means on the untangled features is run with k' > k parts (:func:`oversegment_k`); this
module then merges ADJACENT parts, cheapest first, by a cost that combines

* symmetry similarity: 1 - cos between the parts' mean (unit) untangled feature vectors
  (two parts moved by the same fields are one symmetric part cut in two);
* boundary concavity (the minima rule): the length-weighted mean concave bending
  (:mod:`torchakvf.parts.concavity`) along their shared boundary; a boundary on smooth or
  convex surface is a poor cut, so merging across it is cheap;
* size: the smaller part's share of the surface area (small parts merge first), and the same
  relative to the target part size A / k (``part_size``);
* convex creases (``convexity``): the length-weighted mean convex bending along the boundary
  (a boundary on a sharp ridge is also a cut people make, e.g. on mechanical parts);
* boundary share (``cut``): 1 - L_ij / min(P_i, P_j), P the parts' boundary lengths: a part
  mostly enclosed by its neighbour (a stripe, a patch) is cheap to merge into it;
* the terms that tell a protrusion from half a body (:mod:`torchakvf.parts.merge_terms`): the
  size ratio, the short-cut rule, thickness (the shape diameter function), centricity.

    cost(i, j) = w_sym (1 - cos(m_i, m_j)) + w_cav κ_ij + w_size min(A_i, A_j) / A
                 + w_k min(A_i, A_j) k / A + w_cvx χ_ij + w_cut (1 - L_ij / min(P_i, P_j))
                 + Σ w_t term_t(i, j)   (t: size_ratio, short_cut, thickness, thin, centricity)

κ and χ saturate at ``crease_angle``: bending θ counts min(θ / crease_angle, 1) (π = linear).

The region graph is a handful of [K, K] matrices (K = k' parts), so a loop over the k' - k
merges costs nothing next to the per-face work, which is vectorized (bincount over dual edges).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..mesh.raycast import RayCaster
from ..options import MergeWeights
from ..restarts import first_near_min
from .concavity import DualEdges, crease_weights, dual_edges
from .creases import unit_face_normals
from .grouping import compact_labels, group_sums
from .merge_terms import TERM_NAMES, MergeState, face_thickness, pair_terms, part_sums
from .sightlines import PartSight, SightLines


def oversegment_k(k: int, ratio: float, n_faces: int, extra_max: int | None = None, min_k: int = 1) -> int:
    """k' = ceil(ratio k) parts to over-segment into, at most k + ``extra_max`` (None: no cap)
    and at most the face count; a k below ``min_k`` gets the k' of min_k."""
    k = max(int(k), int(min_k))
    kp = max(math.ceil(ratio * k - 1e-9), k)
    if extra_max is not None:
        kp = min(kp, k + int(extra_max))
    return int(min(kp, n_faces))


@dataclass
class RegionGraph:
    """Parts of a labelling and what the merge cost needs about them.

    labels : [F] compact part ids 0..K-1 (-1 kept where the input had a negative label)
    area : [K] part areas; mean : [K, n] area-weighted mean of the unit feature rows
    length : [K, K] symmetric shared-boundary length (0 = not adjacent)
    concave : [K, K] symmetric length-weighted sum of concavity along the shared boundary
    convex : [K, K] the same of convex bending (None: not computed, counted as 0)
    sums : :func:`~torchakvf.parts.merge_terms.part_sums` (centroids, thickness), the
        lines of sight ("seen", "lines": :meth:`SightLines.counts`) and the vector areas
        ("vector_area" [K, 3]) where the weights read them (None or missing: those terms count
        0, and no part is a sheet)
    """

    labels: np.ndarray
    area: np.ndarray
    mean: np.ndarray
    length: np.ndarray
    concave: np.ndarray
    convex: np.ndarray | None = None
    sums: dict | None = None

    @property
    def n_parts(self) -> int:
        return len(self.area)

    def state(self) -> MergeState:
        """A :class:`~torchakvf.parts.merge_terms.MergeState` of these parts (copies: merging it
        leaves the graph as it is)."""
        sums = self.sums or {}
        copy = lambda name: None if sums.get(name) is None else np.array(sums[name], dtype=np.float64)
        convex = np.zeros_like(self.concave) if self.convex is None else self.convex.copy()
        return MergeState(self.area.copy(), self.mean.copy(), self.length.copy(), self.concave.copy(), convex,
                          thick=copy("thick"), thick_area=copy("thick_area"), centroid=copy("centroid"),
                          center=sums.get("center"), radius=float(sums.get("radius", 1.0)),
                          thick_median=float(sums.get("thick_median", 1.0)), seen=copy("seen"),
                          lines=copy("lines"), vector_area=copy("vector_area"))


#: The :class:`MergeWeights` field weighing each column of
#: :func:`~torchakvf.parts.merge_terms.pair_terms` (``small`` also takes ``size`` / k: see
#: :func:`term_weights`).
FIELD_OF_TERM = dict(symmetry="symmetry", concavity="concavity", convexity="convexity", share="cut",
                     small="part_size", size_ratio="size_ratio", short_cut="short_cut", thickness="thickness",
                     thin="thin", centricity="centricity", sight="sight", sight_excess="sight_excess")


def term_weights(weights: MergeWeights, k: int) -> np.ndarray:
    """[T] the weights of :data:`~torchakvf.parts.merge_terms.TERM_NAMES` the cost is the dot
    product with (the size terms folded into the ``small`` column, min(A_i, A_j) k / A)."""
    values = {name: getattr(weights, field) for name, field in FIELD_OF_TERM.items()}
    values["small"] = weights.size / max(int(k), 1) + weights.part_size
    return np.array([values[name] for name in TERM_NAMES], dtype=np.float64)


def needs_thickness(weights: MergeWeights) -> bool:
    """Whether the cost reads the parts' thickness (then each mesh's is computed)."""
    return weights.thickness != 0 or weights.thin != 0


def needs_sight(weights: MergeWeights) -> bool:
    """Whether the cost reads the lines of sight between parts (then each mesh's are cast)."""
    return weights.sight != 0 or weights.sight_excess != 0


def needs_normals(weights: MergeWeights) -> bool:
    """Whether the merge reads the parts' vector areas (the sheet rule: then the mesh's unit
    face normals go to :func:`region_graph`)."""
    return weights.sheet_flatness is not None


def needs_part_sums(weights: MergeWeights) -> bool:
    """Whether the cost reads :func:`~torchakvf.parts.merge_terms.part_sums` at all."""
    return needs_thickness(weights) or weights.centricity != 0


def unit_rows(features: np.ndarray) -> np.ndarray:
    """[F, n] the feature rows scaled to unit length (zero rows stay zero), as k-means sees
    them. Row by row, so the rows of a subset are those of the whole."""
    feats = np.asarray(features, dtype=np.float64)
    norm = np.linalg.norm(feats, axis=1, keepdims=True)
    return np.divide(feats, norm, out=np.zeros_like(feats), where=norm > 0)


def boundary_bends(dual: DualEdges, crease_angle: float = math.pi) -> tuple[np.ndarray, np.ndarray]:
    """([P] length x concave weight, [P] length x convex weight) of each dual edge
    (:func:`crease_weights` at ``crease_angle``): what a shared boundary sums. Depends on the
    mesh alone, so a caller segmenting one mesh at many k can keep it."""
    cav, cvx = crease_weights(dual.dihedral, crease_angle)
    return dual.length * cav, dual.length * cvx


def region_graph(labels: np.ndarray, dual: DualEdges, features: np.ndarray,
                 face_area: np.ndarray, crease_angle: float = math.pi, *,
                 unit: np.ndarray | None = None, bends: tuple | None = None,
                 centroids: np.ndarray | None = None, thickness: np.ndarray | None = None,
                 sight: SightLines | PartSight | None = None,
                 normals: np.ndarray | None = None) -> RegionGraph:
    """The region adjacency graph of ``labels`` [F] on the mesh whose dual graph is ``dual``.

    features : [F, n] per-face untangled feature rows (normalized here, as k-means does);
    face_area : [F]. Faces with a negative label are left out of every part.
    crease_angle : bending (radians) at which a crease counts fully (:func:`crease_weights`).
    unit, bends : :func:`unit_rows` (features) and :func:`boundary_bends` (dual, crease_angle)
        if at hand (then ``features`` is not read).
    centroids : [F, 3] face centroids and thickness [F] (:func:`face_thickness`, or None) where
        the centricity and thickness terms are wanted (:func:`needs_part_sums`); None: not read.
    sight : the mesh's :class:`~torchakvf.parts.sightlines.SightLines` where the sight term is
        wanted (:func:`needs_sight`), or the counts of these labels by their ids
        (:class:`~torchakvf.parts.sightlines.PartSight`) where they are at hand; None: not read.
    normals : [F, 3] unit outward face normals where the sheet rule is wanted
        (:func:`needs_normals`): each part's vector area Σ a_f n_f, in the units of
        ``face_area``; None: no part is a sheet.
    """
    labels = np.asarray(labels)
    present = labels >= 0
    lab, K = compact_labels(labels)
    every = bool(present.all())           # the usual case: no subset copies
    compact = lab if every else lab[present]
    unit = unit_rows(features) if unit is None else unit
    w = np.asarray(face_area, dtype=np.float64)
    w = w if every else w[present]
    area = np.bincount(compact, weights=w, minlength=K)
    mean = group_sums(compact, (unit if every else unit[present]) * w[:, None], K)
    mean /= np.maximum(area, 1e-300)[:, None]
    la, lb = lab[dual.pairs[:, 0]], lab[dual.pairs[:, 1]]
    cut = (la != lb) & (la >= 0) & (lb >= 0)
    key = la[cut] * K + lb[cut]
    length = np.bincount(key, weights=dual.length[cut], minlength=K * K).reshape(K, K)
    bent_cav, bent_cvx = boundary_bends(dual, crease_angle) if bends is None else bends
    concave = np.bincount(key, weights=bent_cav[cut], minlength=K * K).reshape(K, K)
    convex = np.bincount(key, weights=bent_cvx[cut], minlength=K * K).reshape(K, K)
    sums = None if centroids is None else part_sums(lab, K, np.asarray(face_area, dtype=np.float64),
                                                    np.asarray(centroids, dtype=np.float64), thickness)
    if sight is not None:
        sums = dict(sums or {})
        if isinstance(sight, PartSight):
            counts = sight.take(np.unique(labels[present]))
            sums["seen"], sums["lines"] = counts.seen, counts.lines
        else:
            sums["seen"], sums["lines"] = sight.counts(lab, K)
    if normals is not None:
        sums = dict(sums or {})
        n = np.asarray(normals, dtype=np.float64)
        sums["vector_area"] = group_sums(compact, (n if every else n[present]) * w[:, None], K)
    return RegionGraph(lab, area, mean, length + length.T, concave + concave.T, convex + convex.T, sums)


def state_costs(state: MergeState, rows: np.ndarray, weights: MergeWeights, k: int = 1,
                odds: bool = False) -> np.ndarray:
    """[len(rows), K] merge costs of parts ``rows`` of ``state`` with every part (+inf where not
    adjacent): s = :func:`~torchakvf.parts.merge_terms.pair_terms` . :func:`term_weights`, or
    with ``weights.rand_gamma`` = γ the expected change of the Rand disagreement
    (a_i a_j)^γ (1 - 2 sigmoid(intercept - s)), a the parts' area shares.
    odds : s - intercept instead (the log-odds against one part; s where rand_gamma is None)."""
    rows = np.asarray(rows)
    terms, adjacent = pair_terms(state, rows, k)
    s = terms @ term_weights(weights, k)
    if weights.rand_gamma is not None:
        if odds:
            s = s - weights.intercept
        else:
            share = state.area / state.total
            s = np.outer(share[rows], share) ** weights.rand_gamma * np.tanh(0.5 * (s - weights.intercept))
    s[~adjacent] = np.inf
    return s


def merge_costs(graph: RegionGraph, weights: MergeWeights, k: int = 1) -> np.ndarray:
    """[K, K] cost of merging each pair of parts; +inf where not adjacent (and on the diagonal).
    k : the parts wanted (the size terms read it)."""
    cost = state_costs(graph.state(), np.arange(graph.n_parts), weights, k)
    np.fill_diagonal(cost, np.inf)
    return cost


def greedy_merge(graph: RegionGraph, k: int, weights: MergeWeights) -> tuple[np.ndarray, list]:
    """Merge the cheapest adjacent pair until k parts remain (or no adjacent pair is left).

    Returns (part [K] -> new id in 0..k_out-1, in the order of the parts' smallest old id; the
    cost of each merge done). Ties, round-off ones included (within
    :data:`~torchakvf.restarts.ROUND_OFF_TIE`, relative), go to the first pair in row-major
    order, so the result is the same on any machine. The merged part keeps the smaller id;
    only its row of costs changes.

    Sheets: with ``weights.sheet_flatness`` and the graph's vector areas, where the k parts
    merged by cost include a part flatter than it (a sheet:
    :meth:`~torchakvf.parts.merge_terms.MergeState.flatness`), the pieces are merged again, and
    while a sheet has an adjacent part the merge is the cheapest pair among those with a
    sheet. A plane patch has no volume, so it is a face of a part, never a part of its own; the
    cost alone keeps a socket's floor, cut off by its concave crease, as a part
    (docs/design.md, "Flat parts (sheets)"). The history is that of the merge whose parts are
    returned.
    """
    if k < 1:
        raise ParameterError(f"k must be >= 1, got {k!r}")
    cost = merge_costs(graph, weights, k)
    owner, history, state = _merge_down(graph, k, weights, cost.copy(), sheets_first=False)
    flat = None if weights.sheet_flatness is None else state.flatness()
    if flat is not None and (flat > weights.sheet_flatness).any():
        owner, history, state = _merge_down(graph, k, weights, cost, sheets_first=True)
    roots = np.unique(owner)
    return np.searchsorted(roots, owner), history


def _merge_down(graph: RegionGraph, k: int, weights: MergeWeights, cost: np.ndarray,
                sheets_first: bool) -> tuple[np.ndarray, list, MergeState]:
    """(owner [K]: the part each part joined, the cost of each merge, the merged state) of
    :func:`greedy_merge`'s loop from the pieces' costs ``cost`` [K, K] (:func:`merge_costs`,
    updated in place); sheets_first: the pairs holding a sheet go first."""
    K = graph.n_parts
    state = graph.state()
    owner = np.arange(K)
    history = []
    for _ in range(K - k):
        flat = first_near_min(_sheet_pairs(cost, state, weights.sheet_flatness) if sheets_first else cost)
        i, j = divmod(flat, K)
        if not np.isfinite(cost[i, j]):
            break
        i, j = min(i, j), max(i, j)
        history.append(float(cost[i, j]))
        state.merge(i, j)
        owner[owner == j] = i
        cost[j, :] = cost[:, j] = np.inf
        # Only the merged part's costs change: every term of a pair is read from the pair's
        # own sums and the total area, and a neighbour's perimeter is the same (its boundary
        # with i and j is now all with i).
        row = state_costs(state, np.array([i]), weights, k)[0]
        row[i] = np.inf
        cost[i, :] = cost[:, i] = row
    return owner, history, state


def _sheet_pairs(cost: np.ndarray, state: MergeState, flatness: float) -> np.ndarray:
    """``cost`` [K, K] where no part is flatter than ``flatness`` (or none of those has an
    adjacent part left), else the costs of the pairs with such a part (+inf elsewhere)."""
    sheet = state.flatness() > flatness
    if not sheet.any():
        return cost
    among = np.where(sheet[:, None] | sheet[None, :], cost, np.inf)
    return among if np.isfinite(among).any() else cost


@dataclass
class MergeCache:
    """What :func:`merge_parts` can take ready-made instead of making it from the mesh (each
    None: made there). A caller merging one over-segmentation to several k makes them once.

    dual : :func:`dual_edges` of the mesh; unit : [F, n] :func:`unit_rows` of the features;
    bends : :func:`boundary_bends` (dual, the weights' crease angle); graph :
    :func:`region_graph` of the labels at the weights' crease angle, with what the weights read
    (it does not depend on k);
    thickness : [F] :func:`face_thickness` of the mesh (read where the weights read it and no
    graph is given); sight : the mesh's :class:`~torchakvf.parts.sightlines.SightLines` (read
    where the weights read the lines of sight and no graph is given).
    """

    dual: DualEdges | None = None
    unit: np.ndarray | None = None
    bends: tuple | None = None
    graph: RegionGraph | None = None
    thickness: np.ndarray | None = None
    sight: SightLines | None = None


def merge_parts(labels: np.ndarray, faces: np.ndarray, vertices: np.ndarray, features: np.ndarray,
                face_area: np.ndarray, k: int, weights: MergeWeights | None = None,
                cache: MergeCache | None = None, **moved) -> np.ndarray:
    """Labels [F] of an over-segmentation merged down to k adjacent-part unions.

    labels : [F] int part per face (negative = no part, kept as is); faces [F, 3] and
    vertices [V, 3] the mesh they live on (outward-oriented); features : [F, n] untangled
    per-face features; face_area : [F]; k : parts wanted; weights : :class:`MergeWeights`
    (default: the learned ones); cache : a :class:`MergeCache` of what is at hand (dual edges,
    unit rows, boundary bends, the region graph, thickness).
    Returns labels in 0..k_out-1 (k_out = k unless fewer parts were given or no adjacent pair
    was left, e.g. more connected components than k).
    """
    if moved or not (cache is None or isinstance(cache, MergeCache)):
        # the five caches are one argument: name the new spelling for the old one
        names = sorted(moved) or ["dual"]
        raise ParameterError(f"merge_parts takes {', '.join(names)} as cache=MergeCache("
                             + ", ".join(f"{n}=..." for n in names) + ")")
    weights = MergeWeights() if weights is None else weights
    cache = MergeCache() if cache is None else cache
    graph = cache.graph
    if graph is None:
        dual = dual_edges(vertices, faces) if cache.dual is None else cache.dual
        centroids, thickness = mesh_sums_inputs(vertices, faces, weights, cache.thickness)
        sight = (cache.sight or SightLines(vertices, faces)) if needs_sight(weights) else None
        normals = unit_face_normals(vertices, faces) if needs_normals(weights) else None
        graph = region_graph(labels, dual, features, face_area, weights.crease_angle, unit=cache.unit,
                             bends=cache.bends, centroids=centroids, thickness=thickness, sight=sight,
                             normals=normals)
    new_id, _ = greedy_merge(graph, k, weights)
    out = np.where(graph.labels >= 0, new_id[np.maximum(graph.labels, 0)], graph.labels)
    return out.astype(np.asarray(labels).dtype, copy=False)


def mesh_sums_inputs(vertices: np.ndarray, faces: np.ndarray, weights: MergeWeights,
                     thickness: np.ndarray | None = None, caster: RayCaster | None = None) -> tuple:
    """(centroids [F, 3], thickness [F]) :func:`region_graph` needs for ``weights`` (None where
    not read); thickness: :func:`face_thickness` of the mesh if at hand; caster: the mesh's
    :class:`~torchakvf.mesh.raycast.RayCaster` if at hand (the thickness is cast on it)."""
    if not needs_part_sums(weights):
        return None, None
    centroids = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)].mean(axis=1)
    if needs_thickness(weights) and thickness is None:
        thickness = face_thickness(vertices, faces, caster=caster)
    return centroids, (thickness if needs_thickness(weights) else None)


def next_merge_cost(labels: np.ndarray, dual: DualEdges, features: np.ndarray, face_area: np.ndarray,
                    weights: MergeWeights | None = None, *, unit: np.ndarray | None = None,
                    bends: tuple | None = None, centroids: np.ndarray | None = None,
                    thickness: np.ndarray | None = None, sight: SightLines | PartSight | None = None) -> float:
    """The cost of the cheapest merge left among the parts of ``labels`` [F] (inf when no two
    parts are adjacent): what going from k = (its part count) to k - 1 parts would cost. k auto
    reads it: a large one means the parts are worth keeping apart. With ``weights.rand_gamma`` it
    is the least log-odds against one part (s - intercept, :func:`state_costs`), not the Rand
    cost, whose size factor would make it small wherever a small part is left. features [F, n], face_area [F];
    unit, bends : as :func:`merge_parts` takes them; centroids, thickness, sight : as
    :func:`region_graph` takes them (:func:`mesh_sums_inputs`, :func:`needs_sight`)."""
    weights = MergeWeights() if weights is None else weights
    graph = region_graph(labels, dual, features, face_area, weights.crease_angle, unit=unit, bends=bends,
                         centroids=centroids, thickness=thickness, sight=sight)
    if graph.n_parts < 2:
        return float("inf")
    cost = state_costs(graph.state(), np.arange(graph.n_parts), weights, graph.n_parts, odds=True)
    np.fill_diagonal(cost, np.inf)
    return float(cost.min())


def partition_cost(labels: np.ndarray, features: np.ndarray, *, unit: np.ndarray | None = None) -> float:
    """Spherical k-means cost Σ_f (1 - cos(x_f, c_p)) of a given partition, each part's center
    c_p the normalized sum of its unit feature rows (the optimal one): the k-means objective
    of the merged parts, comparable across k (k auto reads it). Faces labelled < 0 are left out.
    labels : [F]; features : [F, n]; unit : :func:`unit_rows` (features) if at hand."""
    labels = np.asarray(labels)
    keep = labels >= 0
    every = bool(keep.all())               # the usual case: no subset copies
    if unit is None:
        x = np.asarray(features, dtype=np.float64)
        unit = unit_rows(x if every else x[keep])
    elif not every:
        unit = unit[keep]
    lab, n_parts = compact_labels(labels if every else labels[keep])
    centers = group_sums(lab, unit, n_parts)
    centers /= np.maximum(np.linalg.norm(centers, axis=1, keepdims=True), 1e-300)
    return float(np.sum(1.0 - np.einsum("ij,ij->i", unit, centers[lab])))


def merged_distances(distances: np.ndarray, before: np.ndarray, after: np.ndarray, *,
                     faces: np.ndarray | None = None, patches: np.ndarray | None = None) -> np.ndarray:
    """[V, k] distance of each vertex to each merged part: the least over the pieces it unites.

    distances : [V, K'] per-vertex distances to the over-segmentation's k-means centers
    (:func:`~torchakvf.parts.boundaries.vertex_distances`); before : [F] the center of each face's
    piece, after : [F] the merged labels. Centers owning no face after clean-up are left out.
    Isolines of the result are the merged parts' boundaries.

    faces [F, 3], patches [F]: the crease patches the pieces were cut along
    (:func:`~torchakvf.parts.creases.crease_patches`), if they were. A piece is then a (center,
    patch) pair, and its distance is its center's on the vertices of its patch and one more
    (cosine distances are at most 2) off them: two merged parts that share a center, one on each
    side of a crease, then meet on the crease rather than everywhere.
    """
    before, after = np.asarray(before), np.asarray(after)
    ok = (before >= 0) & (after >= 0)
    k = int(after[ok].max()) + 1 if ok.any() else 0
    out = np.full((distances.shape[0], k), np.inf)
    if patches is None:
        # distinct (old, new) pairs by one small integer key and a bincount (np.unique over rows
        # sorts F records)
        for key in np.flatnonzero(np.bincount(before[ok].astype(np.int64) * k + after[ok])):
            old, new = divmod(int(key), k)
            out[:, new] = np.minimum(out[:, new], distances[:, old])
        return out
    patches = np.asarray(patches, dtype=np.int64)
    n_patches = int(patches.max()) + 1
    key = (before[ok].astype(np.int64) * n_patches + patches[ok]) * k + after[ok]
    on_patch = {}
    for piece in np.unique(key):
        rest, new = divmod(int(piece), k)
        old, patch = divmod(rest, n_patches)
        if patch not in on_patch:
            on_patch[patch] = np.zeros(distances.shape[0], dtype=bool)
            on_patch[patch][np.asarray(faces)[patches == patch].ravel()] = True
        d = np.where(on_patch[patch], distances[:, old], distances[:, old] + 1.0)
        out[:, new] = np.minimum(out[:, new], d)
    return out


__all__ = ["MergeWeights", "MergeCache", "FIELD_OF_TERM", "term_weights", "needs_thickness", "needs_sight",
           "needs_part_sums", "needs_normals", "mesh_sums_inputs", "state_costs", "unit_rows", "boundary_bends",
           "merged_distances", "partition_cost", "next_merge_cost", "RegionGraph", "oversegment_k", "region_graph",
           "merge_costs", "greedy_merge", "merge_parts"]
