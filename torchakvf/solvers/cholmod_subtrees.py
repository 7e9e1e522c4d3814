"""CHOLMOD's simplicial LDLᵀ on two threads: the rows of independent subtrees of the elimination
tree computed side by side, then the rows above them; the same factor bit for bit.

Why it is the same: row k of L (CHOLMOD's row-by-row factorization, ``cholmod_rowfac``) reads
the columns of its descendants in the elimination tree only, and writes row k of those columns.
Two disjoint subtrees therefore read and write disjoint columns, and each row is computed by the
same arithmetic from the same entries whatever the order the subtrees are done in; the rows
above them (their common ancestors) come after both, in ascending order, as in one pass.
CHOLMOD's analysis postorders the tree, so a subtree is a range of rows [first, root]. Each
thread has its own ``cholmod_common`` (workspace); ctypes releases the GIL during the calls.

Which subtrees (:func:`two_thread_plan`): from the root down, the heaviest subtree is split
into its root (a row done afterwards) and its children, until the subtrees, dealt to two
threads by size, balance best; a subtree's work is estimated as Σ (column count)², the flops of
its columns. On PSB meshes at full resolution the estimate bounds the factor's speed-up by
1.55-1.85 (the rows above the subtrees, the top separator, are the densest).
"""
from __future__ import annotations

import ctypes as C
import heapq
import threading

import numpy as np

from ..errors import SolverError

#: Flops (CHOLMOD's analysis' count) a factor must take before it is split over two threads,
#: and the estimated speed-up below which it is not: on smaller factors the plan (10-30 ms on
#: PSB meshes, once per pattern) and the second thread cost about what they save (PSB 1: 31
#: MFLOP, 21 ms on one thread; PSB 301: 287 MFLOP, 144 ms).
MIN_FLOPS = 1e8
MIN_SPEEDUP = 1.2
#: Nodes split off the top of the tree at most while looking for the best balance.
MAX_SPLITS = 4000


class Plan:
    """Row ranges [start, stop) of L: ``threads[t]`` the subtrees thread t computes, ``top``
    the rows above them (after both, ascending); ``speedup`` the estimate."""

    def __init__(self, threads: list, top: list, speedup: float):
        self.threads, self.top, self.speedup = threads, top, speedup


def subtree_first(parent: np.ndarray) -> np.ndarray:
    """[n] first row of each node's subtree, for a postordered elimination tree (parent [n],
    -1 at roots); a :class:`SolverError` if the tree is not postordered (a subtree would not
    be a range of rows)."""
    n = len(parent)
    pl = parent.tolist()
    first = list(range(n))
    size = [1] * n
    for j, p in enumerate(pl):             # children come before their parent (checked below)
        if p >= 0:
            size[p] += size[j]
            if first[j] < first[p]:
                first[p] = first[j]
    out = np.asarray(first, dtype=np.int64)
    ok = np.all((parent < 0) | (parent > np.arange(n))) and np.array_equal(out, np.arange(n) - np.asarray(size) + 1)
    if not ok:
        raise SolverError("internal: an elimination tree that is not postordered")
    return out


def two_thread_plan(parent: np.ndarray, colcount: np.ndarray) -> Plan:
    """The subtrees two threads compute side by side, and the rows above them (module notes)."""
    n = len(parent)
    first = subtree_first(parent)
    work = colcount.astype(np.float64) ** 2
    prefix = np.concatenate([[0.0], np.cumsum(work)])
    sub = (prefix[1:] - prefix[first]).tolist()                          # each subtree's work
    # children of j: kids[ptr[j]:ptr[j + 1]]
    has = parent >= 0
    kids = np.flatnonzero(has)[np.argsort(parent[has], kind="stable")].tolist()
    ptr = np.concatenate([[0], np.cumsum(np.bincount(parent[has], minlength=n))]).tolist()
    roots = np.flatnonzero(~has).tolist()
    heap = [(-sub[j], j) for j in roots]
    heapq.heapify(heap)
    top_work, in_heap = 0.0, sum(sub[j] for j in roots)
    best, popped = (np.inf, 0), []
    for step in range(min(MAX_SPLITS, n) + 1):
        # the two threads cannot finish before half the subtrees' work, nor before the largest
        wall = top_work + max(in_heap / 2, -heap[0][0] if heap else 0.0)
        if wall < best[0]:
            best = (wall, step)
        if not heap or step == MAX_SPLITS:
            break
        w, j = heapq.heappop(heap)
        popped.append(j)
        top_work += float(work[j])
        in_heap += w
        for c in kids[ptr[j]:ptr[j + 1]]:
            in_heap += sub[c]
            heapq.heappush(heap, (-sub[c], c))
    # the split at the best step, dealt by size (largest first, to the lighter thread)
    top = popped[:best[1]]
    in_top = set(top)
    split = [j for j in roots if j not in in_top] + [c for j in top for c in kids[ptr[j]:ptr[j + 1]]
                                                     if c not in in_top]
    loads, threads = [0.0, 0.0], [[], []]
    for j in sorted(split, key=lambda j: -sub[j]):
        t = int(loads[1] < loads[0])
        loads[t] += sub[j]
        threads[t].append((int(first[j]), j + 1))
    top_rows = np.array(sorted(top), dtype=np.int64)
    runs = np.split(top_rows, np.flatnonzero(np.diff(top_rows) != 1) + 1) if len(top_rows) else []
    wall = float(work[top_rows].sum()) + max(loads)
    return Plan([sorted(t) for t in threads], [(int(r[0]), int(r[-1]) + 1) for r in runs],
                float(prefix[-1]) / wall if wall > 0 else 1.0)


def factor_rows(lib, upper, factor, commons: list, plan: Plan) -> None:
    """Rows of L by ``plan``: each thread's subtrees on its own common, then the rows above.
    ``upper`` is triu(A(p, p)) and ``factor`` a numeric factor ready for rows from 0 (what
    :meth:`~torchakvf.solvers.cholmod.CholmodFactor.factorize` prepares)."""
    beta = (C.c_double * 2)(0.0, 0.0)
    failed = []

    def rows(ranges, common):
        for start, stop in ranges:
            if not lib.cholmod_rowfac(upper, None, beta, start, stop, factor, C.byref(common)):
                failed.append((start, stop))
                return

    second = threading.Thread(target=rows, args=(plan.threads[1], commons[1]))
    second.start()
    try:
        rows(plan.threads[0], commons[0])
    finally:
        second.join()
    if not failed:
        rows(plan.top, commons[0])
    if failed:
        raise SolverError(f"CHOLMOD failed to factor rows {failed[0]} (out of memory?)")


__all__ = ["MIN_FLOPS", "MIN_SPEEDUP", "Plan", "factor_rows", "subtree_first", "two_thread_plan"]
