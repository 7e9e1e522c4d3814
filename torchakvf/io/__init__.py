"""Reading meshes and writing results."""
from .glb import write_glb
from .load import FORMATS, load_mesh, mesh_format, read_mesh_bytes
from .outputs import (
                      TEMP_SUFFIX,
                      OutputSpaceError,
                      atomic_write_bytes,
                      remove_stale_temp_files,
                      write_npz,
                      write_off,
                      write_ply,
                      write_seg,
)
from .peek import peek_face_count
from .results import OUTPUT_FORMATS, safe_stem, write_segmentation

__all__ = ["FORMATS", "load_mesh", "mesh_format", "read_mesh_bytes", "peek_face_count", "atomic_write_bytes",
           "remove_stale_temp_files", "TEMP_SUFFIX", "OutputSpaceError", "write_npz", "write_off", "write_ply",
           "write_seg", "write_glb", "OUTPUT_FORMATS", "safe_stem", "write_segmentation"]
