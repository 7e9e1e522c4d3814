"""The inputs of a corpus run: which files (:func:`discover_inputs`) and the output stem of each
(:func:`assign_stems`, unique within the run and against the folder's earlier runs)."""
from __future__ import annotations

import glob
import hashlib
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from ..errors import TorchAKVFError
from ..io import FORMATS, safe_stem

_GLOB_CHARS = re.compile(r"[*?\[]")
log = logging.getLogger("torchakvf.pipeline")


def is_mesh_file(path: Path) -> bool:
    """Whether the name ends in a readable mesh extension (optionally .gz)."""
    name = path.name.lower()
    if name.endswith(".gz"):
        name = name[:-3]
    return "." in name and name.rsplit(".", 1)[-1] in FORMATS


@dataclass(frozen=True)
class SkippedFile:
    """A file a folder or pattern named that the run does not read, and why."""

    path: Path
    reason: str


def _extensions() -> str:
    return ", ".join("." + f for f in FORMATS) + " (optionally .gz)"


def scan_inputs(inputs, *, exclude: str | os.PathLike | None = None) -> tuple[list[Path], list[SkippedFile]]:
    """(the mesh files named by ``inputs``, every other file a folder or pattern holds, with
    the reason it is skipped); see :func:`discover_inputs`."""
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
    skipped: list[SkippedFile] = []

    def sort_out(arg: str, candidates, none_found: str) -> None:
        hits = []
        for q in candidates:
            if not q.is_file():
                continue
            if excluded(q):
                skipped.append(SkippedFile(q, "inside the output folder"))
            elif not is_mesh_file(q):
                skipped.append(SkippedFile(q, f"not a mesh file name (meshes are {_extensions()})"))
            else:
                hits.append(q)
        if not hits:
            raise TorchAKVFError(f"{arg}: {none_found} ({_extensions()})")
        found.extend(hits)

    for arg in inputs:
        p = Path(arg).expanduser()
        if p.is_dir():
            sort_out(arg, sorted(p.rglob("*")), "folder holds no mesh files")
        elif p.is_file():
            if not is_mesh_file(p):
                raise TorchAKVFError(f"{arg}: not a mesh file name (expected {_extensions()})")
            found.append(p)
        elif _GLOB_CHARS.search(arg):
            sort_out(arg, sorted(Path(q) for q in glob.glob(os.path.expanduser(arg), recursive=True)),
                     "pattern matches no mesh files")
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
    return out, skipped


def log_skipped(skipped: Sequence[SkippedFile]) -> None:
    """One log line per skipped file (the output folder's own files in one line)."""
    ours = [s for s in skipped if s.reason == "inside the output folder"]
    for s in skipped:
        if s.reason != "inside the output folder":
            log.warning("skipped %s: %s", s.path, s.reason)
    if ours:
        log.info("skipped %d files inside the output folder", len(ours))


def discover_inputs(inputs, *, exclude: str | os.PathLike | None = None,
                    on_skipped: Callable[[list[SkippedFile]], None] | None = log_skipped) -> list[Path]:
    """Mesh files named by ``inputs``: files, folders (searched recursively for the
    :data:`~torchakvf.io.FORMATS` extensions, optionally .gz) and glob patterns (``**`` allowed).

    ``inputs`` is a list of strings (or an argparse namespace with ``.inputs``). Files under
    ``exclude`` (the output folder) are skipped when scanning folders and globs. Every file a
    folder or pattern holds that is not read is passed to ``on_skipped`` with the reason
    (default: one log line each, :func:`log_skipped`; None: not reported). Raises
    :class:`TorchAKVFError` naming the argument for a missing file, a file that is not a mesh,
    or a folder/pattern without any mesh file. The result is deduplicated, in argument order
    (folders and globs sorted).
    """
    paths, skipped = scan_inputs(inputs, exclude=exclude)
    if skipped and on_skipped is not None:
        on_skipped(skipped)
    return paths


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


__all__ = ["is_mesh_file", "discover_inputs", "scan_inputs", "SkippedFile", "log_skipped", "assign_stems"]
