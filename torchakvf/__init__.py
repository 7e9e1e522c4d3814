"""torchakvf: intrinsically symmetric parts of triangle meshes, batched on CPU or CUDA.

Pipeline (one folder a stage): io -> mesh -> operators -> solvers -> fields -> cluster ->
parts -> io outputs. The public API is plain functions on a :class:`MeshBatch` or a
:class:`Mesh`.
"""
from . import data
from .errors import ConvergenceWarning, MeshError, ParameterError, SolverError, TorchAKVFError
from .fields import AKVFResult, UntangledFields, akvf, untangle
from .io import load_mesh
from .mesh import CleanMesh, Mesh, MeshBatch, clean_mesh
from .options import SegmentOptions
from .parts import AutoSegmentation, KChoice, MeshSegmentation, Segmentation, Segmenter, segment
from .solvers import AKVFSolver

__version__ = "0.1.0"

__all__ = ["TorchAKVFError", "MeshError", "SolverError", "ParameterError", "ConvergenceWarning", "load_mesh", "Mesh",
           "CleanMesh", "clean_mesh", "MeshBatch", "AKVFResult", "AKVFSolver", "akvf", "UntangledFields", "untangle",
           "SegmentOptions", "Segmentation", "MeshSegmentation", "segment", "Segmenter", "AutoSegmentation",
           "KChoice", "data", "__version__"]
