"""Binary glTF (GLB) of a segmentation: one scene node per part, each with the part's colour
(what Blender and three.js users expect: parts can be selected, hidden and moved one by one)."""
from __future__ import annotations

import numpy as np

from ..errors import TorchAKVFError
from .outputs import atomic_write_bytes, label_colors

#: Node name of the connecting region (label -1); parts are ``part_<p>``.
CONNECTING_REGION = "connecting_region"


def part_node_name(label: int) -> str:
    """Scene node (and geometry) name of part ``label`` (-1: the connecting region)."""
    return CONNECTING_REGION if label < 0 else f"part_{int(label)}"


def glb_bytes(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray) -> bytes:
    """The GLB file content: one node per distinct label, the faces of that label with only
    the vertices they use, a PBR material whose base colour is the part colour of the PLY/PNG
    outputs (:func:`~torchakvf.io.outputs.label_colors`; grey for the connecting region).

    vertices : [V, 3]; faces : [F, 3] int; labels : [F] int (-1 = connecting region).
    """
    import trimesh

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    labels = np.asarray(labels).astype(np.int64)
    if f.ndim != 2 or f.shape[1] != 3 or v.ndim != 2 or v.shape[1] != 3:
        raise TorchAKVFError(f"GLB export needs vertices [V, 3] and faces [F, 3], got "
                             f"{v.shape} and {f.shape}")
    if labels.shape != (len(f),):
        raise TorchAKVFError(f"GLB export: {labels.shape[0] if labels.ndim else 0} labels for "
                             f"{len(f)} faces (one label per face expected)")
    colors = label_colors(labels)
    scene = trimesh.Scene()
    for lab in np.unique(labels):
        sel = np.flatnonzero(labels == lab)
        used, local = np.unique(f[sel], return_inverse=True)
        rgba = colors[sel[0]]
        material = trimesh.visual.material.PBRMaterial(
            name=part_node_name(lab), baseColorFactor=[int(c) for c in rgba],
            metallicFactor=0.0, roughnessFactor=0.8, doubleSided=True)
        mesh = trimesh.Trimesh(v[used], local.reshape(-1, 3), process=False,
                               visual=trimesh.visual.TextureVisuals(material=material))
        name = part_node_name(lab)
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    return scene.export(file_type="glb")


def write_glb(path, vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray) -> None:
    """Write :func:`glb_bytes` to ``path`` atomically (a temporary file renamed into place)."""
    atomic_write_bytes(path, glb_bytes(vertices, faces, labels))


__all__ = ["write_glb", "glb_bytes", "part_node_name", "CONNECTING_REGION"]
