"""``refine_along_isolines`` alone: a baseline copy of the package against this checkout, on the
inputs full-resolution ``ta.segment`` hands it, in one process, interleaved, process CPU time
(issue 12/13).

Per PSB mesh (full resolution, no decimation) ``ta.segment(mesh, k)`` runs once with every
default; the (vertices, faces, vdist) of its ``refine_along_isolines`` call are recorded. Then
both versions refine that input ``--repeat`` times, alternating which goes first; the best CPU
time of each is kept and the two RefinedMesh are compared bitwise.

``--rounds``: instead, per mesh the AKVFs are solved as eval solves them (n = 36, coarse 4000
faces) and this checkout's ``segment_rounds`` runs at every human segment count with every
default (refine on); every refine call is recorded and timed as above, and the CPU time of the
rounds themselves is reported beside (the share refine takes of the segment stage).

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


def recorded_rounds(mesh_path, ks):
    """(inputs of every refine_along_isolines call of segment_rounds at ``ks``, CPU s of the rounds)."""
    from torchakvf.mesh import MeshBatch
    calls = []
    orig = engine.refine_along_isolines

    def record(vertices, faces, vdist):
        calls.append((vertices.copy(), faces.copy(), vdist.copy()))
        return orig(vertices, faces, vdist)

    mb = MeshBatch.from_meshes([ta.load_mesh(mesh_path)], coarse_faces=4000)
    fields, _ = engine.solve_akvfs(mb, 36, engine.SegmentOptions())
    engine.refine_along_isolines = record
    try:
        t = time.process_time()
        for _ in engine.segment_rounds(fields, [ks], engine.SegmentOptions()):
            pass
        seconds = time.process_time() - t
    finally:
        engine.refine_along_isolines = orig
    return calls, seconds


def time_both(base, new, inputs, repeat):
    """({"main", "branch"}: Σ over ``inputs`` of the best CPU s of ``repeat``), all bitwise same."""
    best = {"main": 0.0, "branch": 0.0}
    ok = True
    for v, f, vdist in inputs:
        one = {"main": np.inf, "branch": np.inf}
        out = {}
        for r in range(repeat):
            for name, fn in ([("main", base), ("branch", new)] if r % 2 == 0 else [("branch", new), ("main", base)]):
                t = time.process_time()
                out[name] = fn(v, f, vdist)
                one[name] = min(one[name], time.process_time() - t)
        ok &= same(out["main"], out["branch"])
        for name in best:
            best[name] += one[name]
    return best, ok


def rounds_report(a, base, new) -> str:
    from torchakvf.evaluate import psb as P
    ents = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    lines = ["| mesh | ks | segment_rounds s (branch) | refine calls | main refine s | branch refine s | "
             "main / branch | main's share of the rounds | bitwise same |",
             "|---:|---|---:|---:|---:|---:|---:|---:|:---:|"]
    tot = {"rounds": 0.0, "main": 0.0, "branch": 0.0, "ok": 0, "n": 0}
    for mid in a.ids:
        ks = sorted(set(P.human_segment_counts(ents[mid])))
        calls, rounds_s = recorded_rounds(ents[mid].mesh_path, ks)
        best, ok = time_both(base, new, calls, a.repeat)
        # the rounds ran the branch's refine: with main's they would take the difference more
        main_rounds = rounds_s - best["branch"] + best["main"]
        lines.append(f"| {mid} | {','.join(map(str, ks))} | {rounds_s:.2f} | {len(calls)} | {best['main']:.3f} | "
                     f"{best['branch']:.3f} | {best['main'] / best['branch']:.1f}x | "
                     f"{100 * best['main'] / main_rounds:.1f}% | {'yes' if ok else 'NO'} |")
        print(lines[-1], flush=True)
        tot["rounds"] += rounds_s
        tot["main"] += best["main"]
        tot["branch"] += best["branch"]
        tot["ok"] += ok
        tot["n"] += 1
    main_rounds = tot["rounds"] - tot["branch"] + tot["main"]
    lines.append(f"| **total** | | {tot['rounds']:.2f} | | {tot['main']:.3f} | {tot['branch']:.3f} | "
                 f"**{tot['main'] / tot['branch']:.1f}x** | {100 * tot['main'] / main_rounds:.1f}% | "
                 f"{tot['ok']}/{tot['n']} |")
    return "\n".join(lines) + "\n"


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
    ap.add_argument("--rounds", action="store_true", help="refine calls of segment_rounds at every "
                    "human k (coarse 4000, as eval) instead of ta.segment at full resolution")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    base = importlib.import_module(f"{a.base}.parts.boundaries").refine_along_isolines
    new = boundaries.refine_along_isolines
    if a.rounds:
        md = rounds_report(a, base, new)
        print(md)
        if a.out:
            with open(a.out, "w") as fh:
                fh.write(md)
        return 0
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
