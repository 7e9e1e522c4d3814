"""Segmentation and part discovery: the paper's method end to end over a batch.

AKVFs -> untangled fields (Algorithm 1) -> per-face features -> spherical k-means -> labels
with smooth boundaries -> (method "merge") adjacent parts merged down to k -> (ε > 0)
connecting region -> symmetry generators per part.
:func:`segment` is one k per mesh of :func:`torchakvf.parts.engine.segment_each_k`, which does
the work for every caller.
"""
from __future__ import annotations

from ..fields.untangle import UntangledFields
from .engine import (BOUNDARIES, CLUSTER_GAP, DEFAULT_METHOD, DEFAULT_REMEDY, METHODS,  # noqa: F401
                     SPARE_FIELDS, UNTANGLE_RESTARTS, KMEANS_RESTARTS, cluster_safe_n, default_n_fields,
                     field_counts, per_mesh, segment_each_k)
from .merge import MergeWeights
from .generators import SymmetryGenerator
from .results import MeshSegmentation, Segmentation


def segment(meshes, k, *, eps: float = 0.0, seed: int = 0, n_fields=None,
            remedy: str = DEFAULT_REMEDY, solver: str = "auto", method: str = DEFAULT_METHOD,
            merge: MergeWeights | None = None,
            kmeans_restarts: int | None = None, untangle_restarts: int = UNTANGLE_RESTARTS,
            boundary: str = "isoline", min_part_fraction: float = 0.01, refine: bool = True,
            untangled: UntangledFields | None = None, coarse_faces: int | None = None,
            device=None, graphcut=True) -> Segmentation:
    """Segment each mesh into k parts (ε = 0) or discover parts with a connecting region (ε > 0).

    Parameters
    ----------
    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`~torchakvf.fields.AKVFResult` to
        reuse (its n must cover n_fields): computing the AKVFs once serves several k
    k : parts per mesh, one int or one per mesh (1 <= k <= faces; Python or numpy integers)
    eps : width of the connecting region in cosine-distance units (0 = plain segmentation);
        faces whose two closest parts differ by less than eps at the barycenter get label -1
    seed : seeds untangling restarts and k-means seeding (per mesh, batch-independent)
    n_fields : fields untangled per mesh; default :func:`default_n_fields` (2k in [16, 32]; with
        method "merge" 3 max(k, merge.min_k) rounded up to a multiple of 8, in [16, 32]), moved
        to the nearest count that does not split a degenerate cluster (:func:`cluster_safe_n`)
    remedy : mesh-quality remedy of the Killing operator ("none" = the paper's)
    solver : the eigensolver of the AKVFs: "auto", "lanczos", "krylov" or "lobpcg"
        (:func:`torchakvf.fields.akvf.akvf`)
    method : "merge" (default: k-means into k' = ceil(ratio max(k, merge.min_k)) parts (at most
        max(k, min_k) + extra_max), then adjacent parts merged
        down to k by symmetry similarity and boundary concavity, :func:`~torchakvf.parts.merge.
        merge_parts`; ε = 0 only, part discovery keeps k clusters) or "paper" (k-means into k
        parts: the paper's method, the output of torchakvf 0.1)
    merge : the :class:`~torchakvf.parts.merge.MergeWeights` of method "merge" (default: the
        cross-validated ones)
    graphcut : method "merge": after merging, the part boundaries are re-decided by an
        alpha-expansion graph cut on the dual graph (:mod:`torchakvf.parts.graphcut`): True (the
        default, cross-validated on the PSB), False (off), or a
        :class:`~torchakvf.parts.graphcut.GraphCut` with other parameters
    kmeans_restarts, untangle_restarts : random restarts (the best is kept); kmeans_restarts
        None: the method's default (engine.KMEANS_RESTARTS_BY_METHOD: paper 5, merge 3)
    boundary : "isoline" (labels from the g_ij = 0 isolines of vertex-averaged features,
        smooth part boundaries) or "faces" (raw k-means labels)
    min_part_fraction : connected pieces of a part below this fraction of the area are
        removed (merged into a neighbour for ε = 0, made connecting region for ε > 0); at k
        parts the floor is at most 0.25 / k (:func:`~torchakvf.parts.engine.part_floor`), so
        that k parts fit
    refine : also return the mesh cut along the part boundaries
    untangled : the :class:`~torchakvf.fields.UntangledFields` of these AKVFs to reuse (from
        :func:`~torchakvf.fields.untangle` with ``n=field_counts(fields, k, method=method, min_k=m)``, m the merge
        weights' min_k with method "merge" at ε = 0, else 1, the same seed and
        restarts): several k's with the same field counts then share one untangling
    coarse_faces : solve on meshes decimated to about this many faces and report on the
        given ones (see :mod:`torchakvf.mesh.coarse`); only with Mesh inputs (a batch built with
        ``MeshBatch.from_meshes(..., coarse_faces=...)`` carries its own)
    device : torch device the batch is built on (Mesh inputs) or moved to (a MeshBatch);
        default: a batch's own, else cpu

    Each :class:`MeshSegmentation` says whether its mesh's eigensolve converged
    (``converged``, ``max_residual``).
    """
    res = segment_each_k(meshes, k, eps=eps, seed=seed, n_fields=n_fields, remedy=remedy,
                         solver=solver, method=method, merge=merge, kmeans_restarts=kmeans_restarts,
                         untangle_restarts=untangle_restarts, boundary=boundary,
                         min_part_fraction=min_part_fraction, refine=refine,
                         coarse_faces=coarse_faces, device=device, untangled=untangled,
                         graphcut=graphcut)
    return res.rounds[0].segmentation()


__all__ = ["segment", "Segmentation", "MeshSegmentation", "SymmetryGenerator", "default_n_fields",
           "field_counts", "DEFAULT_REMEDY", "METHODS", "DEFAULT_METHOD", "MergeWeights"]
