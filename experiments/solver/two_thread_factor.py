"""The numeric factor of the Krylov solver's interior shift on one and on two threads
(:mod:`torchakvf.solvers.cholmod_subtrees`), PSB meshes at full resolution: wall time, best of
``--repeat`` interleaved calls, the plan's own estimate, and that the two factors are the same
bit for bit (their solves of the same right-hand sides compared).

    PYTHONPATH=$PWD nice python3 experiments/solver/two_thread_factor.py --repeat 7 \\
        --out experiments/results/two_thread_factor.md
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
import torch

import torchakvf as ta
from torchakvf.solvers.cholesky import CpuFactor, lower_pattern
from torchakvf.solvers.factor import INTERIOR_SHIFT_PER_PAIR
from torchakvf.solvers.remedy import auto_operator


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--psb", type=Path, default=Path(os.environ.get("TORCHAKVF_PSB", "../shared/psb")))
    p.add_argument("--ids", default="1,21,121,181,301")
    p.add_argument("--n", type=int, default=32)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--out", type=Path, default=Path("experiments/results/two_thread_factor.md"))
    a = p.parse_args()
    saved = torch.get_num_threads()
    rows, tot = [], {1: 0.0, 2: 0.0}
    for i in [int(v) for v in a.ids.split(",")]:
        batch = ta.MeshBatch.from_meshes([ta.load_mesh(a.psb / "meshes" / f"{i}.off.gz")])
        system, _ = auto_operator(batch)
        r, c, v, n = system.block(0)
        pattern, diagonal = lower_pattern(r, c, v, n), -INTERIOR_SHIFT_PER_PAIR * a.n * system.mass.double()
        first = CpuFactor(pattern)
        plan = first.symbolic.two_thread_plan()
        rhs = torch.from_numpy(np.random.default_rng(0).standard_normal((4, n)))
        best, solves = {1: np.inf, 2: np.inf}, {}
        for rep in range(a.repeat):
            for threads in ((1, 2) if rep % 2 == 0 else (2, 1)):
                torch.set_num_threads(threads)
                f = CpuFactor(pattern, like=first.symbolic)
                t0 = time.perf_counter()
                f.factorize(diagonal, indefinite=True)
                best[threads] = min(best[threads], time.perf_counter() - t0)
                solves[threads] = f.factor.solve_rows(rhs)
        torch.set_num_threads(saved)
        same = bool(torch.equal(solves[1], solves[2]))
        tot[1] += best[1]
        tot[2] += best[2]
        rows.append(f"| {i} | {n} | {first.factor.factor_flops / 1e6:.0f} | "
                    f"{'-' if plan is None else f'{plan.speedup:.2f}'} | {1e3 * best[1]:.0f} | {1e3 * best[2]:.0f} | "
                    f"{best[1] / best[2]:.2f} | {same} |")
        print(rows[-1], flush=True)
    lines = ["# The interior-shift factor on one and two threads", "",
             f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, "
             f"{os.cpu_count()} CPUs "
             f"(shared with other jobs: wall times are best of {a.repeat} interleaved calls); σ = "
             f"{INTERIOR_SHIFT_PER_PAIR:g} x {a.n}; `experiments/solver/two_thread_factor.py`",
             "- plan: the subtrees' estimated speed-up (Σ column count² per thread, the rows above after both); "
             "'-': below the size where the factor is split (one thread either way)", "",
             "| PSB | edges | MFLOP | plan | 1 thread ms | 2 threads ms | 1 / 2 | same bits |",
             "|---:|---:|---:|---:|---:|---:|---:|---|", *rows,
             f"| **total** | | | | {1e3 * tot[1]:.0f} | {1e3 * tot[2]:.0f} | **{tot[1] / tot[2]:.2f}** | |"]
    a.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
