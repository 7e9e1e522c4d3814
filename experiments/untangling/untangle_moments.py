"""The untangling's float64 Horst steps: Y's fourth moments against the two products over the
edges (issue 13, features at full resolution), one thread, process CPU time.

1. **Per step**, on random scaled forms [E, n]: the moments' one-time cost (``Qᵀ Q`` over column
   pairs), a step of 9 rotations and of 1 (``FourthMoments``) against the products'
   (``Products`` in float64), and what the size rule (``fourth_moments_pay``) picks for 180 steps
   of single rotations (20 per restart).
2. **Whole untangling** (``ta.untangle``, 8 restarts besides the identity, the default float32
   phase then the float64 one) of real AKVFs, n = 32 at full resolution and n = 16, 24, 32 at
   4000 faces: the size rule's choice for the float64 phase (from the float32 phase's step
   count) against the products forced, best of ``--repeat`` interleaved rounds, with the
   iteration counts and the largest rotation difference.

Usage::

    OMP_NUM_THREADS=1 python experiments/untangling/untangle_moments.py --out experiments/results/untangle_moments.md
"""
from __future__ import annotations

import argparse
import importlib
import platform
import time
from pathlib import Path

import torch

import torchakvf as ta
from torchakvf.bench.script_tools import best_of, write_report
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.io import load_mesh
from torchakvf.mesh import clean_mesh

untangle_mod = importlib.import_module("torchakvf.fields.untangle")
from torchakvf.fields.fourth_moments import FourthMoments  # noqa: E402
from torchakvf.fields.horst import Products  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


def best_ms(fn, repeat: int = 5):
    """(milliseconds of this process's CPU in the fastest of ``repeat`` calls, the result)."""
    seconds, out = best_of(fn, repeat, time.process_time)
    return 1e3 * seconds, out


def per_step_rows(sizes):
    rows = []
    gen = torch.Generator().manual_seed(0)
    for e, n in sizes:
        y = torch.randn(1, e, n, generator=gen, dtype=torch.float64)
        once, mom = best_ms(lambda: FourthMoments(y), 2)
        prod = Products(y, 9, torch.float64)
        al = torch.linalg.qr(torch.randn(1, 9, n, n, generator=gen, dtype=torch.float64))[0]
        m9, g = best_ms(lambda: mom(al))
        p9, h = best_ms(lambda: prod(al))
        m1, _ = best_ms(lambda: mom(al[:, :1]))
        p1, _ = best_ms(lambda: prod(al[:, :1]))
        err = float((g - h).abs().max() / h.abs().max())
        rows.append(f"| {e} | {n} | {once:.0f} | {m9:.1f} | {p9:.1f} | {m1:.2f} | {p1:.2f} | {err:.0e} | "
                    f"{'moments' if untangle_mod.fourth_moments_pay(e, n, 180) else 'products'} |")
    return rows


def _choice(fields, n: int) -> str:
    """What the untangling's float64 phase took, read off a run with the rule spied on."""
    seen = []
    pay = untangle_mod.fourth_moments_pay

    def spy(e, n_, steps):
        out = pay(e, n_, steps)
        seen.append(f"{'moments' if out else 'products'} ({steps} steps)")
        return out

    untangle_mod.fourth_moments_pay = spy
    try:
        ta.untangle(fields, n=n, restarts=8)
    finally:
        untangle_mod.fourth_moments_pay = pay
    return ", ".join(seen)


def whole_rows(cases, repeat: int):
    rows = []
    tot = {"rule": 0.0, "products": 0.0}
    for label, fields, n in cases:
        best = {"rule": float("inf"), "products": float("inf")}
        res = {}
        for rnd in range(repeat):
            for side in (["rule", "products"] if rnd % 2 == 0 else ["products", "rule"]):
                pay = untangle_mod.fourth_moments_pay
                if side == "products":
                    untangle_mod.fourth_moments_pay = lambda e, n, steps: False
                try:
                    t = time.process_time()
                    u = ta.untangle(fields, n=n, restarts=8)
                    best[side] = min(best[side], time.process_time() - t)
                finally:
                    untangle_mod.fourth_moments_pay = pay
                res[side] = u
        e = int(fields.batch.edge_ptr[1])
        diff = float((res["rule"].rotation - res["products"].rotation).abs().max())
        same = torch.equal(res["rule"].iterations, res["products"].iterations)
        choice = _choice(fields, n)          # the float64 phase's, from the float32 phase's steps
        rows.append(f"| {label} | {e} | {n} | {choice} | {best['rule']:.2f} | {best['products']:.2f} | "
                    f"{best['products'] / best['rule']:.2f}x | {same} | {diff:.0e} |")
        for k in tot:
            tot[k] += best[k]
    rows.append(f"| **total** | | | | {tot['rule']:.2f} | {tot['products']:.2f} | "
                f"**{tot['products'] / tot['rule']:.2f}x** | | |")
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--ids", type=int, nargs="+", default=[1, 21, 301])
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    psb = default_psb_root()
    sizes = [(45594, 32), (14112, 32), (6000, 32), (6000, 24), (6000, 16), (3000, 16)]
    lines = ["# The untangling's float64 steps: fourth moments against the products", "",
             f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, "
             f"python {platform.python_version()}; one thread, process CPU time "
             "(experiments/untangling/untangle_moments.py)", "",
             "## Per step (random forms; ms, best of 5)", "",
             "| E | n | moments once | moments step q=9 | products step q=9 | moments q=1 | products q=1 | "
             "rel. diff of G | rule picks |", "|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    lines += per_step_rows(sizes)
    cases = []
    if psb is not None:
        for i in args.ids:
            mesh = clean_mesh(load_mesh(psb / "meshes" / f"{i}.off.gz"))
            full = ta.akvf(mesh, n=32)
            cases.append((f"PSB {i} full", full, 32))
            coarse = ta.akvf(ta.MeshBatch.from_meshes([mesh], coarse_faces=4000), n=32)
            for n in (16, 24, 32):
                cases.append((f"PSB {i} 4000 faces", coarse, n))
        lines += ["", f"## Whole untangling (8 restarts + identity; s, best of {args.repeat} interleaved)", "",
                  "| mesh | E | n | rule picks | rule s | products s | products / rule | same iterations | "
                  "max rotation diff |", "|---|---:|---:|---|---:|---:|---:|---|---:|"]
        lines += whole_rows(cases, args.repeat)
    else:
        lines += ["", "(PSB not found: whole-untangling rows skipped)"]
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
