"""What the benchmark scripts share: the fastest of repeated calls, and writing a report.

Run as ``python benchmarks/<script>.py``, a script finds this module beside it (``benchmarks/``
is the script's own folder, first on ``sys.path``)."""
from __future__ import annotations

import time
from pathlib import Path


def best_of(fn, repeat: int, clock=time.perf_counter):
    """(seconds of the fastest of ``repeat`` calls of ``fn()`` on ``clock``, the last call's
    result). ``clock=time.process_time`` times this process's CPU alone, which the other jobs
    of a shared machine disturb less than wall time."""
    best, out = float("inf"), None
    for _ in range(max(int(repeat), 1)):
        t = clock()
        out = fn()
        best = min(best, clock() - t)
    return best, out


def write_report(text: str, out: Path | str | None) -> None:
    """Print a report and, given a path, write it there (its folder made if missing)."""
    print(text)
    if out:
        out = Path(out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
