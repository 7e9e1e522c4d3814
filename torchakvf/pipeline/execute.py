"""One batch of a corpus run: load, compute and write it into per-mesh manifest records
(:func:`run_batch`, shared by every executor; the batches are planned by :mod:`.batches`).

A task (see :mod:`.features`, :mod:`.segment_task`) is a small object with ``name``,
``params`` (a JSON-able dict), ``stages`` (the names of its timed compute stages),
``output_paths(out_dir, stem)``, ``process(items, device) -> (outputs, stage_seconds)`` and
``write(item, output, out_dir) -> written paths``. Optional hooks:

* ``check_size(path, faces)``: refuse a mesh up front (raise :class:`TorchAKVFError`), called
  with the header's face count before loading and with the exact count after;
* ``validate(item)``: per-mesh checks after loading and cleaning;
* ``cache_lookup(item, out_dir) -> bool`` / ``cache_store(item, written)``;
* ``manifest_fields(output) -> dict``: merged into the mesh's manifest record (e.g. whether
  its eigensolve converged).

Bugs are not bad meshes: an error of one mesh's *input* is recorded as ``failed`` and the run
goes on, but a programming error (:func:`~.parallel.is_programming_error`) propagates with its
traceback; so does a full output disk (:class:`~torchakvf.io.OutputSpaceError`, one line).
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..io import OutputSpaceError, load_mesh
from ..io.manifest import file_fingerprint
from ..mesh import clean_mesh
from .parallel import error_text, is_programming_error, map_batches

log = logging.getLogger("torchakvf.pipeline")


@dataclass
class Item:
    """One input mesh as the runner tracks it. ``mesh`` (as read) and ``clean`` are set only
    while its batch is processed."""

    path: Path
    key: str                  # resolved path: the manifest's identity of this input
    stem: str
    faces: int | None         # peeked face count (None: unknown)
    mesh: object = None
    clean: object = None
    seconds: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    @property
    def cost(self) -> int:
        return self.faces if self.faces is not None else 0


def base_record(item: Item, task, seed: int) -> dict:
    from .. import __version__

    rec = {"path": item.key, "stem": item.stem, "faces": item.faces, "status": None, "error": None,
           "seconds": dict(item.seconds), "seed": seed, "version": __version__, "task": task.name,
           "params": task.params}
    if "input" in item.extra:
        rec["input"] = item.extra["input"]
    return rec


def failed_record(item: Item, task, seed: int, error: str) -> dict:
    rec = base_record(item, task, seed)
    rec.update(status="failed", error=error)
    return rec


def _input_failure(exc: BaseException) -> str:
    """The manifest text of one mesh's failure; a programming error, or an output folder that
    is full, is no mesh's fault: re-raised, it ends the run."""
    if is_programming_error(exc) or isinstance(exc, OutputSpaceError):
        raise exc
    return error_text(exc)


def load_item(it: Item, task, out_dir: Path) -> bool:
    """Load, clean and check one item (True), or find it in the task's cache (False)."""
    t0 = time.perf_counter()
    try:
        it.extra["input"] = file_fingerprint(it.path)  # the content the outputs belong to
    except OSError:
        pass                                           # unreadable: load_mesh says why
    check = getattr(task, "check_size", None)
    if check is not None and it.faces is not None:
        check(it.path, it.faces)                       # before paying for the load
    lookup = getattr(task, "cache_lookup", None)
    if lookup is not None and lookup(it, out_dir):
        it.seconds = {"load": 0.0, "write": time.perf_counter() - t0}
        return False
    it.mesh = load_mesh(it.path)
    it.faces = it.mesh.n_faces
    if check is not None:
        check(it.path, it.faces)
    it.clean = clean_mesh(it.mesh)
    validate = getattr(task, "validate", None)
    if validate is not None:
        validate(it)
    it.seconds = {"load": time.perf_counter() - t0}
    return True


def output_record(rec: dict, task, out_dir: Path, stem: str) -> dict:
    """Adds each output's fingerprint (name: size, sha256), which resume checks."""
    rec["outputs"] = {p.name: file_fingerprint(p) for p in task.output_paths(out_dir, stem)}
    return rec


def process_batch(items: list[Item], task, out_dir: Path, device, seed: int) -> list[dict]:
    """Load, compute and write one batch; returns one manifest record per item (any order).

    A mesh that fails to load, or to write, gets its ``failed`` record here; an error of the
    batch's computation propagates (:func:`run_batch` then retries its halves).
    Self-contained (plain inputs and outputs) so any executor can map it over batches.
    """
    records: list[dict] = []
    ready: list[Item] = []
    for it in items:
        t0 = time.perf_counter()
        try:
            if load_item(it, task, out_dir):
                ready.append(it)
                continue
            rec = base_record(it, task, seed)
            rec.update(status="ok", cached=True)
            records.append(output_record(rec, task, out_dir, it.stem))
        except Exception as exc:  # noqa: BLE001 - a bad input is recorded, a bug re-raised
            error = _input_failure(exc)
            log.debug("load of %s failed", it.path, exc_info=True)
            it.seconds = {"load": time.perf_counter() - t0}
            records.append(failed_record(it, task, seed, error))
            it.mesh = it.clean = None
    if ready:
        records += _compute_and_write(ready, task, out_dir, device, seed)
    return records


def _compute_and_write(items: list[Item], task, out_dir: Path, device, seed: int) -> list[dict]:
    failure = None
    try:
        outputs, stage_s = task.process(items, device)
    except Exception as exc:  # noqa: BLE001
        if is_programming_error(exc):
            raise
        failure = exc
    if failure is not None:
        # Out of the except block, the traceback dropped: the failed batch's tensors are freed.
        failure.__traceback__ = None
        for it in items:
            it.mesh = it.clean = None
        _free_device_memory(device)
        raise failure
    total = sum(len(it.clean.faces) for it in items) or 1
    recs = []
    for it, out in zip(items, outputs):
        share = len(it.clean.faces) / total
        for stage in task.stages:
            it.seconds[stage] = stage_s.get(stage, 0.0) * share
        recs.append(write_item(it, out, task, out_dir, seed))
        it.mesh = it.clean = None
    return recs


def write_item(it: Item, out, task, out_dir: Path, seed: int) -> dict:
    """Write one computed mesh (``out``: what the task computed for it) and return its manifest
    record: ``ok`` with the outputs' fingerprints, or ``failed`` where writing failed."""
    t0 = time.perf_counter()
    try:
        written = task.write(it, out, out_dir)
        store = getattr(task, "cache_store", None)
        if store is not None:
            store(it, written)
        it.seconds["write"] = time.perf_counter() - t0
        rec = base_record(it, task, seed)
        rec.update(status="ok")
        fields = getattr(task, "manifest_fields", None)
        if fields is not None:
            rec.update(fields(out))
        return output_record(rec, task, out_dir, it.stem)
    except Exception as exc:  # noqa: BLE001
        error = _input_failure(exc)
        log.debug("writing %s failed", it.stem, exc_info=True)
        it.seconds["write"] = time.perf_counter() - t0
        return failed_record(it, task, seed, error)


def _free_device_memory(device) -> None:
    if str(device).startswith("cuda"):
        import torch

        torch.cuda.empty_cache()


def run_batch(items: list[Item], task, out_dir: Path, device, seed: int) -> list[dict]:
    """:func:`process_batch` through the shared split-and-retry of
    :func:`~.parallel.map_batches`: when the batch's computation fails, its halves are retried
    (bisection), so only the culprit fails and no finished mesh is lost. One record per item."""
    records: list[dict] = []
    for outcome in map_batches([items], process_batch, (task, out_dir, device, seed),
                               fatal=(OutputSpaceError,)):
        if outcome.split:
            log.warning("batch of %d meshes failed (%s); retrying its halves",
                        len(outcome.batch), outcome.error)
        elif outcome.error is not None:
            records.append(failed_record(outcome.batch[0], task, seed, outcome.error))
        else:
            records += outcome.result
    return records


__all__ = ["Item", "process_batch", "run_batch", "base_record", "failed_record", "load_item", "write_item"]
