"""The three eigensolvers of ``ta.akvf`` on the CPU, same run, one thread, process CPU time:
which one ``solver="auto"`` should take there (issue 13: "LOBPCG ... the default on every device
where it is the fastest, and show by measurement wherever it is not").

Per PSB mesh, ``ta.akvf(batch, n, solver=s)`` for s in krylov (block shift-invert Krylov at its
interior shift where the mesh allows it), lobpcg (the segmented LOBPCG, preconditioned by the
exact shift-invert factor at the definite shift) and lanczos (ARPACK in shift-invert mode on
that factor), best of ``--repeat`` rounds, solvers in a rotating order. Each call is the whole
``ta.akvf`` (cleaning, operator, factor, eigensolve, Whitney vectors). Reported: seconds, ratio
to the Krylov solver, the largest residual, and the largest relative eigenvalue difference to
the Krylov solver's.

Usage::

    OMP_NUM_THREADS=1 python experiments/solver/solvers_cpu.py --out experiments/results/solvers_cpu.md
"""
from __future__ import annotations

import argparse
import math
import platform
import time
from pathlib import Path

import torch

import torchakvf as ta
from torchakvf.bench.script_tools import akvf_agreement, one_thread_on_psb, write_report
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.mesh import MeshBatch

SOLVERS = ("krylov", "lobpcg", "lanczos")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--psb", type=Path, default=default_psb_root())
    p.add_argument("--full", type=int, nargs="*", default=[1, 21, 301], help="PSB ids at full resolution")
    p.add_argument("--decimated", type=int, nargs="*", default=[1, 81, 301], help="PSB ids at 4000 faces")
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    one_thread_on_psb(p, args)
    cases = [(i, None, 32) for i in args.full] + [(i, 4000, 36) for i in args.decimated]
    rows, totals = [], {s: 0.0 for s in SOLVERS}
    for i, coarse, n in cases:
        batch = MeshBatch.from_meshes([ta.load_mesh(args.psb / "meshes" / f"{i}.off.gz")], coarse_faces=coarse)
        best, res = {}, {}
        for rnd in range(args.repeat):
            for j in range(len(SOLVERS)):
                s = SOLVERS[(j + rnd) % len(SOLVERS)]
                t = time.process_time()
                res[s] = ta.akvf(batch, n=n, solver=s)
                best[s] = min(best.get(s, math.inf), time.process_time() - t)
        for s in SOLVERS:
            totals[s] += best[s]
        rows.append((i, "full" if coarse is None else "4000 faces", len(batch.edges), n, best, {
            s: (float(r.residuals.max()), akvf_agreement(res["krylov"], r)[0], bool(r.converged.all()))
            for s, r in res.items()}))
        print(i, coarse, {s: round(v, 3) for s, v in best.items()}, flush=True)
    head = " | ".join(f"{s} s" for s in SOLVERS)
    lines = [
        "# The eigensolvers of `ta.akvf` on the CPU",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, python "
        f"{platform.python_version()}, one thread, process CPU time, best of {args.repeat} rounds, solvers "
        "in rotating order (experiments/solver/solvers_cpu.py)",
        "- whole `ta.akvf(batch, n, solver=...)` calls; krylov at its interior shift where the mesh "
        "allows it, lobpcg and lanczos on the definite shift's factor; res = largest residual; "
        "Δλ = largest |λ − λ_krylov| / max(|λ_krylov|, 1)",
        "",
        f"| mesh | resolution | edges | n | {head} | lobpcg / krylov | lanczos / krylov | res (k / lo / la) "
        "| Δλ lobpcg | Δλ lanczos | converged |",
        "|---:|---|---:|---:|" + "---:|" * (len(SOLVERS) + 5) + "---|",
    ]
    for i, kind, e, n, best, chk in rows:
        lines.append(
            f"| {i} | {kind} | {e:,} | {n} | " + " | ".join(f"{best[s]:.3f}" for s in SOLVERS)
            + f" | {best['lobpcg'] / best['krylov']:.2f}x | {best['lanczos'] / best['krylov']:.2f}x | "
            + " / ".join(f"{chk[s][0]:.0e}" for s in SOLVERS)
            + f" | {chk['lobpcg'][1]:.0e} | {chk['lanczos'][1]:.0e} | "
            + "/".join("y" if chk[s][2] else "n" for s in SOLVERS) + " |")
    lines.append("| **total** | | | | " + " | ".join(f"{totals[s]:.2f}" for s in SOLVERS)
                 + f" | **{totals['lobpcg'] / totals['krylov']:.2f}x** "
                   f"| **{totals['lanczos'] / totals['krylov']:.2f}x** | | | | |")
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
