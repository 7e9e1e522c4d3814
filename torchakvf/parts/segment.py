"""Segmentation and part discovery: the paper's method end to end over a batch.

AKVFs -> untangled fields (Algorithm 1) -> per-face features -> spherical k-means -> labels
with smooth boundaries -> (method "merge") adjacent parts merged down to k -> (ε > 0)
connecting region -> symmetry generators per part.

    segment_each_k(meshes, ks)      one solve, every k of every mesh   -> :class:`SegmentEachK`
      solve_akvfs                   the AKVFs of the batch, once                  (parts.solve)
      segment_rounds                round r: every mesh at its r-th k  -> KRound  (parts.rounds)
        field_counts                fields untangled per mesh for those k   (parts.field_counts)
        spherical_kmeans            the meshes of the round whose (fields, clusters) are new
        cut_parts                   ONE mesh: boundaries, clean-up, merging, graph cut,
                                    generators -> MeshSegmentation                (parts.cut)

:func:`segment` is one k per mesh of :func:`segment_each_k`, which every caller (the corpus
task, the PSB evaluation, the automatic-k scan, the bench) goes through. Both take a
:class:`~torchakvf.options.SegmentOptions` and/or its field names as keywords.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from ..errors import ParameterError
from ..fields.akvf import AKVFResult, as_batch
from ..fields.untangle import UntangledFields
from ..mesh import MeshBatch
from ..mesh.size_check import check_fields_fit
from ..options import SegmentOptions, segment_options
from .field_counts import akvf_count, check_ks, per_mesh
from .generators import SymmetryGenerator
from .results import MeshSegmentation, Segmentation
from .rounds import segment_rounds
from .solve import solve_akvfs


@dataclass
class SegmentEachK:
    """What :func:`segment_each_k` returns.

    fields : the AKVFs (of ``fields.batch``: decimated meshes that could not be solved are at
        full resolution there); fell_back : [(mesh index, why)] of those meshes
    meshes : [B] {k: MeshSegmentation} of every k asked for each mesh
    rounds : the :class:`~torchakvf.parts.rounds.KRound` s, in order (their ``meshes`` are the
        same objects)
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


def segment_each_k(meshes, ks, options: SegmentOptions | None = None, *, n_fields=None,
                   coarse_faces: int | None = None, device=None, n_akvf: int | None = None,
                   untangled: UntangledFields | None = None, **overrides) -> SegmentEachK:
    """Segment every mesh at each of its k's from one AKVF solve.

    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`AKVFResult` to reuse (its n must
        cover the field counts)
    ks : per mesh, the list of its k's (or one int per mesh, or one int for all)
    options, n_fields, coarse_faces, device, untangled, overrides : as in :func:`segment`
    n_akvf : AKVFs to solve for (default :func:`~torchakvf.parts.field_counts.akvf_count`: the
        largest default field count of the k's plus SPARE_FIELDS, or the largest ``n_fields``);
        pass a fixed one to make a mesh's fields independent of the k's of the meshes sharing
        its batch
    """
    opts = segment_options(options, **overrides)
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
        n_akvf = akvf_count(ks, n_fields, opts.method, opts.merge_min_k) if n_akvf is None else n_akvf
        for b in range(len(batch)):
            check_fields_fit(batch.names[b], batch.meshes[b].faces, n_akvf, k=max(ks[b]),
                             fields_for_k=lambda j: akvf_count([[j]], n_fields, opts.method, opts.merge_min_k))
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


def segment(meshes, k, options: SegmentOptions | None = None, *, n_fields=None,
            coarse_faces: int | None = None, device=None, untangled: UntangledFields | None = None,
            **overrides) -> Segmentation:
    """Segment each mesh into k parts (ε = 0) or discover parts with a connecting region (ε > 0).

    Parameters
    ----------
    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`~torchakvf.fields.AKVFResult` to
        reuse (its n must cover n_fields): computing the AKVFs once serves several k
    k : parts per mesh, one int or one per mesh (1 <= k <= faces; Python or numpy integers)
    options : a :class:`~torchakvf.options.SegmentOptions` (default: ``SegmentOptions()``):
        eps, seed, method, solver, merge weights, graph cut, restarts, boundary, ...
    **overrides : SegmentOptions field names, applied to ``options``:
        ``segment(batch, k=6, eps=0.1, seed=1)``; an unknown name is a ParameterError
    n_fields : fields untangled per mesh (one int or one per mesh); default
        :func:`~torchakvf.parts.field_counts.default_n_fields` (2k in [16, 32]; with method
        "merge" 3 max(k, merge.min_k) rounded up to a multiple of 8, in [16, 32]), moved to the
        nearest count that does not split a degenerate cluster
        (:func:`~torchakvf.parts.field_counts.cluster_safe_n`)
    coarse_faces : solve on meshes decimated to about this many faces and report on the
        given ones (see :mod:`torchakvf.mesh.coarse`); only with Mesh inputs (a batch built with
        ``MeshBatch.from_meshes(..., coarse_faces=...)`` carries its own)
    device : torch device the batch is built on (Mesh inputs) or moved to (a MeshBatch);
        default: a batch's own, else cpu
    untangled : the :class:`~torchakvf.fields.UntangledFields` of these AKVFs to reuse (from
        :func:`~torchakvf.fields.untangle` with ``n=field_counts(fields, k, method=method,
        min_k=options.merge_min_k)``, the same seed and restarts): several k's with the same
        field counts then share one untangling

    Each :class:`MeshSegmentation` says whether its mesh's eigensolve converged
    (``converged``, ``max_residual``).
    """
    res = segment_each_k(meshes, k, options, n_fields=n_fields, coarse_faces=coarse_faces, device=device,
                         untangled=untangled, **overrides)
    return res.rounds[0].segmentation()


__all__ = ["segment", "segment_each_k", "SegmentEachK", "Segmentation", "MeshSegmentation", "SymmetryGenerator"]
