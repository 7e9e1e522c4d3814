"""Choosing the number of parts k automatically (beyond the paper, which takes k as given).

Rule ``"elbow"``: segment every mesh for each k in ``k_range`` from *one* AKVF
solve and *one* field count (``n_fields = default_n_fields(k_max)`` for every k, so that the
per-face features, and hence the k-means costs, are comparable across k; moved, like
``segment`` does, off a cluster of near-equal eigenvalues), normalise the
spherical k-means cost ``c(k)`` (sum over faces of 1 - cos to the centre) by ``c(k_min)`` and
pick the k with the largest second difference ``c(k-1) - 2 c(k) + c(k+1)``: the "elbow" after
which extra parts stop paying for themselves. Ties go to the smaller k. Only interior k's
(``k_min < k < k_max``) can be chosen by this rule.

* ``"merge"`` - from the merge costs (:func:`~torchakvf.parts.merge.next_merge_cost`): at each k
  the cheapest merge left among the k parts, c_next(k); descending from k_max, merging goes on
  while that merge is cheap, and stops at the first k whose next merge costs more than τ
  (:data:`MERGE_TAU`, chosen by cross-validation across PSB categories, see docs/design.md);
  k_min when every merge is cheap.

Other rules, kept for comparison (see the measurements in the evaluation report):

* ``"knee"`` - the "kneedle" point: after scaling k and c(k) to [0, 1], the k whose cost lies
  furthest below the chord from (k_min, c(k_min)) to (k_max, c(k_max)).
* ``"spectrum"`` - from the Killing spectrum alone (no clustering): with λ_i the eigenvalues
  (λ·area) of the raw AKVFs, the largest relative gap ``λ_{i+1} / λ_i`` for i in
  ``[2 k_min, 2 k_max]`` gives k = round(i / 2) (the paper's N = 2k fields per k parts).

:func:`choose_k` returns one k per mesh; :func:`scan_k` also returns the costs and the
segmentation for every k tried; :func:`segment_auto` is ``segment(..., k="auto")``, an
:class:`AutoSegmentation` that says which k each mesh got (:class:`KChoice`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..fields.akvf import AKVFResult, as_batch
from ..fields.untangle import UntangledFields
from ..options import SPARE_FIELDS, OverSegmentation, SegmentOptions, segment_options
from .field_counts import cluster_safe_n, default_n_fields
from .results import Segmentation
from .rounds import segment_rounds
from .solve import solve_akvfs

RULES = ("elbow", "knee", "spectrum", "merge")
#: The rule used unless one is given: "merge", the best held-out 1-RI of the rules on the PSB
#: (see docs/design.md).
DEFAULT_RULE = "merge"
#: The "merge" rule's threshold on the cheapest merge left (units of the merge cost): chosen by
#: cross-validation across PSB categories with the default merge weights (see docs/design.md).
MERGE_TAU = 0.95
#: The over-segmentation's min_k of the scan when the caller gives no ``overseg``: 1, every k
#: over-segmented on its own, the setting MERGE_TAU was chosen with. With the segmentation
#: default (OverSegmentation.min_k 8) the small k's of the scan are merged down from one
#: over-segmentation and their next-merge costs read differently (a dumbbell's neck is left as
#: a costly third part).
SCAN_MIN_K = 1
#: The scan's over-segmentation when the caller gives no ``overseg``: every k on its own
#: (:data:`SCAN_MIN_K`), 3 pieces per part, at most 16 beyond k, crease patches' fragments not
#: united, the one MERGE_TAU was chosen and re-validated with. The segmentation's own
#: (:class:`~torchakvf.options.OverSegmentation`, 5 per part, fragments united) was chosen for a
#: given k, not for where this rule stops: other pieces leave other merge costs at each k.
SCAN_OVERSEGMENTATION = OverSegmentation(ratio=3.0, extra_max=16, min_k=SCAN_MIN_K, unite_fragments=False)
DEFAULT_K_RANGE = (2, 10)


def scan_overseg(overseg: OverSegmentation | None) -> OverSegmentation:
    """The scan's over-segmentation: ``overseg`` as given, None: :data:`SCAN_OVERSEGMENTATION`."""
    return SCAN_OVERSEGMENTATION if overseg is None else overseg


def scan_options(options: SegmentOptions | None, overrides: dict) -> SegmentOptions:
    """The options of a scan: ``options`` with ``overrides`` applied; None: the defaults with
    the scan's over-segmentation unless ``overrides`` name another."""
    if options is None:
        return segment_options(**{**overrides, "overseg": scan_overseg(overrides.get("overseg"))})
    return segment_options(options, **overrides)

__all__ = ["RULES", "DEFAULT_RULE", "MERGE_TAU", "SCAN_MIN_K", "SCAN_OVERSEGMENTATION", "scan_overseg",
           "scan_options", "DEFAULT_K_RANGE",
           "KScan", "KChoice", "AutoSegmentation", "scan_k", "scan_akvf_count", "scan_field_counts", "choose_k",
           "segment_auto", "auto_segmentation", "pick_k", "check_k_range", "is_auto"]


def is_auto(k) -> bool:
    """Whether ``k`` asks for the automatic choice (the string "auto", any case)."""
    return isinstance(k, str) and k.strip().lower() == "auto"


@dataclass
class KScan:
    """Result of segmenting a batch for every k of a range.

    ks : the k's tried (ascending)
    costs : [B, len(ks)] spherical k-means cost of each mesh for each k
    eigenvalues : [B, n] raw Killing eigenvalues (λ·area) of each mesh
    chosen : [B] the k picked by ``rule``
    rule : the rule used
    n_fields : fields untangled for every k (an int, or one per mesh)
    segmentations : {k: Segmentation} (only when kept)
    next_costs : [B, len(ks)] cost of the cheapest merge left among each k's parts (inf: none)
    seconds : {"untangle": s, "cluster": s} of the scan's rounds
    """

    ks: list
    costs: np.ndarray
    eigenvalues: np.ndarray
    chosen: list
    rule: str
    n_fields: int
    segmentations: dict = field(default_factory=dict)
    next_costs: np.ndarray | None = None
    seconds: dict = field(default_factory=dict)

    def segmentation(self) -> Segmentation:
        """The chosen k's segmentation of every mesh (needs the segmentations kept)."""
        if not self.segmentations:
            raise ParameterError("this KScan kept no segmentations (keep=False)")
        return Segmentation([self.segmentations[k].meshes[b] for b, k in enumerate(self.chosen)])


def check_k_range(k_range) -> tuple[int, int]:
    try:
        lo, hi = (int(v) for v in k_range)
    except (TypeError, ValueError):
        raise ParameterError(f"k_range must be two integers (k_min, k_max), got {k_range!r}") from None
    if not 1 <= lo or hi - lo < 2:
        raise ParameterError(f"k_range must have 1 <= k_min and k_max >= k_min + 2 (an elbow needs "
                             f"a k on each side), got {k_range!r}")
    return lo, hi


def pick_k(ks, costs, rule: str = DEFAULT_RULE, eigenvalues=None, next_costs=None, tau: float = MERGE_TAU) -> int:
    """The k one rule picks from one mesh's cost curve ``costs[i] = c(ks[i])`` (rule "merge":
    from ``next_costs[i]``, the cheapest merge left at ks[i], and the threshold ``tau``)."""
    ks = np.asarray(ks, dtype=np.int64)
    c = np.asarray(costs, dtype=np.float64)
    if rule not in RULES:
        raise ParameterError(f"rule must be one of {RULES}, got {rule!r}")
    if rule == "merge":
        if next_costs is None:
            raise ParameterError("rule 'merge' needs the next-merge costs (KScan.next_costs)")
        above = ks[np.asarray(next_costs, dtype=np.float64) > tau]
        return int(above.max()) if len(above) else int(ks[0])
    if rule == "spectrum":
        if eigenvalues is None:
            raise ParameterError("rule 'spectrum' needs the Killing eigenvalues")
        lam = np.abs(np.asarray(eigenvalues, dtype=np.float64))
        lo, hi = 2 * int(ks[0]), min(2 * int(ks[-1]), len(lam) - 1)
        if hi <= lo:
            return int(ks[0])
        floor = max(lam.max() * 1e-12, 1e-300)
        i = np.arange(lo, hi + 1)            # gap after the i-th eigenvalue (1-based count i)
        ratio = lam[i] / np.maximum(lam[i - 1], floor)
        best = int(i[int(np.argmax(ratio))])
        return int(np.clip(round(best / 2), ks[0], ks[-1]))
    if not np.all(np.isfinite(c)) or c[0] <= 0:
        return int(ks[0])
    cn = c / c[0]
    if rule == "elbow":
        d2 = cn[:-2] - 2 * cn[1:-1] + cn[2:]
        return int(ks[1 + int(np.argmax(d2))])
    # knee: furthest below the chord, both axes scaled to [0, 1]
    x = (ks - ks[0]) / max(ks[-1] - ks[0], 1)
    span = cn[0] - cn[-1]
    if span <= 0:
        return int(ks[0])
    y = (cn - cn[-1]) / span
    below = (1 - x) - y
    return int(ks[int(np.argmax(below))])


def scan_akvf_count(k_max: int, n_fields: int | None = None) -> int:
    """AKVFs a scan up to ``k_max`` solves for: ``n_fields`` when given, else
    ``default_n_fields(k_max)`` plus the engine's spare fields (so a degenerate cluster is not cut)."""
    return default_n_fields(k_max) + SPARE_FIELDS if n_fields is None else int(n_fields)


def scan_field_counts(fields: AKVFResult, k_max: int, n_fields: int | None = None):
    """Fields untangled for every k of a scan up to ``k_max``: ``n_fields`` as given, else one count
    per mesh, ``default_n_fields(k_max)`` moved off a degenerate eigenvalue cluster
    (:func:`~torchakvf.parts.field_counts.cluster_safe_n`); ParameterError when ``fields`` has fewer."""
    n = default_n_fields(k_max) if n_fields is None else int(n_fields)
    if fields.n < n:
        raise ParameterError(f"the AKVFs given have n = {fields.n} < the {n} fields needed")
    if n_fields is not None:
        return n
    lam = fields.eigenvalues.detach().cpu()
    return [cluster_safe_n(lam[b], n, floor=max(k_max, n // 2)) for b in range(len(fields.batch))]


def scan_k(meshes, k_range=DEFAULT_K_RANGE, options: SegmentOptions | None = None, *,
           rule: str = DEFAULT_RULE, n_fields: int | None = None, keep: bool = True, device=None,
           untangled: UntangledFields | None = None, **overrides) -> KScan:
    """Segment every mesh for each k in ``k_range`` (inclusive) and pick one k per mesh.

    Parameters
    ----------
    meshes : MeshBatch, Mesh, list of Mesh, or an :class:`AKVFResult` to reuse
    k_range : (k_min, k_max), inclusive, k_max >= k_min + 2
    options : the :class:`~torchakvf.options.SegmentOptions` (None: the defaults, with
        the scan's over-segmentation :func:`scan_overseg` unless ``overseg`` is given); used as
        given otherwise
    rule : see the module notes (default :data:`DEFAULT_RULE`)
    n_fields : fields untangled for every k (default ``default_n_fields(k_max)`` per mesh, moved
        by :func:`~torchakvf.parts.field_counts.cluster_safe_n` off a degenerate eigenvalue cluster)
    keep : keep every k's :class:`Segmentation` (memory: one label array per mesh per k)
    device : torch device the batch is built on (Mesh inputs)
    untangled : the untangled fields of these AKVFs at the scan's counts
        (:func:`scan_field_counts`) to reuse, as :func:`~torchakvf.parts.segment` takes them
    overrides : SegmentOptions fields by name (seed, eps, boundary, solver, kmeans_restarts, ...)
    """
    lo, hi = check_k_range(k_range)
    if rule not in RULES:
        raise ParameterError(f"rule must be one of {RULES}, got {rule!r}")
    opts = scan_options(options, overrides)
    if isinstance(meshes, AKVFResult):
        fields = meshes
    else:
        fields, _ = solve_akvfs(as_batch(meshes, device=device), scan_akvf_count(hi, n_fields), opts)
    ns = scan_field_counts(fields, hi, n_fields)
    nb = len(fields.batch)
    for b, m in enumerate(fields.batch.meshes):
        if len(m.faces) < hi:
            raise ParameterError(f"{m.name}: k_max = {hi} is larger than its {len(m.faces)} faces")
    ks = list(range(lo, hi + 1))
    costs = np.zeros((nb, len(ks)))
    nexts = np.full((nb, len(ks)), np.inf)
    segs = {}
    seconds = {"untangle": 0.0, "cluster": 0.0}
    # One field count for every k, so one untangling serves the whole scan.
    for j, rnd in enumerate(segment_rounds(fields, [ks] * nb, opts, n_fields=ns, untangled=untangled)):
        costs[:, j] = [m.cost for m in rnd.meshes]
        nexts[:, j] = [m.params.get("merge_next", np.inf) for m in rnd.meshes]
        for stage, sec in rnd.seconds.items():
            seconds[stage] += sec
        if keep:
            segs[ks[j]] = rnd.segmentation()
    eig = fields.eigenvalues.detach().cpu().numpy().astype(np.float64)
    chosen = [pick_k(ks, costs[b], rule, eig[b], nexts[b]) for b in range(nb)]
    return KScan(ks=ks, costs=costs, eigenvalues=eig, chosen=chosen, rule=rule, n_fields=ns,
                 segmentations=segs, next_costs=nexts, seconds=seconds)


def choose_k(meshes, k_range=DEFAULT_K_RANGE, *, rule: str = DEFAULT_RULE, **kwargs) -> list[int]:
    """One automatically chosen k per mesh (see :func:`scan_k` for the parameters)."""
    return scan_k(meshes, k_range, rule=rule, keep=False, **kwargs).chosen


@dataclass(frozen=True)
class KChoice:
    """How one mesh's k was chosen automatically.

    k : the k chosen; rule : the rule that chose it (:data:`RULES`)
    ks : the k's tried (ascending); costs : [len(ks)] spherical k-means cost c(k) of each
    next_costs : [len(ks)] cost of the cheapest merge left among each k's parts (inf: none)
    """

    k: int
    rule: str
    ks: tuple
    costs: tuple
    next_costs: tuple


@dataclass
class AutoSegmentation(Segmentation):
    """A :class:`Segmentation` whose k's were chosen per mesh (``segment(..., k="auto")``).

    k_auto : [B] :class:`KChoice`, how each mesh's k was chosen (``chosen``: the k's alone)
    """

    k_auto: list = field(default_factory=list)

    @property
    def chosen(self) -> list:
        """[B] the k chosen for each mesh."""
        return [c.k for c in self.k_auto]


def auto_segmentation(scan: KScan) -> AutoSegmentation:
    """Each mesh at the k ``scan`` chose (it must have kept its segmentations); its
    :class:`MeshSegmentation` also carries ``params["k_auto"]`` (the rule, the k's tried and
    their costs). The untangled fields are the scan's (one count for every k)."""
    out = scan.segmentation()
    choices = [KChoice(k=int(k), rule=scan.rule, ks=tuple(scan.ks), costs=tuple(scan.costs[b].tolist()),
                       next_costs=tuple(scan.next_costs[b].tolist())) for b, k in enumerate(scan.chosen)]
    for m, c in zip(out.meshes, choices):
        m.params = dict(m.params, k_auto=dict(rule=c.rule, ks=list(c.ks), costs=list(c.costs)))
    untangled = scan.segmentations[scan.ks[0]].untangled
    return AutoSegmentation(out.meshes, untangled=untangled, k_auto=choices)


def segment_auto(meshes, k_range=DEFAULT_K_RANGE, *, rule: str = DEFAULT_RULE, **kwargs) -> AutoSegmentation:
    """Each mesh segmented with its automatically chosen k (see :func:`scan_k` for the
    parameters and :func:`auto_segmentation` for the result)."""
    return auto_segmentation(scan_k(meshes, k_range, rule=rule, keep=True, **kwargs))
