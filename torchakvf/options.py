"""Segmentation options: :class:`SegmentOptions`, the one home of the segmentation defaults.

Every tuned constant of the segmentation lives here, with the rule it sets and one sentence of
why; the measurements behind each are in docs/design.md. :func:`torchakvf.segment`, the corpus
``segment`` task, the PSB evaluation, the bench and the CLI all build one
:class:`SegmentOptions` and pass it on.

Two layers have defaults of their own, named so: :func:`torchakvf.fields.untangle` alone keeps
:data:`~torchakvf.fields.untangle.DEFAULT_RESTARTS` (8) random starts, a segmentation
:data:`SEGMENT_UNTANGLE_RESTARTS` (1); :func:`torchakvf.cluster.spherical_kmeans` alone keeps
:data:`~torchakvf.cluster.spherical_kmeans.DEFAULT_RESTARTS` (20) restarts and 100 Lloyd
iterations, a segmentation :data:`KMEANS_RESTARTS_BY_METHOD` and :data:`KMEANS_MAX_ITER`.

Method "merge"'s own options, :class:`MergeWeights` (the learned merge cost, read from the
package's weights file) and :class:`OverSegmentation`, live in :mod:`torchakvf.merge_options`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from dataclasses import fields as dataclass_fields

import numpy as np

from .errors import ParameterError
from .fields.akvf import SOLVERS
from .merge_options import (
    LEARNED_FIELDS,
    LEARNED_WEIGHTS,
    MERGE_RECORD_FIELDS,
    OVERSEG_FIELDS,
    ConcaveChoice,
    MergeWeights,
    OverSegmentation,
    is_int,
    merge_weights_record,
    read_merge_weights,
)
from .operators.killing import DEFAULT_REMEDY

#: Segmentation methods. "paper": spherical k-means into k parts (Solomon et al. 2011);
#: "merge": k-means into k' = ceil(ratio k) parts, then adjacent parts merged down to k by
#: symmetry similarity and boundary concavity (:mod:`torchakvf.parts.merge`).
METHODS = ("paper", "merge")
#: "merge": chosen by cross-validation across the PSB categories (see docs/design.md).
DEFAULT_METHOD = "merge"
#: How labels are read from the clustering: "isoline" (the g_ij = 0 isolines of the
#: vertex-averaged distance fields: smooth boundaries) or "faces" (k-means' own face labels).
BOUNDARIES = ("isoline", "faces")

#: Random orthogonal starts of Algorithm 1 besides the identity when segmenting (the function
#: :func:`~torchakvf.fields.untangle`'s own default is 8): one, because the optima are near-equal
#: and more starts did not raise the PSB score (see docs/design.md).
SEGMENT_UNTANGLE_RESTARTS = 1
#: k-means++ restarts per clustering by method (the lowest cost is kept). "paper" 5: k-means has
#: many near-equal optima and more restarts do not move the score beyond its noise; "merge" 3:
#: its over-segmentation into 5k is merged afterwards (see docs/design.md).
KMEANS_RESTARTS_BY_METHOD = {"paper": 5, "merge": 3}
#: Lloyd iterations per precision phase of each clustering (the function's own default is 100):
#: 15 scores as 100 does; the restarts still moving by then creep by a few faces per iteration.
KMEANS_MAX_ITER = 15
#: Untangled fields per part, by method: "paper" the paper's N = 2k; "merge" 3k, since its
#: k-means makes k' = 5k clusters from them (see docs/design.md).
FIELDS_PER_PART = {"paper": 2, "merge": 3}
#: Field counts are rounded up to a multiple of this, by method, so that the k's of a mesh share
#: fewer untanglings (one per distinct count); "merge" 8 gives counts 16, 24 and 32.
FIELDS_STEP = {"paper": 1, "merge": 8}
#: Default field counts are clamped to this range [low, high]: fewer fields cannot separate the
#: parts of the corpus' shapes, more cost time without changing the parts.
FIELD_COUNT_RANGE = (16, 32)
#: AKVFs solved beyond the largest default field count, so that a degenerate eigenvalue cluster
#: cut at that count can be seen and completed (:func:`~torchakvf.parts.field_counts.cluster_safe_n`).
SPARE_FIELDS = 4
#: Eigenvalues closer than this (relative) belong to one cluster, which a field count must not
#: split: a rotation cannot localize part of a degenerate cluster's span.
CLUSTER_GAP = 1e-2
#: Connected pieces of a part below this fraction of the surface area are cleaned away: smaller
#: pieces are isoline noise, not parts.
MIN_PART_FRACTION = 0.01
#: At k parts, the clean-up floor is at most this fraction of a mean part's area (1/k), whatever
#: ``min_part_fraction`` says: k parts of 1% each cannot exist beyond k = 100.
PART_FLOOR_OF_MEAN = 0.25
#: Alpha-expansion cycles of the graph cut (each tries every label once; -1: until no expansion
#: lowers the energy): the cycles past the second change little and cost as much.
EXPANSION_CYCLES = 2
#: Solvers of the graph cut's alpha-expansion: "scipy" (minimum cuts from
#: scipy.sparse.csgraph.maximum_flow, BSD; the default) or "gco" (gco-wrapper, an optional
#: extra licensed for research use only; the same labels).
GRAPHCUT_ENGINES = ("scipy", "gco")


@dataclass(frozen=True)
class GraphCut:
    """Parameters of the graph cut that re-decides part boundaries after the merge
    (:func:`~torchakvf.parts.graphcut.graphcut_labels`). smoothness and beta were chosen by
    cross-validation across the labelled PSB categories; crease_angle and band were fixed
    beforehand (see docs/design.md)."""

    #: λ >= 0, dimensionless (edge lengths over the mean length, areas over the mean area):
    #: the price of a boundary against the data term
    smoothness: float = 10.0
    #: β >= 0: a cut across a concave crease costs 1 / (1 + β w), so boundaries move onto creases
    beta: float = 10.0
    #: radians in (0, π] at which a crease counts fully
    crease_angle: float = np.pi / 4
    #: dual rings a boundary may move (>= 0): the cut moves boundaries and never relabels a
    #: far-away region with look-alike features
    band: int = 6
    #: alpha-expansion cycles (>= 1, or -1: until no expansion lowers the energy)
    cycles: int = EXPANSION_CYCLES
    #: the alpha-expansion's solver, one of :data:`GRAPHCUT_ENGINES` (the same labels)
    engine: str = "scipy"

    def __post_init__(self):
        if not self.smoothness >= 0 or not self.beta >= 0:
            raise ParameterError(f"graph cut smoothness and beta must be >= 0, got {self.smoothness!r}, {self.beta!r}")
        if not 0 < self.crease_angle <= np.pi:
            raise ParameterError(f"graph cut crease_angle must be in (0, π], got {self.crease_angle!r}")
        if not (isinstance(self.band, (int, np.integer)) and self.band >= 0):
            raise ParameterError(f"graph cut band must be an integer >= 0, got {self.band!r}")
        if not (isinstance(self.cycles, (int, np.integer)) and (self.cycles >= 1 or self.cycles == -1)):
            raise ParameterError("graph cut cycles must be an integer >= 1, or -1 (until converged), "
                                 f"got {self.cycles!r}")
        if self.engine not in GRAPHCUT_ENGINES:
            raise ParameterError(f"graph cut engine must be one of {GRAPHCUT_ENGINES}, got {self.engine!r}")


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


@dataclass(frozen=True)
class SegmentOptions:
    """How a segmentation is made, besides k, the field counts and how the batch is built.

    Build one and pass it to :func:`torchakvf.segment` (or
    :func:`torchakvf.parts.segment_each_k`, the corpus task, the evaluation, the bench), or
    pass its field names as keywords there: ``ta.segment(batch, k=6, seed=1)`` is
    ``ta.segment(batch, k=6, options=SegmentOptions(seed=1))``. :meth:`replace` gives a copy with
    some fields changed.
    """

    #: width of the connecting region, in cosine-distance units, >= 0. 0 (default): plain
    #: segmentation into k parts; > 0: part discovery, faces whose two closest parts differ by
    #: less than eps at the barycenter get label -1
    eps: float = 0.0
    #: seeds the untangling's random starts and k-means' seeding, per mesh, so a mesh gets the
    #: same parts in any batch
    seed: int = 0
    #: mesh-quality remedy of the Killing operator (:mod:`torchakvf.operators.killing`; "none"
    #: is the paper's operator); the default, "auto", decides per mesh: the paper's operator on
    #: well-shaped meshes, "smooth" on irregular ones (:mod:`torchakvf.operators.remedy_choice`)
    remedy: str = DEFAULT_REMEDY
    #: the eigensolver of the AKVFs: "auto" (each mesh's fastest), "lanczos", "krylov" or
    #: "lobpcg" (:func:`torchakvf.fields.akvf.akvf`)
    solver: str = "auto"
    #: solve each batch's AKVFs as one batch, as on an accelerator (True), or one mesh at a time
    #: (False); None: the device's way (one at a time on the CPU, as one elsewhere; see
    #: :class:`~torchakvf.solvers.AKVFSolver`). Labels agree either way up to round-off.
    batched: bool | None = None
    #: the segmentation method, one of :data:`METHODS`; default :data:`DEFAULT_METHOD`
    method: str = DEFAULT_METHOD
    #: the merge cost of method "merge" (:class:`MergeWeights`; None: the default weights)
    merge: MergeWeights = field(default_factory=MergeWeights)
    #: the over-segmentation method "merge" merges (:class:`OverSegmentation`; None: the default)
    overseg: OverSegmentation = field(default_factory=OverSegmentation)
    #: method "merge": a second merge of the same pieces, kept where its flattest boundary is
    #: much more concave (:class:`ConcaveChoice`: the hand-set cost, ratio 3, floor 0.05);
    #: None: the first merge's parts alone
    merge_choice: ConcaveChoice | None = field(default_factory=ConcaveChoice)
    #: method "merge": the graph cut that re-decides the boundaries after the merge; on by
    #: default (it scored better on every cross-validation fold); None (or False) = off. Given
    #: True / False / a :class:`GraphCut`, stored as a GraphCut or None. The paper mode never cuts
    graphcut: GraphCut | None = field(default_factory=GraphCut)
    #: k-means++ restarts per clustering, >= 1 (the lowest cost is kept). None: the method's
    #: :data:`KMEANS_RESTARTS_BY_METHOD`, resolved on construction (the field then holds the int)
    kmeans_restarts: int | None = None
    #: Lloyd iterations per precision phase of each clustering, >= 1 (:data:`KMEANS_MAX_ITER`)
    kmeans_max_iter: int = KMEANS_MAX_ITER
    #: k-means restarts of a mesh's rounds after its first, the last of them started from its
    #: previous round's clusters, >= 0. 0 (default): every round from scratch, so a mesh's parts
    #: at k do not depend on the other k's asked for it
    kmeans_seeded_restarts: int = 0
    #: random starts of the untangling besides the identity, >= 0
    #: (:data:`SEGMENT_UNTANGLE_RESTARTS`)
    untangle_restarts: int = SEGMENT_UNTANGLE_RESTARTS
    #: how labels are read from the clustering, one of :data:`BOUNDARIES`; "isoline" gives
    #: smooth boundaries
    boundary: str = "isoline"
    #: connected pieces of a part below this fraction of the area (in [0, 1]) are removed
    #: (merged into a neighbour, or made connecting region with eps > 0); at k parts the floor
    #: is at most :data:`PART_FLOOR_OF_MEAN` / k, so that k parts fit
    min_part_fraction: float = MIN_PART_FRACTION
    #: also return each mesh cut along its part boundaries (:class:`~torchakvf.parts.RefinedMesh`)
    refine: bool = True
    #: whether kmeans_restarts was given (None resolves anew in :meth:`replace`)
    _kmeans_restarts_given: bool = field(default=False, init=False, repr=False, compare=False)

    def __post_init__(self):
        if self.boundary not in BOUNDARIES:
            raise ParameterError(f"boundary must be one of {BOUNDARIES}, got {self.boundary!r}")
        if self.solver not in SOLVERS:
            raise ParameterError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if self.method not in METHODS:
            raise ParameterError(f"method must be one of {METHODS}, got {self.method!r}")
        if not (self.eps >= 0):
            raise ParameterError(f"eps must be >= 0, got {self.eps!r}")
        if self.merge is None:
            object.__setattr__(self, "merge", MergeWeights())
        if not isinstance(self.merge, MergeWeights):
            raise ParameterError(f"merge must be a MergeWeights, got {self.merge!r}")
        if self.overseg is None:
            object.__setattr__(self, "overseg", OverSegmentation())
        if not isinstance(self.overseg, OverSegmentation):
            raise ParameterError(f"overseg must be an OverSegmentation, got {self.overseg!r}")
        if self.merge_choice is not None and not isinstance(self.merge_choice, ConcaveChoice):
            raise ParameterError(f"merge_choice must be a ConcaveChoice or None, got {self.merge_choice!r}")
        object.__setattr__(self, "graphcut", graphcut_option(self.graphcut))
        object.__setattr__(self, "_kmeans_restarts_given", self.kmeans_restarts is not None)
        if self.kmeans_restarts is None:
            object.__setattr__(self, "kmeans_restarts", KMEANS_RESTARTS_BY_METHOD[self.method])
        if not is_int(self.kmeans_restarts, 1):
            raise ParameterError(f"kmeans_restarts must be an integer >= 1, got {self.kmeans_restarts!r}")
        object.__setattr__(self, "kmeans_restarts", int(self.kmeans_restarts))
        if not is_int(self.kmeans_max_iter, 1):
            raise ParameterError(f"kmeans_max_iter must be an integer >= 1, got {self.kmeans_max_iter!r}")
        if not is_int(self.kmeans_seeded_restarts, 0):
            raise ParameterError(f"kmeans_seeded_restarts must be an integer >= 0, "
                                 f"got {self.kmeans_seeded_restarts!r}")

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The option names (the keywords :func:`torchakvf.segment` takes as overrides)."""
        return tuple(f.name for f in dataclass_fields(cls) if f.init)

    def replace(self, **changes) -> "SegmentOptions":
        """A copy with ``changes`` (option names) applied; an unknown name is a ParameterError
        naming the valid ones. kmeans_restarts left to its default follows a new method."""
        unknown = sorted(set(changes) - set(self.names()))
        if unknown:
            raise ParameterError(f"unknown segmentation option(s) {', '.join(unknown)}; "
                                 f"the options are: {', '.join(self.names())}")
        if not changes:
            return self
        values = {name: getattr(self, name) for name in self.names()}
        if not self._kmeans_restarts_given:
            values["kmeans_restarts"] = None
        values.update(changes)
        return SegmentOptions(**values)

    @property
    def merges_parts(self) -> bool:
        """Whether parts are merged: method "merge" on plain segmentations (eps = 0; part
        discovery keeps the paper's k clusters)."""
        return self.method == "merge" and self.eps == 0

    @property
    def merge_min_k(self) -> int:
        """The k below which k's are over-segmented alike (``overseg.min_k`` when parts are
        merged, else 1: every k its own fields and clusters)."""
        return int(self.overseg.min_k) if self.merges_parts else 1

    def merge_record(self) -> dict:
        """{field: value} of the merge weights and the over-segmentation in one flat dict, in
        :data:`MERGE_RECORD_FIELDS` order: how settings files, manifests and a segmentation's
        params record them."""
        return {name: getattr(self.overseg if name in OVERSEG_FIELDS else self.merge, name)
                for name in MERGE_RECORD_FIELDS}

    def recorded(self) -> dict:
        """{option name: value} as records keep the options: every option but ``overseg``,
        whose fields are inside ``merge`` (:meth:`merge_record`, a dict), so that a record of
        the same settings reads the same; ``merge_choice`` as :meth:`choice_record` (a dict or
        None)."""
        return {name: self.merge_record() if name == "merge" else
                self.choice_record() if name == "merge_choice" else getattr(self, name)
                for name in self.names() if name != "overseg"}

    def choice_record(self) -> dict | None:
        """:meth:`ConcaveChoice.record` of ``merge_choice`` (None where off)."""
        return None if self.merge_choice is None else self.merge_choice.record()


def segment_options(options: SegmentOptions | None = None, **overrides) -> SegmentOptions:
    """``options`` (default: ``SegmentOptions()``) with ``overrides`` (option names) applied: what
    every function taking ``options=None, **overrides`` makes of them."""
    if options is None:
        options = SegmentOptions()
    elif not isinstance(options, SegmentOptions):
        raise ParameterError(f"options must be a SegmentOptions, got {type(options).__name__}")
    return options.replace(**overrides)


__all__ = ["SegmentOptions", "MergeWeights", "OverSegmentation", "ConcaveChoice", "GraphCut", "LEARNED_WEIGHTS",
           "LEARNED_FIELDS",
           "MERGE_RECORD_FIELDS", "OVERSEG_FIELDS", "read_merge_weights", "merge_weights_record", "is_int",
           "segment_options", "graphcut_option", "METHODS",
           "DEFAULT_METHOD", "BOUNDARIES", "DEFAULT_REMEDY", "SEGMENT_UNTANGLE_RESTARTS",
           "KMEANS_RESTARTS_BY_METHOD", "KMEANS_MAX_ITER", "FIELDS_PER_PART", "FIELDS_STEP", "FIELD_COUNT_RANGE",
           "SPARE_FIELDS", "CLUSTER_GAP", "MIN_PART_FRACTION", "PART_FLOOR_OF_MEAN", "EXPANSION_CYCLES",
           "GRAPHCUT_ENGINES"]
