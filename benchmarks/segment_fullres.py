"""Full-resolution segmentation: ``ta.segment`` against the plain numpy/scipy pipeline, measured
in the same run, one thread, interleaved, in process CPU time (issue 13, "Full-resolution
``ta.segment`` ≥ 5x the plain pipeline").

Per PSB mesh (loaded from disk once, untimed), at k = ``--k``, best of ``--repeat`` rounds, the
sides one after another in every round:

* **ta paper** — ``torchakvf.segment(mesh, k, method="paper")`` at full resolution (no
  decimation): the same method as the plain pipeline, so the ratio is the engine's speed.
* **ta default** — ``torchakvf.segment(mesh, k)`` with every default (method "merge": 3k
  clusters, merging, graph cut), at full resolution.
* **plain** — :func:`torchakvf.scipy_reference.segment_scipy` on the cleaned mesh: scipy
  operator, ``eigsh`` shift-invert with SuperLU, numpy orthomax, numpy spherical k-means
  (20 restarts), as a user would write it.

CPU time (``time.process_time``) rather than wall time: on a shared machine the wall time of
one call moves 2-3x between rounds; the process's CPU time does not, and with one thread it is
the work done. Labels are compared (ta paper against plain, up to part names) as a check that
both sides did the same job.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/segment_fullres.py         # PSB 1 21 121 181 301 41
    python benchmarks/segment_fullres.py --ids 21 --repeat 1 --out /tmp/x.md
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("OMP_NUM_THREADS", "1")

import torch  # noqa: E402

import torchakvf as ta  # noqa: E402
from torchakvf.evaluate.metrics import rand_index_error  # noqa: E402
from torchakvf.evaluate.psb import default_psb_root  # noqa: E402
from torchakvf.scipy_reference import segment_scipy  # noqa: E402

DEFAULT_IDS = (1, 21, 121, 181, 301, 41)


def _cpu(fn):
    t = time.process_time()
    out = fn()
    return time.process_time() - t, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ids", type=int, nargs="+", default=list(DEFAULT_IDS))
    ap.add_argument("--k", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--psb", default=None)
    ap.add_argument("--out", default="benchmarks/results/segment_fullres.md")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    root = Path(a.psb) if a.psb else default_psb_root()
    if root is None:
        print("no PSB folder (set TORCHAKVF_PSB)", file=sys.stderr)
        return 2
    rows = []
    for mid in a.ids:
        mesh = ta.load_mesh(root / "meshes" / f"{mid}.off.gz")
        clean = ta.clean_mesh(mesh)
        best = {"ta paper": np.inf, "ta default": np.inf, "plain": np.inf}
        labels = {}
        for r in range(a.repeat):
            sides = [("ta paper", lambda: ta.segment(mesh, a.k, method="paper").meshes[0].labels),
                     ("ta default", lambda: ta.segment(mesh, a.k).meshes[0].labels),
                     ("plain", lambda: clean.labels_to_input_faces(
                         segment_scipy(clean.vertices, clean.faces, a.k)))]
            if r % 2:
                sides = sides[::-1]
            for name, fn in sides:
                s, lab = _cpu(fn)
                best[name] = min(best[name], s)
                labels[name] = lab
        agree = 1.0 - rand_index_error(labels["ta paper"], labels["plain"])
        rows.append((mid, len(mesh.faces), best, agree))
        print(mid, len(mesh.faces), {k: round(v, 2) for k, v in best.items()}, f"RI {agree:.3f}", flush=True)

    tot = {k: sum(r[2][k] for r in rows) for k in rows[0][2]}
    lines = ["# Full-resolution segmentation: ta.segment vs the plain numpy/scipy pipeline", "",
             f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, "
             f"{platform.processor() or platform.machine()}, one thread; k = {a.k}; best of {a.repeat} "
             "rounds, process CPU time, sides interleaved (benchmarks/segment_fullres.py)",
             "- ta paper: `ta.segment(mesh, k, method='paper')`; ta default: `ta.segment(mesh, k)` (merge + "
             "graph cut); plain: `scipy_reference.segment_scipy` (eigsh/SuperLU, numpy orthomax, numpy "
             "k-means 20 restarts); all at full resolution", "",
             "| mesh | faces | ta paper s | ta default s | plain s | plain / ta paper | plain / ta default "
             "| RI(ta paper, plain) |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for mid, nf, b, agree in rows:
        lines.append(f"| {mid} | {nf:,} | {b['ta paper']:.2f} | {b['ta default']:.2f} | {b['plain']:.2f} | "
                     f"{b['plain'] / b['ta paper']:.2f}x | {b['plain'] / b['ta default']:.2f}x | {agree:.3f} |")
    lines.append(f"| **total** | | {tot['ta paper']:.2f} | {tot['ta default']:.2f} | {tot['plain']:.2f} | "
                 f"**{tot['plain'] / tot['ta paper']:.2f}x** | **{tot['plain'] / tot['ta default']:.2f}x** | |")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
