"""Preparing the Princeton Segmentation Benchmark from its official archive: conversion of the
benchmark's own layout into this package's, from an archive file or URL.

The official package ``MeshsegBenchmark-1.0`` (zip or tar) holds::

    MeshsegBenchmark-1.0/data/off/N.off                  the 380 meshes
    MeshsegBenchmark-1.0/data/seg/Benchmark/N/N_k.seg    human segmentations
    MeshsegBenchmark-1.0/data/seg/<Algorithm>/...        computer segmentations (ignored here)

:func:`prepare_psb` turns it into the layout :mod:`torchakvf.evaluate.psb` reads::

    <out>/meshes/N.off[.gz]
    <out>/gt/N/N_k.seg[.gz]

Archives are untrusted input: they are unpacked by :func:`~torchakvf.evaluate.archive.safe_extract`
(:mod:`torchakvf.evaluate.archive`; ``ArchiveError`` and ``safe_extract`` are importable from here
too).
"""
from __future__ import annotations

import gzip
import os
import re
import shutil
import tempfile
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from ..errors import MeshError
from ..io.off import off_face_count
from .archive import CHUNK_BYTES, ArchiveError, safe_extract
from .psb import BENCHMARK_CATEGORIES, MAX_MESH_ID, category_of, read_seg

__all__ = [
    "ArchiveError",
    "safe_extract",
    "find_benchmark_data_dir",
    "convert_benchmark_layout",
    "prepare_psb",
    "ConversionReport",
]


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
    report = ConversionReport()
    face_counts = _convert_meshes(data_dir, out_dir, compress, report)
    if log:
        log(f"converted {report.n_meshes} meshes")
    _convert_segmentations(data_dir, out_dir, compress, withhold, face_counts, report)
    if log:
        log(f"converted {report.n_segmentations} human segmentations of "
            f"{report.meshes_with_gt} meshes")
    return report


def _convert_meshes(data_dir: Path, out_dir: Path, compress: bool, report: ConversionReport) -> dict:
    """Copy ``data/off`` into ``meshes/``; returns {mesh id: face count}."""
    suffix = ".gz" if compress else ""
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
    return face_counts


def _convert_segmentations(data_dir: Path, out_dir: Path, compress: bool, withhold: set,
                           face_counts: dict, report: ConversionReport) -> None:
    """Copy ``data/seg/Benchmark`` into ``gt/``, each checked against its mesh's face count."""
    suffix = ".gz" if compress else ""
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
            shutil.copyfileobj(resp, out, CHUNK_BYTES)
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
