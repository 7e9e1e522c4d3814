"""The corpus runner under ``torchakvf segment`` and ``torchakvf features``.

What it guarantees:

* **Streaming, batched by faces.** Inputs are peeked for their face count (the OFF/PLY header,
  the STL size, OBJ ``f`` lines; no full parse), sorted by size so padding stays small, and
  grouped into batches whose face total stays under ``batch_faces`` (a mesh bigger than the
  budget is a batch of its own). Only one batch of meshes is in memory at a time.
* **Nothing is lost.** Every output file is written atomically (temp file + rename); after a
  batch's files are in place, one ``manifest.jsonl`` line per mesh is appended and fsync'ed.
  Re-running skips a mesh whose last manifest line says ``ok`` for the same parameters and
  version and whose output files exist; an interrupt (Ctrl-C, SIGTERM, even SIGKILL) leaves every
  finished mesh usable, and the next run picks up where it stopped.
* **One bad mesh fails alone.** A mesh that cannot be loaded, cleaned or validated gets a
  ``failed`` line with its error; if a batch's computation raises, its meshes are retried one by
  one so only the culprit fails. The run goes on; the summary and the exit code say how many
  failed.

A task (see :mod:`.features`, :mod:`.segment_task`) is a small object with ``name``,
``params`` (a JSON-able dict), ``stages`` (the names of its timed compute stages),
``output_paths(out_dir, stem)``, ``process(items, device) -> (outputs, stage_seconds)`` and
``write(item, output, out_dir) -> written paths``; optionally ``validate(item)`` (per-mesh checks
after loading, raise :class:`TorchAKVFError`), ``cache_lookup(item, out_dir) -> bool`` and
``cache_store(item, written)``.

Manifest ``seconds``: ``load`` and ``write`` are measured per mesh; the compute stages run once
per batch and each mesh is charged the batch's stage time times its share of the batch's faces.
"""
from __future__ import annotations

import glob
import gzip
import hashlib
import json
import logging
import os
import re
import signal
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

from ..errors import TorchAKVFError
from ..io import FORMATS, load_mesh, safe_stem
from ..mesh import clean_mesh

log = logging.getLogger("torchakvf.pipeline")

MANIFEST = "manifest.jsonl"

#: Default face budget per batch. CPU, measured with ``torchakvf features --n 32`` on PSB meshes
#: 1-20 (5k-32k faces, 404k in all; 2 busy cores, OMP_NUM_THREADS=1): one mesh per batch ran
#: 968 faces/s (1.35 GB peak RSS), a 50k budget 746 faces/s, a 200k budget 267 faces/s (~6 GB):
#: on CPU the padded batched work (every mesh iterates until the batch's slowest converges)
#: costs more than it saves, so the budget only groups small meshes (20k: a PSB-size mesh runs
#: about alone). CUDA: batching amortizes kernel launches; 1M faces is a guess, unmeasured here.
DEFAULT_BATCH_FACES = {"cpu": 20_000, "cuda": 1_000_000}

_GLOB_CHARS = re.compile(r"[*?\[]")


def default_batch_faces(device) -> int:
    kind = str(device).split(":")[0]
    return DEFAULT_BATCH_FACES.get(kind, DEFAULT_BATCH_FACES["cpu"])


# ---- inputs -------------------------------------------------------------------------------

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


def peek_faces(path: Path) -> int | None:
    """Face count from the file's header without parsing it (None when it cannot tell).

    OFF: the counts line; PLY: ``element face N``; binary STL: from the size; ASCII STL and OBJ:
    a count of ``facet``/``f`` lines (a byte scan, much cheaper than a parse).
    """
    name = path.name.lower()
    gz = name.endswith(".gz")
    fmt = (name[:-3] if gz else name).rsplit(".", 1)[-1]
    opener = gzip.open if gz else open
    try:
        if fmt == "off":
            with opener(path, "rb") as fh:
                tokens = []
                for _ in range(64):
                    line = fh.readline(4096)
                    if not line:
                        break
                    line = line.split(b"#", 1)[0].strip()
                    if not line:
                        continue
                    if not tokens and line.upper().startswith(b"OFF"):
                        line = line[3:]
                    tokens += line.split()
                    if len(tokens) >= 2:
                        return max(int(tokens[1]), 0)
            return None
        if fmt == "ply":
            with opener(path, "rb") as fh:
                for _ in range(200):
                    line = fh.readline(4096)
                    if not line or line.strip() == b"end_header":
                        break
                    parts = line.split()
                    if len(parts) == 3 and parts[:2] == [b"element", b"face"]:
                        return int(parts[2])
            return None
        if fmt == "stl" and not gz:
            size = path.stat().st_size
            with open(path, "rb") as fh:
                head = fh.read(84)
            if len(head) == 84:
                n = int.from_bytes(head[80:84], "little")
                if 84 + 50 * n == size:
                    return n
        data = opener(path, "rb").read()
        if fmt == "stl":
            return data.count(b"facet normal") or None
        if fmt == "obj":
            return len(re.findall(rb"(?m)^f\s", data))
    except (OSError, ValueError, EOFError):
        return None
    return None


# ---- manifest -----------------------------------------------------------------------------

def read_manifest(out_dir) -> dict[str, dict]:
    """The last manifest record of each input path (key: resolved path string). Lines that do
    not parse (a line cut short by a kill) are ignored."""
    path = Path(out_dir) / MANIFEST
    last: dict[str, dict] = {}
    if not path.exists():
        return last
    with open(path, "rb") as fh:
        for raw in fh:
            try:
                rec = json.loads(raw)
            except ValueError:
                continue
            if isinstance(rec, dict) and "path" in rec:
                last[str(rec["path"])] = rec
    return last


class ManifestWriter:
    """Appends one JSON line per record, flushed and fsync'ed, so a killed run loses none."""

    def __init__(self, out_dir):
        self.path = Path(out_dir) / MANIFEST
        self._fh = open(self.path, "ab")
        # A line cut short by a kill must not glue onto the next one.
        if self._fh.tell() > 0:
            with open(self.path, "rb") as rf:
                rf.seek(-1, os.SEEK_END)
                if rf.read(1) != b"\n":
                    self._fh.write(b"\n")

    def append(self, record: dict) -> None:
        self._fh.write((json.dumps(record, sort_keys=False) + "\n").encode())
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()


def check_output_dir(out_dir) -> Path:
    """Create ``out_dir`` and prove it writable, or raise a one-line :class:`TorchAKVFError`."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".write-test.")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise TorchAKVFError(f"--out {out_dir}: cannot create or write the output folder "
                             f"({exc.strerror or exc})") from None
    return out


# ---- items and batches --------------------------------------------------------------------

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


def assign_stems(paths: Sequence[Path], previous: dict[str, dict] | None = None) -> list[str]:
    """Output stems (``safe_stem``), unique within the run: a path keeps the stem its manifest
    line recorded; otherwise colliding stems get ``-<8 hex of sha1(resolved path)>``."""
    previous = previous or {}
    keys = [str(p.resolve()) for p in paths]
    stems: list[str | None] = [None] * len(paths)
    taken: set[str] = set()
    for i, k in enumerate(keys):
        old = previous.get(k, {}).get("stem")
        if old and old == safe_stem(old) and old not in taken:
            stems[i] = old
            taken.add(old)
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


def plan_batches(items: Sequence[Item], batch_faces: int) -> list[list[Item]]:
    """Sort by face count (then path) and cut into batches under ``batch_faces`` faces;
    a mesh above the budget is a batch alone."""
    order = sorted(items, key=lambda it: (it.cost, it.key))
    batches: list[list[Item]] = []
    cur: list[Item] = []
    total = 0
    for it in order:
        if cur and total + it.cost > batch_faces:
            batches.append(cur)
            cur, total = [], 0
        cur.append(it)
        total += it.cost
    if cur:
        batches.append(cur)
    return batches


def _error_text(exc: BaseException) -> str:
    if isinstance(exc, TorchAKVFError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


# ---- the run ------------------------------------------------------------------------------

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


class _Progress:
    """A carriage-return bar on a terminal; one log line per batch otherwise."""

    def __init__(self, total: int, name: str, stream=None):
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.total, self.name, self.t0 = total, name, time.perf_counter()

    def update(self, done: int, ok: int, failed: int, batch_no: int, n_batches: int, batch_s: float,
               batch_len: int, batch_faces: int) -> None:
        el = time.perf_counter() - self.t0
        if self.tty:
            frac = done / max(self.total, 1)
            bar = "#" * int(30 * frac) + "-" * (30 - int(30 * frac))
            eta = el / frac * (1 - frac) if frac > 0 else 0
            self.stream.write(f"\r{self.name} [{bar}] {done}/{self.total} ok {ok} failed {failed} "
                              f"{el:5.0f}s eta {eta:4.0f}s ")
            self.stream.flush()
        else:
            log.info("%s: batch %d/%d (%d meshes, %d faces) in %.1f s; %d/%d done, %d failed",
                     self.name, batch_no, n_batches, batch_len, batch_faces, batch_s, done, self.total, failed)

    def start(self) -> None:
        if self.tty:
            self.stream.write(f"\r{self.name} [{'-' * 30}] 0/{self.total} ")
            self.stream.flush()

    def clear(self) -> None:
        """Before a log line: erase the bar so the message starts on a clean line."""
        if self.tty:
            self.stream.write("\r\033[K")
            self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _base_record(item: Item, task, seed: int) -> dict:
    from .. import __version__

    return {"path": item.key, "stem": item.stem, "faces": item.faces, "status": None, "error": None,
            "seconds": {}, "seed": seed, "version": __version__, "task": task.name,
            "params": task.params}


def _outputs_exist(task, out_dir: Path, stem: str) -> bool:
    return all(p.exists() for p in task.output_paths(out_dir, stem))


def process_batch(items: list[Item], task, out_dir: Path, device, seed: int) -> list[dict]:
    """Load, compute and write one batch; returns one manifest record per item (any order).

    Self-contained (only plain inputs and outputs) so that executors other than
    :func:`run_corpus` (e.g. the Ray adapter) can map it over batches.
    """
    records: list[dict] = []
    ready: list[Item] = []
    for it in items:
        rec = _base_record(it, task, seed)
        t0 = time.perf_counter()
        try:
            lookup = getattr(task, "cache_lookup", None)
            if lookup is not None and lookup(it, out_dir):
                rec.update(status="ok", cached=True, seconds={"load": 0.0, "write": time.perf_counter() - t0})
                records.append(rec)
                continue
            it.mesh = load_mesh(it.path)
            it.faces = it.mesh.n_faces
            it.clean = clean_mesh(it.mesh)
            validate = getattr(task, "validate", None)
            if validate is not None:
                validate(it)
            it.seconds = {"load": time.perf_counter() - t0}
            ready.append(it)
        except Exception as exc:  # noqa: BLE001 - any failure of one mesh is recorded, not fatal
            log.debug("load of %s failed", it.path, exc_info=True)
            rec.update(status="failed", error=_error_text(exc), faces=it.faces,
                       seconds={"load": time.perf_counter() - t0})
            records.append(rec)
            it.mesh = it.clean = None
    if not ready:
        return records
    records += _compute_and_write(ready, task, out_dir, device, seed, retry=len(ready) > 1)
    return records


def _compute_and_write(items: list[Item], task, out_dir: Path, device, seed: int, retry: bool) -> list[dict]:
    error = None
    try:
        outputs, stage_s = task.process(items, device)
    except Exception as exc:  # noqa: BLE001
        error = _error_text(exc)
        log.debug("computing %s failed", [it.stem for it in items], exc_info=True)
    if error is not None:
        # Out of the except block: the failed batch's tensors (held by the traceback) are freed.
        _free_device_memory(device)
        if retry:
            log.warning("batch of %d meshes failed (%s); retrying them one by one", len(items), error)
            recs = []
            for it in items:
                recs += _compute_and_write([it], task, out_dir, device, seed, retry=False)
            return recs
        it = items[0]
        rec = _base_record(it, task, seed)
        rec.update(status="failed", error=error, seconds=dict(it.seconds))
        it.mesh = it.clean = None
        return [rec]
    total = sum(len(it.clean.faces) for it in items) or 1
    recs = []
    for it, out in zip(items, outputs):
        rec = _base_record(it, task, seed)
        share = len(it.clean.faces) / total
        seconds = dict(it.seconds)
        for stage in task.stages:
            seconds[stage] = stage_s.get(stage, 0.0) * share
        t0 = time.perf_counter()
        try:
            written = task.write(it, out, out_dir)
            store = getattr(task, "cache_store", None)
            if store is not None:
                store(it, written)
            seconds["write"] = time.perf_counter() - t0
            rec.update(status="ok", seconds=seconds)
        except Exception as exc:  # noqa: BLE001
            log.debug("writing %s failed", it.stem, exc_info=True)
            seconds["write"] = time.perf_counter() - t0
            rec.update(status="failed", error=_error_text(exc), seconds=seconds)
        recs.append(rec)
        it.mesh = it.clean = None
    return recs


def _free_device_memory(device) -> None:
    if str(device).startswith("cuda"):
        import torch

        torch.cuda.empty_cache()


def prepare(paths: Sequence[Path], out_dir: Path, task, *, seed: int = 0, resume: bool = True
            ) -> tuple[list[Item], list[Item]]:
    """(items to run, items skipped as already done) for ``paths``."""
    from .. import __version__

    previous = read_manifest(out_dir) if resume else {}
    unique: dict[str, Path] = {}
    for p in map(Path, paths):
        unique.setdefault(str(p.resolve()), p)   # one input once, however often it is named
    paths = list(unique.values())
    stems = assign_stems(paths, previous)
    todo, skipped = [], []
    for p, stem in zip(paths, stems):
        key = str(p.resolve())
        old = previous.get(key)
        if (old is not None and old.get("status") == "ok" and old.get("stem") == stem
                and old.get("task") == task.name and old.get("params") == _jsonable(task.params)
                and old.get("seed") == seed and old.get("version") == __version__
                and _outputs_exist(task, out_dir, stem)):
            skipped.append(Item(p, key, stem, old.get("faces")))
            continue
        todo.append(Item(p, key, stem, None))
    return todo, skipped


def _jsonable(obj):
    return json.loads(json.dumps(obj))


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


def run_corpus(paths: Iterable, out_dir, task, *, batch_faces: int | None = None, device="cpu",
               seed: int = 0, resume: bool = True, progress: bool | None = None,
               on_batch: Callable[[int, list[dict]], None] | None = None) -> RunSummary:
    """Run ``task`` over mesh files ``paths`` into ``out_dir`` (see the module docstring).

    batch_faces : face budget per batch (default :data:`DEFAULT_BATCH_FACES` for the device)
    device : torch device the batched computation runs on
    seed : recorded in the manifest (the task's own params carry it into the computation)
    resume : skip meshes the manifest records as done with the same params (False: redo all)
    progress : force the terminal bar on/off (default: when stderr is a terminal)
    on_batch : called after each batch's manifest lines are written, with the batch number
        and its records (tests use it to interrupt a run)

    Returns a :class:`RunSummary`; ``summary.exit_code`` is 0 when no mesh failed, else 1.
    KeyboardInterrupt propagates after the finished meshes are safely recorded.
    """
    t_start = time.perf_counter()
    out_dir = check_output_dir(out_dir)
    batch_faces = int(batch_faces) if batch_faces is not None else default_batch_faces(device)
    if batch_faces < 1:
        raise TorchAKVFError(f"--batch-faces must be a positive integer, got {batch_faces}")
    todo, skipped = prepare(list(paths), out_dir, task, seed=seed, resume=resume)
    summary = RunSummary(skipped=len(skipped), manifest=out_dir / MANIFEST)
    if skipped:
        log.info("%s: %d meshes already done in %s, skipping them", task.name, len(skipped), out_dir)
    for it in todo:
        it.faces = peek_faces(it.path)
    batches = plan_batches(todo, batch_faces)
    bar = _Progress(len(todo), f"torchakvf {task.name}")
    if progress is not None:
        bar.tty = progress
    writer = ManifestWriter(out_dir)
    done = 0
    bar.start()
    try:
        with _TermAsInterrupt():
            for bno, batch in enumerate(batches, 1):
                t0 = time.perf_counter()
                records = process_batch(batch, task, out_dir, device, seed)
                for rec in records:
                    writer.append(rec)
                    if not summary.add(rec):
                        bar.clear()
                        log.warning("%s failed: %s", rec["path"], rec["error"])
                done += len(batch)
                bar.update(done, summary.ok, summary.failed, bno, len(batches), time.perf_counter() - t0,
                           len(batch), sum(it.cost for it in batch))
                if on_batch is not None:
                    on_batch(bno, records)
    except KeyboardInterrupt:
        summary.interrupted = True
        raise
    finally:
        writer.close()
        bar.close()
        summary.elapsed = time.perf_counter() - t_start
    return summary
