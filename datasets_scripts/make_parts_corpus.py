#!/usr/bin/env python3
"""Write the procedural corpus of part-labelled shapes (training and selection data).

Every shape is drawn from a seed by :func:`torchakvf.shapes.procedural.make_procedural`, so the
corpus is the same bits on every run, whatever the worker count::

    python datasets_scripts/make_parts_corpus.py --out corpus/ --per-family 30 --seed 0

writes ``<out>/<family>/<family>_<i:03d>.off`` (the mesh), ``<family>_<i:03d>.seg`` (one part
label per face, the PSB's format) and ``<out>/index.json`` (per shape: name, family, kind,
n_parts, part names, seed, faces and the main parameters drawn). Shape i of a family has seed
``1000 * seed + i``. See docs/procedural_corpus.md. Errors print one line on stderr and exit
with status 1.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

try:
    import torchakvf.shapes.procedural  # noqa: F401  (installed, or run from the repo root)
except ImportError:  # run as a plain script from a checkout: make the package importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from torchakvf import __version__  # noqa: E402
from torchakvf.errors import TorchAKVFError  # noqa: E402
from torchakvf.io import atomic_write_bytes, write_off, write_seg  # noqa: E402
from torchakvf.shapes.procedural import FAMILIES, make_procedural  # noqa: E402

#: Shapes per family a seed can number (shape i of a family has seed 1000 * seed + i).
MAX_PER_FAMILY = 1000


def shape_seed(seed: int, i: int) -> int:
    """The seed of shape i of each family in the corpus of ``seed``: corpora of distinct seeds
    share no shape."""
    return MAX_PER_FAMILY * seed + i


def make_one(task) -> dict:
    """Draw, mesh and write one shape; its index entry (and the seconds it took, apart)."""
    out, family, i, seed, detail = task
    start = time.process_time()
    ps = make_procedural(family, seed, detail)
    stem = f"{family}_{i:03d}"
    folder = Path(out) / family
    folder.mkdir(parents=True, exist_ok=True)
    write_off(folder / f"{stem}.off", ps.shape.vertices, ps.shape.faces)
    write_seg(folder / f"{stem}.seg", ps.shape.part_labels)
    entry = {"name": stem, "family": family, "kind": ps.kind, "n_parts": ps.shape.n_parts, "parts": ps.part_names,
             "seed": seed, "faces": int(len(ps.shape.faces)), "vertices": int(len(ps.shape.vertices)),
             "params": ps.params}
    return {"entry": entry, "seconds": time.process_time() - start}


def make_corpus(out, families, per_family: int, seed: int, workers: int = 1, detail: float = 1.0,
                log=print) -> list[dict]:
    """Write the corpus under ``out`` (see the module docstring); returns the index entries,
    ordered by family then number."""
    tasks = [(str(out), f, i, shape_seed(seed, i), detail) for f in families for i in range(per_family)]
    done = []
    if workers > 1:
        with ProcessPoolExecutor(workers) as pool:
            for res in pool.map(make_one, tasks, chunksize=1):
                done.append(res)
                _progress(log, res, len(done), len(tasks))
    else:
        for task in tasks:
            done.append(make_one(task))
            _progress(log, done[-1], len(done), len(tasks))
    index = [res["entry"] for res in done]
    body = {"generator": "torchakvf.shapes.procedural", "version": __version__, "seed": seed,
            "per_family": per_family, "detail": detail,
            "families": {f: {"kind": FAMILIES[f].kind, "about": FAMILIES[f].about} for f in families},
            "shapes": index}
    atomic_write_bytes(Path(out) / "index.json", (json.dumps(body, indent=1) + "\n").encode())
    return index


def _progress(log, res, n: int, total: int) -> None:
    if log is None:
        return
    e = res["entry"]
    log(f"[{n}/{total}] {e['name']}: k={e['n_parts']} faces={e['faces']} {e['params']['quality']} "
        f"{res['seconds']:.1f}s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="make_parts_corpus", description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path, help="output folder")
    parser.add_argument("--per-family", type=int, default=30, help="shapes per family (default 30)")
    parser.add_argument("--seed", type=int, default=0, help="corpus seed (default 0)")
    parser.add_argument("--families", default=",".join(FAMILIES),
                        help=f"comma-separated families (default all: {', '.join(FAMILIES)})")
    parser.add_argument("--workers", type=int, default=1, help="processes (default 1; the output is the same)")
    parser.add_argument("--detail", type=float, default=1.0,
                        help="face-count multiplier (default 1: about 6,000-40,000 faces a shape)")
    parser.add_argument("-q", "--quiet", action="store_true", help="print only errors and the summary")
    args = parser.parse_args(argv)
    families = [f for f in args.families.split(",") if f]
    try:
        unknown = [f for f in families if f not in FAMILIES]
        if unknown or not families:
            raise TorchAKVFError(f"unknown families {unknown}; choose from {', '.join(FAMILIES)}")
        if not 1 <= args.per_family <= MAX_PER_FAMILY or args.seed < 0 or args.workers < 1:
            raise TorchAKVFError(f"--per-family must be in 1..{MAX_PER_FAMILY}, --seed >= 0, --workers >= 1")
        start = time.perf_counter()
        index = make_corpus(args.out, families, args.per_family, args.seed, args.workers, args.detail,
                            log=None if args.quiet else (lambda m: print(m, flush=True)))
    except (TorchAKVFError, OSError) as exc:
        print(f"make_parts_corpus: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    faces = [e["faces"] for e in index]
    print(f"wrote {len(index)} shapes of {len(families)} families to {args.out} ({min(faces)}-{max(faces)} faces, "
          f"{time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
