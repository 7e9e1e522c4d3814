"""Safe extraction of untrusted zip and tar archives.

:func:`safe_extract` checks *every* member before writing anything and refuses the whole archive
if one member would land outside the target folder (absolute path, drive letter, ``..``
component, a link whose target leaves the folder) or is a device / FIFO. Hard links are copied,
symbolic links kept only when they stay inside; every file is copied to its exact declared size,
so a truncated or damaged archive raises :class:`ArchiveError` with a one-line message naming
the file.
"""
from __future__ import annotations

import gzip
import lzma
import os
import posixpath
import re
import shutil
import stat
import tarfile
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from ..errors import TorchAKVFError

__all__ = ["ArchiveError", "safe_extract", "CHUNK_BYTES"]

#: Bytes read at a time when copying a member (or a download) to disk.
CHUNK_BYTES = 1 << 20


class ArchiveError(TorchAKVFError, ValueError):
    """An archive is unsafe, damaged, truncated, or not the benchmark."""


def _archive_kind(path: Path) -> str:
    """'zip', 'tar' (uncompressed) or 'tar-compressed', from the file's first bytes."""
    with open(path, "rb") as fh:
        head = fh.read(512)
    if head[:4] in (b"PK\x03\x04", b"PK\x05\x06", b"PK\x07\x08"):
        return "zip"
    if head[:2] == b"\x1f\x8b" or head[:3] == b"BZh" or head[:6] == b"\xfd7zXZ\x00":
        return "tar-compressed"
    if len(head) == 512 and head[257:262] == b"ustar":
        return "tar"
    if zipfile.is_zipfile(path):  # e.g. a self-extracting zip with a stub in front
        return "zip"
    raise ArchiveError(f"{path}: not a zip or tar archive (unrecognised content)")


def _member_parts(archive: Path, name: str) -> list[str]:
    """Validated path components of a member name; raises for anything that could escape."""
    if "\x00" in name:
        raise ArchiveError(f"{archive}: refusing member {name!r}: NUL byte in name")
    # Backslashes are separators on Windows; treat them as such so 'a\\..\\..\\x' cannot slip by.
    norm = name.replace("\\", "/")
    if norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        raise ArchiveError(f"{archive}: refusing member {name!r}: absolute path")
    parts = [p for p in norm.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise ArchiveError(f"{archive}: refusing member {name!r}: "
                           f"'..' would leave the target folder")
    return parts


def _check_link(archive: Path, name: str, parts: list[str], target: str, hard: bool) -> list[str]:
    """Validated components of a link's target, relative to the extraction folder."""
    norm = target.replace("\\", "/")
    if not norm or norm.startswith("/") or re.match(r"^[A-Za-z]:", norm):
        raise ArchiveError(f"{archive}: refusing link {name!r} -> {target!r}: absolute target")
    # A symlink's target is relative to the link's folder; a tar hard link's to the archive root.
    base = "" if hard else "/".join(parts[:-1])
    resolved = posixpath.normpath(posixpath.join(base, norm)) if base else posixpath.normpath(norm)
    if resolved == ".." or resolved.startswith("../") or resolved.startswith("/"):
        raise ArchiveError(f"{archive}: refusing link {name!r} -> {target!r}: "
                           f"target is outside the target folder")
    return [p for p in resolved.split("/") if p not in ("", ".")]


@dataclass
class _Member:
    parts: list[str]
    kind: str               # 'dir' | 'file' | 'symlink' | 'hardlink'
    size: int = 0
    link: str = ""          # symlink text, or hard-link target (archive path)
    link_parts: list[str] = field(default_factory=list)
    handle: object = None   # ZipInfo / TarInfo


def _scan_zip(archive: Path, zf: zipfile.ZipFile) -> list[_Member]:
    out = []
    for info in zf.infolist():
        parts = _member_parts(archive, info.filename)
        if not parts:
            continue
        mode = info.external_attr >> 16
        if stat.S_ISLNK(mode):
            target = zf.read(info).decode("utf-8", "replace")
            link_parts = _check_link(archive, info.filename, parts, target, hard=False)
            out.append(_Member(parts, "symlink", 0, target, link_parts, info))
        elif info.is_dir():
            out.append(_Member(parts, "dir", 0, handle=info))
        else:
            out.append(_Member(parts, "file", info.file_size, handle=info))
    return out


def _scan_tar(archive: Path, tf: tarfile.TarFile) -> list[_Member]:
    out = []
    for info in tf.getmembers():  # reads the whole archive: truncation shows up here
        parts = _member_parts(archive, info.name)
        if info.issym():
            link_parts = _check_link(archive, info.name, parts, info.linkname, hard=False)
            out.append(_Member(parts, "symlink", 0, info.linkname, link_parts, info))
        elif info.islnk():
            link_parts = _check_link(archive, info.name, parts, info.linkname, hard=True)
            out.append(_Member(parts, "hardlink", 0, info.linkname, link_parts, info))
        elif info.isdir():
            if parts:
                out.append(_Member(parts, "dir", 0, handle=info))
        elif info.isreg():
            if not parts:
                raise ArchiveError(f"{archive}: refusing member {info.name!r}: empty file name")
            out.append(_Member(parts, "file", info.size, handle=info))
        else:
            raise ArchiveError(f"{archive}: refusing member {info.name!r}: "
                               f"special file (device or FIFO)")
    return out


def _inside(path: str, root: str) -> bool:
    return path == root or path.startswith(root.rstrip(os.sep) + os.sep)


def _prepare_target(dest_real: str, parts: list[str], name: str, archive: Path) -> Path:
    """Create the member's parent folder and make sure it really lies inside the destination.

    The name check already rules out escapes; this re-check on the real file system also covers
    a path running through a symlink that an earlier member created.
    """
    target = Path(dest_real, *parts)
    target.parent.mkdir(parents=True, exist_ok=True)
    if not _inside(os.path.realpath(target.parent), dest_real):
        raise ArchiveError(f"{archive}: refusing member {name!r}: it would be written "
                           f"outside the target folder through a link")
    if target.is_symlink():
        target.unlink()  # a later member replaces an earlier link; never write through it
    return target


def _copy_exact(src, target: Path, size: int, archive: Path, name: str) -> None:
    written = 0
    with open(target, "wb") as out:
        while True:
            chunk = src.read(CHUNK_BYTES)
            if not chunk:
                break
            out.write(chunk)
            written += len(chunk)
    if written != size:
        raise ArchiveError(f"{archive}: truncated archive: member {name!r} has {written} of "
                           f"{size} bytes")


_READ_ERRORS = (zipfile.BadZipFile, tarfile.TarError, EOFError, zlib.error, lzma.LZMAError,
                gzip.BadGzipFile)


def safe_extract(archive, dest) -> list[Path]:
    """Extract a zip or tar (plain, gz, bz2, xz) archive into ``dest``, refusing unsafe members.

    Every member is checked before anything is written; one unsafe member refuses the whole
    archive. Refused: absolute paths (``/x``, ``C:x``), ``..`` components, symbolic or hard links
    whose target leaves ``dest``, devices and FIFOs. File modes and owners are not restored.

    Parameters
    ----------
    archive : str or Path
        The archive file. Its type is recognised from its content, not its name.
    dest : str or Path
        Target folder (created if missing).

    Returns
    -------
    list[Path]
        The regular files written.

    Raises
    ------
    FileNotFoundError
        If ``archive`` does not exist.
    ArchiveError
        If the archive is unsafe, truncated, damaged or not an archive.
    """
    archive = Path(archive)
    if not archive.is_file():
        raise FileNotFoundError(f"archive {str(archive)!r} does not exist")
    kind = _archive_kind(archive)
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    dest_real = os.path.realpath(dest)
    try:
        if kind == "zip":
            with zipfile.ZipFile(archive) as zf:
                return _extract_members(archive, dest_real, _scan_zip(archive, zf),
                                        lambda m: zf.open(m.handle))
        if kind == "tar":
            _check_tar_end(archive)
        with tarfile.open(archive, "r:*") as tf:
            return _extract_members(archive, dest_real, _scan_tar(archive, tf),
                                    lambda m: tf.extractfile(m.handle))
    except ArchiveError:
        raise
    except (*_READ_ERRORS, OSError) as exc:
        # Decompressors report bad data as OSError without an errno (e.g. BadGzipFile, bz2's
        # "Invalid data stream"); an OSError with an errno is a real file-system problem
        # (disk full, permissions) and must not be blamed on the archive.
        if isinstance(exc, OSError) and not isinstance(exc, _READ_ERRORS) and exc.errno is not None:
            raise
        what = "zip" if kind == "zip" else "tar"
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise ArchiveError(f"{archive}: damaged or truncated {what} archive ({detail})") from None


def _check_tar_end(archive: Path) -> None:
    # tarfile quietly stops at a missing header, so a plain tar cut at a member boundary would
    # look complete. Every complete tar ends with two zero blocks (plus zero padding) on a
    # 512-byte boundary; check that. (Compressed tars: the compressor's end marker catches it.)
    size = archive.stat().st_size
    with open(archive, "rb") as fh:
        fh.seek(max(0, size - 1024))
        tail = fh.read()
    if size % 512 or len(tail) < 1024 or tail.strip(b"\0"):
        raise ArchiveError(f"{archive}: truncated tar archive (no end-of-archive marker)")


def _extract_members(archive: Path, dest_real: str, members: list[_Member],
                     open_member: Callable) -> list[Path]:
    written: list[Path] = []
    for m in members:
        name = "/".join(m.parts)
        if m.kind == "dir":
            target = Path(dest_real, *m.parts)
            target.mkdir(parents=True, exist_ok=True)
            if not _inside(os.path.realpath(target), dest_real):
                raise ArchiveError(f"{archive}: refusing member {name!r}: folder resolves "
                                   f"outside the target folder through a link")
        elif m.kind == "file":
            target = _prepare_target(dest_real, m.parts, name, archive)
            src = open_member(m)
            if src is None:
                raise ArchiveError(f"{archive}: cannot read member {name!r}")
            with src:
                _copy_exact(src, target, m.size, archive, name)
            written.append(target)
        elif m.kind == "symlink":
            target = _prepare_target(dest_real, m.parts, name, archive)
            if target.exists():
                if target.is_dir():
                    raise ArchiveError(f"{archive}: link {name!r} would replace a folder")
                target.unlink()
            os.symlink(m.link, target)
        elif m.kind == "hardlink":
            # Copy the earlier member instead of hard-linking (as tarfile's 'data' filter does).
            source = Path(dest_real, *m.link_parts)
            if not source.is_file() or not _inside(os.path.realpath(source), dest_real):
                raise ArchiveError(f"{archive}: hard link {name!r} -> {m.link!r} has no "
                                   f"earlier file inside the archive")
            target = _prepare_target(dest_real, m.parts, name, archive)
            shutil.copyfile(source, target)
            written.append(target)
    return written
