"""Resume: which inputs a run can skip because the output folder already holds their results.

A mesh is done only when its last manifest record says ``ok`` for the same task, parameters,
seed and version, for the same input *content* (size and sha256 of the file) and the same
stem, and every output file is still the one recorded (size and sha256). A file rewritten
since (by a run of other parameters killed before its manifest line), torn, or deleted is not
done, and is computed again.
"""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Sequence

from ..io.manifest import file_fingerprint, read_manifest
from .execute import Item
from .inputs import assign_stems

log = logging.getLogger("torchakvf.pipeline")


def _jsonable(obj):
    return json.loads(json.dumps(obj))


def _same_file(path: Path, recorded) -> bool:
    try:
        return isinstance(recorded, dict) and file_fingerprint(path) == recorded
    except OSError:
        return False


def is_done(record: dict | None, path: Path, stem: str, out_dir: Path, task, seed: int) -> bool:
    """Whether ``record`` (the input's last manifest record) proves its outputs current."""
    from .. import __version__

    if (record is None or record.get("status") != "ok" or record.get("stem") != stem
            or record.get("task") != task.name or record.get("params") != _jsonable(task.params)
            or record.get("seed") != seed or record.get("version") != __version__):
        return False
    if not _same_file(path, record.get("input")):
        log.info("%s: the input changed since it was recorded; computing it again", path)
        return False
    outputs = record.get("outputs")
    expected = task.output_paths(out_dir, stem)
    if not isinstance(outputs, dict) or set(outputs) != {p.name for p in expected}:
        return False
    for p in expected:
        if not _same_file(p, outputs[p.name]):
            if p.exists():
                log.info("%s: not the file this run's manifest recorded (stale or torn); "
                         "computing %s again", p, path)
            return False
    return True


def prepare(paths: Sequence[Path], out_dir: Path, task, *, seed: int = 0, resume: bool = True
            ) -> tuple[list[Item], list[Item]]:
    """(items to run, items skipped as already done) for ``paths``; stems are resolved against
    the folder's manifest whether or not ``resume`` (so no run overwrites another input's).

    A task with a ``done_already(item) -> bool`` hook (called for every input, with its stem)
    says itself which inputs are done, from its own output files, instead of the manifest:
    evaluation, whose outputs accumulate per (mesh, k) across runs and protocols."""
    out_dir = Path(out_dir)
    previous = read_manifest(out_dir)
    unique: dict[str, Path] = {}
    for p in map(Path, paths):
        unique.setdefault(str(p.resolve()), p)   # one input once, however often it is named
    paths = list(unique.values())
    stems = assign_stems(paths, previous)
    todo, skipped = [], []
    for p, stem in zip(paths, stems):
        key = str(p.resolve())
        old = previous.get(key)
        own = getattr(task, "done_already", None)
        if own is not None:
            done = own(Item(p, key, stem, None)) and resume
        else:
            done = resume and is_done(old, p, stem, out_dir, task, seed)
        if done:
            skipped.append(Item(p, key, stem, (old or {}).get("faces")))
        else:
            todo.append(Item(p, key, stem, None))
    return todo, skipped


__all__ = ["prepare", "is_done"]
