#!/usr/bin/env python3
"""Prepare the Princeton Segmentation Benchmark from its official archive.

Converts ``MeshsegBenchmark-1.0`` (``data/off/N.off``, ``data/seg/Benchmark/N/N_k.seg``) into
the layout torchakvf reads (``<out>/meshes/N.off.gz``, ``<out>/gt/N/N_k.seg.gz``)::

    python datasets_scripts/prepare_psb.py MeshsegBenchmark-1.0.zip --out data/psb
    python datasets_scripts/prepare_psb.py https://.../MeshsegBenchmark-1.0.zip --out data/psb

A URL is only fetched when the network is reachable; otherwise the script says so and asks for
a local file. Archive members that would land outside the output folder are refused. Errors
print one line on stderr and exit with status 1. The logic lives in
:mod:`torchakvf.evaluate.psb_archive`.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

try:
    import torchakvf.evaluate.psb_archive  # noqa: F401  (installed, or run from the repo root)
except ImportError:  # run as a plain script from a checkout: make the package importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from torchakvf.evaluate.psb import BENCHMARK_CATEGORIES  # noqa: E402
from torchakvf.evaluate.psb_archive import prepare_psb  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="prepare_psb",
        description="Prepare the Princeton Segmentation Benchmark (meshes/ and gt/) "
                    "from the official MeshsegBenchmark-1.0 archive.")
    parser.add_argument("source", help="the archive (.zip, .tar, .tar.gz/.bz2/.xz) or an "
                                       "http(s) URL to download it from")
    parser.add_argument("--out", required=True, type=Path,
                        help="output folder (receives meshes/ and gt/)")
    parser.add_argument("--no-compress", action="store_true",
                        help="write plain .off/.seg files instead of .gz")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace meshes/ and gt/ already in the output folder")
    parser.add_argument("--withhold", action="append", default=[], metavar="CATEGORY",
                        choices=BENCHMARK_CATEGORIES,
                        help="do not write the human segmentations of this category "
                             "(repeatable; for blind evaluation)")
    parser.add_argument("--timeout", type=float, default=60.0,
                        help="download timeout in seconds (URL sources only)")
    parser.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    args = parser.parse_args(argv)

    log = None if args.quiet else (lambda msg: print(msg, flush=True))
    try:
        report = prepare_psb(args.source, args.out, compress=not args.no_compress,
                             overwrite=args.overwrite, withhold=args.withhold,
                             download_timeout=args.timeout, log=log)
    # ArchiveError is a ValueError, FileNotFoundError an OSError: every expected failure.
    except (OSError, ValueError) as exc:
        message = " ".join(str(exc).split()) or type(exc).__name__
        print(f"prepare_psb: error: {message}", file=sys.stderr)
        return 1
    if log:
        log(f"done: {report.summary()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
