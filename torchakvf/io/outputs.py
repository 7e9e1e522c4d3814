"""Writing results: .seg (PSB format), .npz, face-coloured PLY, OFF meshes. Every write is atomic."""
from __future__ import annotations

import errno
import gzip
import os
import tempfile
from pathlib import Path

import numpy as np

from ..errors import ParameterError, TorchAKVFError

#: Suffix of every temporary file a write leaves while it runs (``.<name>.<random>.torchakvf.tmp``):
#: a run killed by SIGKILL leaves them behind, and the next run in that folder removes them
#: (:func:`remove_stale_temp_files`).
TEMP_SUFFIX = ".torchakvf.tmp"


#: errno values that mean the output folder cannot take more data: no mesh is to blame, so a
#: corpus run stops at once (finished meshes stay recorded) instead of failing every later mesh.
_NO_ROOM = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG}


class OutputSpaceError(TorchAKVFError):
    """An output could not be written because its file system is full (or read-only)."""


def _write_error(path: Path, exc: OSError) -> TorchAKVFError:
    text = f"{path}: cannot write output ({exc.strerror or exc})"
    if exc.errno in _NO_ROOM:
        return OutputSpaceError(text + "; free space and run again: finished meshes are kept")
    return TorchAKVFError(text)


def _umask() -> int:
    """The process umask, read without changing it where Linux tells it (/proc)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    old = os.umask(0o022)   # elsewhere: set and restore (not thread-safe, but only a fallback)
    os.umask(old)
    return old


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to a temporary file beside ``path``, then rename it into place, so an
    interrupted run never leaves a half-written file under the final name. The file gets the
    mode a plain ``open(path, "w")`` would (0666 less the umask), not mkstemp's 0600."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TEMP_SUFFIX)
    except OSError as exc:
        raise _write_error(path, exc) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), 0o666 & ~_umask())
            fh.write(data)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if isinstance(exc, OSError):
            raise _write_error(path, exc) from None
        raise


def remove_stale_temp_files(folder: str | os.PathLike, older_than_s: float = 0.0) -> int:
    """Delete the temporary files (:data:`TEMP_SUFFIX`) a killed run left in ``folder``; only
    those older than ``older_than_s`` seconds (a folder other runs may be writing into, like a
    shared cache, needs an age). Returns how many were removed."""
    import time

    removed = 0
    now = time.time()
    for tmp in Path(folder).glob(f".*{TEMP_SUFFIX}"):
        try:
            if now - tmp.stat().st_mtime >= older_than_s:
                tmp.unlink()
                removed += 1
        except OSError:
            pass
    return removed


#: Widest label range written through a table of the labels' decimal strings.
_TABLE_SPAN = 4096


def _seg_text(labels: np.ndarray) -> bytes:
    """The ``.seg`` bytes of int64 labels [F]: one decimal integer per line.

    Part labels span a few dozen values, so each one's string is made once and the rows are
    picked from that table (object-array indexing): 4x faster than ``str`` per face on PSB-sized
    label arrays (1.9 against 0.5 ms at 20,000 faces), byte for byte the same text."""
    lo, hi = int(labels.min()), int(labels.max())
    if hi - lo <= _TABLE_SPAN:
        table = np.array([str(v) for v in range(lo, hi + 1)], dtype=object)
        words = table[labels - lo].tolist()
    else:
        words = map(str, labels.tolist())
    return ("\n".join(words) + "\n").encode("ascii")


def write_seg(path, labels) -> Path:
    """Write per-face labels as a PSB ``.seg`` file (one integer per line, one line per face of
    the input file), atomically; a name ending in ``.gz`` is written gzip-compressed
    (byte-identical for identical labels). Returns the path.

    Raises :class:`ParameterError` unless ``labels`` is a non-empty 1-D integer array.
    """
    arr = np.asarray(labels)
    if arr.ndim != 1 or arr.size == 0:
        raise ParameterError(f"{path}: labels must be a non-empty 1-D array, got shape {list(arr.shape)}")
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.integer):
        raise ParameterError(f"{path}: labels must be integers, got dtype {arr.dtype}")
    path = Path(path)
    text = _seg_text(arr.astype(np.int64))
    if path.name.endswith(".gz"):
        text = gzip.compress(text, mtime=0)
    atomic_write_bytes(path, text)
    return path


def write_off(path, vertices, faces) -> Path:
    """Write a triangle mesh as ASCII OFF (vertices [V, 3], faces [F, 3] 0-based), atomically;
    each coordinate as the shortest decimal that reads back to the same float64, so
    :func:`~torchakvf.io.load_mesh` returns the same arrays; a name ending in ``.gz`` is
    written gzip-compressed. Returns the path.

    Raises :class:`ParameterError` unless vertices are [V, 3] finite and faces [F, 3] integers
    in range.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise ParameterError(f"{path}: vertices must be finite with shape [V, 3], got shape {list(v.shape)}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer) or len(f) == 0 \
            or f.min() < 0 or f.max() >= len(v):
        raise ParameterError(f"{path}: faces must be [F, 3] integers in 0..{len(v) - 1}, got shape {list(f.shape)}")
    lines = [f"OFF\n{len(v)} {len(f)} 0\n"]
    lines += [f"{a!r} {b!r} {c!r}\n" for a, b, c in v.tolist()]
    lines += [f"3 {a} {b} {c}\n" for a, b, c in f.tolist()]
    path = Path(path)
    data = "".join(lines).encode("ascii")
    atomic_write_bytes(path, gzip.compress(data, mtime=0) if path.name.endswith(".gz") else data)
    return path


#: zlib level of the .npz files: per-face float32 columns (features, descriptors) barely compress
#: at any level; level 1 writes them in 60 % of the default level's time (6), 1-2 % larger
NPZ_COMPRESSLEVEL = 1


def write_npz(path, **arrays) -> None:
    """A compressed .npz of plain arrays (loadable with ``allow_pickle=False``), as
    ``numpy.savez_compressed`` writes one but at zlib level :data:`NPZ_COMPRESSLEVEL`."""
    import io
    import zipfile

    clean = {}
    for key, val in arrays.items():
        arr = np.asarray(val)
        if arr.dtype == object:
            raise TorchAKVFError(f"{path}: npz field {key!r} is not a plain array")
        clean[key] = arr
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=NPZ_COMPRESSLEVEL) as zf:
        for key, arr in clean.items():
            with zf.open(f"{key}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, arr, allow_pickle=False)
    atomic_write_bytes(path, buf.getvalue())


def label_colors(labels: np.ndarray) -> np.ndarray:
    """[F, 4] uint8 RGBA per label (-1, the connecting region, is light grey)."""
    import matplotlib

    cmap = matplotlib.colormaps["tab20"]
    labels = np.asarray(labels)
    rgba = (np.asarray(cmap(np.arange(max(int(labels.max()) + 1, 1)) % 20)) * 255).astype(np.uint8)
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
