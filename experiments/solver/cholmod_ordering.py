"""Where the CPU factor's time goes, per fill-reducing ordering: cholespy's constructor (NESDIS,
the path before) against CHOLMOD called directly (``torchakvf.solvers.cholmod``) with AMD (its
default choice here), METIS and NESDIS.

Per PSB mesh (full resolution, cleaned, ``remedy="smooth"`` operator at σ = -1), best of
``--repeat`` rounds, sides interleaved, wall clock, one thread:

* **analyse** — ordering + symbolic analysis (``CholmodFactor(...)``);
* **numeric** — the numeric factor (``factorize``);
* **solve4** — one solve of 4 right-hand sides (the Krylov solver's block; best of 5);
* **nnz(L), MFLOP** — CHOLMOD's own prediction for the ordering.

cholespy's constructor does ordering, analysis and numeric factor in one call (column "total").

Usage::

    OMP_NUM_THREADS=1 python experiments/solver/cholmod_ordering.py --out experiments/results/cholmod_ordering.md
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import time
from pathlib import Path

import numpy as np
import torch

from torchakvf.bench.script_tools import best_of, write_report
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.fields.akvf import as_batch
from torchakvf.io import load_mesh
from torchakvf.mesh import clean_mesh
from torchakvf.operators.killing import killing_operator
from torchakvf.solvers import cholmod
from torchakvf.solvers.cholesky import CpuFactor, cholesky, lower_pattern


def shifted_pattern(mesh_id: int, psb: Path, sigma: float = -1.0):
    system = killing_operator(as_batch(clean_mesh(load_mesh(psb / "meshes" / f"{mesh_id}.off.gz"))),
                              remedy="smooth")
    idx, vals = system.stiffness.indices(), system.stiffness.values()
    pattern = lower_pattern(idx[0], idx[1], vals, len(system.mass))
    return pattern, -sigma * system.mass.to(torch.float64)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--psb", type=Path, default=default_psb_root())
    p.add_argument("--ids", type=int, nargs="+", default=[1, 21, 121, 181, 301])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    if args.psb is None or not (args.psb / "meshes").is_dir():
        p.error(f"no PSB meshes at {args.psb}: pass --psb or set TORCHAKVF_PSB")
    if cholmod.library() is None:
        p.error("CHOLMOD cannot be called directly here (cholmod.library() is None)")
    torch.set_num_threads(1)
    sides = ["cholespy", None, "metis", "nesdis"]
    rows = []
    for i in args.ids:
        pattern, diagonal = shifted_pattern(i, args.psb)
        n = pattern[0]
        rhs = torch.from_numpy(np.random.default_rng(0).standard_normal((4, n)))
        best = {s: {} for s in sides}
        for _ in range(args.repeat):
            for side in sides:
                if side == "cholespy":
                    with cholmod.disabled():
                        t = time.perf_counter()
                        solver, _ = cholesky(pattern, diagonal)
                        best[side]["total"] = min(best[side].get("total", math.inf), time.perf_counter() - t)
                    out = torch.empty(n, 4, dtype=torch.float64)
                    rhs_c = rhs.T.contiguous()
                    ts, _ = best_of(lambda: solver.solve(rhs_c, out), 5)
                else:
                    t = time.perf_counter()
                    eng = CpuFactor(pattern, ordering=side)
                    ta_ = time.perf_counter() - t
                    t = time.perf_counter()
                    assert eng.factorize(diagonal)
                    tn = time.perf_counter() - t
                    ts, _ = best_of(lambda: eng.factor.solve_rows(rhs), 5)
                    b = best[side]
                    b["analyse"] = min(b.get("analyse", math.inf), ta_)
                    b["numeric"] = min(b.get("numeric", math.inf), tn)
                    b["total"] = min(b.get("total", math.inf), ta_ + tn)
                    b["nnz"], b["mflop"] = eng.factor.factor_nonzeros, eng.factor.factor_flops / 1e6
                    b["ordering"] = eng.factor.ordering
                best[side]["solve4"] = min(best[side].get("solve4", math.inf), ts)
        rows.append((i, n, best))
        print(i, n, {k: {kk: (round(vv * 1e3, 1) if isinstance(vv, float) and vv < 100 else vv)
                         for kk, vv in v.items()} for k, v in best.items()}, flush=True)

    lines = [
        "# The CPU factor per ordering: cholespy's constructor against CHOLMOD called directly",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, numpy "
        f"{np.__version__}, python {platform.python_version()}, {os.cpu_count()} CPUs, one thread; "
        f"best of {args.repeat} interleaved rounds, wall ms (experiments/solver/cholmod_ordering.py)",
        "- matrix: R - σS1 at σ = -1 of the full-resolution mesh (remedy smooth); solve4 = one solve "
        "of 4 right-hand sides (best of 5)",
        "- 'default' is CHOLMOD's own choice (nmethods = 0), what `ta.akvf` uses on the CPU now",
        "",
        "| mesh | edges | cholespy (NESDIS) total | solve4 | default: ordering | analyse | numeric | total | "
        "solve4 | nnz(L) | MFLOP | METIS total | solve4 | nnz(L) | MFLOP | NESDIS analyse | numeric | "
        "total | solve4 | nnz(L) | MFLOP | cholespy / default (factor) |",
        "|" + "---:|" * 22,
    ]
    ms = lambda x: f"{x * 1e3:.0f}"
    for i, n, b in rows:
        c, d, m, nd = b["cholespy"], b[None], b["metis"], b["nesdis"]
        lines.append(
            f"| {i} | {n} | {ms(c['total'])} | {c['solve4'] * 1e3:.1f} | {d['ordering']} | {ms(d['analyse'])} | "
            f"{ms(d['numeric'])} | {ms(d['total'])} | {d['solve4'] * 1e3:.1f} | {d['nnz']:,.0f} | "
            f"{d['mflop']:.0f} | {ms(m['total'])} | {m['solve4'] * 1e3:.1f} | {m['nnz']:,.0f} | "
            f"{m['mflop']:.0f} | {ms(nd['analyse'])} | {ms(nd['numeric'])} | {ms(nd['total'])} | "
            f"{nd['solve4'] * 1e3:.1f} | {nd['nnz']:,.0f} | {nd['mflop']:.0f} | "
            f"{c['total'] / d['total']:.2f}x |")
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
