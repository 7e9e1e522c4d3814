"""Parts: labels with smooth boundaries, connecting regions, symmetry generators.

:func:`segment` (one k per mesh) and :func:`segment_each_k` (every k of every mesh from one
solve) are the entry points (:mod:`torchakvf.parts.segment`); their options are a
:class:`~torchakvf.options.SegmentOptions`."""
from ..options import DEFAULT_REMEDY, GraphCut, MergeWeights, OverSegmentation, SegmentOptions
from .boundaries import RefinedMesh
from .field_counts import default_n_fields
from .k_auto import AutoSegmentation, KChoice
from .results import MeshSegmentation, Segmentation
from .segment import SegmentEachK, SymmetryGenerator, segment, segment_each_k
from .segmenter import Segmenter

__all__ = ["DEFAULT_REMEDY", "MeshSegmentation", "Segmentation", "SegmentEachK", "SymmetryGenerator",
           "SegmentOptions", "MergeWeights", "OverSegmentation", "GraphCut", "default_n_fields", "segment",
           "segment_each_k", "RefinedMesh", "Segmenter", "AutoSegmentation", "KChoice"]
