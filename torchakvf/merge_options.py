"""Options of method "merge": :class:`MergeWeights`, the merge cost, whose defaults are learned and
read from the package's weights file (parts/merge_weights.json, written by
experiments/segmentation/train_merge.py), and :class:`OverSegmentation`, the over-segmentation it merges.
Both are held by :class:`~torchakvf.options.SegmentOptions` (``merge``, ``overseg``).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from dataclasses import fields as dataclass_fields
from importlib.resources import files
from pathlib import Path
from types import MappingProxyType

import numpy as np

from .errors import ParameterError, TorchAKVFError


class MovedOptionError(ParameterError, AttributeError):
    """An over-segmentation setting read from :class:`MergeWeights`: a ParameterError naming where
    it lives now, and an AttributeError, so that ``hasattr`` and ``getattr`` with a default see
    no such attribute."""


def is_int(value, minimum: int) -> bool:
    """Whether value is a Python or numpy integer (not a bool) of at least ``minimum``."""
    return (isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
            and value >= minimum)


def read_merge_weights(path) -> dict[str, float]:
    """{MergeWeights field: value} of a learned-weights file, the format experiments/segmentation/train_merge.py
    writes (:func:`merge_weights_record`): {"trained_on": what it was fitted on, "merge_weights":
    {field: number}}. A file that is not one is a one-line error naming it."""
    try:
        record = json.loads((Path(path) if isinstance(path, str) else path).read_text())
        values = record["merge_weights"]
        return {str(name): float(value) for name, value in values.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise TorchAKVFError(f"{path}: not a merge weights file ({type(exc).__name__}: {exc})") from None


def merge_weights_record(values: dict, trained_on: str) -> dict:
    """What a learned-weights file holds (:func:`read_merge_weights` reads it back): ``values``
    {MergeWeights field: number}, every one a field whose default the file sets
    (:data:`LEARNED_FIELDS`), and a line saying what they were fitted on."""
    if set(values) != set(LEARNED_FIELDS):
        raise ParameterError(f"merge weights file fields must be {', '.join(LEARNED_FIELDS)}, got {', '.join(values)}")
    return dict(trained_on=str(trained_on), merge_weights={name: float(values[name]) for name in LEARNED_FIELDS})


#: The :class:`MergeWeights` fields the learned-weights file sets: the pair terms' weights, the
#: intercept and the Rand exponent (``crease_angle`` is fixed beforehand, not fitted).
LEARNED_FIELDS = ("symmetry", "concavity", "convexity", "cut", "part_size", "size_ratio", "short_cut", "thickness",
                  "thin", "centricity", "sight", "sight_excess", "size", "intercept", "rand_gamma")
#: The learned merge weights, package data written by experiments/segmentation/train_merge.py, read once here:
#: the defaults of :class:`MergeWeights` (a read-only mapping; floats are immutable).
LEARNED_WEIGHTS = MappingProxyType(read_merge_weights(files(__package__) / "parts" / "merge_weights.json"))


@dataclass(frozen=True)
class OverSegmentation:
    """The over-segmentation that method "merge" merges down to k parts
    (:mod:`torchakvf.parts.merge`): k-means into k' = ceil(ratio max(k, min_k)) clusters, at
    most max(k, min_k) + extra_max, cut along concave creases. Chosen by cross-validation
    (see docs/design.md); not fitted with the merge weights, so kept apart from them."""

    #: over-segmentation factor k' = ceil(ratio k), >= 1: the merge can only join pieces, and
    #: with 5 per part fewer of them straddle a smooth junction (a leg and its body, a fin) than
    #: with 3 (chosen held out over 3-6: docs/design.md, "The merge method")
    ratio: float = 5.0
    #: at most this many clusters beyond k (None: ceil(ratio k) at every k): 32 lets the ratio
    #: act up to k = 8, and keeps a mesh asking for many parts from asking for 5k clusters
    extra_max: int | None = 32
    #: a k below this is over-segmented as this k is (its fields and clusters those of min_k),
    #: so the small k's of a mesh share one untangling and one k-means, merged down to each k;
    #: 1: every k its own. 8 scored better than 1 (see docs/design.md)
    min_k: int = 8
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
    #: a crease patch of at least the small-piece floor that k-means cut into pieces all below
    #: it is one piece (:func:`~torchakvf.parts.creases.unite_patch_fragments`): a thin part
    #: delimited by creases (a leg, a spoke, a fin) is kept for the merge, not absorbed piece by
    #: piece (docs/design.md, "Creases")
    unite_fragments: bool = True
    #: True: the crease bands also cut each k-means piece they cross into the patches of its own
    #: faces, not only where they enclose a patch of the whole surface. On a shape with a hole
    #: the crease round a hub on a bored disc, or a pipe's junction, encloses none (the bore's
    #: wall joins the two sides past it), and a piece across it reaches the merge whole. Better on
    #: mechanical shapes, worse on the PSB and organic ones, so off by default (docs/design.md,
    #: "Creases")
    crease_per_piece: bool = False

    def __post_init__(self):
        if not self.ratio >= 1:
            raise ParameterError(f"over-segmentation ratio must be >= 1, got {self.ratio!r}")
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
        if not isinstance(self.unite_fragments, bool):
            raise ParameterError(f"unite_fragments must be True or False, got {self.unite_fragments!r}")
        if not isinstance(self.crease_per_piece, bool):
            raise ParameterError(f"crease_per_piece must be True or False, got {self.crease_per_piece!r}")


@dataclass(frozen=True)
class MergeWeights:
    """Weights of the merge cost (:mod:`torchakvf.parts.merge`); the over-segmentation it merges
    is an :class:`OverSegmentation`. Every weight is dimensionless; those of terms whose sign is
    learned (:attr:`SIGNED`) may be negative, the others are >= 0.

    The default is a learned merge decision, read from the package's weights file
    (:data:`LEARNED_WEIGHTS`): the weights of the pair terms
    (:func:`~torchakvf.parts.merge_terms.pair_terms`) and ``intercept`` are a logistic regression
    of "the two adjacent parts lie in one part people cut" on the 15 labelled PSB categories
    (experiments/segmentation/train_merge.py), and the cost is the expected change of the Rand disagreement
    with the size exponent ``rand_gamma`` chosen by leave-one-category-out (see
    docs/design.md). ``MergeWeights.hand_set()`` gives the hand-set cost (symmetry 1,
    concavity 16, convexity 4, boundary share 0.25, no size terms, the weighted sum as cost)."""

    #: weight of 1 - cos between the parts' mean unit feature rows (two parts moved by the same
    #: fields are one symmetric part cut in two)
    symmetry: float = LEARNED_WEIGHTS["symmetry"]
    #: weight of the length-weighted mean concave bending along the shared boundary (the minima
    #: rule: a boundary on smooth or convex surface is a poor cut)
    concavity: float = LEARNED_WEIGHTS["concavity"]
    #: weight of the smaller part's share of the whole surface (0: off)
    size: float = LEARNED_WEIGHTS["size"]
    #: weight of the smaller part's area relative to the target part size A / k (0: off)
    part_size: float = LEARNED_WEIGHTS["part_size"]
    #: weight of the length-weighted mean convex bending along the boundary (a sharp ridge is
    #: also a cut people make, e.g. on mechanical parts)
    convexity: float = LEARNED_WEIGHTS["convexity"]
    #: weight of the boundary share 1 - L_ij / min(P_i, P_j) (a part mostly enclosed by its
    #: neighbour is cheap to merge into it)
    cut: float = LEARNED_WEIGHTS["cut"]
    #: radians in (0, π] at which a crease's bending counts fully (π: linear in the angle)
    crease_angle: float = math.pi
    #: weight of log(A_max / A_min), the two parts' size ratio (> 0: a small part is kept off a
    #: large one, as a protrusion off a body)
    size_ratio: float = LEARNED_WEIGHTS["size_ratio"]
    #: weight of log(L_ij / sqrt(A_min)), the shared boundary against the smaller part's size
    #: (the short-cut rule; < 0: a short cut is a good one, merging across it costs more)
    short_cut: float = LEARNED_WEIGHTS["short_cut"]
    #: weight of |log(t_i / t_j)|, t a part's mean shape diameter (a thin fin or leg off a thick
    #: body); != 0 here or in ``thin`` computes the thickness of every mesh (igl rays)
    thickness: float = LEARNED_WEIGHTS["thickness"]
    #: weight of log(t_small / t_median), the smaller part's thickness against the mesh's median
    thin: float = LEARNED_WEIGHTS["thin"]
    #: weight of (d_small - d_large) / R, the smaller part's distance from the surface's centroid
    #: beyond the larger one's, R the RMS radius (a protrusion lies further out)
    centricity: float = LEARNED_WEIGHTS["centricity"]
    #: weight of the share of the segments between the two parts' samples that leave the solid
    #: (two pieces of one convex part see each other through its inside; a plate does not see
    #: the plate it meets at a right angle, a leg the body); != 0 casts those segments on every
    #: mesh (:mod:`torchakvf.parts.sightlines`, igl rays)
    sight: float = LEARNED_WEIGHTS["sight"]
    #: weight of that share less the mean of the two parts' own (the segments between a part's
    #: own samples): a hollow part's inside and outside never see each other
    sight_excess: float = LEARNED_WEIGHTS["sight_excess"]

    #: the cost's form. None: the weighted sum s above is the cost. A number γ >= 0: s is read as
    #: the log-odds that the two parts lie in one part people cut, p = sigmoid(intercept - s),
    #: and the cost is the expected change of the Rand disagreement, (A_i A_j / A^2)^γ (1 - 2p)
    #: (γ = 1; 0 orders pairs as s does)
    rand_gamma: float | None = LEARNED_WEIGHTS["rand_gamma"]
    #: the log-odds of "one part" where s = 0 (read only with ``rand_gamma``)
    intercept: float = LEARNED_WEIGHTS["intercept"]
    #: a part whose flatness |Σ a_f n_f| / Σ a_f (its vector area over its area: 1 for a plane
    #: patch, 0 for a closed surface) exceeds this is a sheet, a face of a solid rather than a
    #: part of it (the floor of a socket, the end face of a tube): where the merge by cost
    #: leaves one among the k parts, the pieces are merged again with the pairs that hold a
    #: sheet first (:func:`~torchakvf.parts.merge.greedy_merge`). In (0, 1]; None: off. Chosen
    #: on the procedural corpus and the PSB (docs/design.md, "Flat parts (sheets)")
    sheet_flatness: float | None = 0.9

    #: terms whose weight may be negative (their sign is learned, not known beforehand)
    SIGNED = ("convexity", "cut", "short_cut", "thin", "centricity", "sight_excess", "intercept")

    def __new__(cls, *args, **changes):
        # The over-segmentation's settings are an OverSegmentation's: name the new spelling
        # rather than fail on an unknown keyword (also for dataclasses.replace and hand_set).
        moved = [name for name in changes if name in OVERSEG_FIELDS]
        if moved:
            spelled = ", ".join(f"{name}={changes[name]!r}" for name in moved)
            raise ParameterError(f"{', '.join(moved)} moved to OverSegmentation: "
                                 f"SegmentOptions(overseg=OverSegmentation({spelled}))")
        return super().__new__(cls)

    def __getattr__(self, name):
        if name in OVERSEG_FIELDS:
            raise MovedOptionError(f"{name} moved to OverSegmentation: read SegmentOptions.overseg.{name}")
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @classmethod
    def hand_set(cls, **changes) -> "MergeWeights":
        """The hand-set cost chosen by cross-validation before the learned one (the weighted
        sum of symmetry 1, concavity 16, convexity 4, boundary share 0.25), with ``changes``."""
        base = dict(symmetry=1.0, concavity=16.0, part_size=0.0, convexity=4.0, cut=0.25, size_ratio=0.0,
                    short_cut=0.0, thickness=0.0, thin=0.0, centricity=0.0, sight=0.0, sight_excess=0.0,
                    rand_gamma=None, intercept=0.0)
        return cls(**{**base, **changes})

    def __post_init__(self):
        for name in ("symmetry", "concavity", "size", "part_size", "size_ratio", "thickness", "sight"):
            if not getattr(self, name) >= 0:
                raise ParameterError(f"merge weight {name} must be >= 0, got {getattr(self, name)!r}")
        for name in self.SIGNED:
            if not np.isfinite(getattr(self, name)):
                raise ParameterError(f"merge weight {name} must be a finite number, got {getattr(self, name)!r}")
        if self.rand_gamma is not None and not self.rand_gamma >= 0:
            raise ParameterError(f"rand_gamma must be None or >= 0, got {self.rand_gamma!r}")
        if self.sheet_flatness is not None and not 0 < self.sheet_flatness <= 1:
            raise ParameterError(f"sheet_flatness must be None or in (0, 1], got {self.sheet_flatness!r}")
        if not 0 < self.crease_angle <= math.pi:
            raise ParameterError(f"crease_angle must be in (0, π] radians, got {self.crease_angle!r}")


@dataclass(frozen=True)
class ConcaveChoice:
    """A second merge of method "merge": the same over-segmentation merged again with
    ``weights``, whose parts replace the first merge's where the flattest boundary between two
    of them bends concavely more than ``floor`` and more than ``ratio`` times the first merge's
    flattest (:mod:`torchakvf.parts.concave_choice`). The learned cost keeps a wheel's rim in
    arcs where the hand-set one cuts at the spokes' fillets; ratio and floor were chosen
    leave-one-group-out over the PSB's 15 labelled categories and the procedural corpus's 15
    families (docs/design.md, "A second merge")."""

    #: the second merge's cost (default: :meth:`MergeWeights.hand_set`, concavity and symmetry)
    weights: MergeWeights = field(default_factory=lambda: MergeWeights.hand_set())
    #: how many times as concave (mean dihedral over π along the flattest boundary) the second
    #: merge's flattest boundary must be, >= 1
    ratio: float = 3.0
    #: and at least this concave, in [0, 1) (0.05: about 9° on average along it)
    floor: float = 0.05

    #: weights of terms the second merge does not compute (rays, part sums): they must be 0
    MESH_TERMS = ("thickness", "thin", "centricity", "sight", "sight_excess")

    def __post_init__(self):
        if not isinstance(self.weights, MergeWeights):
            raise ParameterError(f"ConcaveChoice weights must be a MergeWeights, got {self.weights!r}")
        read = [name for name in self.MESH_TERMS if getattr(self.weights, name) != 0]
        if read:
            raise ParameterError(f"ConcaveChoice weights may not read {', '.join(read)} (the second merge "
                                 "reads the region graph's boundary and feature terms only); set them to 0")
        if not (np.isfinite(self.ratio) and self.ratio >= 1):
            raise ParameterError(f"ConcaveChoice ratio must be a number >= 1, got {self.ratio!r}")
        if not (0 <= self.floor < 1):
            raise ParameterError(f"ConcaveChoice floor must be in [0, 1), got {self.floor!r}")

    def record(self) -> dict:
        """{ratio, floor, weights: {MergeWeights field: value}}: how records keep it."""
        w = {f.name: getattr(self.weights, f.name) for f in dataclass_fields(MergeWeights)}
        return dict(ratio=float(self.ratio), floor=float(self.floor), weights=w)


#: The fields of :class:`OverSegmentation` (a MergeWeights given one names the new spelling).
OVERSEG_FIELDS = tuple(f.name for f in dataclass_fields(OverSegmentation))
#: The merge weights' and over-segmentation's fields as records keep them, in one flat "merge"
#: entry in this order (:meth:`SegmentOptions.recorded`): settings files, manifests and a
#: segmentation's params are file formats, and a record of the same settings must read the same.
MERGE_RECORD_FIELDS = ("symmetry", "concavity", "size", "ratio", "part_size", "convexity", "cut", "crease_angle",
                       "extra_max", "min_k", "size_ratio", "short_cut", "thickness", "thin", "crease_split",
                       "crease_rings", "crease_concave", "centricity", "rand_gamma", "intercept", "sight",
                       "sight_excess", "unite_fragments", "crease_per_piece", "sheet_flatness")


__all__ = ["MergeWeights", "OverSegmentation", "ConcaveChoice", "LEARNED_WEIGHTS", "LEARNED_FIELDS", "OVERSEG_FIELDS",
           "MERGE_RECORD_FIELDS", "MovedOptionError", "read_merge_weights", "merge_weights_record", "is_int"]
