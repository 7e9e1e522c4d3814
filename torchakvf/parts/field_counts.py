"""How many fields to untangle and clusters to make for a mesh at k parts, and how many AKVFs
to solve for that (the count policy of a segmentation).

The rules and their defaults live in :mod:`torchakvf.options` (:data:`~torchakvf.options.
FIELDS_PER_PART`, :data:`~torchakvf.options.FIELDS_STEP`, :data:`~torchakvf.options.
FIELD_COUNT_RANGE`, :data:`~torchakvf.options.SPARE_FIELDS`, :data:`~torchakvf.options.
CLUSTER_GAP`); this module applies them.
"""
from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..fields.akvf import AKVFResult
from ..options import (
    CLUSTER_GAP,
    DEFAULT_METHOD,
    FIELD_COUNT_RANGE,
    FIELDS_PER_PART,
    FIELDS_STEP,
    SPARE_FIELDS,
    OverSegmentation,
    SegmentOptions,
)
from .merge import oversegment_k


def per_mesh(value, nb: int, what: str) -> list[int]:
    """One positive int (Python or numpy) for every mesh, or a sequence of nb of them -> list."""
    vals = [value] * nb if isinstance(value, (int, np.integer)) else list(value)
    if len(vals) != nb:
        raise ParameterError(f"{what} has {len(vals)} values for {nb} meshes")
    for v in vals:
        if not isinstance(v, (int, np.integer)) or isinstance(v, (bool, np.bool_)) or v < 1:
            raise ParameterError(f"{what} must be a positive integer (or one per mesh), got {v!r}")
    return [int(v) for v in vals]


def check_ks(batch, ks) -> list:
    """ks : one int or one list of k's per mesh of ``batch`` (a MeshBatch) -> [B] lists of
    distinct ints (order kept); ParameterError for a k that is not a positive integer or
    exceeds its mesh's faces."""
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


def min_k_of(method: str, min_k: int | None) -> int:
    """min_k as given, or for None the default OverSegmentation's with method "merge", else 1."""
    if min_k is not None:
        return int(min_k)
    return int(OverSegmentation().min_k) if method == "merge" else 1


def default_n_fields(k: int, method: str = "paper", min_k: int | None = None) -> int:
    """Fields untangled for k parts: FIELDS_PER_PART[method] x max(k, min_k), rounded up to a
    multiple of FIELDS_STEP[method], clamped to FIELD_COUNT_RANGE ([16, 32]; method "paper",
    the default here: the paper's N = 2k). min_k: the merge method's
    :attr:`~torchakvf.options.OverSegmentation.min_k` (a k below it is over-segmented as min_k
    is, from the same fields); None: the default OverSegmentation's with method "merge", else 1."""
    if method not in FIELDS_PER_PART:
        raise ParameterError(f"method must be one of {tuple(FIELDS_PER_PART)}, got {method!r}")
    step = FIELDS_STEP[method]
    n = -(-FIELDS_PER_PART[method] * max(int(k), min_k_of(method, min_k)) // step) * step
    low, high = FIELD_COUNT_RANGE
    return int(min(max(n, low), high))


def cluster_safe_n(eigenvalues, n: int, floor: int = 1) -> int:
    """The field count nearest below ``n`` (at least ``floor``) that does not split a cluster of
    near-equal eigenvalues (:data:`~torchakvf.options.CLUSTER_GAP`); if none, the nearest above
    within the computed ones, else ``n``.

    Only the span of a degenerate cluster is meaningful: cutting one leaves fields that no
    rotation can localize (two spheres, n = 16 splitting a 10-fold cluster: 13% leakage).
    eigenvalues : the ascending computed spectrum, length >= n.
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


def field_counts(fields: AKVFResult, k, n_fields=None, method: str = DEFAULT_METHOD,
                 min_k: int | None = None) -> list[int]:
    """The number of fields untangled per mesh for these k.

    Default (``n_fields=None``): :func:`default_n_fields` of k, the method and min_k (the
    paper's 2k, the merge method's 3 max(k, min_k), clamped to [16, 32]), moved by
    :func:`cluster_safe_n` off a degenerate cluster of the mesh's computed eigenvalues;
    otherwise ``n_fields`` (one int or one per mesh), which must not exceed ``fields.n``.
    min_k None: the default OverSegmentation's for method "merge" (:func:`default_n_fields`).
    """
    min_k = min_k_of(method, min_k)
    nb = len(fields.batch)
    ks = per_mesh(k, nb, "k")
    ns = ([default_n_fields(kb, method, min_k) for kb in ks] if n_fields is None
          else per_mesh(n_fields, nb, "n_fields"))
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
    min_k) plus :data:`~torchakvf.options.SPARE_FIELDS`."""
    if n_fields is not None:
        ns = [n_fields] if isinstance(n_fields, (int, np.integer)) else list(n_fields)
        return max(per_mesh(ns, len(ns), "n_fields"))
    return default_n_fields(max(max(kb) for kb in ks), method, min_k) + SPARE_FIELDS


def cluster_count(k: int, n_faces: int, opts: SegmentOptions) -> int:
    """Clusters k-means makes for a mesh of n_faces faces segmented into k parts: k, or
    k' = ceil(ratio max(k, min_k)) (at most max(k, min_k) + extra_max, at most its faces) when
    the parts are merged afterwards (:func:`~torchakvf.parts.merge.oversegment_k`)."""
    if not opts.merges_parts:
        return int(k)
    return oversegment_k(k, opts.overseg.ratio, n_faces, opts.overseg.extra_max, opts.overseg.min_k)


__all__ = ["per_mesh", "check_ks", "min_k_of", "default_n_fields", "cluster_safe_n", "field_counts", "akvf_count",
           "cluster_count"]
