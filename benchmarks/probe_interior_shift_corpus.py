"""The interior shift on every PSB mesh as eval and bench solve it (decimated to 4000 faces,
n = 36), against the definite shift: how often the interior factor is taken, at which shift,
how often the solver falls back, and whether both sides give the same eigenvalues and spans.

Per mesh, one call each side (``ta.akvf(batch, n)``, its defaults), sides alternating, one
thread, process CPU time. 'definite' replaces :func:`torchakvf.solvers.factor.interior_factor`
by the definite ladder, the solver before. The interior side's path is read from what
``interior_factor`` returned (an InteriorFactor at 5n or 5n/2, or the definite factor) and from
the shift of the result (a negative shift after an InteriorFactor: the result check failed and
the mesh was solved again at the definite shift).

Usage::

    OMP_NUM_THREADS=1 python benchmarks/probe_interior_shift_corpus.py --out benchmarks/results/interior_shift_corpus.md
"""
from __future__ import annotations

import argparse
import platform
import time
from collections import Counter
from pathlib import Path

import torch

import torchakvf as ta
from torchakvf.evaluate.psb import default_psb_root, find_psb_meshes
from torchakvf.mesh import MeshBatch
from torchakvf.solvers.factor import InteriorFactor, interior_factor
from timing import akvf_agreement, definite_only, interior_factor_as, one_thread_on_psb, write_report



def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--psb", type=Path, default=default_psb_root())
    p.add_argument("--n", type=int, default=36, help="eval's AKVF count")
    p.add_argument("--coarse-faces", type=int, default=4000)
    p.add_argument("--limit", type=int, default=None)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    one_thread_on_psb(p, args)
    taken: list = []

    def recording(system, b, need, definite):
        f = interior_factor(system, b, need, definite)
        taken.append(f.sigma if isinstance(f, InteriorFactor) else None)
        return f

    entries = sorted(find_psb_meshes(args.psb), key=lambda e: e.mesh_id)[:args.limit]
    paths, secs = Counter(), {"definite": 0.0, "interior": 0.0}
    worst = {"dlam": (0.0, None), "span": (0.0, None), "res": (0.0, None)}
    unconverged, dropped_differ, failed = [], [], []
    for j, e in enumerate(entries):
        try:
            batch = MeshBatch.from_meshes([ta.load_mesh(e.mesh_path)], coarse_faces=args.coarse_faces)
        except ta.TorchAKVFError as exc:
            failed.append((e.mesh_id, f"load: {exc}"))
            continue
        res = {}
        order = ("definite", "interior") if j % 2 == 0 else ("interior", "definite")
        try:
            for side in order:
                taken.clear()
                with interior_factor_as(definite_only if side == "definite" else recording):
                    t = time.process_time()
                    res[side] = ta.akvf(batch, n=args.n)
                    secs[side] += time.process_time() - t
                if side == "interior":
                    got = list(taken)
        except ta.TorchAKVFError as exc:
            failed.append((e.mesh_id, str(exc).splitlines()[0][:120]))
            continue
        a, b = res["definite"], res["interior"]
        shift = float(b.shifts[0])
        if not got or got[-1] is None:
            path = "definite (no interior factor)" if got else "not the Krylov solver"
        elif shift < 0:
            path = f"interior σ = {got[-1]:g} refused by the result check, solved again at the definite shift"
        else:
            path = f"interior σ = {got[-1]:g}"
        paths[path] += 1
        dlam, span = akvf_agreement(a, b)
        for key, v in (("dlam", dlam), ("span", span), ("res", float(b.residuals.max()))):
            if v > worst[key][0]:
                worst[key] = (v, e.mesh_id)
        if not bool(b.converged.all()) or not bool(a.converged.all()):
            unconverged.append((e.mesh_id, bool(a.converged.all()), bool(b.converged.all())))
        if int(a.dropped[0]) != int(b.dropped[0]):
            dropped_differ.append((e.mesh_id, int(a.dropped[0]), int(b.dropped[0])))
        if j % 20 == 0:
            print(j, e.mesh_id, path, f"{dlam:.1e} {span:.1e}", {k: round(v, 1) for k, v in secs.items()}, flush=True)
    done = sum(paths.values())
    lines = [
        "# The interior shift on the whole PSB corpus (decimated as eval solves it)",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, python "
        f"{platform.python_version()}, one thread, process CPU time, one call per side and mesh, sides "
        "alternating (benchmarks/probe_interior_shift_corpus.py)",
        f"- {done} of {len(entries)} PSB meshes, `MeshBatch.from_meshes(coarse_faces={args.coarse_faces})`, "
        f"`ta.akvf(batch, n={args.n})` defaults; definite = the same with every mesh at its definite shift",
        "",
        "| path of the interior side | meshes |",
        "|---|---:|",
    ] + [f"| {k} | {v} |" for k, v in paths.most_common()] + [
        "",
        f"- CPU time, all meshes: definite {secs['definite']:.1f} s, interior {secs['interior']:.1f} s: "
        f"**{secs['definite'] / max(secs['interior'], 1e-9):.2f}x**",
        f"- largest relative eigenvalue difference {worst['dlam'][0]:.1e} (mesh {worst['dlam'][1]}); "
        f"largest principal-angle sine between the spans {worst['span'][0]:.1e} (mesh {worst['span'][1]}); "
        f"largest interior residual {worst['res'][0]:.1e} (mesh {worst['res'][1]})",
        f"- not converged on a side (mesh, definite, interior): {unconverged or 'none'}",
        f"- spurious counts that differ (mesh, definite, interior): {dropped_differ or 'none'}",
        f"- failed (mesh, error): {failed or 'none'}",
    ]
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
