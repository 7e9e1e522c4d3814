"""The corpus runner under ``torchakvf segment`` and ``torchakvf features``: the run loop.

What it guarantees:

* **Streaming, batched by faces.** Inputs are peeked for their face count
  (:func:`torchakvf.io.peek_face_count`: the header, no parse), sorted by size so padding
  stays small, and grouped into batches whose face total stays under ``batch_faces`` (a mesh
  bigger than the budget is a batch of its own). Only one batch of meshes is in memory at a time.
* **Nothing is lost, nothing stale is kept.** Every output file is written atomically (temp
  file + rename); after a batch's files are in place, one ``manifest.jsonl`` line per mesh is
  appended and fsync'ed, with the size and sha256 of the input and of every output. Re-running
  skips a mesh only when its record matches this run's parameters and version, the input's
  content and every output file (:mod:`.resume`); an interrupt (Ctrl-C, SIGTERM, even SIGKILL)
  leaves every finished mesh usable, and the next run picks up where it stopped and removes
  the killed run's temporary files. One run at a time holds an output folder (``.lock``).
* **One bad mesh fails alone; a bug stops the run.** A mesh that cannot be loaded, cleaned or
  validated gets a ``failed`` line with its error; if a batch's computation raises, its halves
  are retried (bisection) so only the culprit fails (:mod:`.execute`). The run goes on; the
  summary and the exit code say how many failed. A programming error (TypeError, IndexError,
  ...) is no bad mesh: it ends the run with its traceback, the manifest flushed.

Manifest ``seconds``: ``load`` and ``write`` are measured per mesh; the compute stages run once
per batch and each mesh is charged the batch's stage time times its share of the batch's faces.
"""
from __future__ import annotations

import logging
import signal
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from ..devices import resolve_device
from ..errors import TorchAKVFError
from ..io import peek_face_count
from ..io.manifest import MANIFEST, ManifestWriter, read_manifest
from ..progress import progress as progress_report
from .batches import DEFAULT_BATCH_FACES, default_batch_faces, plan_batches
from .execute import Item, process_batch, run_batch
from .inputs import assign_stems, discover_inputs, is_mesh_file
from .outdir import OutputLock, check_output_dir
from .resume import prepare

log = logging.getLogger("torchakvf.pipeline")

#: A batch of more faces than this gets a line of its own before it starts (it takes minutes).
ANNOUNCE_FACES = 200_000


def peek_faces(path: Path) -> int | None:
    """The header's face count for planning; None where it cannot tell (the load then fails
    the mesh with the full reason)."""
    try:
        return peek_face_count(path)
    except TorchAKVFError:
        return None


@dataclass
class RunSummary:
    ok: int = 0
    failed: int = 0
    skipped: int = 0
    cached: int = 0
    elapsed: float = 0.0
    faces: int = 0
    manifest: Path | None = None
    failures: list = field(default_factory=list)     # (path, error)
    interrupted: bool = False
    timings: dict | None = None    # a batched run's stage seconds (OverlapTimes.record())

    @property
    def exit_code(self) -> int:
        return 0 if self.failed == 0 else 1

    def add(self, rec: dict) -> bool:
        """Count one manifest record; True when the mesh is done ("ok")."""
        if rec["status"] == "ok":
            self.ok += 1
            self.cached += bool(rec.get("cached"))
            self.faces += rec.get("faces") or 0
            return True
        self.failed += 1
        self.failures.append((rec["path"], rec["error"]))
        return False

    def line(self, name: str) -> str:
        rate = f", {self.faces / self.elapsed:,.0f} faces/s" if self.elapsed > 0 and self.faces else ""
        cached = f" ({self.cached} from cache)" if self.cached else ""
        return (f"torchakvf {name}: {self.ok} ok{cached}, {self.failed} failed, {self.skipped} skipped "
                f"(already done), {self.elapsed:.1f} s{rate}; manifest: {self.manifest}")


class _TermAsInterrupt:
    """Inside the block, SIGTERM raises KeyboardInterrupt (main thread only), so temp files are
    removed and the manifest is closed as for Ctrl-C."""

    def __enter__(self):
        self.old = None
        try:
            self.old = signal.signal(signal.SIGTERM, self._raise)
        except (ValueError, OSError):  # not the main thread
            self.old = None
        return self

    @staticmethod
    def _raise(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    def __exit__(self, *exc):
        if self.old is not None:
            signal.signal(signal.SIGTERM, self.old)
        return False


@dataclass
class RunPlan:
    """What a run will do, and where: shared by :func:`run_corpus` and the Ray runner."""

    out_dir: Path
    batches: list
    summary: RunSummary


def plan_run(paths: Iterable, out_dir: Path, task, *, batch_faces: int | None, device, seed: int,
             resume: bool, workers: int | None = None) -> RunPlan:
    """Resume check, size peek and batches of a run into ``out_dir`` (created, writable; the
    caller holds its :class:`OutputLock`). A task with a ``plan_batches(items, batch_faces,
    device=, workers=)`` hook cuts its own batches (evaluation: by how many k's a mesh needs);
    otherwise :func:`~.batches.plan_batches`."""
    batch_faces = int(batch_faces) if batch_faces is not None else default_batch_faces(device)
    if batch_faces < 1:
        raise TorchAKVFError(f"--batch-faces must be a positive integer, got {batch_faces}")
    todo, skipped = prepare(list(paths), out_dir, task, seed=seed, resume=resume)
    summary = RunSummary(skipped=len(skipped), manifest=out_dir / MANIFEST)
    if skipped:
        log.info("%s: %d meshes already done in %s, skipping them", task.name, len(skipped), out_dir)
    for it in todo:
        it.faces = peek_faces(it.path)
    planner = getattr(task, "plan_batches", None)
    batches = (plan_batches(todo, batch_faces) if planner is None
               else planner(todo, batch_faces, device=str(device), workers=workers))
    return RunPlan(out_dir, batches, summary)


@contextmanager
def recording(out_dir: Path, summary: RunSummary, start_bar: Callable):
    """(manifest writer, progress bar) of a run; inside, SIGTERM acts as Ctrl-C; on the way out
    (done, interrupted, failed) both are closed and an interrupt is noted in ``summary``."""
    writer = ManifestWriter(out_dir)
    bar = start_bar()
    try:
        with _TermAsInterrupt():
            yield writer, bar
    except KeyboardInterrupt:
        summary.interrupted = True
        raise
    finally:
        writer.close()
        bar.close()


def record_batch(records: list[dict], writer: ManifestWriter, summary: RunSummary, bar, name: str) -> None:
    """Append a batch's records to the manifest and count them; a failure gets its own line."""
    for rec in records:
        writer.append(rec)
        if not summary.add(rec):
            bar.write(f"torchakvf {name}: failed: {failure_text(rec['path'], rec['error'])}")


def failure_text(path, error: str) -> str:
    """A failure's error, prefixed by its input path unless the error names the file already."""
    return error if Path(path).name in error else f"{path}: {error}"


def run_corpus(paths: Iterable, out_dir, task, *, batch_faces: int | None = None, device="cpu",
               seed: int = 0, resume: bool = True, progress: bool | None = None,
               on_batch: Callable[[int, list[dict]], None] | None = None,
               workers: int | None = None) -> RunSummary:
    """Run ``task`` over mesh files ``paths`` into ``out_dir`` (see the module docstring).

    batch_faces : face budget per batch (default :data:`DEFAULT_BATCH_FACES` for the device)
    device : torch device the batched computation runs on
    seed : recorded in the manifest (the task's own params carry it into the computation)
    resume : skip meshes the manifest records as done with the same params (False: redo all)
    progress : False: report nothing; otherwise a bar on a terminal, log lines elsewhere
    on_batch : called after each batch's manifest lines are written, with the batch number
        and its records (tests use it to interrupt a run); on the overlapped path after each
        mesh's line, with the count of meshes done
    workers : processes of a batched run (:func:`overlapped`): this one solves, the others
        load, cut and write (default :func:`~.parallel.default_workers` of a batched run);
        otherwise processes running whole batches side by side, one thread each (default 1:
        this process; the task is pickled to them)

    Returns a :class:`RunSummary`; ``summary.exit_code`` is 0 when no mesh failed, else 1.
    KeyboardInterrupt propagates after the finished meshes are safely recorded; so does a
    programming error (with its traceback). Raises :class:`TorchAKVFError` (one line) when the
    folder is held by another run or the manifest cannot be written.
    """
    t_start = time.perf_counter()
    device = str(resolve_device(device))   # before any work: one line, not N failed meshes
    out_dir = check_output_dir(out_dir)
    with OutputLock(out_dir):
        plan = plan_run(paths, out_dir, task, batch_faces=batch_faces, device=device, seed=seed,
                        resume=resume, workers=workers)
        summary = plan.summary
        total_faces = sum(it.cost for b in plan.batches for it in b)
        start_bar = lambda: progress_report(total_faces, f"torchakvf {task.name}", "faces",  # noqa: E731
                                            enabled=progress is not False)
        try:
            with recording(out_dir, summary, start_bar) as (writer, bar):
                if overlapped(task, device):
                    _run_overlapped(plan, task, device, seed, workers, writer, bar, on_batch)
                elif workers is not None and int(workers) > 1:
                    _run_side_by_side(plan, task, device, seed, int(workers), writer, bar, on_batch)
                else:
                    _run_in_turn(plan, task, device, seed, writer, bar, on_batch)
        finally:
            summary.elapsed = time.perf_counter() - t_start
    return summary


def overlapped(task, device) -> bool:
    """Whether a run of ``task`` on ``device`` goes through the host/device overlap
    (:mod:`.batched_run`): the task can, and its batches are solved as one (``batched``, by
    default on every device but the CPU)."""
    from ..solvers.akvf_solver import batched_by_default
    from .batched_run import overlaps

    if not overlaps(task):
        return False
    opts = getattr(task, "options", None)
    b = opts.batched if opts is not None else getattr(task, "batched", None)
    return batched_by_default(device) if b is None else bool(b)


def _run_in_turn(plan: RunPlan, task, device, seed: int, writer, bar, on_batch) -> None:
    """The batches one after the other in this process: load, compute, write."""
    summary, n_meshes, done = plan.summary, sum(map(len, plan.batches)), 0
    for bno, batch in enumerate(plan.batches, 1):
        faces = sum(it.cost for it in batch)
        if faces > ANNOUNCE_FACES:
            bar.write(f"torchakvf {task.name}: batch {bno}/{len(plan.batches)}: {len(batch)} "
                      f"mesh(es), {faces:,} faces ({batch[0].path.name}...); this can take minutes")
        records = run_batch(batch, task, plan.out_dir, device, seed)
        record_batch(records, writer, plan.summary, bar, task.name)
        done += len(batch)
        bar.update(faces, note=f"{done}/{n_meshes} meshes, {summary.failed} failed")
        if on_batch is not None:
            on_batch(bno, records)


def _run_side_by_side(plan: RunPlan, task, device, seed: int, workers: int, writer, bar, on_batch) -> None:
    """The batches on ``workers`` single-threaded processes (:func:`~.parallel.map_batches`),
    each batch's lines written as it finishes; a failing batch is bisected as in turn."""
    from ..io import OutputSpaceError
    from .execute import failed_record
    from .parallel import map_batches

    summary, n_meshes, done, bno = plan.summary, sum(map(len, plan.batches)), 0, 0
    for outcome in map_batches(plan.batches, process_batch, (task, plan.out_dir, device, seed),
                               workers=workers, fatal=(OutputSpaceError,)):
        if outcome.split:
            bar.write(f"torchakvf {task.name}: a batch of {len(outcome.batch)} meshes failed "
                      f"({outcome.error}); retrying its halves")
            continue
        records = (outcome.result if outcome.error is None
                   else [failed_record(outcome.batch[0], task, seed, outcome.error)])
        record_batch(records, writer, summary, bar, task.name)
        bno, done = bno + 1, done + len(outcome.batch)
        bar.update(sum(it.cost for it in outcome.batch), note=f"{done}/{n_meshes} meshes, {summary.failed} failed")
        if on_batch is not None:
            on_batch(bno, records)


def _run_overlapped(plan: RunPlan, task, device, seed: int, workers, writer, bar, on_batch) -> None:
    """The batches through the host/device overlap: host workers load and cut, this process
    solves; each mesh's line is written as it finishes; the stage seconds go to ``timings.json``
    and a line."""
    from .batched_run import run_batches_overlapped
    from .parallel import default_workers

    summary, n_meshes, done = plan.summary, sum(map(len, plan.batches)), [0]

    def record(records, item):
        record_batch(records, writer, summary, bar, task.name)
        done[0] += 1
        bar.update(item.cost, note=f"{done[0]}/{n_meshes} meshes, {summary.failed} failed")
        if on_batch is not None:
            on_batch(done[0], records)

    workers = default_workers(device, batched=True) if workers is None else int(workers)
    times = run_batches_overlapped(plan.batches, task, plan.out_dir, device, seed, workers, record,
                                   lambda line: bar.write(f"torchakvf {task.name}: {line}"))
    summary.timings = times.record()
    bar.write(f"torchakvf {task.name}: {times.line()}")


__all__ = ["MANIFEST", "overlapped", "RunSummary", "run_corpus", "plan_run", "record_batch", "recording",
           "default_batch_faces", "peek_faces", "failure_text", "DEFAULT_BATCH_FACES",
           # re-exported from the modules a run is made of
           "Item", "plan_batches", "process_batch", "run_batch", "assign_stems", "discover_inputs",
           "is_mesh_file", "prepare", "read_manifest", "ManifestWriter", "check_output_dir", "OutputLock"]
