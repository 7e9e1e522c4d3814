"""Fields on meshes: AKVFs (eigenpairs + Whitney vectors) and their untangling."""
from .whitney import whitney_face_vectors, face_norms
from .akvf import AKVFResult, akvf, as_batch
from .untangle import UntangledFields, untangle

__all__ = ["whitney_face_vectors", "face_norms", "AKVFResult", "akvf", "as_batch", "UntangledFields", "untangle"]
