"""Safe extraction of the official PSB archive and conversion to this package's layout.

The official package ``MeshsegBenchmark-1.0`` (zip or tar) holds::

    MeshsegBenchmark-1.0/data/off/N.off                  the 380 meshes
    MeshsegBenchmark-1.0/data/seg/Benchmark/N/N_k.seg    human segmentations
    MeshsegBenchmark-1.0/data/seg/<Algorithm>/...        computer segmentations (ignored here)

:func:`prepare_psb` turns it into the layout :mod:`torchakvf.evaluate.psb` reads::

    <out>/meshes/N.off[.gz]
    <out>/gt/N/N_k.seg[.gz]

Archives are untrusted input. :func:`safe_extract` checks *every* member before writing
anything and refuses the whole archive if one member would land outside the target folder
(absolute path, drive letter, ``..`` component, a link whose target leaves the folder) or is a
device / FIFO. A truncated or damaged archive raises :class:`ArchiveError` with a one-line
message naming the file.
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
import tempfile
import urllib.error
import urllib.parse
import urllib.request
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from ..errors import MeshError, TorchAKVFError
from ..io.off import off_face_count
from .psb import BENCHMARK_CATEGORIES, MAX_MESH_ID, category_of, read_seg

__all__ = [
    "ArchiveError",
    "safe_extract",
    "find_benchmark_data_dir",
    "convert_benchmark_layout",
    "prepare_psb",
    "ConversionReport",
]

_CHUNK = 1 << 20


class ArchiveError(TorchAKVFError, ValueError):
    """An archive is unsafe, damaged, truncated, or not the benchmark."""


# ---------------------------------------------------------------------------------------------
# safe extraction
# ---------------------------------------------------------------------------------------------

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
            chunk = src.read(_CHUNK)
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


# ---------------------------------------------------------------------------------------------
# layout conversion
# ---------------------------------------------------------------------------------------------

@dataclass
class ConversionReport:
    """What :func:`convert_benchmark_layout` / :func:`prepare_psb` wrote."""

    n_meshes: int = 0
    n_segmentations: int = 0
    meshes_with_gt: int = 0
    withheld_meshes: list[int] = field(default_factory=list)
    out_dir: Path | None = None

    def summary(self) -> str:
        text = (f"{self.n_meshes} meshes, {self.n_segmentations} human segmentations of "
                f"{self.meshes_with_gt} meshes")
        if self.withheld_meshes:
            text += f", ground truth withheld for {len(self.withheld_meshes)} meshes"
        if self.out_dir is not None:
            text += f" -> {self.out_dir}"
        return text


def find_benchmark_data_dir(root, max_depth: int = 5) -> Path:
    """The folder ``D`` under ``root`` holding ``D/off`` and ``D/seg/Benchmark`` (``data/``).

    Raises
    ------
    ArchiveError
        If there is no such folder, or several equally shallow ones.
    """
    root = Path(root)
    level = [root]
    for _ in range(max_depth + 1):
        hits = [d for d in level if (d / "off").is_dir() and (d / "seg" / "Benchmark").is_dir()]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise ArchiveError(f"{root}: several benchmark data folders: "
                               f"{', '.join(str(h) for h in sorted(hits))}")
        level = sorted(c for d in level for c in d.iterdir() if c.is_dir() and not c.is_symlink())
        if not level:
            break
    raise ArchiveError(f"{root}: no benchmark data found (expected a folder holding "
                       f"'off/N.off' and 'seg/Benchmark/N/N_k.seg', as in "
                       f"MeshsegBenchmark-1.0/data)")


def _off_face_count(data: bytes, path: Path) -> int:
    """Number of faces declared in an OFF header (the package's OFF header reader)."""
    try:
        return off_face_count(data, str(path))
    except MeshError as exc:
        raise ArchiveError(str(exc)) from None


def _write(data: bytes, target: Path, compress: bool) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    if compress:
        data = gzip.compress(data, compresslevel=6, mtime=0)
    target.write_bytes(data)


def _read_maybe_gz(path: Path) -> bytes:
    data = path.read_bytes()
    return gzip.decompress(data) if data[:2] == b"\x1f\x8b" else data


def _check_withhold(withhold: Iterable[str]) -> set[str]:
    withhold = set(withhold)
    unknown = withhold - set(BENCHMARK_CATEGORIES)
    if unknown:
        raise ArchiveError(f"unknown categories to withhold: {', '.join(sorted(unknown))} "
                           f"(known: {', '.join(BENCHMARK_CATEGORIES)})")
    return withhold


def convert_benchmark_layout(data_dir, out_dir, compress: bool = True,
                             withhold: Iterable[str] = (),
                             log: Callable[[str], None] | None = None) -> ConversionReport:
    """Copy the benchmark's ``data/off`` and ``data/seg/Benchmark`` into ``meshes/`` and ``gt/``.

    Every human segmentation is checked to hold one integer label per face of its mesh.

    Parameters
    ----------
    data_dir : str or Path
        The benchmark's ``data`` folder (see :func:`find_benchmark_data_dir`).
    out_dir : str or Path
        Receives ``meshes/N.off[.gz]`` and ``gt/N/N_k.seg[.gz]``.
    compress : bool
        Gzip the outputs (``.gz``), as in the shared copy.
    withhold : iterable of str
        Category names whose human segmentations are not written (kept back for blind evaluation).
    log : callable, optional
        Receives progress lines.

    Returns
    -------
    ConversionReport

    Raises
    ------
    ArchiveError
        On a misnamed mesh, a segmentation without mesh, or a segmentation whose length differs
        from its mesh's face count.
    """
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    withhold = _check_withhold(withhold)
    suffix = ".gz" if compress else ""
    report = ConversionReport()

    face_counts: dict[int, int] = {}
    mesh_re = re.compile(r"^(\d+)\.off(\.gz)?$")
    for path in sorted((data_dir / "off").iterdir()):
        m = mesh_re.match(path.name)
        if not m or not path.is_file():
            continue
        mesh_id = int(m.group(1))
        if not 1 <= mesh_id <= MAX_MESH_ID:
            raise ArchiveError(f"{path}: mesh id {mesh_id} outside 1..{MAX_MESH_ID}")
        data = _read_maybe_gz(path)
        face_counts[mesh_id] = _off_face_count(data, path)
        _write(data, out_dir / "meshes" / f"{mesh_id}.off{suffix}", compress)
        report.n_meshes += 1
    if not face_counts:
        raise ArchiveError(f"{data_dir / 'off'}: no meshes (N.off) found")
    if log:
        log(f"converted {report.n_meshes} meshes")

    seg_root = data_dir / "seg" / "Benchmark"
    seg_re = re.compile(r"^(\d+)_(\d+)\.seg(\.gz)?$")
    withheld = set()
    for folder in sorted(seg_root.iterdir()):
        if not folder.is_dir() or not folder.name.isdigit():
            continue
        mesh_id = int(folder.name)
        segs = [p for p in folder.iterdir() if seg_re.match(p.name) and p.is_file()]
        if not segs:
            continue
        if mesh_id not in face_counts:
            raise ArchiveError(f"{folder}: human segmentations of mesh {mesh_id}, which has no "
                               f"mesh in {data_dir / 'off'}")
        if category_of(mesh_id) in withhold:
            withheld.add(mesh_id)
            continue
        for path in segs:
            m = seg_re.match(path.name)
            if int(m.group(1)) != mesh_id:
                raise ArchiveError(f"{path}: segmentation of mesh {m.group(1)} in the folder "
                                   f"of mesh {mesh_id}")
            try:
                labels = read_seg(path)
            except ValueError as exc:
                raise ArchiveError(str(exc)) from None
            if labels.size != face_counts[mesh_id]:
                raise ArchiveError(f"{path}: {labels.size} labels but mesh {mesh_id} has "
                                   f"{face_counts[mesh_id]} faces")
            _write(_read_maybe_gz(path), out_dir / "gt" / str(mesh_id)
                   / f"{mesh_id}_{int(m.group(2))}.seg{suffix}", compress)
            report.n_segmentations += 1
        report.meshes_with_gt += 1
    report.withheld_meshes = sorted(withheld)
    if log:
        log(f"converted {report.n_segmentations} human segmentations of "
            f"{report.meshes_with_gt} meshes")
    return report


# ---------------------------------------------------------------------------------------------
# whole pipeline
# ---------------------------------------------------------------------------------------------

def _is_url(source: str) -> bool:
    return urllib.parse.urlparse(str(source)).scheme in ("http", "https", "ftp")


def _download(url: str, folder: Path, timeout: float, log) -> Path:
    name = Path(urllib.parse.urlparse(url).path).name or "archive"
    target = folder / name
    if log:
        log(f"downloading {url}")
    try:
        with urllib.request.urlopen(url, timeout=timeout) as resp, open(target, "wb") as out:
            shutil.copyfileobj(resp, out, _CHUNK)
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        raise ArchiveError(f"cannot download {url} ({reason}); without network access, download "
                           f"the archive elsewhere and pass its file path") from None
    return target


def prepare_psb(source, out_dir, *, compress: bool = True, overwrite: bool = False,
                withhold: Iterable[str] = (), download_timeout: float = 60.0,
                log: Callable[[str], None] | None = None) -> ConversionReport:
    """Prepare the benchmark from the official archive into ``out_dir`` (``meshes/``, ``gt/``).

    Parameters
    ----------
    source : str or Path
        Path of the archive (zip, tar, tar.gz / bz2 / xz), or an http(s) URL, which is
        downloaded (a clear error without network access).
    out_dir : str or Path
        Destination folder; created if missing.
    compress : bool
        Gzip meshes and segmentations.
    overwrite : bool
        Replace an existing ``meshes/`` / ``gt/`` in ``out_dir`` (otherwise: error).
    withhold : iterable of str
        Categories whose human segmentations are not written.
    download_timeout : float
        Seconds before a stalled download is abandoned.
    log : callable, optional
        Receives progress lines.

    Returns
    -------
    ConversionReport

    Notes
    -----
    Extraction and conversion happen in a temporary folder inside ``out_dir`` (same file system,
    so the final move is a rename); ``meshes/`` and ``gt/`` are moved into place only when
    everything succeeded, so a failure leaves ``out_dir`` as it was (and removes it again if
    this call created it).
    """
    out_dir = Path(out_dir)
    withhold = _check_withhold(withhold)  # fail before the (slow) extraction
    existing = [out_dir / n for n in ("meshes", "gt") if (out_dir / n).exists()]
    if existing and not overwrite:
        raise ArchiveError(f"{out_dir} already holds a prepared benchmark "
                           f"({', '.join(p.name for p in existing)}); pass overwrite=True "
                           f"(--overwrite) to replace it")
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    try:
        report = _prepare_into(source, out_dir, existing, compress, withhold, download_timeout, log)
    except BaseException:
        if created and not any(out_dir.iterdir()):
            out_dir.rmdir()  # leave no empty folder behind after a failure
        raise
    report.out_dir = out_dir
    return report


def _prepare_into(source, out_dir: Path, existing: list[Path], compress: bool, withhold,
                  download_timeout: float, log) -> ConversionReport:
    with tempfile.TemporaryDirectory(prefix=".psb-prepare-", dir=out_dir) as tmp:
        tmp = Path(tmp)
        if _is_url(str(source)):
            archive = _download(str(source), tmp, download_timeout, log)
        else:
            archive = Path(source)
            if not archive.is_file():
                raise FileNotFoundError(f"archive {str(archive)!r} does not exist")
        if log:
            log(f"extracting {archive}")
        safe_extract(archive, tmp / "extracted")
        data_dir = find_benchmark_data_dir(tmp / "extracted")
        stage = tmp / "stage"
        report = convert_benchmark_layout(data_dir, stage, compress=compress,
                                          withhold=withhold, log=log)
        for old in existing:
            shutil.rmtree(old)
        for name in ("meshes", "gt"):
            if (stage / name).exists():
                os.replace(stage / name, out_dir / name)
    return report
