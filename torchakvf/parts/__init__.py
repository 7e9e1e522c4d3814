"""Parts: labels with smooth boundaries, connecting regions, symmetry generators."""
from .segment import (DEFAULT_REMEDY, MeshSegmentation, Segmentation, SymmetryGenerator,
                      default_n_fields, segment)
from .boundaries import RefinedMesh

__all__ = ["DEFAULT_REMEDY", "MeshSegmentation", "Segmentation", "SymmetryGenerator",
           "default_n_fields", "segment", "RefinedMesh"]
