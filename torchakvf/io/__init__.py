"""Reading meshes and writing results."""
from .load import FORMATS, load_mesh, mesh_format

__all__ = ["FORMATS", "load_mesh", "mesh_format"]
