"""The one-time cost of the untangling's fourth moments (``_FourthMoments``, the float64 Horst
steps' gradient): a baseline git revision's code against this checkout's, on the scaled AKVF
forms of real PSB meshes, one thread, process CPU time, the two sides interleaved (best of
``--repeat`` rounds).

Reported per mesh and n: milliseconds of each side, their ratio, and the largest difference
of the moments and of one Horst gradient G = Yᵀ (Y A)^3 (random rotation), relative to the
largest entry: the two sides sum the same products in another order.

    OMP_NUM_THREADS=1 python benchmarks/bench_fourth_moments.py --out benchmarks/results/fourth_moments.md
"""
from __future__ import annotations

import argparse
import importlib
import platform
import time
from pathlib import Path

import torch

import torchakvf as ta
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.io import load_mesh
from timing import best_of, module_at_revision, one_thread_on_psb, write_report

new_untangle = importlib.import_module("torchakvf.fields.untangle")
#: main before the moments were computed from sorted quadruples only (the baseline).
BASELINE_REV = "f2f523b"
PATH = "torchakvf/fields/untangle.py"


def scaled_forms(mesh_path: Path, n: int, coarse_faces: int | None) -> torch.Tensor:
    """[1, E, n] forms scaled by sqrt(S1), as the untangling takes them."""
    mesh = load_mesh(mesh_path)
    if coarse_faces:
        mesh = ta.MeshBatch.from_meshes([mesh], coarse_faces=coarse_faces)
    f = ta.akvf(mesh, n=n)
    return (f.forms[:, :n].double() * f.system.mass.double().sqrt()[:, None])[None]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--psb", type=Path, default=default_psb_root())
    ap.add_argument("--ids", default="1,21,121,181,301")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--baseline", default=BASELINE_REV)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    one_thread_on_psb(ap, args)
    old = module_at_revision(args.baseline, PATH, "torchakvf.fields._baseline_untangle")
    gen = torch.Generator().manual_seed(0)
    rows, tot = [], [0.0, 0.0]
    cases = [(c, n) for c in (None, 4000) for n in (16, 24, 32)]
    for mid in [int(v) for v in args.ids.split(",")]:
        path = args.psb / "meshes" / f"{mid}.off.gz"
        for coarse, n in cases:
            y = scaled_forms(path, n, coarse)
            times = {"old": float("inf"), "new": float("inf")}
            for _ in range(args.repeat):
                for side, cls in (("old", old._FourthMoments), ("new", new_untangle._FourthMoments)):
                    sec, mom = best_of(lambda: cls(y), 1, time.process_time)
                    times[side] = min(times[side], sec)
            a, b = old._FourthMoments(y), new_untangle._FourthMoments(y)
            d_mom = float((a.moments - b.moments).abs().max() / a.moments.abs().max())
            rot = torch.linalg.qr(torch.randn(1, 1, n, n, generator=gen, dtype=torch.float64))[0]
            ga, gb = a(rot), b(rot)
            d_g = float((ga - gb).abs().max() / ga.abs().max())
            tot[0] += times["old"]
            tot[1] += times["new"]
            rows.append(f"| {mid} | {'full' if coarse is None else coarse} | {y.shape[1]} | {n} | "
                        f"{1e3 * times['old']:.1f} | {1e3 * times['new']:.1f} | "
                        f"{times['old'] / times['new']:.2f}x | {d_mom:.0e} | {d_g:.0e} |")
            print(rows[-1], flush=True)
    head = [
        "# The fourth moments' one-time cost: sorted quadruples only, against Qᵀ Q's upper block triangle",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, "
        f"{platform.machine()}, one thread; process CPU time, best of {args.repeat} interleaved rounds "
        f"(benchmarks/bench_fourth_moments.py)",
        f"- old: `_FourthMoments` at {args.baseline}; new: this checkout's; the scaled forms of "
        "`ta.akvf(mesh, n)` (cleaned; full resolution or decimated to 4000 faces)",
        "- Δ: largest difference relative to the largest entry, of the moments [n, C] and of one "
        "gradient G = Yᵀ (Y A)^3 at a random rotation",
        "",
        "| mesh | faces | edges | n | old ms | new ms | old / new | Δ moments | Δ G |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    total = (f"| **total** | | | | {1e3 * tot[0]:.0f} | {1e3 * tot[1]:.0f} | "
             f"**{tot[0] / tot[1]:.2f}x** | | |")
    write_report("\n".join(head + rows + [total, ""]), args.out)


if __name__ == "__main__":
    main()
