"""Meshes: one mesh as given (:class:`Mesh`), cleaned (:func:`clean_mesh`), and many packed (:class:`MeshBatch`)."""
from .mesh import Mesh
from .clean import CleanMesh, clean_mesh, face_areas, face_cross_products
from .batch import MeshBatch, owner_index

__all__ = ["Mesh", "CleanMesh", "clean_mesh", "face_areas", "face_cross_products", "MeshBatch", "owner_index"]
