"""Reading meshes and writing results."""
from .load import FORMATS, load_mesh, mesh_format
from .outputs import atomic_write_bytes, write_npz, write_ply, write_seg
from .results import OUTPUT_FORMATS, safe_stem, write_segmentation

__all__ = ["FORMATS", "load_mesh", "mesh_format", "atomic_write_bytes", "write_npz", "write_ply",
           "write_seg", "OUTPUT_FORMATS", "safe_stem", "write_segmentation"]
