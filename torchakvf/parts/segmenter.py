"""A mesh batch's segmentations at any k, with what they share kept across calls.

:class:`Segmenter` keeps a batch's AKVFs (and the :class:`~torchakvf.solvers.AKVFSolver` with
its factors) and its untanglings, as the solver keeps its factors: ``segment(3)`` then
``segment(5)`` solve the AKVFs once, a k whose field counts an earlier call untangled reuses
that untangling, and what the cut makes of each mesh alone (crease patches, thickness, dual
edges: :class:`~torchakvf.parts.cut.MeshCache`) is made once. :func:`~torchakvf.parts.segment.segment` and
:func:`~torchakvf.parts.segment.segment_each_k` are a Segmenter used once.

Every call gives the labels the plain functions give on these AKVFs: a mesh's untangling and
clustering depend on its own fields, the counts and the seed alone
(:mod:`torchakvf.parts.rounds`), so what is reused is bit for bit what would be recomputed.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from numbers import Integral

from ..errors import ParameterError
from ..fields.akvf import AKVFResult, as_batch
from ..fields.untangle import UntangledFields
from ..mesh import MeshBatch
from ..mesh.size_check import check_fields_fit
from ..options import SegmentOptions, segment_options
from ..solvers.akvf_solver import AKVFSolver
from .cut import MeshCache
from .field_counts import akvf_count, check_ks, per_mesh
from .k_auto import (
    DEFAULT_K_RANGE,
    DEFAULT_RULE,
    AutoSegmentation,
    auto_segmentation,
    check_k_range,
    is_auto,
    scan_akvf_count,
    scan_field_counts,
    scan_k,
    scan_options,
)
from .results import Segmentation
from .rounds import round_plan, segment_rounds
from .solve import AKVF_TOL


@dataclass
class SegmentEachK:
    """What :func:`~torchakvf.parts.segment.segment_each_k` (and
    :meth:`Segmenter.segment_each_k`) returns.

    fields : the AKVFs (of ``fields.batch``: decimated meshes that could not be solved are at
        full resolution there); fell_back : [(mesh index, why)] of those meshes
    meshes : [B] {k: MeshSegmentation} of every k asked for each mesh
    rounds : the :class:`~torchakvf.parts.rounds.KRound` s, in order (their ``meshes`` are the
        same objects)
    seconds : {"akvf": s, "untangle": s, "cluster": s} spent by this call ("akvf": 0 when the
        AKVFs were reused)
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


class Segmenter:
    """The segmentations of one mesh batch, sharing its AKVFs and untanglings across calls.

    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`~torchakvf.fields.AKVFResult` to use
        (its n must cover the field counts asked for)
    options : a :class:`~torchakvf.options.SegmentOptions` (None: the defaults); ``**overrides``
        are its field names, as in :func:`~torchakvf.parts.segment.segment`. With ``k="auto"``
        and no options given, the scan's over-segmentation
        (:func:`~torchakvf.parts.k_auto.scan_options`), as the evaluation's ``-k auto`` uses
    n : AKVFs to solve for (the count :func:`~torchakvf.fields.akvf` calls ``n``). Default: what
        the first call needs (:func:`~torchakvf.parts.field_counts.akvf_count`; with k auto
        :func:`~torchakvf.parts.k_auto.scan_akvf_count`), solved again (the solver's factors
        kept) only when a later call needs more. Give one to make a mesh's fields independent
        of the order of the calls
    n_fields : fields untangled per mesh (one int or one per mesh; None: each k's default), as in
        :func:`~torchakvf.parts.segment.segment`
    coarse_faces, device : as in :func:`~torchakvf.parts.segment.segment`

    ``segment(k)`` (one k per mesh, or ``"auto"``) and ``segment_each_k(ks)`` (several k's of
    every mesh) may be called any number of times. ``fields`` is the current AKVFs (None before
    the first call), ``solves`` the number of AKVF solves so far, ``seconds`` the stage seconds
    of every call so far.
    """

    def __init__(self, meshes, options: SegmentOptions | None = None, *, n: int | None = None, n_fields=None,
                 coarse_faces: int | None = None, device=None, **overrides):
        t0 = time.perf_counter()
        self.options = segment_options(options, **overrides)       # one-line errors before any work
        self.auto_options = scan_options(options, overrides)
        if coarse_faces is not None and isinstance(meshes, (AKVFResult, MeshBatch)):
            raise ParameterError("coarse_faces applies to Mesh inputs; build the batch with "
                                 "MeshBatch.from_meshes(meshes, coarse_faces=...) instead")
        self.n = None if n is None else per_mesh(n, 1, "n")[0]
        self.n_fields = n_fields
        self.fell_back: list = []
        self.solves = 0
        self._solver: AKVFSolver | None = None
        self._untangled: dict[tuple, UntangledFields] = {}      # per-mesh counts -> untangling of ``fields``
        # per mesh of ``fields.batch``, what the cut makes of the mesh alone, kept across calls
        self._mesh_caches: list[MeshCache] | None = None
        if isinstance(meshes, AKVFResult):
            self.fields: AKVFResult | None = meshes
            self.batch = meshes.batch
        else:
            self.fields = None
            self.batch = as_batch(meshes, device=device, coarse_faces=coarse_faces)
        # packing the batch counts with the first call's AKVFs, as the plain functions report it
        self._unreported = time.perf_counter() - t0
        self.seconds = {"akvf": self._unreported, "untangle": 0.0, "cluster": 0.0}

    def __len__(self) -> int:
        return len(self.batch)

    # ---- the AKVFs --------------------------------------------------------------------------

    def _akvf_seconds(self) -> float:
        """The AKVF seconds no call has reported yet (packing, solves), for the calling one."""
        seconds, self._unreported = self._unreported, 0.0
        return seconds

    def _solve(self, needed: int, k_max: list, fields_for_k) -> None:
        """Makes ``fields`` cover ``needed`` AKVFs (solving at ``n`` if given, else at ``needed``,
        unless the AKVFs at hand cover it). AKVFs given by the caller are used as they are (a
        count they do not cover fails where it is read)."""
        have = self.fields
        if have is not None and (self._solver is None or self.n is not None or have.n >= needed):
            return
        t0 = time.perf_counter()
        n = self.n if self.n is not None else int(needed)
        for b in range(len(self.batch)):
            check_fields_fit(self.batch.names[b], self.batch.meshes[b].faces, n, k=k_max[b], fields_for_k=fields_for_k)
        opts = self.options
        if self._solver is None:
            self._solver = AKVFSolver(self.batch, remedy=opts.remedy, solver=opts.solver, batched=opts.batched,
                                      full_resolution_fallback=True)
        self.fields = self._solver.solve(n, tol=AKVF_TOL, seed=opts.seed)
        self.fell_back = list(self._solver.fell_back)
        self.solves += 1
        self._untangled.clear()             # untanglings of the AKVFs replaced
        self._mesh_caches = None            # a fallback may have re-packed a mesh at full resolution
        seconds = time.perf_counter() - t0
        self.seconds["akvf"] += seconds
        self._unreported += seconds

    def _keep(self, untangled: UntangledFields) -> None:
        if untangled is not None and untangled.source is self.fields:
            self._untangled.setdefault(tuple(int(v) for v in untangled.n_fields), untangled)

    def _kept_for(self, ks: list, opts: SegmentOptions) -> UntangledFields | None:
        """The kept untangling every round of ``ks`` (one list of k's per mesh) would make, if
        the rounds agree on one count per mesh and every mesh takes part in each."""
        if not self._untangled or len({len(kb) for kb in ks}) != 1:
            return None
        counts = {tuple(round_plan(self.fields, ks, r, self.n_fields, opts).n_fields) for r in range(len(ks[0]))}
        return self._untangled.get(counts.pop()) if len(counts) == 1 else None

    # ---- segmentations ----------------------------------------------------------------------

    def segment_each_k(self, ks, *, untangled: UntangledFields | None = None) -> SegmentEachK:
        """Every mesh at each of its k's (one list per mesh, one int per mesh, or one int),
        in rounds over the kept AKVFs (:func:`~torchakvf.parts.segment.segment_each_k`).

        untangled : an untangling of these AKVFs to use (its counts those the k's need); None:
            a kept one where the k's need its counts, else untangled now and kept
        """
        opts = self.options
        if self.fields is None or self._solver is not None:
            ks = check_ks(self.batch, ks)
            nf, method, min_k = self.n_fields, opts.method, opts.merge_min_k
            self._solve(akvf_count(ks, nf, method, min_k), [max(kb) for kb in ks],
                        lambda j: akvf_count([[j]], nf, method, min_k))
        fields = self.fields
        if untangled is None:
            untangled = self._kept_for(check_ks(fields.batch, ks), opts)
        out = SegmentEachK(fields=fields, fell_back=list(self.fell_back), meshes=[{} for _ in range(len(fields.batch))],
                           seconds={"akvf": self._akvf_seconds(), "untangle": 0.0, "cluster": 0.0})
        if self._mesh_caches is None:
            self._mesh_caches = [MeshCache() for _ in range(len(fields.batch))]
        for rnd in segment_rounds(fields, ks, opts, n_fields=self.n_fields, untangled=untangled,
                                  mesh_caches=self._mesh_caches):
            out.rounds.append(rnd)
            if len(rnd.active) == len(fields.batch):
                self._keep(rnd.untangled)
            for b in rnd.active:
                out.meshes[b][rnd.ks[b]] = rnd.meshes[b]
            for stage, s in rnd.seconds.items():
                out.seconds[stage] += s
                self.seconds[stage] += s
        return out

    def segment(self, k, *, k_range=None, k_rule: str | None = None,
                untangled: UntangledFields | None = None) -> Segmentation:
        """Each mesh at k parts: one int, one per mesh, or ``"auto"`` (chosen per mesh from
        ``k_range`` by ``k_rule``, default (2, 10) and "merge", :mod:`torchakvf.parts.k_auto`; an
        :class:`AutoSegmentation`, whose ``k_auto`` says which k each mesh got).

        untangled : as in :meth:`segment_each_k` (a given k only)
        """
        if is_auto(k):
            if untangled is not None:
                raise ParameterError("untangled applies to a given k; k='auto' untangles at the scan's counts")
            return self.segment_auto(DEFAULT_K_RANGE if k_range is None else k_range,
                                     DEFAULT_RULE if k_rule is None else k_rule)
        if isinstance(k, str):
            raise ParameterError(f"k must be a positive integer, one per mesh, or 'auto', got {k!r}")
        if k_range is not None or k_rule is not None:
            raise ParameterError("k_range and k_rule apply to k='auto'")
        return self.segment_each_k(k, untangled=untangled).rounds[0].segmentation()

    def segment_auto(self, k_range=DEFAULT_K_RANGE, k_rule: str = DEFAULT_RULE) -> AutoSegmentation:
        """``segment("auto")``: every k of ``k_range`` from one field count per mesh, each mesh at
        the k ``k_rule`` picks (:func:`~torchakvf.parts.k_auto.scan_k` on the kept AKVFs)."""
        lo, hi = check_k_range(k_range)
        n_fields = self.n_fields
        if n_fields is not None and (not isinstance(n_fields, Integral) or isinstance(n_fields, bool)):
            raise ParameterError(f"k='auto' untangles one field count for every mesh; n_fields {n_fields!r} "
                                 f"is not one integer")
        if self._solver is not None or self.fields is None:
            self._solve(scan_akvf_count(hi, n_fields), [hi] * len(self.batch), lambda j: scan_akvf_count(j, n_fields))
        ns = scan_field_counts(self.fields, hi, n_fields)
        kept = self._untangled.get(tuple(ns) if isinstance(ns, list) else (ns,) * len(self.fields.batch))
        scan = scan_k(self.fields, (lo, hi), self.auto_options, rule=k_rule, n_fields=n_fields, keep=True,
                      untangled=kept)
        for stage, s in scan.seconds.items():
            self.seconds[stage] += s
        self._akvf_seconds()                # in ``seconds``; an AutoSegmentation carries no timings
        out = auto_segmentation(scan)
        self._keep(out.untangled)
        return out


__all__ = ["Segmenter", "SegmentEachK"]
