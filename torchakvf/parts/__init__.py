"""Parts: labels with smooth boundaries, connecting regions, symmetry generators.

:func:`segment` (one k per mesh) and :func:`segment_each_k` (every k of every mesh from one
solve; :mod:`torchakvf.parts.engine`) are the entry points."""
from .boundaries import RefinedMesh
from .engine import DEFAULT_REMEDY, SegmentEachK, default_n_fields, segment_each_k
from .results import MeshSegmentation, Segmentation
from .segment import SymmetryGenerator, segment

__all__ = ["DEFAULT_REMEDY", "MeshSegmentation", "Segmentation", "SegmentEachK", "SymmetryGenerator",
           "default_n_fields", "segment", "segment_each_k", "RefinedMesh"]
