"""Meshes: one mesh as given (:class:`Mesh`), cleaned (:func:`clean_mesh`), and many packed (:class:`MeshBatch`)."""
from .batch import MeshBatch, owner_index
from .clean import CleanMesh, clean_mesh, face_areas, face_cross_products
from .mesh import Mesh

__all__ = ["Mesh", "CleanMesh", "clean_mesh", "face_areas", "face_cross_products", "MeshBatch", "owner_index"]
