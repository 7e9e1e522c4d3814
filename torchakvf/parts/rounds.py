"""Rounds of a segmentation: round r untangles and clusters every mesh of the batch at its r-th
k, and cuts its parts (:func:`~torchakvf.parts.cut.cut_parts`).

Each mesh is untangled once per distinct field count and clustered once per distinct
(fields, clusters) pair, whatever the round: a mesh's rotation and clustering depend on its own
rows, the counts and the seed alone, so a mesh gets the bits it gets alone, in any batch.

The solve phase and the cut phase can run apart (the batched pipeline solves on the device
while host processes cut): ``segment_rounds(..., cut=False)`` yields the rounds clustered but
not cut, :func:`mesh_cut_job` takes one mesh's share of them (small, picklable: its rows only)
and :func:`cut_mesh_rounds` cuts it anywhere, with the bits ``cut=True`` gives.
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import torch

from ..cluster import KMeansResult, spherical_kmeans
from ..errors import ParameterError
from ..fields.akvf import AKVFResult
from ..fields.untangle import UntangledFields, orthomax_rotations, untangled_from_rotations
from ..mesh.batch import pad_packed
from ..options import SegmentOptions
from .cut import MeshCache, cut_parts
from .field_counts import check_ks, cluster_count, field_counts
from .results import Segmentation

#: k given to a mesh that sits out a round of :func:`segment_rounds` (its clustering is trivial
#: and its parts are not cut).
PAD_K = 1


@dataclass
class KRound:
    """One round of :func:`segment_rounds`: every mesh at one k.

    ks : [B] the k of each mesh in this round (:data:`PAD_K` for a mesh with no k left)
    active : indices of the meshes whose own k this round is
    meshes : [B] MeshSegmentation per active mesh, None for the others
    untangled : the untangled fields the round clustered (shared with rounds of equal counts)
    seconds : {"untangle": s (0 when shared), "cluster": s (k-means + cutting the parts)}
    kmeans : the round's clustering [B, ...] (what the parts are cut from)
    """

    ks: list
    active: list
    meshes: list
    untangled: UntangledFields
    seconds: dict
    kmeans: KMeansResult | None = None

    def segmentation(self) -> Segmentation:
        return Segmentation(self.meshes, untangled=self.untangled)


def segment_rounds(fields: AKVFResult, ks, opts: SegmentOptions, *, n_fields=None,
                   untangled: UntangledFields | None = None, cut: bool = True,
                   mesh_caches: list[MeshCache] | None = None, untangle_frame: str = "eigen",
                   extras: bool = True):
    """Yields one :class:`KRound` per round: round r segments every mesh with its r-th k.

    ks : one list of k's per mesh (or one int, or one int per mesh); meshes with fewer k's sit
        out the later rounds (clustered with :data:`PAD_K`, not cut)
    n_fields : fields untangled per mesh, as :func:`field_counts` (None: from each round's k)
    untangled : the untangled fields of these AKVFs to use (their counts must be those the k's
        need): rounds whose counts agree share one untangling either way
    cut : False: the rounds' parts are not cut (``meshes`` all None; cut them with
        :func:`mesh_cut_job` and :func:`cut_mesh_rounds`)
    mesh_caches : [B] a :class:`~torchakvf.parts.cut.MeshCache` per mesh of ``fields.batch``, to
        keep what the cut makes of each mesh alone (crease patches, thickness, dual edges) for
        later calls on the same batch (other seeds or k's); None: made for this call
    untangle_frame : the frame of the untangling's starts
        (:data:`~torchakvf.fields.untangle.START_FRAMES`; the part descriptors' "moments")
    extras : False: the meshes' parts without symmetry generators, refined meshes or next
        merge's costs (:func:`~torchakvf.parts.cut.cut_parts`; what the part descriptors and the
        eval skip)
    """
    batch = fields.batch
    ks = check_ks(batch, ks)
    nb = len(batch)
    if mesh_caches is None:
        mesh_caches = [MeshCache() for _ in range(nb)]
    elif len(mesh_caches) != nb:
        raise ParameterError(f"mesh_caches has {len(mesh_caches)} entries for a batch of {nb} meshes")
    state = _RoundsState(mesh_caches=list(mesh_caches), prev_labels=[None] * nb, frame=untangle_frame)
    if untangled is not None:
        state.assembled[tuple(int(v) for v in untangled.n_fields)] = untangled
    plans = {}          # round -> its round_plan, made once: read by the round and the one before

    def plan(r: int) -> RoundPlan:
        if r not in plans:
            plans[r] = round_plan(fields, ks, r, n_fields, opts)
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
            unt = _round_untangled(fields, ns, active, state.rotations, state.assembled, opts, state.frame)
        t1 = time.perf_counter()
        km = _round_kmeans(unt, r, km_ks, ns, active, state, opts)
        following = None
        if r + 1 < n_rounds:
            try:
                following = plan(r + 1)
            except ParameterError:     # that round raises it itself, after this one is yielded
                pass
        meshes = [None] * nb
        for b in (active if cut else ()):
            meshes[b] = cut_parts(batch, fields, unt, km, b, round_ks[b], opts, state.mesh_caches[b],
                                  extras=extras)
            if following is None or b not in following.active or \
                    (following.n_fields[b], following.clusters[b]) != (ns[b], km_ks[b]):
                # the mesh's next k clusters otherwise (or it has none): its over-segmentation
                # (fine-mesh arrays, ~10 MB at 20k faces) goes, not kept for the batch's life
                state.mesh_caches[b].over = None
        t2 = time.perf_counter()
        yield KRound(ks=round_ks, active=active, meshes=meshes, untangled=unt,
                     seconds={"untangle": t1 - t0, "cluster": t2 - t1}, kmeans=km)


@dataclass
class _RoundsState:
    """What the rounds of one :func:`segment_rounds` keep for the later ones.

    rotations : {(mesh, n): MeshRotation}: a mesh is untangled once per field count
    assembled : {per-mesh counts: UntangledFields} shared by the rounds that agree
    clusterings : {(mesh, n, k'): MeshClustering}: k's with equal counts share one k-means
    mesh_caches : [B] each mesh's :class:`~torchakvf.parts.cut.MeshCache`
    prev_labels : [B] each mesh's k-means labels of its last round (kmeans_seeded_restarts)
    """

    mesh_caches: list
    prev_labels: list
    frame: str = "eigen"
    rotations: dict = field(default_factory=dict)
    assembled: dict = field(default_factory=dict)
    clusterings: dict = field(default_factory=dict)


def _round_kmeans(unt: UntangledFields, r: int, km_ks: list, ns: list, active: list, state: _RoundsState,
                  opts: SegmentOptions) -> KMeansResult:
    """The k-means of round r: from scratch (:func:`_round_clustering`), or with
    ``kmeans_seeded_restarts`` after the first round, warm-started from each mesh's last one."""
    if opts.kmeans_seeded_restarts and r > 0:
        batch = unt.batch
        xpad, mask = pad_packed(unt.features.double(), batch.face_ptr)
        # Warm start: each active mesh's last restart begins at the centroids, in this
        # round's features, of its previous round's clusters (the extra clusters k-means++).
        init = [previous_centroids(xpad[b], mask[b], state.prev_labels[b], km_ks[b]) if b in active else None
                for b in range(len(batch))]
        km = spherical_kmeans(xpad, mask, km_ks, restarts=opts.kmeans_seeded_restarts, seed=opts.seed,
                              max_iter=opts.kmeans_max_iter, init=init)
    else:
        km = _round_clustering(unt, km_ks, ns, active, state.clusterings, opts)
    if opts.kmeans_seeded_restarts:
        for b in active:
            state.prev_labels[b] = km.labels[b]
    return km


class RoundPlan(NamedTuple):
    """Round r of :func:`segment_rounds`: ks [B] each mesh's k (:data:`PAD_K` for a mesh with no k
    left), active the meshes whose own k it is, n_fields [B] fields untangled per mesh
    (:func:`~torchakvf.parts.field_counts.field_counts`), clusters [B] k-means clusters per mesh
    (:func:`~torchakvf.parts.field_counts.cluster_count`)."""

    ks: list
    active: list
    n_fields: list
    clusters: list


def round_plan(fields: AKVFResult, ks: list, r: int, n_fields, opts: SegmentOptions) -> RoundPlan:
    """The :class:`RoundPlan` of round r of :func:`segment_rounds`; raises as field_counts does."""
    batch = fields.batch
    nb = len(ks)
    active = [b for b in range(nb) if r < len(ks[b])]
    round_ks = [ks[b][r] if r < len(ks[b]) else PAD_K for b in range(nb)]
    ns = field_counts(fields, round_ks, n_fields, opts.method, opts.merge_min_k)
    n_faces = (batch.face_ptr[1:] - batch.face_ptr[:-1]).tolist()
    km_ks = [cluster_count(round_ks[b], n_faces[b], opts) if b in active else PAD_K for b in range(nb)]
    return RoundPlan(round_ks, active, ns, km_ks)


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
                     opts: SegmentOptions, frame: str = "eigen") -> UntangledFields:
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
        new = orthomax_rotations(fields, missing, seed=opts.seed, restarts=opts.untangle_restarts, frame=frame)
        rotations.update({(b, counts[b]): rot for b, rot in new.items()})
        assembled[key] = untangled_from_rotations(fields, [rotations[(b, counts[b])] for b in range(len(counts))])
    return assembled[key]


@dataclass
class MeshGeometry:
    """face_area [F_b] of one mesh: the part of a KillingSystem's geometry a cut reads."""

    face_area: torch.Tensor


@dataclass
class MeshSystem:
    geometry: MeshGeometry


@dataclass
class MeshFields:
    """One mesh's AKVF solve as :func:`~torchakvf.parts.cut.cut_parts` reads it (index 0):
    eigenvalues [1, n], residuals [1, n], converged [1], system.geometry.face_area [F_b],
    remedies [1] (the remedy its operator was built with)."""

    eigenvalues: torch.Tensor
    residuals: torch.Tensor
    converged: torch.Tensor
    system: MeshSystem
    remedies: list


@dataclass
class MeshUntangled:
    """One mesh's untangled fields of one round as a cut reads them (index 0): features [F_b, n_b],
    energies [1, n_b], n_fields [n_b]."""

    features: torch.Tensor
    energies: torch.Tensor
    n_fields: list

    def mesh_features(self, b: int) -> torch.Tensor:
        return self.features


@dataclass
class MeshCutJob:
    """Mesh b's share of a batch's rounds, everything its parts are cut from, as a batch of one:
    batch (``MeshBatch.mesh(b)``: its tensors, clean mesh and decimation), fields
    (:class:`MeshFields`), and per round it takes part in (k, :class:`MeshUntangled`, its
    clustering as a one-mesh KMeansResult). Picklable: a host process cuts it."""

    batch: object
    fields: MeshFields
    rounds: list = field(default_factory=list)


def mesh_cut_job(fields: AKVFResult, rounds: list, b: int) -> MeshCutJob:
    """Mesh b's :class:`MeshCutJob` from the (uncut) rounds of ``segment_rounds(fields, ...,
    cut=False)``; the tensors are moved to the CPU (a host process cuts them)."""
    batch = fields.batch
    f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
    # own copies: a view would carry (and pickle) the whole batch's storage
    cpu = lambda t: t.detach().cpu().clone()  # noqa: E731
    area = cpu(fields.system.geometry.face_area[f0:f1])
    one_mesh = batch.mesh(b)
    tensors = {f.name: cpu(getattr(one_mesh, f.name)) for f in dataclasses.fields(one_mesh)
               if isinstance(getattr(one_mesh, f.name), torch.Tensor)}
    job = MeshCutJob(batch=dataclasses.replace(one_mesh, **tensors),
                     fields=MeshFields(eigenvalues=cpu(fields.eigenvalues[b:b + 1]),
                                       residuals=cpu(fields.residuals[b:b + 1]),
                                       converged=cpu(fields.converged[b:b + 1]),
                                       system=MeshSystem(MeshGeometry(area)),
                                       remedies=[fields.remedies[b]]))
    for rnd in rounds:
        if b not in rnd.active:
            continue
        n_b = int(rnd.untangled.n_fields[b])
        unt = MeshUntangled(features=cpu(rnd.untangled.mesh_features(b)),
                            energies=cpu(rnd.untangled.energies[b:b + 1, :n_b]), n_fields=[n_b])
        km = rnd.kmeans
        one = KMeansResult(labels=cpu(km.labels[b:b + 1, :f1 - f0]), centers=cpu(km.centers[b:b + 1]),
                           cost=cpu(km.cost[b:b + 1]), iterations=cpu(km.iterations[b:b + 1]),
                           restart_costs=cpu(km.restart_costs[b:b + 1]))
        job.rounds.append((int(rnd.ks[b]), unt, one))
    return job


def cut_mesh_rounds(job: MeshCutJob, opts: SegmentOptions, extras: bool = True):
    """Yields (k, MeshSegmentation) for each round of ``job`` in order: the parts
    ``segment_rounds(..., cut=True, extras=extras)`` cuts for that mesh, bit for bit (one
    MeshCache across the rounds, as there)."""
    cache = MeshCache()
    for k, unt, km in job.rounds:
        yield k, cut_parts(job.batch, job.fields, unt, km, 0, k, opts, cache, extras=extras)


__all__ = ["mesh_cut_job", "cut_mesh_rounds", "MeshCutJob", "segment_rounds", "round_plan", "RoundPlan", "KRound",
           "MeshClustering", "previous_centroids", "PAD_K"]
