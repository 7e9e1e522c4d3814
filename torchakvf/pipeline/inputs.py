"""The inputs of a corpus run: which files (:func:`discover_inputs`) and the output stem of each
(:func:`assign_stems`, unique within the run and against the folder's earlier runs)."""
from __future__ import annotations

import glob
import hashlib
import os
import re
from pathlib import Path
from typing import Sequence

from ..errors import TorchAKVFError
from ..io import FORMATS, safe_stem

_GLOB_CHARS = re.compile(r"[*?\[]")


def is_mesh_file(path: Path) -> bool:
    """Whether the name ends in a readable mesh extension (optionally .gz)."""
    name = path.name.lower()
    if name.endswith(".gz"):
        name = name[:-3]
    return "." in name and name.rsplit(".", 1)[-1] in FORMATS


def discover_inputs(inputs, *, exclude: str | os.PathLike | None = None) -> list[Path]:
    """Mesh files named by ``inputs``: files, folders (searched recursively for
    .off/.obj/.ply/.stl, optionally .gz) and glob patterns (``**`` allowed).

    ``inputs`` is a list of strings (or an argparse namespace with ``.inputs``). Files under
    ``exclude`` (the output folder) are skipped when scanning folders and globs. Raises
    :class:`TorchAKVFError` naming the argument for a missing file, a file that is not a mesh,
    or a folder/pattern without any mesh file. The result is deduplicated, in argument order
    (folders and globs sorted).
    """
    if hasattr(inputs, "inputs"):
        inputs = inputs.inputs
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    inputs = [str(i) for i in inputs]
    if not inputs:
        raise TorchAKVFError("no input given: name mesh files, folders or glob patterns")
    ex = Path(exclude).resolve() if exclude is not None else None

    def excluded(p: Path) -> bool:
        if ex is None:
            return False
        rp = p.resolve()
        return rp == ex or ex in rp.parents

    found: list[Path] = []
    for arg in inputs:
        p = Path(arg).expanduser()
        if p.is_dir():
            hits = sorted(q for q in p.rglob("*") if q.is_file() and is_mesh_file(q) and not excluded(q))
            if not hits:
                raise TorchAKVFError(f"{arg}: folder holds no mesh files (.{', .'.join(FORMATS)}, optionally .gz)")
            found += hits
        elif p.is_file():
            if not is_mesh_file(p):
                raise TorchAKVFError(f"{arg}: not a mesh file name (expected .{', .'.join(FORMATS)}, "
                                     "optionally .gz)")
            found.append(p)
        elif _GLOB_CHARS.search(arg):
            hits = sorted(Path(q) for q in glob.glob(os.path.expanduser(arg), recursive=True))
            hits = [q for q in hits if q.is_file() and is_mesh_file(q) and not excluded(q)]
            if not hits:
                raise TorchAKVFError(f"{arg}: pattern matches no mesh files")
            found += hits
        elif p.exists():
            raise TorchAKVFError(f"{arg}: not a regular file or folder")
        else:
            raise TorchAKVFError(f"{arg}: file not found")
    seen, out = set(), []
    for q in found:
        key = q.resolve()
        if key not in seen:
            seen.add(key)
            out.append(q)
    return out


def assign_stems(paths: Sequence[Path], previous: dict[str, dict] | None = None) -> list[str]:
    """Output stems (``safe_stem``), unique within the run and against the output folder's
    earlier runs (``previous``: the manifest's last record per input path).

    A path keeps the stem its manifest record gave it; a stem recorded for another input (an
    earlier run's ``a/x.off`` when this run has ``b/x.off``) is taken, so no run overwrites
    another input's outputs; colliding stems get ``-<8 hex of sha1(resolved path)>``.
    """
    previous = previous or {}
    keys = [str(p.resolve()) for p in paths]
    stems: list[str | None] = [None] * len(paths)
    taken: set[str] = set()
    for i, k in enumerate(keys):
        old = previous.get(k, {}).get("stem")
        if old and old == safe_stem(old) and old not in taken:
            stems[i] = old
            taken.add(old)
    in_run = set(keys)
    taken |= {str(r.get("stem")) for k, r in previous.items() if k not in in_run and r.get("stem")}
    base = [safe_stem(p.name) for p in paths]
    counts: dict[str, int] = {}
    for i, b in enumerate(base):
        if stems[i] is None:
            counts[b] = counts.get(b, 0) + 1
    for i, b in enumerate(base):
        if stems[i] is not None:
            continue
        stem = b
        if counts[b] > 1 or stem in taken:
            stem = f"{b}-{hashlib.sha1(keys[i].encode()).hexdigest()[:8]}"
        while stem in taken:  # astronomically unlikely; keeps the promise anyway
            stem = f"{stem}-{hashlib.sha1(stem.encode()).hexdigest()[:4]}"
        stems[i] = stem
        taken.add(stem)
    return stems  # type: ignore[return-value]


__all__ = ["is_mesh_file", "discover_inputs", "assign_stems"]
