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
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from dataclasses import fields as dataclass_fields

import numpy as np

from .errors import ParameterError
from .fields.akvf import SOLVERS
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
#: its over-segmentation into 3k is merged afterwards (see docs/design.md).
KMEANS_RESTARTS_BY_METHOD = {"paper": 5, "merge": 3}
#: Lloyd iterations per precision phase of each clustering (the function's own default is 100):
#: 15 scores as 100 does; the restarts still moving by then creep by a few faces per iteration.
KMEANS_MAX_ITER = 15
#: Untangled fields per part, by method: "paper" the paper's N = 2k; "merge" 3k, since its
#: k-means makes k' = 3k clusters from them (see docs/design.md).
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


def is_int(value, minimum: int) -> bool:
    """Whether value is a Python or numpy integer (not a bool) of at least ``minimum``."""
    return (isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
            and value >= minimum)


@dataclass(frozen=True)
class MergeWeights:
    """Weights of the merge cost (:mod:`torchakvf.parts.merge`) and the over-segmentation
    k' = ceil(ratio max(k, min_k)). Every weight is dimensionless; those of terms whose sign is
    learned (:attr:`SIGNED`) may be negative, the others are >= 0.

    The default is a learned merge decision: the weights of the pair terms
    (:func:`~torchakvf.parts.merge_terms.pair_terms`) and ``intercept`` are a logistic regression
    of "the two adjacent parts lie in one part people cut" on the 15 labelled PSB categories
    (experiments/segmentation/train_merge.py), and the cost is the expected change of the Rand disagreement
    with the size exponent ``rand_gamma`` chosen by leave-one-category-out (see
    docs/design.md). ``MergeWeights.hand_set()`` gives the hand-set cost (symmetry 1,
    concavity 16, convexity 4, boundary share 0.25, no size terms, the weighted sum as cost)."""

    #: weight of 1 - cos between the parts' mean unit feature rows (two parts moved by the same
    #: fields are one symmetric part cut in two)
    symmetry: float = 4.099
    #: weight of the length-weighted mean concave bending along the shared boundary (the minima
    #: rule: a boundary on smooth or convex surface is a poor cut)
    concavity: float = 28.69
    #: weight of the smaller part's share of the whole surface (0: off)
    size: float = 0.0
    #: over-segmentation factor k' = ceil(ratio k), >= 1: 3 leaves the merge room to choose
    ratio: float = 3.0
    #: weight of the smaller part's area relative to the target part size A / k (0: off)
    part_size: float = 0.7441
    #: weight of the length-weighted mean convex bending along the boundary (a sharp ridge is
    #: also a cut people make, e.g. on mechanical parts)
    convexity: float = -0.206
    #: weight of the boundary share 1 - L_ij / min(P_i, P_j) (a part mostly enclosed by its
    #: neighbour is cheap to merge into it)
    cut: float = -0.4207
    #: radians in (0, π] at which a crease's bending counts fully (π: linear in the angle)
    crease_angle: float = math.pi
    #: at most this many clusters beyond k (None: ceil(ratio k) at every k); 16 keeps the merge
    #: method's time near the paper mode's on meshes asking for many parts, at the same score
    extra_max: int | None = 16
    #: a k below this is over-segmented as this k is (its fields and clusters those of min_k),
    #: so the small k's of a mesh share one untangling and one k-means, merged down to each k;
    #: 1: every k its own. 8 scored better than 1 (see docs/design.md)
    min_k: int = 8
    #: weight of log(A_max / A_min), the two parts' size ratio (> 0: a small part is kept off a
    #: large one, as a protrusion off a body)
    size_ratio: float = 0.3394
    #: weight of log(L_ij / sqrt(A_min)), the shared boundary against the smaller part's size
    #: (the short-cut rule; < 0: a short cut is a good one, merging across it costs more)
    short_cut: float = -0.2115
    #: weight of |log(t_i / t_j)|, t a part's mean shape diameter (a thin fin or leg off a thick
    #: body); != 0 here or in ``thin`` computes the thickness of every mesh (igl rays)
    thickness: float = 1.718
    #: weight of log(t_small / t_median), the smaller part's thickness against the mesh's median
    thin: float = -0.1241
    #: radians in (0, π): the over-segmentation is also cut along creases where the surface
    #: normal turns by more than this within ``crease_rings`` dual rings
    #: (:mod:`torchakvf.parts.creases`), so the merge can keep parts apart that only a crease
    #: separates (coaxial cylinders, a slab and its legs); None: not cut. Chosen with
    #: ``crease_concave`` leave-one-group-out over the PSB categories and the procedural
    #: corpus's families (docs/design.md, "Creases").
    crease_split: float | None = math.radians(60.0)
    #: dual rings (>= 1) over which ``crease_split`` measures a crease (a crease rounded over up
    #: to about this many triangles is found)
    crease_rings: int = 3
    #: only concave creases cut the over-segmentation (people cut where the surface turns
    #: inward, the minima rule; a convex crease is usually the edge of one part: a box leg's)
    crease_concave: bool = True
    #: weight of (d_small - d_large) / R, the smaller part's distance from the surface's centroid
    #: beyond the larger one's, R the RMS radius (a protrusion lies further out)
    centricity: float = -0.1763

    #: the cost's form. None: the weighted sum s above is the cost. A number γ >= 0: s is read as
    #: the log-odds that the two parts lie in one part people cut, p = sigmoid(intercept - s),
    #: and the cost is the expected change of the Rand disagreement, (A_i A_j / A^2)^γ (1 - 2p)
    #: (γ = 1; 0 orders pairs as s does)
    rand_gamma: float | None = 0.5
    #: the log-odds of "one part" where s = 0 (read only with ``rand_gamma``)
    intercept: float = 3.038

    #: terms whose weight may be negative (their sign is learned, not known beforehand)
    SIGNED = ("convexity", "cut", "short_cut", "thin", "centricity", "intercept")

    @classmethod
    def hand_set(cls, **changes) -> "MergeWeights":
        """The hand-set cost chosen by cross-validation before the learned one (the weighted
        sum of symmetry 1, concavity 16, convexity 4, boundary share 0.25), with ``changes``."""
        base = dict(symmetry=1.0, concavity=16.0, part_size=0.0, convexity=4.0, cut=0.25, size_ratio=0.0,
                    short_cut=0.0, thickness=0.0, thin=0.0, centricity=0.0, rand_gamma=None, intercept=0.0)
        return cls(**{**base, **changes})

    def __post_init__(self):
        for name in ("symmetry", "concavity", "size", "part_size", "size_ratio", "thickness"):
            if not getattr(self, name) >= 0:
                raise ParameterError(f"merge weight {name} must be >= 0, got {getattr(self, name)!r}")
        for name in self.SIGNED:
            if not np.isfinite(getattr(self, name)):
                raise ParameterError(f"merge weight {name} must be a finite number, got {getattr(self, name)!r}")
        if self.rand_gamma is not None and not self.rand_gamma >= 0:
            raise ParameterError(f"rand_gamma must be None or >= 0, got {self.rand_gamma!r}")
        if not self.ratio >= 1:
            raise ParameterError(f"over-segmentation ratio must be >= 1, got {self.ratio!r}")
        if not 0 < self.crease_angle <= math.pi:
            raise ParameterError(f"crease_angle must be in (0, π] radians, got {self.crease_angle!r}")
        if self.extra_max is not None and not is_int(self.extra_max, 0):
            raise ParameterError(f"extra_max must be None or an integer >= 0, got {self.extra_max!r}")
        if not is_int(self.min_k, 1):
            raise ParameterError(f"min_k must be an integer >= 1, got {self.min_k!r}")
        if self.crease_split is not None and not 0 < self.crease_split < math.pi:
            raise ParameterError(f"crease_split must be None or in (0, π) radians, got {self.crease_split!r}")
        if not is_int(self.crease_rings, 1):
            raise ParameterError(f"crease_rings must be an integer >= 1, got {self.crease_rings!r}")
        if not isinstance(self.crease_concave, bool):
            raise ParameterError(f"crease_concave must be True or False, got {self.crease_concave!r}")


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
            raise ParameterError(f"graph cut cycles must be an integer >= 1, or -1 (until converged), got {self.cycles!r}")
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
    #: the merge cost and over-segmentation of method "merge" (:class:`MergeWeights`; None: the
    #: default weights)
    merge: MergeWeights = field(default_factory=MergeWeights)
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
        """The k below which k's are over-segmented alike (``merge.min_k`` when parts are
        merged, else 1: every k its own fields and clusters)."""
        return int(self.merge.min_k) if self.merges_parts else 1


def segment_options(options: SegmentOptions | None = None, **overrides) -> SegmentOptions:
    """``options`` (default: ``SegmentOptions()``) with ``overrides`` (option names) applied: what
    every function taking ``options=None, **overrides`` makes of them."""
    if options is None:
        options = SegmentOptions()
    elif not isinstance(options, SegmentOptions):
        raise ParameterError(f"options must be a SegmentOptions, got {type(options).__name__}")
    return options.replace(**overrides)


__all__ = ["SegmentOptions", "MergeWeights", "GraphCut", "segment_options", "graphcut_option", "METHODS",
           "DEFAULT_METHOD", "BOUNDARIES", "DEFAULT_REMEDY", "SEGMENT_UNTANGLE_RESTARTS",
           "KMEANS_RESTARTS_BY_METHOD", "KMEANS_MAX_ITER", "FIELDS_PER_PART", "FIELDS_STEP", "FIELD_COUNT_RANGE",
           "SPARE_FIELDS", "CLUSTER_GAP", "MIN_PART_FRACTION", "PART_FLOOR_OF_MEAN", "EXPANSION_CYCLES", "GRAPHCUT_ENGINES"]
