"""Writers of small OFF meshes and .seg label files for the tests (independent of torchakvf)."""
from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np


def write_off(path: Path, vertices, faces, gz: bool = False) -> Path:
    """An ASCII OFF file (gzip-compressed when ``gz``); coordinates round-trip exactly."""
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [" ".join(repr(float(c)) for c in v) for v in vertices]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in faces]
    data = ("\n".join(lines) + "\n").encode()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(gzip.compress(data) if gz else data)
    return path


def write_seg(path: Path, labels) -> Path:
    """One integer label per line, the benchmark's .seg format."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(map(str, np.asarray(labels).tolist())) + "\n")
    return path
