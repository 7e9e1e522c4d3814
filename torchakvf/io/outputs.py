"""Writing results: .seg (PSB format), .npz, face-coloured PLY. Every write is atomic."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from ..errors import TorchAKVFError


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, then rename it into place, so an
    interrupted run never leaves a half-written file under the final name."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:
        raise TorchAKVFError(f"{path}: cannot write output ({exc.strerror or exc})") from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_seg(path, labels: np.ndarray) -> None:
    """PSB .seg: one integer label per line, one line per face of the input file."""
    labels = np.asarray(labels).astype(np.int64).reshape(-1)
    atomic_write_bytes(path, ("\n".join(map(str, labels.tolist())) + "\n").encode())


def write_npz(path, **arrays) -> None:
    """An uncompressed-safe .npz of plain arrays (loadable with ``allow_pickle=False``)."""
    import io

    buf = io.BytesIO()
    clean = {}
    for key, val in arrays.items():
        arr = np.asarray(val)
        if arr.dtype == object:
            raise TorchAKVFError(f"{path}: npz field {key!r} is not a plain array")
        clean[key] = arr
    np.savez_compressed(buf, **clean)
    atomic_write_bytes(path, buf.getvalue())


def label_colors(labels: np.ndarray) -> np.ndarray:
    """[F, 4] uint8 RGBA per label (-1, the connecting region, is light grey)."""
    import matplotlib

    cmap = matplotlib.colormaps["tab20"]
    labels = np.asarray(labels)
    rgba = (np.array([cmap(int(v) % 20) for v in range(max(int(labels.max()) + 1, 1))]) * 255).astype(np.uint8)
    out = np.full((len(labels), 4), 200, dtype=np.uint8)
    ok = labels >= 0
    out[ok] = rgba[labels[ok]]
    out[:, 3] = 255
    return out


def write_ply(path, vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray) -> None:
    """Binary PLY with per-face colours and a per-face ``label`` property (for MeshLab)."""
    vertices = np.asarray(vertices, dtype="<f4")
    faces = np.asarray(faces, dtype="<i4")
    colors = label_colors(labels)
    header = (f"ply\nformat binary_little_endian 1.0\ncomment torchakvf segmentation\n"
              f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty int label\n"
              "end_header\n").encode()
    rec = np.zeros(len(faces), dtype=[("n", "u1"), ("v", "<i4", 3), ("rgb", "u1", 3), ("label", "<i4")])
    rec["n"], rec["v"], rec["rgb"], rec["label"] = 3, faces, colors[:, :3], np.asarray(labels)
    atomic_write_bytes(path, header + vertices.tobytes() + rec.tobytes())
