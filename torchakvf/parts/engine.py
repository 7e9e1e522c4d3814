"""The segmentation engine: solve the AKVFs once, untangle once per field count, cluster per k,
cut the parts. Every caller (``segment``, the corpus ``segment`` task, the PSB harness, the
automatic-k scan, the bench) goes through here.

    segment_each_k(meshes, ks)      one solve, every k of every mesh   -> :class:`SegmentEachK`
      solve_akvfs                   the AKVFs of the batch, once
      segment_rounds                round r: every mesh at its r-th k  -> :class:`KRound` s
        field_counts                fields untangled per mesh for those k (each mesh untangled
                                    once per distinct count, only the meshes whose count is new)
        spherical_kmeans            the meshes of the round whose (fields, clusters) are new, at
                                    once (a mesh's k's below MergeWeights.min_k share one)
        cut_parts                   ONE mesh: boundaries, clean-up, (method "merge") merging
                                    of adjacent parts, generators -> MeshSegmentation

A new stage of the method that works on one mesh's clustering (a merge of parts, a boundary
refinement) goes in :func:`cut_parts`, and only there.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, fields as dataclass_fields

import numpy as np
import torch

from ..cluster import KMeansResult, spherical_kmeans
from ..errors import ParameterError
from ..fields.akvf import SOLVERS, AKVFResult, akvf, akvf_falling_back, as_batch
from ..fields.untangle import UntangledFields, orthomax_rotations, untangled_from_rotations
from ..mesh import MeshBatch
from ..mesh.batch import pad_packed
from ..operators.killing import DEFAULT_REMEDY
from .boundaries import (face_margins, isoline_face_labels, refine_along_isolines,
                         vertex_distances)
from .discovery import absorb_single_neighbour_regions, connecting_region, remove_small_parts
from .generators import part_generators
from .concavity import dual_edges
from .graphcut import CornerMeans, GraphCut, edge_weights, graphcut_labels
from .merge import (MergeWeights, boundary_bends, merge_parts, merged_distances, next_merge_cost,
                    oversegment_k, partition_cost, region_graph, unit_rows)
from .results import MeshSegmentation, Segmentation
from .topology import face_adjacency

BOUNDARIES = ("isoline", "faces")
#: Segmentation methods. "paper": spherical k-means into k parts (Solomon et al. 2011 as
#: implemented here); "merge": k-means into k' = ceil(ratio k) parts, then adjacent parts merged
#: down to k by symmetry similarity and boundary concavity (:mod:`torchakvf.parts.merge`).
METHODS = ("paper", "merge")
#: Chosen by 3-fold cross-validation across PSB categories (benchmarks/results/quality_cv.md).
DEFAULT_METHOD = "merge"
#: Random orthogonal starts of Algorithm 1 besides the identity (the best is kept). One: on 68
#: (mesh, n) problems of 30 PSB meshes the identity and the first random start reach the best of
#: 1 + 8 starts to 1.7e-5 of the objective on average (the optima are near-equal); the PSB
#: score did not get worse with fewer (benchmarks/results/segment_profile.md; it was 8).
UNTANGLE_RESTARTS = 1
#: k-means++ restarts per clustering (the lowest cost is kept), also of the "merge" method's
#: over-segmentation into 3k. Five: the cost's winner among 20 is spread evenly over the restart
#: indices (many near-equal local optima), and the PSB score does not move with the count beyond
#: k-means' own noise (~0.005 of 1-RI): 60 meshes, 20 -> 5 / 3 restarts 0.1729 -> 0.1710 / 0.1715
#: (segment_profile.md); over-segmentations at 3k, 20 -> 5 restarts 0.1587 -> 0.1557
#: (quality_v2_restarts.md). It was 20. The paper mode's default (:data:`KMEANS_RESTARTS_BY_METHOD`).
KMEANS_RESTARTS = 5
#: k-means++ restarts by method when SegmentOptions.kmeans_restarts is None. "merge": 3, since its
#: over-segmentation into 3k is merged afterwards: 60 PSB meshes (20c+1..20c+4 of the 15 labelled
#: categories, eval harness, coarse 4000) 5 / 3 / 2 restarts 1-RI 0.1444 / 0.1433 / 0.1457, 3
#: chosen on every cross-validation fold's other two folds (held-out vs 5: -0.0009, -0.0034,
#: +0.0009); segment-stage CPU 158.0 / 138.4 / 131.7 s (benchmarks/results/quality_restarts_merge.md).
KMEANS_RESTARTS_BY_METHOD = {"paper": KMEANS_RESTARTS, "merge": 3}
#: Eigenvalues closer than this (relative) belong to one cluster, which N must not split.
CLUSTER_GAP = 1e-2
#: AKVFs computed beyond the default N when the engine solves them itself, so that a degenerate
#: eigenvalue cluster cut at N can be seen and completed (:func:`cluster_safe_n`).
SPARE_FIELDS = 4
#: k given to a mesh that sits out a round of :func:`segment_rounds` (its clustering is trivial
#: and its parts are not cut).
PAD_K = 1
#: The residual tolerance of an AKVF solve made without one (akvf's default).
AKVF_TOL = akvf.__kwdefaults__["tol"]


#: Lloyd iterations per precision phase of the round's k-means (spherical_kmeans' own default is
#: 100). 15 (issue 13): on 30 PSB meshes (2 per labelled category) 1-RI 0.1413, as at 100 (30:
#: 0.1410); restarts still moving after 15 iterations creep by a few faces per iteration, and
#: the restart kept is the lowest-cost one either way.
KMEANS_MAX_ITER = 15


#: Restarts of a mesh's k-means rounds after its first (0: every round from scratch with
#: kmeans_restarts). 2 was measured: one k-means++ start and, last, a warm start from the centroids (in the
#: round's features) of the mesh's previous round's clusters, the new clusters k-means++
#: (issue 13). On 30 PSB meshes (2 per labelled category; benchmarks/results/seed_rounds.md),
#: same run: segment stage 0.86-0.89x of from-scratch, its k-means 0.50x; the warm start is the
#: restart kept in 50 of 89 rounds; 1-RI 0.1381 against 0.1373 (3 restarts: 0.1384; 1, the warm
#: start alone: costs up to 16% higher). Off (0) by default: with it, a mesh's clustering at k
#: depends on its earlier k's, so segment_each_k no longer equals segment at each k alone
#: (tests/test_segmentation.py::test_segment_each_k_equals_segment_per_k).
KMEANS_SEEDED_RESTARTS = 0


#: Untangled fields per part wanted, by method, before the clamp to [16, 32]. "paper": the
#: paper's N = 2k. "merge": 3k, since its k-means makes k' = 3k clusters (at most k + 16) from
#: them. On the 15 labelled PSB categories (benchmarks/results/quality_v3.md; former merge
#: weights) 3k against 2k: 1-RI 0.1466 / 0.1528 with the graph cut (48 meshes), 0.1557 / 0.1579
#: without it (74 meshes), not worse in any cross-validation fold; 2k' (32 from k = 6 on) was
#: better on one fold and worse on the other two. The paper mode keeps 2k.
FIELDS_PER_PART = {"paper": 2, "merge": 3}


#: Field counts by method are rounded up to a multiple of this, so that the k's of a mesh share
#: fewer untanglings (one per distinct count). "merge": 8 (counts 16, 24, 32), with the floor
#: MergeWeights.min_k = 8 (every k <= 8 untangles 24): on the 300 labelled PSB meshes 1-RI 0.1471
#: against 0.1566 for 3k each and its own k', segment stage 0.83x; 457 untanglings against 853
#: over the protocol k's (benchmarks/results/quality_field_counts.md).
FIELDS_STEP = {"paper": 1, "merge": 8}


def _min_k_of(method: str, min_k: int | None) -> int:
    """min_k as given, or None: the default MergeWeights' for method "merge", else 1."""
    if min_k is not None:
        return int(min_k)
    return int(MergeWeights().min_k) if method == "merge" else 1


def default_n_fields(k: int, method: str = "paper", min_k: int | None = None) -> int:
    """Fields untangled for k parts: :data:`FIELDS_PER_PART` [method] x max(k, min_k), rounded
    up to a multiple of :data:`FIELDS_STEP` [method], clamped to [16, 32] (method "paper", the
    default here: the paper's N = 2k). min_k: the merge method's
    :attr:`~torchakvf.parts.merge.MergeWeights.min_k` (a k below it is over-segmented as min_k
    is, from the same fields); None: the default MergeWeights' with method "merge", else 1."""
    if method not in FIELDS_PER_PART:
        raise ParameterError(f"method must be one of {tuple(FIELDS_PER_PART)}, got {method!r}")
    step = FIELDS_STEP[method]
    n = -(-FIELDS_PER_PART[method] * max(int(k), _min_k_of(method, min_k)) // step) * step
    return int(min(max(n, 16), 32))


def cluster_safe_n(eigenvalues, n: int, floor: int = 1) -> int:
    """The field count nearest below ``n`` (at least ``floor``) that does not split a cluster of
    near-equal eigenvalues; if none, the nearest above within the computed ones, else ``n``.

    Only the span of a degenerate cluster is meaningful: cutting one leaves fields that no
    rotation can localize (measured: two spheres, n = 16 splitting a 10-fold cluster -> 13%
    leakage). eigenvalues : the ascending computed spectrum, length >= n.
    """
    lam = [float(x) for x in eigenvalues]

    def splits(m: int) -> bool:
        return m < len(lam) and lam[m] - lam[m - 1] <= CLUSTER_GAP * max(abs(lam[m - 1]), 1.0)

    for m in range(n, floor - 1, -1):
        if m >= 1 and not splits(m):
            return m
    for m in range(n + 1, len(lam) + 1):
        if not splits(m):
            return m
    return n


def per_mesh(value, nb: int, what: str) -> list[int]:
    """One positive int (Python or numpy) for every mesh, or a sequence of nb of them -> list."""
    vals = [value] * nb if isinstance(value, (int, np.integer)) else list(value)
    if len(vals) != nb:
        raise ParameterError(f"{what} has {len(vals)} values for {nb} meshes")
    for v in vals:
        if not isinstance(v, (int, np.integer)) or isinstance(v, (bool, np.bool_)) or v < 1:
            raise ParameterError(f"{what} must be a positive integer (or one per mesh), got {v!r}")
    return [int(v) for v in vals]


def _default_or_given(ks: list[int], n_fields, nb: int, method: str, min_k: int) -> list[int]:
    return ([default_n_fields(kb, method, min_k) for kb in ks] if n_fields is None
            else per_mesh(n_fields, nb, "n_fields"))


def field_counts(fields: AKVFResult, k, n_fields=None, method: str = DEFAULT_METHOD,
                 min_k: int | None = None) -> list[int]:
    """The number of fields untangled per mesh for these k.

    Default (``n_fields=None``): :func:`default_n_fields` of k, the method and min_k (the
    paper's 2k, the merge method's 3 max(k, min_k), clamped to [16, 32]), moved by
    :func:`cluster_safe_n` off a degenerate cluster of the mesh's computed eigenvalues;
    otherwise ``n_fields`` (one int or one per mesh), which must not exceed ``fields.n``.
    min_k None: the default MergeWeights' for method "merge" (:func:`default_n_fields`).
    """
    min_k = _min_k_of(method, min_k)
    nb = len(fields.batch)
    ks = per_mesh(k, nb, "k")
    ns = _default_or_given(ks, n_fields, nb, method, min_k)
    if max(ns) > fields.n:
        why = ("" if n_fields is not None else
               f" (the default of k = {ks[ns.index(max(ns))]}, method {method!r}: "
               f"{FIELDS_PER_PART[method]} x max(k, {min_k}) rounded up to a multiple of {FIELDS_STEP[method]}, "
               f"in [16, 32]; akvf_count gives the n to solve for)")
        raise ParameterError(f"n_fields up to {max(ns)} asked for{why}, but the AKVFs given have n = {fields.n}: "
                             f"solve more AKVFs or pass n_fields")
    if n_fields is None:
        lam = fields.eigenvalues.detach().cpu()
        ns = [cluster_safe_n(lam[b], ns[b], floor=max(ks[b], min_k, ns[b] // 2)) for b in range(nb)]
    return ns


def akvf_count(ks, n_fields=None, method: str = DEFAULT_METHOD, min_k: int | None = None) -> int:
    """AKVFs to solve for so that every k of ``ks`` (one list of k's per mesh) finds its fields:
    the largest ``n_fields`` when given, else the largest default count (of the method and
    min_k) plus :data:`SPARE_FIELDS`."""
    if n_fields is not None:
        ns = [n_fields] if isinstance(n_fields, (int, np.integer)) else list(n_fields)
        return max(per_mesh(ns, len(ns), "n_fields"))
    return default_n_fields(max(max(kb) for kb in ks), method, min_k) + SPARE_FIELDS


@dataclass(frozen=True)
class SegmentOptions:
    """How the parts are cut (the options of :func:`~torchakvf.parts.segment` besides k,
    n_fields and the batch's own: device, decimation). See ``segment`` for each one."""

    eps: float = 0.0
    seed: int = 0
    remedy: str = DEFAULT_REMEDY
    solver: str = "auto"
    method: str = DEFAULT_METHOD
    merge: MergeWeights = field(default_factory=MergeWeights)
    #: None = the method's default (:data:`KMEANS_RESTARTS_BY_METHOD`), resolved on construction
    #: (the recorded value, ``params["kmeans_restarts"]``, is the int used)
    kmeans_restarts: int | None = None
    #: Lloyd iterations per precision phase of each clustering (:data:`KMEANS_MAX_ITER`)
    kmeans_max_iter: int = KMEANS_MAX_ITER
    #: k-means restarts of a mesh's rounds after its first, the last of them seeded from its
    #: previous round's clustering (:data:`KMEANS_SEEDED_RESTARTS`); 0: every round from
    #: scratch with kmeans_restarts k-means++ starts (:func:`segment_rounds`)
    kmeans_seeded_restarts: int = KMEANS_SEEDED_RESTARTS
    untangle_restarts: int = UNTANGLE_RESTARTS
    boundary: str = "isoline"
    min_part_fraction: float = 0.01
    refine: bool = True
    #: method "merge": boundaries re-decided by a graph cut on the dual graph after the merge
    #: (:mod:`torchakvf.parts.graphcut`); None = off. On by default: 1-RI better on every
    #: cross-validation fold (benchmarks/results/quality_v2.md). The paper mode never cuts.
    graphcut: GraphCut | None = field(default_factory=GraphCut)

    def __post_init__(self):
        if self.boundary not in BOUNDARIES:
            raise ParameterError(f"boundary must be one of {BOUNDARIES}, got {self.boundary!r}")
        if self.solver not in SOLVERS:
            raise ParameterError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if self.method not in METHODS:
            raise ParameterError(f"method must be one of {METHODS}, got {self.method!r}")
        if not (self.eps >= 0):
            raise ParameterError(f"eps must be >= 0, got {self.eps!r}")
        # True / False / None as the API's graphcut= (a caller passing SegmentOptions keywords
        # straight through, e.g. evaluate_psb(graphcut=False), gets them checked here)
        object.__setattr__(self, "graphcut", graphcut_option(self.graphcut))
        if self.kmeans_restarts is None:
            object.__setattr__(self, "kmeans_restarts", KMEANS_RESTARTS_BY_METHOD[self.method])
        r = self.kmeans_restarts
        if not (isinstance(r, (int, np.integer)) and not isinstance(r, (bool, np.bool_)) and r >= 1):
            raise ParameterError(f"kmeans_restarts must be an integer >= 1, got {self.kmeans_restarts!r}")
        object.__setattr__(self, "kmeans_restarts", int(self.kmeans_restarts))
        if not (isinstance(self.kmeans_max_iter, (int, np.integer)) and self.kmeans_max_iter >= 1):
            raise ParameterError(f"kmeans_max_iter must be an integer >= 1, got {self.kmeans_max_iter!r}")
        if not (isinstance(self.kmeans_seeded_restarts, (int, np.integer)) and self.kmeans_seeded_restarts >= 0):
            raise ParameterError(f"kmeans_seeded_restarts must be an integer >= 0, "
                                 f"got {self.kmeans_seeded_restarts!r}")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in dataclass_fields(cls))


def graphcut_option(graphcut) -> GraphCut | None:
    """``SegmentOptions.graphcut`` from the API's ``graphcut=``: True -> the default
    :class:`GraphCut`, False or None -> off, a GraphCut -> itself."""
    if isinstance(graphcut, GraphCut):
        return graphcut
    if graphcut is None or graphcut is False:
        return None
    if graphcut is True:
        return GraphCut()
    raise ParameterError(f"graphcut must be True, False or a GraphCut, got {graphcut!r}")


def solve_akvfs(batch: MeshBatch, n: int, opts: SegmentOptions) -> tuple[AKVFResult, list]:
    """The n smallest AKVFs of every mesh of the batch, once for every k: (result, [(mesh index,
    why it was solved at full resolution)]) as :func:`~torchakvf.fields.akvf.akvf_falling_back`."""
    return akvf_falling_back(batch, n=int(n), seed=opts.seed, remedy=opts.remedy, solver=opts.solver,
                             tol=AKVF_TOL)


def solve_quality(fields: AKVFResult, b: int) -> tuple[bool, float]:
    """(converged, max_residual) of mesh b's eigensolve: its largest relative eigenpair residual
    and whether that is within the solve's tolerance (:data:`AKVF_TOL`)."""
    return bool(fields.converged[b]), float(fields.residuals[b].max())


def merging(opts: SegmentOptions) -> bool:
    """Whether parts are merged: method "merge" on plain segmentations (ε = 0; part discovery
    keeps the paper's k clusters)."""
    return opts.method == "merge" and opts.eps == 0


def merge_min_k(opts: SegmentOptions) -> int:
    """The k below which k's are over-segmented alike (``opts.merge.min_k`` when parts are
    merged, else 1: every k its own fields and clusters)."""
    return int(opts.merge.min_k) if merging(opts) else 1


def cluster_count(k: int, n_faces: int, opts: SegmentOptions) -> int:
    """Clusters k-means makes for a mesh segmented into k parts: k, or k' = ceil(ratio
    max(k, min_k)) (at most max(k, min_k) + extra_max, at most its faces) when the parts are
    merged afterwards (:func:`~torchakvf.parts.merge.oversegment_k`)."""
    if not merging(opts):
        return int(k)
    return oversegment_k(k, opts.merge.ratio, n_faces, opts.merge.extra_max, opts.merge.min_k)


def cut_parts(batch: MeshBatch, fields: AKVFResult, untangled: UntangledFields, km, b: int, k: int,
              opts: SegmentOptions, mesh_cache: dict | None = None) -> MeshSegmentation:
    """Mesh b's parts from its clustering: boundaries, (ε > 0) connecting region, clean-up of
    small pieces and symmetry generators, on the input's faces.

    batch : the batch that was solved (``fields.batch``); km : the
    :class:`~torchakvf.cluster.spherical_kmeans.KMeansResult` of the round (with
    :func:`cluster_count` clusters for mesh b), k : mesh b's k in it.
    mesh_cache : a dict kept for mesh b across the rounds of one solve: what depends on its
        mesh alone (face adjacency, dual edges) is computed once, not once per k, and what
        depends on its clustering alone (:class:`_OverSegmentation`) once per clustering.
    """
    cache = {} if mesh_cache is None else mesh_cache
    unt = untangled
    n_b = int(unt.n_fields[b])
    f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
    k_cluster = cluster_count(k, f1 - f0, opts)
    clustered = (unt.mesh_features(b).detach().cpu().numpy(),
                 km.centers[b, :k_cluster, :n_b].detach().cpu().numpy(),
                 km.labels[b, :f1 - f0].detach().cpu().numpy())
    cost = float(km.cost[b])
    merge_next = None
    over = cache.get("over") if opts.eps == 0 else None
    floor = part_floor(k, opts)
    if over is None or not over.made_from(clustered, opts, floor):
        over = _over_segmentation(batch, fields, b, clustered, opts, cache, floor)
        if opts.eps == 0:
            # k's clustered alike (the merge method's k <= min_k) share it; one entry, as the
            # rounds visit a mesh's k's in order
            cache["over"] = over
    clean, vdist, feats, labels, area = over.mesh, over.vdist, over.feats, over.labels, over.area
    adjacency = cache["adjacency"]
    if opts.eps > 0:
        labels = connecting_region(labels, face_margins(clean.faces, vdist), opts.eps)
        labels = absorb_single_neighbour_regions(labels, adjacency)
        labels = remove_small_parts(labels, adjacency, area, floor, into_connecting=True)
        labels = absorb_single_neighbour_regions(labels, adjacency)
    else:
        if "dual" not in cache:
            cache["dual"] = dual_edges(clean.vertices, clean.faces)
        dual = cache["dual"]
        # per mesh (kept across k): the dual edges' bending sums at the merge's crease angle
        bends_key = ("bends", opts.merge.crease_angle)
        if bends_key not in cache:
            cache[bends_key] = boundary_bends(dual, opts.merge.crease_angle)
        bends = cache[bends_key]
        unit = over.unit
        if merging(opts):
            graph_key = ("graph", opts.merge.crease_angle)
            if graph_key not in over.graphs:
                over.graphs[graph_key] = region_graph(labels, dual, feats, area, opts.merge.crease_angle,
                                                      unit=unit, bends=bends)
            merged = merge_parts(labels, clean.faces, clean.vertices, feats, area, k, opts.merge,
                                 dual=dual, unit=unit, bends=bends, graph=over.graphs[graph_key])
            vdist = merged_distances(vdist, labels, merged)   # the refined cut follows the merged parts
            labels = merged
            # the k-means cost of the merged parts, in units of the solved mesh's faces (k auto reads it)
            cost = partition_cost(labels, feats, unit=unit) * (f1 - f0) / len(labels)
            if opts.graphcut is not None:
                # data term: each face's distance to each part, the mean over its corners
                # (made for the faces the cut reads: those near a boundary)
                face_dist = CornerMeans(clean.faces, vdist)
                cut_key = ("cut_cost", opts.graphcut)
                if cut_key not in cache:
                    cache[cut_key] = edge_weights(dual, opts.graphcut)
                labels = graphcut_labels(labels, face_dist, dual, area, opts.graphcut, cut_cost=cache[cut_key],
                                         min_fraction=floor)
        # what merging two of these parts would cost (k auto's "merge" rule reads it)
        merge_next = next_merge_cost(labels, dual, feats, area, opts.merge, unit=unit, bends=bends)
    gens = part_generators(labels, feats, area, unt.energies[b, :n_b].detach().cpu().numpy(), k)
    converged, residual = solve_quality(fields, b)
    return MeshSegmentation(
        name=clean.name, k=k, labels=clean.labels_to_input_faces(labels),
        features=clean.to_input_faces(feats), eigenvalues=fields.eigenvalues[b].detach().cpu().numpy(),
        generators=gens,
        refined=refine_along_isolines(clean.vertices, clean.faces, vdist) if opts.refine else None,
        cost=cost,
        params=dict(k=k, eps=opts.eps, seed=opts.seed, n_fields=n_b, remedy=opts.remedy,
                    boundary=opts.boundary, kmeans_restarts=opts.kmeans_restarts,
                    kmeans_max_iter=opts.kmeans_max_iter, kmeans_seeded_restarts=opts.kmeans_seeded_restarts,
                    untangle_restarts=opts.untangle_restarts, min_part_fraction=opts.min_part_fraction,
                    part_floor=floor,
                    coarse_faces=0 if batch.coarse_of(b) is None else len(batch.coarse_of(b).coarse.faces),
                    solver=opts.solver, method=opts.method,
                    **({"graphcut": True, **{f"graphcut_{name}": float(v) for name, v in vars(opts.graphcut).items()}}
                       if opts.graphcut is not None and merging(opts) else {}),
                    **({"merge_next": merge_next} if merge_next is not None else {}),
                    **({"k_oversegment": k_cluster, **{f"merge_{name}": float(v) for name, v in
                                                       vars(opts.merge).items() if v is not None}} if merging(opts) else {})),
        converged=converged, max_residual=residual)


@dataclass
class _OverSegmentation:
    """One mesh's clustering carried to the mesh its parts are cut on, up to the merge: the
    boundaries (isolines) and, with ε = 0, the clean-up of small pieces. It depends on the
    clustering alone, not on k, so k's clustered alike (the merge method's k <= min_k, one
    k-means) share it (:func:`cut_parts` keeps the last one in its mesh cache).

    source : (features [F_b, n], centers [k', n], labels [F_b]) as clustered, on the solved
        mesh; settings : the options read here (:func:`_over_settings`): an entry serves only
        an identical clustering under the same options
    mesh : the mesh the parts are cut on (the fine one when solved on a decimated mesh) and, on
        it, vdist [V, k'] (each vertex's distance to each center), feats [F, n], labels [F]
        (with ε = 0 cleaned of small pieces), area [F] (unit total), unit [F, n] (unit feature
        rows; None with ε > 0)
    graphs : the merge's region graph of ``labels``, by crease angle (made when first asked)
    """

    source: tuple
    settings: tuple
    mesh: object
    vdist: np.ndarray
    feats: np.ndarray
    labels: np.ndarray
    area: np.ndarray
    unit: np.ndarray | None
    graphs: dict = field(default_factory=dict)

    def made_from(self, clustered: tuple, opts: SegmentOptions, floor: float) -> bool:
        """Whether this entry is for exactly this clustering (equal arrays) and these options."""
        return self.settings == _over_settings(opts, floor) and all(
            a.shape == c.shape and np.array_equal(a, c) for a, c in zip(self.source, clustered))


def _over_settings(opts: SegmentOptions, floor: float) -> tuple:
    """The options an :class:`_OverSegmentation` depends on besides its clustering (floor:
    :func:`part_floor` of its k)."""
    return (opts.boundary, opts.eps > 0, floor)


#: At k parts, pieces are cleaned away below at most this fraction of a mean part's area
#: (1/k), whatever ``min_part_fraction`` says: k parts of at least 1% cannot exist beyond
#: k = 100, and at the PSB humans' k = 81 the 1% floor left 43 parts.
PART_FLOOR_OF_MEAN = 0.25


def part_floor(k: int, opts: SegmentOptions) -> float:
    """The area fraction below which pieces are cleaned away at k parts: ``min_part_fraction``,
    at most PART_FLOOR_OF_MEAN / k (so the floor changes nothing up to k = 25 at the default)."""
    return min(float(opts.min_part_fraction), PART_FLOOR_OF_MEAN / max(int(k), 1))


def _over_segmentation(batch: MeshBatch, fields: AKVFResult, b: int, clustered: tuple,
                       opts: SegmentOptions, cache: dict, floor: float) -> _OverSegmentation:
    """:class:`_OverSegmentation` of mesh b from its clustering (features, centers, labels on
    the solved mesh); puts the mesh's face adjacency in ``cache`` ("adjacency")."""
    feats, centers, labels = clustered
    clean = batch.meshes[b]
    f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
    area = fields.system.geometry.face_area[f0:f1].detach().cpu().numpy()
    vdist = vertex_distances(clean.vertices, clean.faces, feats, area, centers)
    coarse = batch.coarse_of(b)
    if coarse is not None:
        # Solved on a decimated mesh: the distance fields are interpolated at the fine
        # vertices, so boundaries (isolines) and everything after are cut on the fine mesh.
        clean, vdist = coarse.fine, coarse.vertex_field(vdist)
        feats, labels = coarse.face_values(feats), coarse.face_values(labels)
        area = coarse.fine_area
    if opts.boundary == "isoline":
        labels = isoline_face_labels(clean.faces, vdist)
    if "adjacency" not in cache:
        cache["adjacency"] = face_adjacency(clean.faces)
    unit = None
    if opts.eps == 0:
        labels = remove_small_parts(labels, cache["adjacency"], area, floor, into_connecting=False)
        unit = unit_rows(feats)    # the merge, its cost and the next merge's all read them
    for shared in (vdist, feats, labels, unit):
        if shared is not None:     # read by every k that shares them: a write would be a bug
            shared.flags.writeable = False
    return _OverSegmentation(source=tuple(np.array(a) for a in clustered), settings=_over_settings(opts, floor),
                             mesh=clean,
                             vdist=vdist, feats=feats, labels=labels, area=area, unit=unit)


@dataclass
class KRound:
    """One round of :func:`segment_rounds`: every mesh at one k.

    ks : [B] the k of each mesh in this round (:data:`PAD_K` for a mesh with no k left)
    active : indices of the meshes whose own k this round is
    meshes : [B] MeshSegmentation per active mesh, None for the others
    untangled : the untangled fields the round clustered (shared with rounds of equal counts)
    seconds : {"untangle": s (0 when shared), "cluster": s (k-means + cutting the parts)}
    """

    ks: list
    active: list
    meshes: list
    untangled: UntangledFields
    seconds: dict

    def segmentation(self) -> Segmentation:
        return Segmentation(self.meshes, untangled=self.untangled)


def check_ks(batch: MeshBatch, ks: list) -> list:
    """ks : one int or one list of k's per mesh -> [B] lists of distinct ints (order kept);
    ParameterError for a k that is not a positive integer or exceeds its mesh's faces."""
    nb = len(batch)
    if isinstance(ks, (int, np.integer)):
        ks = [[ks]] * nb
    ks = list(ks)
    if len(ks) != nb:
        raise ParameterError(f"k has {len(ks)} values for {nb} meshes")
    out = []
    for b, kb in enumerate(ks):
        kb = [kb] if isinstance(kb, (int, np.integer)) else list(kb)
        kb = list(dict.fromkeys(per_mesh(kb, len(kb), "k")))
        n_f = len(batch.meshes[b].faces)
        for kk in kb:
            if kk > n_f:
                raise ParameterError(f"{batch.meshes[b].name}: k = {kk} is larger than its {n_f} faces")
        out.append(kb)
    return out


def segment_rounds(fields: AKVFResult, ks, opts: SegmentOptions, *, n_fields=None,
                   untangled: UntangledFields | None = None):
    """Yields one :class:`KRound` per round: round r segments every mesh with its r-th k.

    ks : one list of k's per mesh (or one int, or one int per mesh); meshes with fewer k's sit
        out the later rounds (clustered with :data:`PAD_K`, not cut)
    n_fields : fields untangled per mesh, as :func:`field_counts` (None: from each round's k)
    untangled : the untangled fields of these AKVFs to use (their counts must be those the k's
        need): rounds whose counts agree share one untangling either way
    """
    batch = fields.batch
    ks = check_ks(batch, ks)
    nb = len(batch)
    rotations = {}      # (mesh, n) -> MeshRotation: a mesh is untangled once per field count
    assembled = {}      # tuple of per-mesh counts -> UntangledFields shared by the rounds that agree
    mesh_caches = [{} for _ in range(nb)]
    prev_labels = [None] * nb   # kmeans_seeded_restarts: each mesh's k-means labels of its last round
    clusterings = {}    # (mesh, n, k') -> MeshClustering: k's with equal counts share one k-means
    if untangled is not None:
        assembled[tuple(int(v) for v in untangled.n_fields)] = untangled
    plans = {}          # round -> its _round_plan, made once: read by the round and the one before

    def plan(r: int) -> tuple:
        if r not in plans:
            plans[r] = _round_plan(fields, ks, r, n_fields, opts)
        return plans[r]

    n_rounds = max(len(kb) for kb in ks)
    for r in range(n_rounds):
        t0 = time.perf_counter()
        round_ks, active, ns, km_ks = plan(r)
        if untangled is not None:
            if untangled.source is not fields or any(int(untangled.n_fields[b]) != ns[b] for b in active):
                raise ParameterError(f"the untangled fields given are for n = {list(untangled.n_fields)} "
                                     f"of other AKVFs; these k need n = {list(ns)} of the AKVFs passed")
            unt = untangled
        else:
            unt = _round_untangled(fields, ns, active, rotations, assembled, opts)
        t1 = time.perf_counter()
        if opts.kmeans_seeded_restarts and r > 0:
            xpad, mask = pad_packed(unt.features.double(), batch.face_ptr)
            # Warm start: each active mesh's last restart begins at the centroids, in this
            # round's features, of its previous round's clusters (the extra clusters k-means++).
            init = [previous_centroids(xpad[b], mask[b], prev_labels[b], km_ks[b]) if b in active else None
                    for b in range(nb)]
            km = spherical_kmeans(xpad, mask, km_ks, restarts=opts.kmeans_seeded_restarts, seed=opts.seed,
                                  max_iter=opts.kmeans_max_iter, init=init)
        else:
            km = _round_clustering(unt, km_ks, ns, active, clusterings, opts)
        if opts.kmeans_seeded_restarts:
            for b in active:
                prev_labels[b] = km.labels[b]
        meshes = [None] * nb
        following = None
        if r + 1 < n_rounds:
            try:
                following = plan(r + 1)
            except ParameterError:     # that round raises it itself, after this one is yielded
                pass
        for b in active:
            meshes[b] = cut_parts(batch, fields, unt, km, b, round_ks[b], opts, mesh_caches[b])
            if following is None or b not in following[1] or \
                    (following[2][b], following[3][b]) != (ns[b], km_ks[b]):
                # the mesh's next k clusters otherwise (or it has none): its over-segmentation
                # (fine-mesh arrays, ~10 MB at 20k faces) goes, not kept for the batch's life
                mesh_caches[b].pop("over", None)
        t2 = time.perf_counter()
        yield KRound(ks=round_ks, active=active, meshes=meshes, untangled=unt,
                     seconds={"untangle": t1 - t0, "cluster": t2 - t1})


def _round_plan(fields: AKVFResult, ks: list, r: int, n_fields, opts: SegmentOptions) -> tuple:
    """Round r of :func:`segment_rounds`: ([B] each mesh's k, :data:`PAD_K` for a mesh with no
    k left; the meshes whose own k it is; [B] fields untangled per mesh, :func:`field_counts`;
    [B] clusters per mesh, :func:`cluster_count`). Raises as field_counts does."""
    batch = fields.batch
    nb = len(ks)
    active = [b for b in range(nb) if r < len(ks[b])]
    round_ks = [ks[b][r] if r < len(ks[b]) else PAD_K for b in range(nb)]
    ns = field_counts(fields, round_ks, n_fields, opts.method, merge_min_k(opts))
    n_faces = (batch.face_ptr[1:] - batch.face_ptr[:-1]).tolist()
    km_ks = [cluster_count(round_ks[b], n_faces[b], opts) if b in active else PAD_K for b in range(nb)]
    return round_ks, active, ns, km_ks


def previous_centroids(x: torch.Tensor, mask: torch.Tensor, labels: torch.Tensor, k: int) -> torch.Tensor | None:
    """Seed centers for one mesh from a previous clustering of its rows.

    x : [N_max, d] padded feature rows (this round's); mask : [N_max]; labels : [N_max] the
    previous round's cluster of each row (-1 on padding); k : clusters of this round.
    Returns [j, d] unit centroids (rows normalized, then summed per cluster: spherical k-means'
    center of the cluster) of the previous clusters that are not empty, the heaviest k of them
    if there are more (the k's of a mesh need not be ascending), or None if there are none.
    """
    xn = torch.nn.functional.normalize(x.double(), dim=-1)
    keep = mask & (labels >= 0)
    lab = labels[keep]
    if len(lab) == 0:
        return None
    sums = xn.new_zeros(int(lab.max()) + 1, x.shape[1]).index_add_(0, lab, xn[keep])
    norm = sums.norm(dim=-1)
    ok = torch.nonzero(norm > 0).reshape(-1)
    if len(ok) == 0:
        return None
    if len(ok) > k:
        ok = ok[torch.argsort(-norm[ok], stable=True)[:k]].sort().values
    return sums[ok] / norm[ok, None]


@dataclass
class MeshClustering:
    """One mesh's k-means answer at (n fields, k' clusters): labels [N_b] of its rows, centers
    [k', n] (unit), cost, Lloyd iterations and restart_costs [R]."""

    labels: torch.Tensor
    centers: torch.Tensor
    cost: torch.Tensor
    iterations: torch.Tensor
    restart_costs: torch.Tensor


def _round_clustering(unt: UntangledFields, km_ks: list, ns: list, active: list,
                      clusterings: dict, opts: SegmentOptions) -> KMeansResult:
    """The round's k-means: each active mesh b into km_ks[b] clusters of its ns[b] features
    (``unt``), from ``clusterings`` {(b, n, k'): MeshClustering} where a round before made it,
    the others clustered now (together) and added to it. Meshes sitting out the round get a
    placeholder (every row in cluster 0; they are not cut). Returns labels [B, F_max] and
    centers [B, k_max, unt.n] over the whole batch.

    A mesh's clustering depends on its own rows (its n columns), k' and the seed alone
    (:func:`~torchakvf.cluster.spherical_kmeans`), so a mesh gets the bits it gets alone, in
    any batch; this saves the k-means of every k whose (n, k') an earlier k of the mesh had (the
    merge method over-segments every k up to a floor alike, :func:`cluster_count`).
    """
    batch = unt.batch
    nb, d = len(batch), unt.n
    dev = unt.source.forms.device
    n_faces = (batch.face_ptr[1:] - batch.face_ptr[:-1]).tolist()
    keys = {b: (b, ns[b], km_ks[b]) for b in active}
    missing = [b for b in active if keys[b] not in clusterings]
    for n in sorted({ns[b] for b in missing}):
        # The meshes at n fields cluster their n columns, padded to their own largest face
        # count (a mesh alone: no padding), not the whole batch's.
        group = [b for b in missing if ns[b] == n]
        rows = max(n_faces[b] for b in group)
        x = torch.zeros(len(group), rows, n, dtype=torch.float64, device=dev)
        mask = torch.zeros(len(group), rows, dtype=torch.bool, device=dev)
        for j, b in enumerate(group):
            x[j, :n_faces[b]] = unt.mesh_features(b).double()
            mask[j, :n_faces[b]] = True
        km = spherical_kmeans(x, mask, [km_ks[b] for b in group],
                              restarts=opts.kmeans_restarts, seed=opts.seed, max_iter=opts.kmeans_max_iter)
        for j, b in enumerate(group):
            clusterings[keys[b]] = MeshClustering(
                labels=km.labels[j, :n_faces[b]], centers=km.centers[j, :km_ks[b]], cost=km.cost[j],
                iterations=km.iterations[j], restart_costs=km.restart_costs[j])
    k_max = max([km_ks[b] for b in active] + [PAD_K])
    f_max = max(n_faces)
    labels = torch.where(torch.arange(f_max, device=dev)[None, :] < torch.tensor(n_faces, device=dev)[:, None], 0, -1)
    centers = torch.zeros(nb, k_max, d, dtype=torch.float64, device=dev)
    cost = torch.zeros(nb, dtype=torch.float64, device=dev)
    iters = torch.zeros(nb, dtype=torch.long, device=dev)
    restart_costs = torch.zeros(nb, opts.kmeans_restarts, dtype=torch.float64, device=dev)
    for b in active:
        c = clusterings[keys[b]]
        labels[b, :len(c.labels)] = c.labels
        centers[b, :c.centers.shape[0], :c.centers.shape[1]] = c.centers
        cost[b], iters[b], restart_costs[b] = c.cost, c.iterations, c.restart_costs
    return KMeansResult(labels=labels, centers=centers, cost=cost, iterations=iters, restart_costs=restart_costs)


def _round_untangled(fields: AKVFResult, ns: list, active: list, rotations: dict, assembled: dict,
                     opts: SegmentOptions) -> UntangledFields:
    """The untangled fields of one round: each active mesh b at ns[b], from ``rotations``
    {(b, n): MeshRotation} where known, the others untangled now (together) and added to it.

    A mesh sitting out the round is clustered with PAD_K and not cut, so any of its known
    rotations serves (the smallest n, which keeps the round's arrays narrow); only a mesh with
    none yet is untangled, at its ns[b]. A mesh's rotation depends on its own fields, n and the
    seed alone (:func:`~torchakvf.fields.untangle.orthomax_rotations`), so this gives the bits
    an untangling of the whole batch at these counts gives.
    """
    counts = list(ns)
    for b in range(len(ns)):
        known = sorted(n for (mb, n) in rotations if mb == b)
        if b not in active and known and (b, ns[b]) not in rotations:
            counts[b] = known[0]
    key = tuple(counts)
    if key not in assembled:
        missing = {b: counts[b] for b in range(len(counts)) if (b, counts[b]) not in rotations}
        new = orthomax_rotations(fields, missing, seed=opts.seed, restarts=opts.untangle_restarts)
        rotations.update({(b, counts[b]): rot for b, rot in new.items()})
        assembled[key] = untangled_from_rotations(fields, [rotations[(b, counts[b])] for b in range(len(counts))])
    return assembled[key]


@dataclass
class SegmentEachK:
    """What :func:`segment_each_k` returns.

    fields : the AKVFs (of ``fields.batch``: decimated meshes that could not be solved are at
        full resolution there); fell_back : [(mesh index, why)] of those meshes
    meshes : [B] {k: MeshSegmentation} of every k asked for each mesh
    rounds : the :class:`KRound` s, in order (their ``meshes`` are the same objects)
    seconds : {"akvf": s, "untangle": s, "cluster": s}
    """

    fields: AKVFResult
    fell_back: list
    meshes: list
    rounds: list = field(default_factory=list)
    seconds: dict = field(default_factory=dict)

    def segmentation(self, k) -> Segmentation:
        """Every mesh at k (one int, or one per mesh); with the untangled fields behind them when
        one round made them all."""
        ks = per_mesh(k, len(self.meshes), "k")
        for r in self.rounds:
            if r.ks == ks and len(r.active) == len(ks):
                return r.segmentation()
        return Segmentation([self.meshes[b][kb] for b, kb in enumerate(ks)])


def segment_each_k(meshes, ks, *, eps: float = 0.0, seed: int = 0, n_fields=None,
                   remedy: str = DEFAULT_REMEDY, solver: str = "auto", method: str = DEFAULT_METHOD,
                   merge: MergeWeights | None = None,
                   kmeans_restarts: int | None = None, untangle_restarts: int = UNTANGLE_RESTARTS,
                   boundary: str = "isoline", min_part_fraction: float = 0.01, refine: bool = True,
                   coarse_faces: int | None = None, device=None, n_akvf: int | None = None,
                   untangled: UntangledFields | None = None, graphcut=True) -> SegmentEachK:
    """Segment every mesh at each of its k's from one AKVF solve.

    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`AKVFResult` to reuse (its n must
        cover the field counts)
    ks : per mesh, the list of its k's (or one int per mesh, or one int for all)
    n_akvf : AKVFs to solve for (default :func:`akvf_count`: the largest default field count
        of the k's plus :data:`SPARE_FIELDS`, or the largest ``n_fields``); pass a fixed one to
        make a mesh's fields independent of the k's of the meshes sharing its batch
    graphcut : True (default), False, or a :class:`~torchakvf.parts.graphcut.GraphCut`: see
        ``segment``
    coarse_faces, device : how the batch is built from Mesh inputs (see ``segment``)
    the rest : as in :func:`~torchakvf.parts.segment`
    """
    opts = SegmentOptions(eps=eps, seed=seed, remedy=remedy, solver=solver, method=method,
                          merge=MergeWeights() if merge is None else merge,
                          graphcut=graphcut,
                          kmeans_restarts=kmeans_restarts, untangle_restarts=untangle_restarts,
                          boundary=boundary, min_part_fraction=min_part_fraction, refine=refine)
    if coarse_faces is not None and isinstance(meshes, (AKVFResult, MeshBatch)):
        raise ParameterError("coarse_faces applies to Mesh inputs; build the batch with "
                             "MeshBatch.from_meshes(meshes, coarse_faces=...) instead")
    t0 = time.perf_counter()
    fell_back = []
    if isinstance(meshes, AKVFResult):
        fields = meshes
    else:
        batch = as_batch(meshes, device=device, coarse_faces=coarse_faces)
        ks = check_ks(batch, ks)
        n_akvf = akvf_count(ks, n_fields, opts.method, merge_min_k(opts)) if n_akvf is None else n_akvf
        fields, fell_back = solve_akvfs(batch, n_akvf, opts)
    t1 = time.perf_counter()
    out = SegmentEachK(fields=fields, fell_back=fell_back, meshes=[{} for _ in range(len(fields.batch))],
                       seconds={"akvf": t1 - t0, "untangle": 0.0, "cluster": 0.0})
    for rnd in segment_rounds(fields, ks, opts, n_fields=n_fields, untangled=untangled):
        out.rounds.append(rnd)
        for b in rnd.active:
            out.meshes[b][rnd.ks[b]] = rnd.meshes[b]
        for stage, s in rnd.seconds.items():
            out.seconds[stage] += s
    return out


__all__ = ["segment_each_k", "segment_rounds", "solve_akvfs", "solve_quality", "cut_parts", "check_ks",
           "field_counts", "akvf_count", "graphcut_option", "merge_min_k", "cluster_count", "default_n_fields", "cluster_safe_n", "per_mesh",
           "SegmentOptions", "SegmentEachK", "KRound", "DEFAULT_REMEDY", "BOUNDARIES", "METHODS", "DEFAULT_METHOD",
           "UNTANGLE_RESTARTS", "KMEANS_RESTARTS", "KMEANS_RESTARTS_BY_METHOD", "KMEANS_SEEDED_RESTARTS", "SPARE_FIELDS",
           "FIELDS_PER_PART", "FIELDS_STEP", "PAD_K", "AKVF_TOL"]
