"""Fields on meshes: AKVFs (eigenpairs + Whitney vectors) and their untangling."""
from .whitney import whitney_face_vectors, face_norms
from .akvf import AKVFResult, akvf, as_batch

__all__ = ["whitney_face_vectors", "face_norms", "AKVFResult", "akvf", "as_batch"]
