"""The batched solver (a batch solved as one, ``batched=True``, the accelerator's path) on the CPU:
two checkouts of the package compared in one run, interleaved, on a batch of decimated PSB meshes
with mesh 114 (which no shift makes definite when decimated).

For each checkout (``--tree``, a folder holding the ``torchakvf`` package; the first is the
baseline), in a fresh process per round: wall time of ``AKVFSolver(batch, batched=True).solve(n)``
(operator, shifts, factors, LOBPCG, Whitney vectors; the loading and decimation are not timed),
the numeric factorizations it made (every trial shift counted, with the sum of their orders),
its LOBPCG calls (and the meshes in them), and the host synchronizations per LOBPCG iteration
and per Horst (untangling) step, counted with ``tests/helpers/syncs.py`` as the tests count them.
Rounds alternate between the checkouts; the best of ``--repeat`` wall times is kept. Both
checkouts precondition with one block-diagonal factor of the batch, as on a GPU
(``lobpcg.BLOCK_FACTOR_ON`` set to include the CPU).

    PYTHONPATH=$PWD python benchmarks/batched_solver.py --tree BASELINE_DIR --tree . \\
        --out benchmarks/results/batched_solver.md

(BASELINE_DIR: e.g. ``git archive <commit> | tar -x -C DIR``.)
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
IDS = [1, 21, 41, 61, 81, 114, 161, 181, 241, 301]


def _worker(args) -> None:
    """One round in this process (the checkout is first on sys.path): prints one JSON line."""
    import warnings

    import torch

    sys.path.insert(0, str(HERE.parent / "tests"))
    import torchakvf as ta
    from torchakvf.solvers import akvf_solver, group_solver
    from torchakvf.solvers import cholesky as chol
    from torchakvf.solvers import lobpcg as lobpcg_module

    # The accelerator's preconditioner (one block-diagonal factor per batch) on the CPU too,
    # for a checkout whose batched=True would take one factor per mesh there.
    lobpcg_module.BLOCK_FACTOR_ON = ("cpu", "cuda")
    torch.set_num_threads(1)
    warnings.simplefilter("ignore")
    meshes = [ta.load_mesh(args.psb / "meshes" / f"{i}.off.gz") for i in args.ids]
    batch = ta.MeshBatch.from_meshes(meshes, coarse_faces=args.coarse_faces)
    sizes, groups = [], []
    real_cholesky, real_lobpcg = chol.cholesky, group_solver.segmented_lobpcg

    def cholesky(pattern, diagonal, engine=None):
        sizes.append(int(pattern[0]))
        return real_cholesky(pattern, diagonal, engine)

    def lobpcg(system, n, **kw):
        groups.append(len(kw.get("names") or []))
        return real_lobpcg(system, n, **kw)

    chol.cholesky, group_solver.segmented_lobpcg = cholesky, lobpcg
    t, cpu = time.perf_counter(), time.process_time()
    solver = akvf_solver.AKVFSolver(batch, batched=True)
    res = solver.solve(args.n)
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu
    chol.cholesky, group_solver.segmented_lobpcg = real_cholesky, real_lobpcg
    print(json.dumps({"wall": wall, "cpu": cpu, "factorizations": len(sizes), "factored_rows": sum(sizes),
                      "lobpcg_calls": groups, "fell_back": [b for b, _ in solver.fell_back],
                      "eigenvalues": res.eigenvalues.tolist(), "shifts": res.shifts.tolist(),
                      "syncs_lobpcg": _lobpcg_syncs(), "syncs_horst": _horst_syncs()}))


def _lobpcg_syncs() -> float:
    """Synchronizations per LOBPCG iteration (block factor), as tests/test_lobpcg.py counts them."""
    from helpers.eigen_checks import batch_with_a_low_mesh
    from helpers.syncs import SyncCounter

    from torchakvf.solvers import lobpcg

    system = batch_with_a_low_mesh()
    block = lobpcg.BlockDiagonalFactor(system)

    def counted(iterations: int) -> int:
        counter, real = SyncCounter(), block.solve

        def solve(rhs):
            with counter.paused():
                return real(rhs)

        block.solve = solve
        make = lobpcg.BlockDiagonalFactor
        try:
            if hasattr(lobpcg, "CHECK_EVERY"):      # takes the block factor as ``factors``
                with counter:
                    lobpcg.segmented_lobpcg(system, 8, tol=1e-30, max_iter=iterations, factors=block)
            else:
                lobpcg.BlockDiagonalFactor = lambda *a, **k: block
                with counter:
                    lobpcg.segmented_lobpcg(system, 8, tol=1e-30, max_iter=iterations, block_factor=True)
        finally:
            lobpcg.BlockDiagonalFactor = make
            del block.solve
        return counter.total

    return (counted(10) - counted(4)) / 6


def _horst_syncs() -> float:
    """Synchronizations per batched Horst step, as tests/test_untangle.py counts them."""
    import importlib

    import torch
    from helpers.syncs import SyncCounter

    untangle = importlib.import_module("torchakvf.fields.untangle")

    y = torch.randn(2, 300, 6, generator=torch.Generator().manual_seed(0), dtype=torch.float64)

    def counted(steps: int) -> int:
        with SyncCounter() as counter:
            untangle.orthomax(y, 3, 0, 1e-30, steps, torch.float32)
        return counter.total

    return (counted(12) - counted(3)) / 18


def main() -> None:
    from torchakvf.evaluate.psb import default_psb_root

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tree", type=Path, action="append", required=True,
                   help="a folder holding the torchakvf package (first: the baseline)")
    p.add_argument("--psb", type=Path, default=default_psb_root())
    p.add_argument("--ids", type=int, nargs="+", default=IDS)
    p.add_argument("--coarse-faces", type=int, default=4000)
    p.add_argument("--n", type=int, default=16)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--out", type=Path)
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.worker:
        return _worker(args)
    rounds = {str(t): [] for t in args.tree}
    for _ in range(args.repeat):
        for tree in args.tree:
            env = dict(os.environ, PYTHONPATH=str(tree.resolve()), OMP_NUM_THREADS="1")
            cmd = [sys.executable, __file__, "--worker", "--psb", str(args.psb), "--n", str(args.n),
                   "--coarse-faces", str(args.coarse_faces), "--tree", str(tree), "--ids",
                   *map(str, args.ids)]
            out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
            rounds[str(tree)].append(json.loads(out.strip().splitlines()[-1]))
    _report(args, rounds)


def _report(args, rounds: dict) -> None:
    import numpy as np

    sys.path.insert(0, str(HERE))
    from torchakvf.bench.script_tools import write_report

    trees = list(rounds)
    base = rounds[trees[0]][-1]
    lines = [f"# Batched solver on the CPU (`batched=True`): {len(args.ids)} PSB meshes at "
             f"{args.coarse_faces} faces, n = {args.n}", "",
             f"PSB meshes {', '.join(map(str, args.ids))} (114: no shift makes it definite "
             "decimated), one torch thread, best of "
             f"{args.repeat} interleaved rounds, each in a fresh process. Command: "
             "`PYTHONPATH=$PWD python benchmarks/batched_solver.py --tree BASELINE --tree .` "
             "(BASELINE: the checkout before, e.g. `git archive <commit> | tar -x -C DIR`).", "",
             "| checkout | wall s (best) | baseline / this (wall) | CPU s (best) | baseline / this (CPU) "
             "| factorizations | rows factored | LOBPCG calls (meshes each) | fell back | syncs / LOBPCG "
             "iteration | syncs / Horst step |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    best0 = min(r["wall"] for r in rounds[trees[0]])
    cpu0 = min(r["cpu"] for r in rounds[trees[0]])
    for t in trees:
        r, best = rounds[t][-1], min(x["wall"] for x in rounds[t])
        cpu = min(x["cpu"] for x in rounds[t])
        lines.append(f"| {t} | {best:.2f} | {best0 / best:.2f}x | {cpu:.2f} | {cpu0 / cpu:.2f}x | "
                     f"{r['factorizations']} | {r['factored_rows']} | {len(r['lobpcg_calls'])} ({r['lobpcg_calls']}) | "
                     f"{r['fell_back']} | {r['syncs_lobpcg']:.2f} | {r['syncs_horst']:.2f} |")
    for t in trees[1:]:
        a, b = np.array(base["eigenvalues"]), np.array(rounds[t][-1]["eigenvalues"])
        rel = float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1.0)))
        lines += ["", f"Eigenvalues of {t} against the baseline: largest difference {rel:.1e} "
                  "relative (max(|λ|, 1)); shifts "
                  f"{'equal' if base['shifts'] == rounds[t][-1]['shifts'] else 'differ'}."]
    walls = {t: ", ".join(f"{x['wall']:.2f} ({x['cpu']:.2f} CPU)" for x in rounds[t]) for t in trees}
    lines += ["", "Wall (CPU) seconds of every round: " + "; ".join(f"{t}: {w}" for t, w in walls.items())]
    for t in trees[1:]:
        ratios = [a["wall"] / b["wall"] for a, b in zip(rounds[trees[0]], rounds[t])]
        lines += ["", f"Per-round wall ratios, baseline / {t}: " + ", ".join(f"{x:.2f}" for x in ratios)]
    lines.append("")
    write_report("\n".join(lines), args.out)


if __name__ == "__main__":
    main()
