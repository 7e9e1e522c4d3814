"""The output folder of a run: writable (:func:`check_output_dir`), held by one run at a time
(:class:`OutputLock`), and rid of the temporary files a killed run left behind."""
from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

from ..errors import TorchAKVFError
from ..io import remove_stale_temp_files

LOCK = ".lock"


def check_output_dir(out_dir, flag: str = "--out") -> Path:
    """Create ``out_dir`` and prove it writable, or raise a one-line :class:`TorchAKVFError`
    naming the option ``flag`` it came from (``--out``, ``--cache``)."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out, prefix=".write-test.")
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise TorchAKVFError(f"{flag} {out_dir}: cannot create or write the output folder "
                             f"({exc.strerror or exc})") from None
    return out


class OutputLock:
    """An exclusive ``flock`` on ``out_dir/.lock`` for the length of a run, so two runs on one
    folder do not both do all the work: the second stops at once with a one-line error naming
    the holder's pid. The kernel drops the lock when its process dies (even by SIGKILL), so a
    stale lock file never blocks a later run. Entering also removes the temporary files of
    killed runs (nobody else can be writing them while the lock is held)."""

    def __init__(self, out_dir):
        self.path = Path(out_dir) / LOCK
        self._fh = None

    def __enter__(self) -> "OutputLock":
        import fcntl

        try:
            fh = open(self.path, "a+")
        except OSError as exc:
            raise TorchAKVFError(f"--out {self.path.parent}: cannot create the lock file {LOCK} "
                                 f"({exc.strerror or exc})") from None
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            fh.seek(0)
            holder = fh.read().strip() or "unknown"
            fh.close()
            if exc.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise TorchAKVFError(f"--out {self.path.parent}: another torchakvf run (pid {holder}) "
                                     "is writing this folder; wait for it to finish or choose another "
                                     "--out") from None
            raise TorchAKVFError(f"--out {self.path.parent}: cannot lock the folder "
                                 f"({exc.strerror or exc})") from None
        fh.seek(0)
        fh.truncate()
        fh.write(str(os.getpid()))
        fh.flush()
        self._fh = fh
        remove_stale_temp_files(self.path.parent)
        return self

    def __exit__(self, *exc) -> bool:
        if self._fh is not None:
            self._fh.close()   # releases the flock
            self._fh = None
        return False


__all__ = ["check_output_dir", "OutputLock", "LOCK"]
