"""``manifest.jsonl``: one JSON line per finished mesh of a corpus run (the one reader and writer).

The writer appends a whole line per record and fsyncs it, so a killed run loses nothing it had
finished; the reader skips a line that does not parse (the torn tail of a run killed, or of a
disk that filled, mid-append) and keeps every whole line.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from ..errors import TorchAKVFError

MANIFEST = "manifest.jsonl"


def read_manifest_records(out_dir) -> list[dict]:
    """Every whole record of ``out_dir/manifest.jsonl``, in file order ([] without a manifest).

    Lines that do not parse as a JSON object with a ``path`` are skipped (a torn last line).
    A manifest that exists but cannot be read raises :class:`TorchAKVFError` naming it.
    """
    path = Path(out_dir) / MANIFEST
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return []
    except OSError as exc:
        raise TorchAKVFError(f"{path}: cannot read the manifest ({exc.strerror or exc})") from None
    records = []
    for raw in data.splitlines():
        try:
            rec = json.loads(raw)
        except ValueError:
            continue
        if isinstance(rec, dict) and "path" in rec:
            records.append(rec)
    return records


def read_manifest(out_dir) -> dict[str, dict]:
    """The last manifest record of each input (key: the resolved input path string)."""
    return {str(rec["path"]): rec for rec in read_manifest_records(out_dir)}


def file_fingerprint(path) -> dict:
    """{"size": bytes, "sha256": hex digest} of a file: what a manifest records of each output
    (and of each input) so a later run can tell a whole, matching file from a stale or torn one."""
    h = hashlib.sha256()
    size = 0
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
            size += len(block)
    return {"size": size, "sha256": h.hexdigest()}


class ManifestWriter:
    """Appends one JSON line per record, fsync'ed, so a killed run loses none.

    Failures are one-line :class:`TorchAKVFError` s naming the manifest: one that cannot be
    opened (a read-only folder, a name taken by a folder), and an append that fails (a full
    disk), after which the partial line is cut off again so the file keeps whole lines only.
    """

    def __init__(self, out_dir):
        self.path = Path(out_dir) / MANIFEST
        try:
            self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        except OSError as exc:
            raise TorchAKVFError(f"{self.path}: cannot open the manifest for appending "
                                 f"({exc.strerror or exc}); make it writable or choose another --out") from None
        try:
            end = os.lseek(self._fd, 0, os.SEEK_END)
            if end > 0:
                # A line cut short by a kill must not glue onto the next one.
                with open(self.path, "rb") as rf:
                    rf.seek(end - 1)
                    if rf.read(1) != b"\n":
                        self._write(b"\n")
        except OSError as exc:
            os.close(self._fd)
            raise TorchAKVFError(f"{self.path}: cannot write the manifest ({exc.strerror or exc})") from None
        self.appended = 0

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]

    def append(self, record: dict) -> None:
        line = (json.dumps(record, sort_keys=False) + "\n").encode()
        end = os.lseek(self._fd, 0, os.SEEK_END)
        try:
            self._write(line)
            os.fsync(self._fd)
        except OSError as exc:
            try:
                os.ftruncate(self._fd, end)   # no torn line left behind where we can help it
            except OSError:
                pass
            raise TorchAKVFError(
                f"{self.path}: cannot append to the manifest ({exc.strerror or exc}); the "
                f"{self.appended} meshes recorded by this run and all earlier ones are kept, "
                f"{record.get('path')} is not: free space and run again to finish") from None
        self.appended += 1

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


__all__ = ["MANIFEST", "read_manifest", "read_manifest_records", "file_fingerprint", "ManifestWriter"]
