"""Meshes: one mesh as given (:class:`Mesh`), cleaned (:func:`clean_mesh`), and many packed (:class:`MeshBatch`)."""
from .mesh import Mesh
from .clean import CleanMesh, clean_mesh, face_areas
from .batch import MeshBatch

__all__ = ["Mesh", "CleanMesh", "clean_mesh", "face_areas", "MeshBatch"]
