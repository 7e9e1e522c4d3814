"""Per-mesh result files of a segmentation: <stem>.seg, .npz, .ply, .png, .glb."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import TorchAKVFError
from .outputs import write_npz, write_ply, write_seg

OUTPUT_FORMATS = ("seg", "npz", "ply", "png", "glb")


def safe_stem(name: str) -> str:
    """A file-name stem derived from an input path that cannot escape the output folder:
    the base name without mesh/.gz extensions, with anything but [A-Za-z0-9._-] replaced."""
    base = Path(str(name)).name
    for ext in (".gz", ".off", ".obj", ".ply", ".stl", ".glb", ".gltf"):
        if base.lower().endswith(ext):
            base = base[: -len(ext)]
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", base).lstrip(".")
    return stem or "mesh"


def flat_params(params: dict) -> dict:
    """``params`` with each dict value spread into ``name_key`` entries (a -k auto choice's
    ``k_auto`` {rule, ks, costs} becomes ``k_auto_rule``, ``k_auto_ks``, ``k_auto_costs``), so
    every value is a plain array in an .npz."""
    out = {}
    for name, value in params.items():
        if isinstance(value, dict):
            out.update({f"{name}_{key}": v for key, v in flat_params(value).items()})
        else:
            out[name] = value
    return out


def write_segmentation(seg, vertices: np.ndarray, faces: np.ndarray, out_dir, stem: str,
                       formats=OUTPUT_FORMATS, face_vectors: np.ndarray | None = None) -> dict:
    """Write one :class:`~torchakvf.parts.MeshSegmentation` of the input mesh (vertices [V, 3],
    faces [F, 3] as in the file). Returns {format: path}.

    face_vectors : optional [F, n, 3] untangled vectors, for generator arrows in the PNG.
    """
    out_dir = Path(out_dir)
    if stem != safe_stem(stem):
        raise TorchAKVFError(f"output stem {stem!r} is not a plain file name")
    written = {}
    for fmt in formats:
        if fmt not in OUTPUT_FORMATS:
            raise TorchAKVFError(f"unknown output format {fmt!r} (expected {OUTPUT_FORMATS})")
    if "seg" in formats:
        written["seg"] = out_dir / f"{stem}.seg"
        write_seg(written["seg"], seg.labels)
    if "npz" in formats:
        written["npz"] = out_dir / f"{stem}.npz"
        gens = [(p, g.field, g.share, g.energy) for p, gs in enumerate(seg.generators) for g in gs]
        gens = np.array(gens, dtype=np.float64).reshape(-1, 4)
        params = {f"param_{k}": np.asarray(v) for k, v in flat_params(seg.params).items()}
        write_npz(written["npz"], labels=seg.labels, features=seg.features.astype(np.float32),
                  eigenvalues=seg.eigenvalues, generators=gens, cost=np.float64(seg.cost), **params)
    if "ply" in formats:
        written["ply"] = out_dir / f"{stem}.ply"
        write_ply(written["ply"], vertices, faces, seg.labels)
    if "glb" in formats:
        from .glb import write_glb

        written["glb"] = out_dir / f"{stem}.glb"
        write_glb(written["glb"], vertices, faces, seg.labels)
    if "png" in formats:
        from .render import render_png

        written["png"] = out_dir / f"{stem}.png"
        flow = None if face_vectors is None else (face_vectors, seg.generators)
        render_png(written["png"], vertices, faces, seg.labels,
                   title=f"{stem}  k={seg.k}" + (f"  eps={seg.params.get('eps')}" if seg.params.get("eps") else ""),
                   flow=flow)
    return written
