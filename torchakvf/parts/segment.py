"""Segmentation and part discovery: the paper's method end to end over a batch.

AKVFs -> untangled fields (Algorithm 1) -> per-face features -> spherical k-means -> labels
with smooth boundaries -> (ε > 0) connecting region -> symmetry generators per part.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..cluster import spherical_kmeans
from ..errors import ParameterError
from ..fields.akvf import AKVFResult, akvf_falling_back, as_batch
from ..fields.untangle import UntangledFields, untangle
from ..mesh import MeshBatch
from ..mesh.batch import pad_packed
from .boundaries import (RefinedMesh, face_margins, isoline_face_labels, refine_along_isolines,
                         vertex_distances)
from .discovery import absorb_single_neighbour_regions, connecting_region, remove_small_parts
from .generators import SymmetryGenerator, part_generators
from .merge import MergeWeights, merge_parts, merged_distances, oversegment_k, partition_cost
from .topology import face_adjacency

#: Mesh-quality remedy used by default (see torchakvf.operators.killing); chosen by the
#: PSB measurements in the README.
DEFAULT_REMEDY = "smooth"
BOUNDARIES = ("isoline", "faces")
#: "paper": k-means into k parts (the paper's output); "merge": k-means into k' > k parts, then
#: adjacent parts merged by symmetry, concavity and size (:mod:`torchakvf.parts.merge`).
METHODS = ("paper", "merge")
#: Chosen by cross-validation across PSB categories (benchmarks/results/quality_cv.md).
DEFAULT_METHOD = "merge"
#: Random orthogonal starts of Algorithm 1 besides the identity (the best is kept).
UNTANGLE_RESTARTS = 8


#: Eigenvalues closer than this (relative) belong to one cluster, which N must not split.
CLUSTER_GAP = 1e-2


def default_n_fields(k: int) -> int:
    """The paper's N = 2k, clamped to [16, 32]."""
    return int(min(max(2 * k, 16), 32))


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


@dataclass
class MeshSegmentation:
    """The segmentation of one mesh.

    labels : [F_input] int, part per face of the input (file order); -1 = connecting region
    features : [F_input, n] per-face untangled AKVF norms (0 on faces dropped as degenerate;
        on a decimated mesh, those of the coarse face under each input face)
    eigenvalues : [n] Killing eigenvalues (λ·area) of the raw AKVFs used
    generators : per part, the :class:`SymmetryGenerator` s localized on it
    refined : the mesh cut along the part boundaries (cleaned-mesh vertices, full resolution),
        or None
    cost : spherical k-means cost Σ(1 - cos) of the clustering kept (method "merge": of the
        merged parts, :func:`~torchakvf.parts.merge.partition_cost`, scaled to the solved faces)
    """

    name: str
    k: int
    labels: np.ndarray
    features: np.ndarray
    eigenvalues: np.ndarray
    generators: list
    refined: RefinedMesh | None
    cost: float
    params: dict = field(default_factory=dict)


@dataclass
class Segmentation:
    """Per-mesh results of :func:`segment`, in batch order, and the untangled fields behind them."""

    meshes: list
    untangled: UntangledFields | None = None

    def face_vectors(self, b: int) -> np.ndarray:
        """[F_input, n_b, 3] untangled Whitney vectors of mesh b on the input's faces (0 on
        dropped faces; on a decimated mesh, those of the coarse face under each input face);
        ``generators[p][i].field`` indexes the second axis."""
        unt = self.untangled
        ptr = unt.batch.face_ptr
        fv = unt.face_vectors[int(ptr[b]):int(ptr[b + 1]), :unt.n_fields[b]].detach().cpu().numpy()
        coarse = unt.batch.coarse_of(b)
        if coarse is not None:  # the coarse face under each fine barycenter
            fv = coarse.face_values(fv)
        return unt.batch.input_mesh(b).to_input_faces(fv)

    def __len__(self) -> int:
        return len(self.meshes)

    def __getitem__(self, b: int) -> MeshSegmentation:
        return self.meshes[b]

    @property
    def labels(self) -> list:
        return [m.labels for m in self.meshes]

    @property
    def generators(self) -> list:
        return [m.generators for m in self.meshes]


#: AKVFs computed beyond the default N when segment solves them itself, so that a degenerate
#: eigenvalue cluster cut at N can be seen and completed (:func:`cluster_safe_n`).
SPARE_FIELDS = 4


def _default_or_given(ks: list[int], n_fields, nb: int) -> list[int]:
    return [default_n_fields(kb) for kb in ks] if n_fields is None else _per_mesh(n_fields, nb, "n_fields")


def field_counts(fields: AKVFResult, k, n_fields=None) -> list[int]:
    """The number of fields :func:`segment` untangles per mesh for these k.

    Default (``n_fields=None``): the paper's 2k clamped to [16, 32], moved by
    :func:`cluster_safe_n` off a degenerate cluster of the mesh's computed eigenvalues;
    otherwise ``n_fields`` (one int or one per mesh), which must not exceed ``fields.n``.
    """
    nb = len(fields.batch)
    ks = _per_mesh(k, nb, "k")
    ns = _default_or_given(ks, n_fields, nb)
    if max(ns) > fields.n:
        raise ParameterError(f"n_fields up to {max(ns)} asked for, but the AKVFs given have n = {fields.n}")
    if n_fields is None:
        lam = fields.eigenvalues.detach().cpu()
        ns = [cluster_safe_n(lam[b], ns[b], floor=max(ks[b], ns[b] // 2)) for b in range(nb)]
    return ns


def _per_mesh(value, nb: int, what: str) -> list[int]:
    vals = [value] * nb if isinstance(value, (int, np.integer)) else list(value)
    if len(vals) != nb:
        raise ParameterError(f"{what} has {len(vals)} values for {nb} meshes")
    for v in vals:
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
            raise ParameterError(f"{what} must be a positive integer (or one per mesh), got {v!r}")
    return [int(v) for v in vals]


def segment(meshes, k, *, eps: float = 0.0, seed: int = 0, n_fields=None,
            remedy: str = DEFAULT_REMEDY, kmeans_restarts: int = 20, untangle_restarts: int = UNTANGLE_RESTARTS,
            boundary: str = "isoline", min_part_fraction: float = 0.01, refine: bool = True,
            untangled: UntangledFields | None = None, coarse_faces: int | None = None,
            method: str = DEFAULT_METHOD, merge: MergeWeights | None = None) -> Segmentation:
    """Segment each mesh into k parts (ε = 0) or discover parts with a connecting region (ε > 0).

    Parameters
    ----------
    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`AKVFResult` to reuse (its n must
        cover n_fields): computing the AKVFs once serves several k.
    k : parts per mesh, one int or one per mesh (1 <= k <= faces)
    eps : width of the connecting region in cosine-distance units (0 = plain segmentation);
        faces whose two closest parts differ by less than eps at the barycenter get label -1
    seed : seeds untangling restarts and k-means seeding (per mesh, batch-independent)
    n_fields : fields untangled per mesh; default :func:`default_n_fields` (2k in [16, 32]),
        moved to the nearest count that does not split a degenerate cluster (:func:`cluster_safe_n`)
    remedy : mesh-quality remedy of the Killing operator ("none" = the paper's)
    kmeans_restarts, untangle_restarts : random restarts (the best is kept)
    boundary : "isoline" (labels from the g_ij = 0 isolines of vertex-averaged features,
        smooth part boundaries) or "faces" (raw k-means labels)
    min_part_fraction : connected pieces of a part below this fraction of the area are
        removed (merged into a neighbour for ε = 0, made connecting region for ε > 0)
    refine : also return the mesh cut along the part boundaries
    untangled : the :class:`~torchakvf.fields.UntangledFields` of these AKVFs to reuse (from
        :func:`~torchakvf.fields.untangle` with ``n=field_counts(fields, k)``, the same seed and
        restarts): several k's with the same field counts then share one untangling
    coarse_faces : solve on meshes decimated to about this many faces and report on the
        given ones (see :mod:`torchakvf.mesh.coarse`); only with Mesh inputs (a batch built with
        ``MeshBatch.from_meshes(..., coarse_faces=...)`` carries its own)
    method : "merge" (default: over-segment into k' = ceil(ratio k) parts and merge adjacent
        parts down to k, :func:`~torchakvf.parts.merge.merge_parts`; ε = 0 only, part discovery
        keeps the paper's k) or "paper" (k-means into k parts: the paper's output)
    merge : the :class:`~torchakvf.parts.merge.MergeWeights` of method "merge" (default: the
        cross-validated ones)
    """
    if boundary not in BOUNDARIES:
        raise ParameterError(f"boundary must be one of {BOUNDARIES}, got {boundary!r}")
    if method not in METHODS:
        raise ParameterError(f"method must be one of {METHODS}, got {method!r}")
    merge = MergeWeights() if merge is None else merge
    if not (eps >= 0):
        raise ParameterError(f"eps must be >= 0, got {eps!r}")
    if coarse_faces is not None and isinstance(meshes, (AKVFResult, MeshBatch)):
        raise ParameterError("coarse_faces applies to Mesh inputs; build the batch with "
                             "MeshBatch.from_meshes(meshes, coarse_faces=...) instead")
    if isinstance(meshes, AKVFResult):
        fields, batch = meshes, meshes.batch
    else:
        fields, batch = None, as_batch(meshes, coarse_faces=coarse_faces)
    nb = len(batch)
    ks = _per_mesh(k, nb, "k")
    for b, kb in enumerate(ks):
        n_f = len(batch.meshes[b].faces)
        if kb > n_f:
            raise ParameterError(f"{batch.meshes[b].name}: k = {kb} is larger than its {n_f} faces")
    if fields is None:
        # Compute a few more than needed so a cluster cut at N can be seen (and completed).
        n_max = max(_default_or_given(ks, n_fields, nb))
        fields, _ = akvf_falling_back(batch, n=n_max + SPARE_FIELDS if n_fields is None else n_max,
                                      seed=seed, remedy=remedy)
        batch = fields.batch   # a decimated mesh that could not be solved is now at full resolution
    ns = field_counts(fields, ks, n_fields)
    if untangled is None:
        untangled = untangle(fields, n=ns, seed=seed, restarts=untangle_restarts)
    elif untangled.source is not fields or list(untangled.n_fields) != ns:
        raise ParameterError(f"the untangled fields given are for n = {list(untangled.n_fields)} of "
                             f"other AKVFs; these k need n = {ns} of the AKVFs passed")
    unt = untangled
    xpad, mask = pad_packed(unt.features.double(), batch.face_ptr)
    merging = method == "merge" and eps == 0
    n_faces = [int(batch.face_ptr[b + 1] - batch.face_ptr[b]) for b in range(nb)]
    ks_km = [oversegment_k(kb, merge.ratio, n_faces[b]) if merging else kb for b, kb in enumerate(ks)]
    km = spherical_kmeans(xpad, mask, ks_km, restarts=kmeans_restarts, seed=seed)

    geo = fields.system.geometry
    out = []
    for b in range(nb):
        clean = batch.meshes[b]
        f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
        feats = unt.mesh_features(b).detach().cpu().numpy()
        area = geo.face_area[f0:f1].detach().cpu().numpy()
        centers = km.centers[b, :ks_km[b], :ns[b]].detach().cpu().numpy()
        labels = km.labels[b, :f1 - f0].detach().cpu().numpy()
        cost = float(km.cost[b])
        vdist = vertex_distances(clean.vertices, clean.faces, feats, area, centers)
        coarse = batch.coarse_of(b)
        if coarse is not None:
            # Solved on a decimated mesh: the distance fields are interpolated at the fine
            # vertices, so boundaries (isolines) and everything after are cut on the fine mesh.
            clean, vdist = coarse.fine, coarse.vertex_field(vdist)
            feats, labels = coarse.face_values(feats), coarse.face_values(labels)
            area = coarse.fine_area
        if boundary == "isoline":
            labels = isoline_face_labels(clean.faces, vdist)
        adjacency = face_adjacency(clean.faces)
        if eps > 0:
            labels = connecting_region(labels, face_margins(clean.faces, vdist), eps)
            labels = absorb_single_neighbour_regions(labels, adjacency)
            labels = remove_small_parts(labels, adjacency, area, min_part_fraction, into_connecting=True)
            labels = absorb_single_neighbour_regions(labels, adjacency)
        else:
            labels = remove_small_parts(labels, adjacency, area, min_part_fraction, into_connecting=False)
            if merging:
                before = labels
                labels = merge_parts(labels, clean.faces, clean.vertices, feats, area, ks[b], merge)
                vdist = merged_distances(vdist, before, labels)   # the refined cut: merged parts only
                # k-means cost of the k merged parts, in units of the solved mesh's faces
                cost = partition_cost(labels, feats) * (f1 - f0) / len(labels)
        gens = part_generators(labels, feats, area, unt.energies[b, :ns[b]].detach().cpu().numpy(), ks[b])
        out.append(MeshSegmentation(
            name=clean.name, k=ks[b], labels=clean.labels_to_input_faces(labels),
            features=clean.to_input_faces(feats), eigenvalues=fields.eigenvalues[b].detach().cpu().numpy(),
            generators=gens,
            refined=refine_along_isolines(clean.vertices, clean.faces, vdist) if refine else None,
            cost=cost,
            params=dict(k=ks[b], eps=eps, seed=seed, n_fields=ns[b], remedy=remedy, boundary=boundary,
                        kmeans_restarts=kmeans_restarts, untangle_restarts=untangle_restarts,
                        min_part_fraction=min_part_fraction, method=method,
                        **({f"merge_{name}": float(v) for name, v in vars(merge).items()} if merging else {}),
                        **({"k_oversegment": ks_km[b]} if merging else {}),
                        coarse_faces=0 if coarse is None else len(coarse.coarse.faces))))
    return Segmentation(out, untangled=unt)


__all__ = ["segment", "Segmentation", "MeshSegmentation", "SymmetryGenerator", "default_n_fields",
           "field_counts", "DEFAULT_REMEDY", "METHODS", "DEFAULT_METHOD"]
