"""Cutting one mesh's parts from its clustering: boundaries, clean-up of small pieces, (method
"merge") merging of adjacent parts and the graph cut, (ε > 0) the connecting region, symmetry
generators -> :class:`~torchakvf.parts.results.MeshSegmentation`.

A new stage of the method that works on one mesh's clustering (a merge of parts, a boundary
refinement) goes in :func:`cut_parts`, and only there.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..fields.akvf import AKVFResult
from ..fields.untangle import UntangledFields
from ..mesh import MeshBatch
from ..mesh.raycast import RayCaster
from ..options import PART_FLOOR_OF_MEAN, GraphCut, SegmentOptions
from .boundaries import face_margins, isoline_face_labels, refine_along_isolines, vertex_distances
from .concave_choice import prefers_other, same_partition
from .concavity import DualEdges, dual_edges
from .creases import crease_band_of, crease_patches, split_by_patches, unit_face_normals, unite_patch_fragments
from .discovery import absorb_single_neighbour_regions, connecting_region, remove_small_parts
from .field_counts import cluster_count
from .generators import part_generators
from .graphcut import CornerMeans, edge_weights, graphcut_labels
from .merge import (
    MergeCache,
    RegionGraph,
    boundary_bends,
    merge_parts,
    merged_distances,
    mesh_sums_inputs,
    needs_normals,
    needs_part_sums,
    needs_sight,
    needs_thickness,
    next_merge_cost,
    partition_cost,
    region_graph,
    unit_rows,
)
from .pieces import limit_parts
from .results import MeshSegmentation
from .sightlines import PartSight, SightLines
from .solve import solve_quality
from .topology import face_adjacency


@dataclass
class ClusteredParts:
    """One mesh's clustering carried to the mesh its parts are cut on, up to the merge: the
    boundaries (isolines) and, with ε = 0, the clean-up of small pieces. It depends on the
    clustering alone, not on k, so k's clustered alike (the merge method's k <= min_k, one
    k-means) share it (:func:`cut_parts` keeps the last one in the :class:`MeshCache`).

    source : (features [F_b, n], centers [k', n], labels [F_b]) as clustered, on the solved
        mesh; settings : the options read here (:func:`over_settings`): an entry serves only
        an identical clustering under the same options
    mesh : the mesh the parts are cut on (the fine one when solved on a decimated mesh) and, on
        it, vdist [V, k'] (each vertex's distance to each center), feats [F, n], labels [F]
        (with ε = 0 cleaned of small pieces; cut along creases where the merge asks for it:
        then center ``labels // n_patches``), area [F] (unit total), unit [F, n] (unit feature
        rows; None with ε > 0)
    graphs : the merge's region graph of ``labels`` by (crease angle, whether it holds the
        centroids, the thickness, the lines of sight) (made when first asked)
    n_patches : the crease patches ``labels`` were cut along (1: not cut)
    """

    source: tuple
    settings: tuple
    mesh: object
    vdist: np.ndarray
    feats: np.ndarray
    labels: np.ndarray
    area: np.ndarray
    unit: np.ndarray | None
    graphs: dict[tuple, RegionGraph] = field(default_factory=dict)
    n_patches: int = 1

    @property
    def centers(self) -> np.ndarray:
        """[F] the k-means center (a column of ``vdist``) of each face's piece."""
        return self.labels // self.n_patches if self.n_patches > 1 else self.labels

    def made_from(self, clustered: tuple, opts: SegmentOptions, floor: float) -> bool:
        """Whether this entry is for exactly this clustering (equal arrays) and these options."""
        return self.settings == over_settings(opts, floor) and all(
            a.shape == c.shape and np.array_equal(a, c) for a, c in zip(self.source, clustered))


@dataclass
class MeshCache:
    """What :func:`cut_parts` keeps for one mesh across the rounds of one solve: what depends on
    the mesh alone is made once, not once per k, and what depends on its clustering alone once
    per clustering.

    adjacency : [P, 2] face pairs sharing an edge (of the mesh the parts are cut on)
    dual : its dual edges; bends : {crease angle: :func:`~torchakvf.parts.merge.boundary_bends`}
        (:meth:`bends_at`)
    cut_costs : {GraphCut: [P] dual-edge costs of the graph cut}
    over : the last :class:`ClusteredParts` (ε = 0), for the next k clustered alike
    sums_inputs : (centroids, thickness) of the mesh the merge terms read
        (:func:`~torchakvf.parts.merge.mesh_sums_inputs`), made when first needed
    patches : {(angle, rings, concave only): ([F] :func:`~torchakvf.parts.creases.crease_band_of`,
        [F] :func:`~torchakvf.parts.creases.crease_patches`)}
    caster : the mesh's :class:`~torchakvf.mesh.raycast.RayCaster`, made when first needed: the
        thickness and the lines of sight cast on one tree
    sight : the mesh's :class:`~torchakvf.parts.sightlines.SightLines`, made when first needed
    normals : [F, 3] the mesh's unit face normals, made when a merge first reads them
        (:meth:`normals_of`)
    """

    adjacency: np.ndarray | None = None
    patches: dict[tuple, tuple] = field(default_factory=dict)
    sums_inputs: tuple | None = None
    dual: DualEdges | None = None
    bends: dict[float, tuple] = field(default_factory=dict)
    cut_costs: dict[GraphCut, np.ndarray] = field(default_factory=dict)
    over: ClusteredParts | None = None
    caster: RayCaster | None = None
    sight: SightLines | None = None
    normals: np.ndarray | None = None

    def normals_of(self, mesh, weights) -> np.ndarray | None:
        """The unit face normals of ``mesh`` (the one the parts are cut on), made once, where
        ``weights`` read them (:func:`~torchakvf.parts.merge.needs_normals`); else None."""
        if not needs_normals(weights):
            return None
        if self.normals is None:
            self.normals = unit_face_normals(mesh.vertices, mesh.faces)
        return self.normals

    def bends_at(self, crease: float) -> tuple:
        """:func:`~torchakvf.parts.merge.boundary_bends` of ``dual`` at ``crease``, made once."""
        if crease not in self.bends:
            self.bends[crease] = boundary_bends(self.dual, crease)
        return self.bends[crease]

    def ray_caster(self, mesh) -> RayCaster:
        """The mesh's ray caster (``mesh`` the one the parts are cut on), made once."""
        if self.caster is None:
            self.caster = RayCaster(mesh.vertices, mesh.faces)
        return self.caster


def over_settings(opts: SegmentOptions, floor: float) -> tuple:
    """The options an :class:`ClusteredParts` depends on besides its clustering (floor:
    :func:`part_floor` of its k)."""
    split = ((*crease_key(opts), opts.overseg.unite_fragments, opts.overseg.crease_per_piece)
             if crease_split_on(opts) else None)
    return (opts.boundary, opts.eps > 0, floor, split)


def crease_key(opts: SegmentOptions) -> tuple:
    """(angle, rings, concave only): the arguments of the crease patches the options ask for."""
    return (opts.overseg.crease_split, opts.overseg.crease_rings, opts.overseg.crease_concave)


def crease_split_on(opts: SegmentOptions) -> bool:
    """Whether the over-segmentation is cut along creases: only where parts are merged."""
    return opts.merges_parts and opts.overseg.crease_split is not None


def joining_weights(dual: DualEdges) -> np.ndarray:
    """[P] weight of each dual edge when a small piece chooses the neighbour to join: 1 on flat
    and convex surface, falling to 0 on concave creases of 45° and more (the minima rule)."""
    return 1.0 - np.clip(dual.dihedral / (np.pi / 4), 0.0, 1.0)


def part_floor(k: int, opts: SegmentOptions) -> float:
    """The area fraction below which pieces are cleaned away at k parts: ``min_part_fraction``,
    at most :data:`~torchakvf.options.PART_FLOOR_OF_MEAN` / k (so the floor changes nothing up
    to k = 25 at the default)."""
    return min(float(opts.min_part_fraction), PART_FLOOR_OF_MEAN / max(int(k), 1))


def over_segmentation(batch: MeshBatch, fields: AKVFResult, b: int, clustered: tuple,
                      opts: SegmentOptions, cache: MeshCache, floor: float) -> ClusteredParts:
    """:class:`ClusteredParts` of mesh b from its clustering (features, centers, labels on
    the solved mesh); sets the mesh's face adjacency in ``cache``."""
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
    if cache.adjacency is None:
        cache.adjacency = face_adjacency(clean.faces)
    unit = None
    n_patches = 1
    if crease_split_on(opts):
        key = crease_key(opts)
        if cache.dual is None:
            cache.dual = dual_edges(clean.vertices, clean.faces)
        dual = cache.dual
        if key not in cache.patches:
            band = crease_band_of(clean.vertices, clean.faces, dual, *key)
            cache.patches[key] = band, crease_patches(clean.vertices, clean.faces, dual, *key, band=band)
        band, patches = cache.patches[key]
        if opts.overseg.crease_per_piece:
            # each k-means piece cut where a crease crosses it, whether or not the crease
            # encloses a patch of the whole surface (see OverSegmentation.crease_per_piece)
            apart = labels[dual.pairs[:, 0]] != labels[dual.pairs[:, 1]]
            pieces = crease_patches(clean.vertices, clean.faces, dual, *key, cut=apart, band=band)
            labels, n_patches = split_by_patches(labels, pieces)
        else:
            labels, n_patches = split_by_patches(labels, patches)
        if opts.overseg.unite_fragments:
            labels = unite_patch_fragments(labels, patches, cache.adjacency, area, floor)
        # A small piece joins a piece of its own patch where it has one (the k-means boundary is
        # the weaker of the two it was cut by), else the neighbour across its least concave
        # boundary (creases where primitives meet are concave; convex ones run inside parts).
        same = patches[cache.adjacency[:, 0]] == patches[cache.adjacency[:, 1]]
        labels = remove_small_parts(labels, cache.adjacency[same], area, floor, into_connecting=False)
        labels = remove_small_parts(labels, cache.adjacency, area, floor, into_connecting=False,
                                    weights=joining_weights(cache.dual))
    if opts.eps == 0:
        labels = remove_small_parts(labels, cache.adjacency, area, floor, into_connecting=False)
        unit = unit_rows(feats)    # the merge, its cost and the next merge's all read them
    for shared in (vdist, feats, labels, unit):
        if shared is not None:     # read by every k that shares them: a write would be a bug
            shared.flags.writeable = False
    return ClusteredParts(source=tuple(np.array(a) for a in clustered), settings=over_settings(opts, floor),
                            mesh=clean, vdist=vdist, feats=feats, labels=labels, area=area, unit=unit,
                            n_patches=n_patches)


@dataclass
class CutParts:
    """A mesh's labels [F] on the mesh they are cut on, the distance fields vdist [V, parts] the
    refined cut follows, the clustering cost and (ε = 0) what merging two parts would cost."""

    labels: np.ndarray
    vdist: np.ndarray
    cost: float
    merge_next: float | None = None
    #: whether the :class:`~torchakvf.options.ConcaveChoice`'s second merge made the parts
    merge_second: bool = False


def cut_parts(batch: MeshBatch, fields: AKVFResult, untangled: UntangledFields, km, b: int, k: int,
              opts: SegmentOptions, mesh_cache: MeshCache | None = None, extras: bool = True
              ) -> MeshSegmentation:
    """Mesh b's parts from its clustering: boundaries, (ε > 0) connecting region, clean-up of
    small pieces and symmetry generators, on the input's faces.

    batch : the batch that was solved (``fields.batch``); km : the
    :class:`~torchakvf.cluster.spherical_kmeans.KMeansResult` of the round (with
    :func:`~torchakvf.parts.field_counts.cluster_count` clusters for mesh b), k : mesh b's k in it.
    mesh_cache : the :class:`MeshCache` kept for mesh b across the rounds of one solve.
    extras : False: the same labels and cost without what only some callers read: no symmetry
        generators, refined mesh or next merge's cost (``generators`` empty, ``refined`` None, no
        ``merge_next`` in ``params``; the part descriptors and the eval read neither)
    """
    cache = MeshCache() if mesh_cache is None else mesh_cache
    unt = untangled
    n_b = int(unt.n_fields[b])
    f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
    k_cluster = cluster_count(k, f1 - f0, opts)
    clustered = (unt.mesh_features(b).detach().cpu().numpy(),
                 km.centers[b, :k_cluster, :n_b].detach().cpu().numpy(),
                 km.labels[b, :f1 - f0].detach().cpu().numpy())
    floor = part_floor(k, opts)
    over = cache.over if opts.eps == 0 else None
    if over is None or not over.made_from(clustered, opts, floor):
        over = over_segmentation(batch, fields, b, clustered, opts, cache, floor)
        if opts.eps == 0:
            # k's clustered alike (the merge method's k <= min_k) share it; one entry, as the
            # rounds visit a mesh's k's in order
            cache.over = over
    if opts.eps > 0:
        cut = CutParts(labels=_discovery_labels(over, cache, opts, floor), vdist=over.vdist, cost=float(km.cost[b]))
    else:
        cut = segmentation_labels(over, cache, opts, k, floor, float(km.cost[b]), f1 - f0, next_cost=extras)
    clean, feats = over.mesh, over.feats
    labels = limit_parts(cut.labels, clean.vertices, clean.faces, k)
    gens = part_generators(labels, feats, over.area, unt.energies[b, :n_b].detach().cpu().numpy(), k) \
        if extras else []
    converged, residual = solve_quality(fields, b)
    return MeshSegmentation(
        name=clean.name, k=k, labels=clean.labels_to_input_faces(labels),
        features=clean.to_input_faces(feats), eigenvalues=fields.eigenvalues[b].detach().cpu().numpy(),
        generators=gens,
        refined=refine_along_isolines(clean.vertices, clean.faces, cut.vdist) if opts.refine and extras else None,
        cost=cut.cost, params={**recorded_params(batch, b, k, n_b, k_cluster, floor, opts, cut.merge_next,
                                                 cut.merge_second),
                               "remedy": fields.remedies[b]},
        converged=converged, max_residual=residual)


def _discovery_labels(over: ClusteredParts, cache: MeshCache, opts: SegmentOptions, floor: float) -> np.ndarray:
    """Part discovery (ε > 0): the connecting region between the parts, small pieces made
    connecting region."""
    adjacency = cache.adjacency
    labels = connecting_region(over.labels, face_margins(over.mesh.faces, over.vdist), opts.eps)
    labels = absorb_single_neighbour_regions(labels, adjacency)
    labels = remove_small_parts(labels, adjacency, over.area, floor, into_connecting=True)
    return absorb_single_neighbour_regions(labels, adjacency)


def segmentation_labels(over: ClusteredParts, cache: MeshCache, opts: SegmentOptions, k: int, floor: float,
                        cost: float, n_solved: int, next_cost: bool = True) -> CutParts:
    """Plain segmentation (ε = 0): with method "merge", adjacent parts merged down to k and the
    boundaries re-decided by the graph cut; the cost of the next merge either way. The one place
    an over-segmentation becomes k parts, so the merge's training captures record its inputs
    here (experiments/segmentation/merge_capture.py).
    n_solved : the faces of the solved mesh (the cost's unit).
    next_cost : False: the next merge's cost is not computed (merge_next None)."""
    clean, vdist, feats, labels, area, unit = over.mesh, over.vdist, over.feats, over.labels, over.area, over.unit
    if cache.dual is None:
        cache.dual = dual_edges(clean.vertices, clean.faces)
    dual = cache.dual
    took_second = False
    crease = opts.merge.crease_angle
    bends = cache.bends_at(crease)
    centroids = thickness = None
    if needs_part_sums(opts.merge):
        have = cache.sums_inputs
        if have is None or (needs_thickness(opts.merge) and have[1] is None):
            # made once per mesh; weights that read the thickness where earlier ones did not add it
            caster = cache.ray_caster(clean) if needs_thickness(opts.merge) else None
            cache.sums_inputs = mesh_sums_inputs(clean.vertices, clean.faces, opts.merge,
                                                 thickness=None if have is None else have[1], caster=caster)
        centroids, thickness = cache.sums_inputs
        thickness = thickness if needs_thickness(opts.merge) else None
    sight = None
    if needs_sight(opts.merge):
        if cache.sight is None:
            cache.sight = SightLines(clean.vertices, clean.faces, caster=cache.ray_caster(clean))
        sight = cache.sight
    if opts.merges_parts:
        normals = cache.normals_of(clean, opts.merge)
        key = (crease, centroids is not None, thickness is not None, sight is not None, normals is not None)
        if key not in over.graphs:
            over.graphs[key] = region_graph(labels, dual, feats, area, crease, unit=unit, bends=bends,
                                            centroids=centroids, thickness=thickness, sight=sight,
                                            normals=normals)
        graph = over.graphs[key]
        merged = merge_parts(labels, clean.faces, clean.vertices, feats, area, k, opts.merge,
                             MergeCache(dual=dual, unit=unit, bends=bends, graph=graph))
        labels, merged_vdist = _cut_merged(over, cache, opts, merged, floor)
        if opts.merge_choice is not None:
            second = _second_merge(over, cache, opts.merge_choice.weights, k)
            if not same_partition(second, merged):
                second_labels, second_vdist = _cut_merged(over, cache, opts, second, floor)
                took_second = prefers_other(labels, second_labels, dual, opts.merge_choice.ratio,
                                            opts.merge_choice.floor)
                if took_second:
                    merged, labels, merged_vdist = second, second_labels, second_vdist
        vdist = merged_vdist
        if sight is not None and next_cost:
            # the next merge reads the merged parts' lines of sight, summed from the pieces'
            # (those the merge itself saw) rather than cast again for the cut's labels
            owner = np.zeros(graph.n_parts, dtype=np.int64)
            owner[graph.labels[graph.labels >= 0]] = merged[graph.labels >= 0]
            sight = PartSight(graph.sums["seen"], graph.sums["lines"]).merged(owner, int(merged.max()) + 1)
        # the k-means cost of the merged parts, in units of the solved mesh's faces (k auto reads it)
        cost = partition_cost(merged, feats, unit=unit) * n_solved / len(merged)
    # what merging two of these parts would cost (k auto's "merge" rule reads it)
    merge_next = next_merge_cost(labels, dual, feats, area, opts.merge, unit=unit, bends=bends,
                                 centroids=centroids, thickness=thickness, sight=sight) if next_cost else None
    return CutParts(labels=labels, vdist=vdist, cost=cost, merge_next=merge_next, merge_second=took_second)


def _cut_merged(over: ClusteredParts, cache: MeshCache, opts: SegmentOptions, merged: np.ndarray,
                floor: float) -> tuple[np.ndarray, np.ndarray]:
    """(labels [F], distances [V, parts]) of merged labels [F] of the over-segmentation: the
    distance fields of the merged parts (the refined cut and the graph cut's data term follow
    them), and the labels the graph cut re-decides from them (the merged labels where it is
    off)."""
    clean, dual = over.mesh, cache.dual
    vdist = merged_distances(over.vdist, over.centers, merged, faces=clean.faces,
                             patches=over.labels % over.n_patches if over.n_patches > 1 else None)
    if opts.graphcut is None:
        return merged, vdist
    # data term: each face's distance to each part, the mean over its corners
    # (made for the faces the cut reads: those near a boundary)
    face_dist = CornerMeans(clean.faces, vdist)
    if opts.graphcut not in cache.cut_costs:
        cache.cut_costs[opts.graphcut] = edge_weights(dual, opts.graphcut)
    labels = graphcut_labels(merged, face_dist, dual, over.area, opts.graphcut,
                             cut_cost=cache.cut_costs[opts.graphcut], min_fraction=floor)
    return labels, vdist


def _second_merge(over: ClusteredParts, cache: MeshCache, weights, k: int) -> np.ndarray:
    """The over-segmentation's labels merged down to k with ``weights`` (the
    :class:`~torchakvf.options.ConcaveChoice`'s), from the region graph its terms read (made
    once per mesh and weights)."""
    clean, dual = over.mesh, cache.dual
    crease = weights.crease_angle
    bends = cache.bends_at(crease)
    normals = cache.normals_of(clean, weights)
    key = ("second", crease, normals is not None)
    if key not in over.graphs:
        over.graphs[key] = region_graph(over.labels, dual, over.feats, over.area, crease, unit=over.unit,
                                        bends=bends, normals=normals)
    return merge_parts(over.labels, clean.faces, clean.vertices, over.feats, over.area, k, weights,
                       MergeCache(dual=dual, unit=over.unit, bends=bends, graph=over.graphs[key]))


def recorded_params(batch: MeshBatch, b: int, k: int, n_fields: int, k_cluster: int, floor: float,
                    opts: SegmentOptions, merge_next: float | None, merge_second: bool = False) -> dict:
    """What a :class:`MeshSegmentation` records of how it was made (its ``params``);
    merge_second: whether the :class:`~torchakvf.options.ConcaveChoice`'s merge made the parts."""
    coarse = batch.coarse_of(b)
    params = dict(k=k, eps=opts.eps, seed=opts.seed, n_fields=n_fields, remedy=opts.remedy,
                  boundary=opts.boundary, kmeans_restarts=opts.kmeans_restarts,
                  kmeans_max_iter=opts.kmeans_max_iter, kmeans_seeded_restarts=opts.kmeans_seeded_restarts,
                  untangle_restarts=opts.untangle_restarts, min_part_fraction=opts.min_part_fraction,
                  part_floor=floor, coarse_faces=0 if coarse is None else len(coarse.coarse.faces),
                  solver=opts.solver, method=opts.method)
    if opts.graphcut is not None and opts.merges_parts:
        params["graphcut"] = True
        params.update({f"graphcut_{name}": v if isinstance(v, str) else float(v)
                       for name, v in vars(opts.graphcut).items()})
    if merge_next is not None:
        params["merge_next"] = merge_next
    if opts.merges_parts:
        params["k_oversegment"] = k_cluster
        params.update({f"merge_{name}": float(v) for name, v in opts.merge_record().items() if v is not None})
        if opts.merge_choice is not None:
            params.update(merge_choice_ratio=float(opts.merge_choice.ratio),
                          merge_choice_floor=float(opts.merge_choice.floor), merge_second=bool(merge_second))
    return params


__all__ = ["cut_parts", "MeshCache", "ClusteredParts", "CutParts", "over_segmentation", "over_settings",
           "segmentation_labels", "part_floor", "recorded_params"]
