"""Writers of small OFF meshes, .seg label files and a tiny corpus for the tests (the writers do
not use torchakvf; the corpus takes its shapes from ``torchakvf.shapes``)."""
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


def write_small_corpus(root: Path, degenerate_face: bool = False) -> Path:
    """ico.off, ell.off, sub/dumb.off (320-492 faces) and broken.off (garbage bytes) under root.

    degenerate_face : insert a repeated-index face as input face 100 of ell.off (dropped by
    cleaning, so per-face outputs must still have the file's face count).
    """
    from torchakvf import shapes

    root = Path(root)
    ico = shapes.icosphere(2)
    write_off(root / "ico.off", ico.vertices, ico.faces)
    ell = shapes.ellipsoid(level=2)
    faces = np.insert(ell.faces, 100, [[0, 0, 1]], axis=0) if degenerate_face else ell.faces
    write_off(root / "ell.off", ell.vertices, faces)
    dumb = shapes.dumbbell(n_around=18)
    write_off(root / "sub" / "dumb.off", dumb.vertices, dumb.faces)
    (root / "broken.off").write_bytes(b"\x00\x9f garbage \xff" * 20)
    return root


def off_text(vertices, faces, header_inline: bool = False) -> str:
    """An ASCII OFF file's text: a comment line after the ``OFF`` line, or the counts on the
    ``OFF`` line itself when ``header_inline``; coordinates round-trip exactly."""
    head = f"OFF {len(vertices)} {len(faces)} 0\n" if header_inline else \
        f"OFF\n# a comment line\n{len(vertices)} {len(faces)} 0\n"
    body = "".join(f"{float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in vertices)
    body += "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    return head + body
