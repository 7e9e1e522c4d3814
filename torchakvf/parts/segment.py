"""Segmentation and part discovery: the paper's method end to end over a batch.

AKVFs -> untangled fields (Algorithm 1) -> per-face features -> spherical k-means -> labels
with smooth boundaries -> (method "merge") adjacent parts merged down to k -> (ε > 0)
connecting region -> symmetry generators per part.

    segment_each_k(meshes, ks)      one solve, every k of every mesh   -> :class:`SegmentEachK`
      Segmenter                     the AKVFs of the batch, kept across calls (parts.segmenter)
      segment_rounds                round r: every mesh at its r-th k  -> KRound  (parts.rounds)
        field_counts                fields untangled per mesh for those k   (parts.field_counts)
        spherical_kmeans            the meshes of the round whose (fields, clusters) are new
        cut_parts                   ONE mesh: boundaries, clean-up, merging, graph cut,
                                    generators -> MeshSegmentation                (parts.cut)

:func:`segment` is one k per mesh (or ``k="auto"``, :mod:`torchakvf.parts.k_auto`) and
:func:`segment_each_k` every k of every mesh; both are a :class:`~torchakvf.parts.segmenter.Segmenter`
used once (keep one to segment a batch at several k's from one solve). Both take a
:class:`~torchakvf.options.SegmentOptions` and/or its field names as keywords.

Counts: ``n`` is the number of AKVFs solved (as in :func:`~torchakvf.fields.akvf`), ``n_fields``
the number untangled per mesh; ``n_akvf`` is the old spelling of ``n``.
"""
from __future__ import annotations

from ..errors import ParameterError
from ..fields.untangle import UntangledFields
from ..options import SegmentOptions
from .generators import SymmetryGenerator
from .results import MeshSegmentation, Segmentation
from .segmenter import SegmentEachK, Segmenter


def _solve_count(n, n_akvf):
    """The AKVF count from ``n`` or its old spelling ``n_akvf`` (both: they must agree)."""
    if n_akvf is None:
        return n
    if n is not None and n != n_akvf:
        raise ParameterError(f"n_akvf is the old spelling of n (AKVFs solved); pass n alone, got n={n}, "
                             f"n_akvf={n_akvf}")
    return n_akvf


def segment_each_k(meshes, ks, options: SegmentOptions | None = None, *, n_fields=None,
                   coarse_faces: int | None = None, device=None, n: int | None = None,
                   untangled: UntangledFields | None = None, n_akvf: int | None = None,
                   **overrides) -> SegmentEachK:
    """Segment every mesh at each of its k's from one AKVF solve.

    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`AKVFResult` to reuse (its n must
        cover the field counts)
    ks : per mesh, the list of its k's (or one int per mesh, or one int for all)
    options, n_fields, coarse_faces, device, untangled, overrides : as in :func:`segment`
    n : AKVFs to solve for (default :func:`~torchakvf.parts.field_counts.akvf_count`: the
        largest default field count of the k's plus SPARE_FIELDS, or the largest ``n_fields``);
        pass a fixed one to make a mesh's fields independent of the k's of the meshes sharing
        its batch. ``n_akvf``: its old spelling
    """
    sg = Segmenter(meshes, options, n=_solve_count(n, n_akvf), n_fields=n_fields, coarse_faces=coarse_faces,
                   device=device, **overrides)
    return sg.segment_each_k(ks, untangled=untangled)


def segment(meshes, k, options: SegmentOptions | None = None, *, n_fields=None,
            coarse_faces: int | None = None, device=None, untangled: UntangledFields | None = None,
            k_range=None, k_rule: str | None = None, **overrides) -> Segmentation:
    """Segment each mesh into k parts (ε = 0) or discover parts with a connecting region (ε > 0).

    Parameters
    ----------
    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`~torchakvf.fields.AKVFResult` to
        reuse (its n must cover n_fields): computing the AKVFs once serves several k (or keep a
        :class:`~torchakvf.parts.segmenter.Segmenter`)
    k : parts per mesh, one int or one per mesh (1 <= k <= faces; Python or numpy integers), or
        ``"auto"``: chosen per mesh from ``k_range`` by ``k_rule``
        (:mod:`torchakvf.parts.k_auto`); the result is then an
        :class:`~torchakvf.parts.k_auto.AutoSegmentation`, whose ``k_auto`` [B]
        (:class:`~torchakvf.parts.k_auto.KChoice`) says which k each mesh got
    options : a :class:`~torchakvf.options.SegmentOptions` (default: ``SegmentOptions()``; with
        ``k="auto"``, the defaults with the scan's over-segmentation,
        :func:`~torchakvf.parts.k_auto.scan_overseg`): eps, seed, method, solver, merge
        weights, over-segmentation, graph cut, restarts, boundary, ...
    **overrides : SegmentOptions field names, applied to ``options``:
        ``segment(batch, k=6, eps=0.1, seed=1)``; an unknown name is a ParameterError
    n_fields : fields untangled per mesh (one int or one per mesh; with k "auto" one int for
        every k); default :func:`~torchakvf.parts.field_counts.default_n_fields` (2k in [16, 32];
        with method "merge" 3 max(k, overseg.min_k) rounded up to a multiple of 8, in [16, 32];
        k "auto": that of k_max, method "paper"), moved to the nearest count that does not split
        a degenerate cluster (:func:`~torchakvf.parts.field_counts.cluster_safe_n`)
    coarse_faces : solve on meshes decimated to about this many faces and report on the
        given ones (see :mod:`torchakvf.mesh.coarse`); only with Mesh inputs (a batch built with
        ``MeshBatch.from_meshes(..., coarse_faces=...)`` carries its own)
    device : torch device the batch is built on (Mesh inputs) or moved to (a MeshBatch);
        default: a batch's own, else cpu
    untangled : the :class:`~torchakvf.fields.UntangledFields` of these AKVFs to reuse (from
        :func:`~torchakvf.fields.untangle` with ``n=field_counts(fields, k, method=method,
        min_k=options.merge_min_k)``, the same seed and restarts): several k's with the same
        field counts then share one untangling (a given k only)
    k_range, k_rule : with ``k="auto"``, the k's tried (k_min, k_max), inclusive (default
        :data:`~torchakvf.parts.k_auto.DEFAULT_K_RANGE`, (2, 10)), and the rule
        (:data:`~torchakvf.parts.k_auto.RULES`; default "merge")

    Each :class:`MeshSegmentation` says whether its mesh's eigensolve converged
    (``converged``, ``max_residual``).
    """
    sg = Segmenter(meshes, options, n_fields=n_fields, coarse_faces=coarse_faces, device=device, **overrides)
    return sg.segment(k, k_range=k_range, k_rule=k_rule, untangled=untangled)


__all__ = ["segment", "segment_each_k", "SegmentEachK", "Segmenter", "Segmentation", "MeshSegmentation",
           "SymmetryGenerator"]
