"""The block Krylov solver at its interior shift against the definite shift, same run, one
thread, process CPU time (the choice in torchakvf.solvers.factor.InteriorFactor).

Per PSB mesh, ``ta.akvf(mesh, n)`` with its defaults twice per round, sides alternating, best
of ``--repeat`` rounds:

* **interior** — the default: CPU factor at σ = INTERIOR_SHIFT_PER_PAIR · n where the mesh
  allows it (:func:`torchakvf.solvers.factor.interior_factor`);
* **definite** — the same call with ``interior_factor`` replaced by the definite ladder
  (σ = -1, -8, ... until R - σS1 is positive definite): the solver before.

Reported: each side's shift, right-hand sides solved, seconds, and the largest relative
eigenvalue difference between the sides (each pair has residual <= tol, so they agree to about
tol·max(|λ|, 1) at worst, r²/gap in practice), with the dropped spurious counts.

Usage::

    OMP_NUM_THREADS=1 python experiments/solver/interior_shift.py --out experiments/results/interior_shift.md
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import math
import platform
import time
from pathlib import Path

import torch

import torchakvf as ta
from torchakvf.bench.script_tools import akvf_agreement, one_thread_on_psb, write_report
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.mesh import MeshBatch
from torchakvf.solvers.factor import interior_factor

FULL = [1, 21, 121, 181, 301, 41, 81]
DECIMATED = [1, 41, 81, 91, 101, 121, 141, 181, 301, 341]


def definite_only(system, b, need, definite):
    """An ``interior_factor`` that never takes an interior shift: every mesh at its definite
    shift, the Krylov solver as it was before the interior shift."""
    return definite()


@contextlib.contextmanager
def interior_factor_as(fn):
    """Within the block, ``ta.akvf`` makes its Krylov factors with ``fn`` (the signature of
    :func:`torchakvf.solvers.factor.interior_factor`) instead; restored on leaving."""
    akvf_module = importlib.import_module("torchakvf.solvers.group_solver")
    kept = akvf_module.interior_factor
    akvf_module.interior_factor = fn
    try:
        yield
    finally:
        akvf_module.interior_factor = kept


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--psb", type=Path, default=default_psb_root())
    p.add_argument("--full", type=int, nargs="*", default=FULL, help="PSB ids at full resolution")
    p.add_argument("--decimated", type=int, nargs="*", default=DECIMATED, help="PSB ids at 4000 faces")
    p.add_argument("--n-full", type=int, default=32)
    p.add_argument("--n-decimated", type=int, default=36, help="eval's AKVF count")
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    one_thread_on_psb(p, args)
    cases = [(i, None, args.n_full) for i in args.full] + [(i, 4000, args.n_decimated) for i in args.decimated]
    rows, totals = [], {"full": [0.0, 0.0], "decimated": [0.0, 0.0]}
    for i, coarse, n in cases:
        batch = MeshBatch.from_meshes([ta.load_mesh(args.psb / "meshes" / f"{i}.off.gz")], coarse_faces=coarse)
        best, res = {}, {}
        for _ in range(args.repeat):
            for side, fn in (("definite", definite_only), ("interior", interior_factor)):
                with interior_factor_as(fn):
                    t = time.process_time()
                    r = ta.akvf(batch, n=n)
                    dt = time.process_time() - t
                best[side] = min(best.get(side, math.inf), dt)
                res[side] = r
        a, b = res["definite"], res["interior"]
        dlam, span = akvf_agreement(a, b)
        kind = "full" if coarse is None else "decimated"
        totals[kind][0] += best["definite"]
        totals[kind][1] += best["interior"]
        rows.append((i, kind, len(batch.edges), n, a, b, best, dlam, span))
        print(i, kind, len(batch.edges), {k: round(v, 3) for k, v in best.items()},
              int(a.iterations[0]), int(b.iterations[0]), float(b.shifts[0]), f"{dlam:.1e}", f"{span:.1e}", flush=True)
    lines = [
        "# Block Krylov: interior shift (default) against the definite shift",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, python "
        f"{platform.python_version()}, one thread; process CPU time, best of {args.repeat} rounds, sides "
        "alternating (experiments/solver/interior_shift.py)",
        "- `ta.akvf(mesh, n)` defaults (solver auto: Krylov on these sizes), whole call (cleaning + "
        "operator + factor + solve + Whitney); 'decimated' = `MeshBatch.from_meshes(coarse_faces=4000)`, "
        "as eval and bench solve",
        "- Δλ = max |λ_interior − λ_definite| / max(|λ|, 1) over the n pairs; res = the interior side's "
        "largest residual; span = sin of the largest principal angle between the two sides' spans of "
        "n forms (Euclidean): small where the sides agree as subspaces, their vectors may still differ "
        "by a rotation among close eigenvalues",
        "",
        "| mesh | resolution | edges | n | definite σ | solves | s | interior σ | solves | s | "
        "definite / interior | Δλ | span | res | dropped (def / int) | converged |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for i, kind, e, n, a, b, best, dlam, span in rows:
        lines.append(
            f"| {i} | {kind} | {e:,} | {n} | {float(a.shifts[0]):g} | {int(a.iterations[0])} | "
            f"{best['definite']:.3f} | {float(b.shifts[0]):g} | {int(b.iterations[0])} | {best['interior']:.3f} | "
            f"{best['definite'] / best['interior']:.2f}x | {dlam:.1e} | {span:.1e} | {float(b.residuals.max()):.1e} | "
            f"{int(a.dropped[0])} / {int(b.dropped[0])} | {bool(a.converged.all())} / {bool(b.converged.all())} |")
    for kind, (d, s) in totals.items():
        if s > 0:
            lines.append(f"| **{kind} total** | | | | | | {d:.2f} | | | {s:.2f} | **{d / s:.2f}x** | | | | | |")
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
