"""Fields on meshes: AKVFs (eigenpairs + Whitney vectors) and their untangling."""
from .akvf import AKVFResult, akvf, as_batch
from .untangle import UntangledFields, untangle
from .whitney import face_norms, whitney_face_vectors

__all__ = ["whitney_face_vectors", "face_norms", "AKVFResult", "akvf", "as_batch", "UntangledFields", "untangle"]
