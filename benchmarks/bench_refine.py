"""``refine_along_isolines`` alone: a baseline copy of the package against this checkout, on the
inputs full-resolution ``ta.segment`` hands it, in one process, interleaved, process CPU time
(issue 12/13).

Per PSB mesh (full resolution, no decimation) ``ta.segment(mesh, k)`` runs once with every
default; the (vertices, faces, vdist) of its ``refine_along_isolines`` call are recorded. Then
both versions refine that input ``--repeat`` times, alternating which goes first; the best CPU
time of each is kept and the two RefinedMesh are compared bitwise.

The baseline is the package at a git revision under another top-level name::

    mkdir -p /tmp/refbase && git archive main torchakvf | tar -x -C /tmp/refbase \\
        && mv /tmp/refbase/torchakvf /tmp/refbase/torchakvf_base
    PYTHONPATH=$PWD:/tmp/refbase OMP_NUM_THREADS=1 nice -n 5 python benchmarks/bench_refine.py \\
        --out benchmarks/results/refine_vectorized.md
"""
from __future__ import annotations

import argparse
import importlib
import os
import time

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

import torchakvf as ta  # noqa: E402
from torchakvf.evaluate.psb import default_psb_root  # noqa: E402
from torchakvf.parts import boundaries, engine  # noqa: E402

DEFAULT_IDS = (1, 21, 121, 181, 301, 41)


def recorded_input(mesh, k: int):
    """(vertices, faces, vdist) of the refine_along_isolines call of ``ta.segment(mesh, k)``."""
    calls = []
    orig = engine.refine_along_isolines

    def record(vertices, faces, vdist):
        calls.append((vertices.copy(), faces.copy(), vdist.copy()))
        return orig(vertices, faces, vdist)

    engine.refine_along_isolines = record
    try:
        ta.segment(mesh, k)
    finally:
        engine.refine_along_isolines = orig
    return calls[0]


def same(a, b) -> bool:
    return all(getattr(a, n).dtype == getattr(b, n).dtype and getattr(a, n).shape == getattr(b, n).shape
               and getattr(a, n).tobytes() == getattr(b, n).tobytes()
               for n in ("vertices", "faces", "labels", "parent"))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ids", type=int, nargs="+", default=list(DEFAULT_IDS))
    ap.add_argument("--k", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--base", default="torchakvf_base", help="top-level name of the baseline package")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    base = importlib.import_module(f"{a.base}.parts.boundaries").refine_along_isolines
    new = boundaries.refine_along_isolines
    root = default_psb_root()
    rows = []
    for mid in a.ids:
        mesh = ta.load_mesh(root / "meshes" / f"{mid}.off.gz")
        v, f, vdist = recorded_input(mesh, a.k)
        flab = vdist.argmin(axis=1)[f]
        n_cut = int((~((flab[:, 0] == flab[:, 1]) & (flab[:, 1] == flab[:, 2]))).sum())
        best = {"main": np.inf, "branch": np.inf}
        out = {}
        for r in range(a.repeat):
            for name, fn in ([("main", base), ("branch", new)] if r % 2 == 0 else [("branch", new), ("main", base)]):
                t = time.process_time()
                out[name] = fn(v, f, vdist)
                best[name] = min(best[name], time.process_time() - t)
        rows.append((mid, len(f), n_cut, best, same(out["main"], out["branch"])))
        print(rows[-1], flush=True)
    tot = {n: sum(r[3][n] for r in rows) for n in ("main", "branch")}
    lines = [f"| mesh | faces | cut faces | main ms | branch ms | main / branch | bitwise same |",
             "|---:|---:|---:|---:|---:|---:|:---:|"]
    for mid, nf, nc, b, ok in rows:
        lines.append(f"| {mid} | {nf:,} | {nc:,} | {1e3 * b['main']:.1f} | {1e3 * b['branch']:.1f} | "
                     f"{b['main'] / b['branch']:.1f}x | {'yes' if ok else 'NO'} |")
    lines.append(f"| **total** | | | {1e3 * tot['main']:.1f} | {1e3 * tot['branch']:.1f} | "
                 f"**{tot['main'] / tot['branch']:.1f}x** | {sum(r[4] for r in rows)}/{len(rows)} |")
    md = "\n".join(lines) + "\n"
    print(md)
    if a.out:
        with open(a.out, "w") as fh:
            fh.write(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
