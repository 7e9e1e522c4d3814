"""Batches over worker processes: one single-threaded process per CPU core.

On a CPU the per-mesh work (a sparse factorization, ARPACK, small SVDs, GEMMs of a few
thousand rows) gains little from intra-op threads, and two OpenMP threads on a busy 2-core
machine spin-wait on each other; one process per core, each on one thread, keeps every core
busy with useful work. :func:`map_batches` runs a queue of batches either inline
(``workers=1``) or on a spawned process pool, retries a failing multi-mesh batch by halves
(bisection) until the culprit fails alone, and reports every outcome to the caller as it finishes,
so results are written (by the function itself, atomically) and counted as they come and an
interrupt loses nothing finished.
"""
from __future__ import annotations

import collections
import ctypes
import multiprocessing
import os
import sys
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable

#: Batches a worker runs before it is replaced by a fresh process (Python >= 3.11): a backstop
#: against resident memory growing with what a worker has served. Workers hand freed heap pages
#: back after each batch (:func:`_release_freed_memory`) and a fresh process costs seconds of
#: imports, so the limit is set above a PSB run's batches per worker (see docs/design.md).
RECYCLE_AFTER = 250
#: Thread-count variables of the BLAS/OpenMP runtimes and libigl a worker may load (set before its imports).
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "IGL_NUM_THREADS")


#: Processes of a batched run at most by default (the solving process and its host workers):
#: a 16-core GPU machine keeps all its cores on the host stages.
MAX_BATCHED_PROCESSES = 16


def usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def default_workers(device: str = "cpu", batched: bool = False) -> int:
    """Processes by default: one per usable CPU core (at most 8) on CPU; 1 elsewhere (one
    process owns a GPU); for a batched run (one solving process fed by host workers) one per
    core, at most :data:`MAX_BATCHED_PROCESSES`, on any device."""
    if batched:
        return max(1, min(usable_cores(), MAX_BATCHED_PROCESSES))
    if not str(device).startswith("cpu"):
        return 1
    return max(1, min(usable_cores(), 8))


@dataclass
class BatchOutcome:
    """One finished batch: its items, what ``fn`` returned (None on failure), the error text
    (None on success), its wall seconds, and ``split``: the batch failed as a whole and its
    two halves are retried (:func:`halves`; then neither result nor a final error is given)."""

    batch: list
    result: Any
    error: str | None
    seconds: float
    split: bool = False


def _init_worker(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def _timed(fn, batch, args):
    t0 = time.perf_counter()
    try:
        return fn(batch, *args), time.perf_counter() - t0
    finally:
        _release_freed_memory()


def _release_freed_memory() -> None:
    """Return the heap's free pages to the system (glibc ``malloc_trim``; elsewhere nothing).
    A batch's large arrays are freed when it ends, but glibc keeps their pages, fragmented
    among live ones, so a worker's resident size would ratchet up batch after batch."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


#: Exceptions that mean a bug in the code, not a bad input: they are never recorded as one
#: mesh's failure but propagate with their traceback (a torchakvf error never counts as one).
PROGRAMMING_ERRORS = (TypeError, LookupError, AttributeError, NameError, AssertionError,
                      NotImplementedError, ImportError, SyntaxError)


def is_programming_error(exc: BaseException) -> bool:
    """Whether ``exc`` is a bug to surface rather than a bad input to record and skip."""
    from ..errors import TorchAKVFError

    return isinstance(exc, PROGRAMMING_ERRORS) and not isinstance(exc, TorchAKVFError)


def error_text(exc: BaseException) -> str:
    """One line for a manifest or a report: a torchakvf error's own message (it names the
    input), any other error prefixed by its type."""
    from ..errors import TorchAKVFError

    text = str(exc) if isinstance(exc, TorchAKVFError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split())[:500]


def map_batches(batches: list, fn: Callable, args: tuple = (), *, workers: int = 1,
                fatal: tuple = ()):
    """Run ``fn(batch, *args)`` for each batch; yield a :class:`BatchOutcome` as each finishes.

    fn must be a module-level function (pickled to the workers) that writes its own outputs;
    its return value comes back to this process. With ``workers`` > 1 the batches run on a
    pool of spawned processes, each on one thread. A batch of several items that raises is
    bisected: its halves are retried (recursively), so a bad item ends alone and is reported
    with its error, and every other item is run again at most about log2(batch size) times.
    A programming error (:func:`is_programming_error`: TypeError, IndexError, ...) is not a bad
    item: it propagates, with its traceback, and ends the map; so does an exception of a type
    in ``fatal`` (e.g. :class:`~torchakvf.io.OutputSpaceError`: no item is to blame).
    A worker that dies (killed, out of memory) fails its batch the same way, and the pool is
    started again for the rest.
    """
    queue = collections.deque(list(b) for b in batches)
    if workers <= 1:
        while queue:
            batch = queue.popleft()
            t0 = time.perf_counter()
            try:
                result, error = fn(batch, *args), None
            except Exception as exc:  # noqa: BLE001 - one bad mesh must not end the run
                if is_programming_error(exc) or isinstance(exc, fatal):
                    raise
                result, error = None, error_text(exc)
            yield from _outcome(queue, batch, result, error, time.perf_counter() - t0)
        return

    with one_thread_environment():
        ctx = multiprocessing.get_context("spawn")          # no fork of a process holding threads
        pool_args = dict(max_workers=workers, mp_context=ctx, initializer=_init_worker, initargs=(1,))
        if sys.version_info >= (3, 11):
            pool_args["max_tasks_per_child"] = RECYCLE_AFTER
        pool = ProcessPoolExecutor(**pool_args)
        running: dict = {}
        try:
            while queue or running:
                while queue and len(running) < workers:
                    batch = queue.popleft()
                    running[pool.submit(_timed, fn, batch, args)] = (batch, time.perf_counter())
                done, _ = wait(list(running), return_when=FIRST_COMPLETED)
                broken = False
                for fut in done:
                    batch, t0 = running.pop(fut)
                    try:
                        result, seconds = fut.result()
                        error = None
                    except BrokenProcessPool as exc:
                        result, seconds, broken = None, time.perf_counter() - t0, True
                        error = f"worker process died ({exc})"
                    except Exception as exc:  # noqa: BLE001
                        if is_programming_error(exc) or isinstance(exc, fatal):
                            raise
                        result, seconds, error = None, time.perf_counter() - t0, error_text(exc)
                    yield from _outcome(queue, batch, result, error, seconds)
                if broken:
                    # Every batch still on the dead pool is lost with it: run them again.
                    for fut, (batch, _) in running.items():
                        queue.appendleft(batch)
                    running.clear()
                    pool.shutdown(wait=False, cancel_futures=True)
                    pool = ProcessPoolExecutor(**pool_args)
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


@contextmanager
def one_thread_environment():
    """The BLAS/OpenMP thread variables (:data:`_THREAD_VARS`) set to 1 for the block, so that
    processes spawned in it start single-threaded; each restored (or removed) afterwards."""
    saved = {v: os.environ.get(v) for v in _THREAD_VARS}
    os.environ.update({v: "1" for v in _THREAD_VARS})
    try:
        yield
    finally:
        for v, old in saved.items():
            if old is None:
                os.environ.pop(v, None)
            else:
                os.environ[v] = old


def halves(batch: list) -> list[list]:
    """A failed batch's two halves (the first the larger), retried before the rest of the queue:
    bisection finds one bad item among m in about 2 log2(m) runs instead of m, and the meshes of
    a half that succeeds keep the batch's sharing (one solve) instead of each paying alone."""
    mid = (len(batch) + 1) // 2
    return [batch[:mid], batch[mid:]]


class InlineExecutor:
    """The :class:`concurrent.futures.Executor` calls :func:`host_pool` gives with no worker:
    each call runs at once, in this process, and returns a finished future."""

    def submit(self, fn, *args, **kwargs) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except Exception as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(exc)
        return fut

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        pass


@contextmanager
def host_pool(workers: int):
    """An executor of ``workers`` spawned single-threaded processes for the host stages of a
    batched run (0: :class:`InlineExecutor`, everything in this process, in call order)."""
    if workers <= 0:
        yield InlineExecutor()
        return
    with one_thread_environment():
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_init_worker, initargs=(1,))
        try:
            yield pool
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _outcome(queue, batch, result, error, seconds):
    if error is not None and len(batch) > 1:
        queue.extendleft(reversed(halves(batch)))
        yield BatchOutcome(batch, None, error, seconds, split=True)
    else:
        yield BatchOutcome(batch, result, error, seconds)


__all__ = ["map_batches", "halves", "host_pool", "InlineExecutor", "usable_cores", "MAX_BATCHED_PROCESSES",
           "BatchOutcome", "default_workers", "error_text", "is_programming_error", "PROGRAMMING_ERRORS"]
