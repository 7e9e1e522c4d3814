"""Progress of long work: a tqdm bar when stderr is a terminal, ``logging`` lines otherwise.

One helper for every command (corpus runner, eval, bench, features), so a terminal user sees a
bar and a log file or CI gets plain, throttled lines it can grep.

    with progress(total=n_faces, desc="eval", unit="faces") as bar:
        bar.update(faces_done, note="3 meshes, akvf 1.2s")
        bar.write("a line that must not be torn by the bar")
"""
from __future__ import annotations

import logging
import sys
import time

log = logging.getLogger("torchakvf.progress")

#: Seconds between two logging lines (a bar redraws itself; lines must not flood a log).
LOG_EVERY_S = 10.0


class Progress:
    """A progress report over ``total`` units; see :func:`progress`."""

    def __init__(self, total: int, desc: str, unit: str, enabled: bool, stream=None):
        self.total, self.desc, self.unit = int(total), desc, unit
        self.done = 0
        self.last = ""            # the last note given (callers print it in their summaries)
        self._stream = sys.stderr if stream is None else stream
        self._bar = None
        self._t0 = time.perf_counter()
        self._last_log = -float("inf")
        self.enabled = bool(enabled)
        if self.enabled and _is_terminal(self._stream):
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, desc=desc, unit=unit, file=self._stream,
                             dynamic_ncols=True, leave=False, unit_scale=self.total > 10_000)

    @property
    def bar(self):
        """The terminal's tqdm bar while it is open, else None (a log line every few seconds)."""
        return self._bar

    def update(self, n: int = 1, note: str = "") -> None:
        """Adds ``n`` units done; ``note`` says what was just finished."""
        self.done += int(n)
        if note:
            self.last = note
        if not self.enabled:
            return
        if self._bar is not None:
            self._bar.update(int(n))
            if note:
                self._bar.set_postfix_str(note, refresh=False)
            return
        now = time.perf_counter()
        if now - self._last_log >= LOG_EVERY_S or self.done >= self.total:
            self._last_log = now
            pct = 100.0 * self.done / self.total if self.total else 100.0
            log.info("%s: %d/%d %s (%.0f%%) in %.0f s%s", self.desc, self.done, self.total, self.unit,
                     pct, now - self._t0, f"; {note}" if note else "")

    def write(self, line: str) -> None:
        """Prints a whole line to the stream without tearing the bar."""
        if self._bar is not None:
            self._bar.write(line, file=self._stream)
        else:
            print(line, file=self._stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def progress(total: int, desc: str, unit: str = "meshes", *, enabled: bool = True, stream=None) -> Progress:
    """A :class:`Progress` over ``total`` ``unit`` s: a tqdm bar on a terminal ``stream``
    (default stderr), INFO lines of the ``torchakvf.progress`` logger at most every
    :data:`LOG_EVERY_S` seconds otherwise; ``enabled=False`` reports nothing."""
    return Progress(total, desc, unit, enabled, stream)


__all__ = ["Progress", "progress", "LOG_EVERY_S"]
