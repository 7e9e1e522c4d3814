"""Probe: the surface map's two closest-point searches on PSB meshes (issue 13, the pack stage).

Per PSB mesh (cleaned, decimated to ``--coarse`` faces as ``coarse_mesh`` does; meshes that
``coarse_mesh`` solves as they are are skipped), the fine vertices and face barycenters (the
points ``coarse_mesh`` locates) are located on the coarse surface by ``SurfaceIndex`` with
``search="samples"`` (the kd-tree of face samples, the only search before) and
``search="aabb"`` (libigl's AABB tree and the tie resolution), each timed from building its
index, interleaved, best of ``--repeat``, process CPU time with IGL_NUM_THREADS=1. Reported
per mesh: both times, their ratio and whether the answers (face, barycentric coordinates,
distance) are bitwise equal; where they are not, how many points differ and by how much.

    IGL_NUM_THREADS=1 OMP_NUM_THREADS=1 python experiments/pipeline/surface_map_aabb.py --all \\
        --out experiments/results/surface_map_aabb.md
"""
from __future__ import annotations

import argparse
import os
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from torchakvf.io import load_mesh
from torchakvf.mesh.clean import clean_mesh
from torchakvf.mesh.coarse import DECIMATE_ABOVE, SurfaceIndex, decimate

ROOT = Path(__file__).resolve().parents[2]
#: 2 meshes of every PSB category (ids 261-280 are not in the benchmark).
DEFAULT_IDS = [c + i for c in (1, 21, 41, 61, 81, 101, 121, 141, 161, 181, 201, 221, 241, 281, 301,
                                321, 341, 361, 381) for i in (0, 1)]


def timed(fn):
    t = time.process_time()
    out = fn()
    return time.process_time() - t, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--psb", default=str(ROOT.parent / "shared" / "psb"))
    ap.add_argument("--ids", type=int, nargs="*", default=DEFAULT_IDS)
    ap.add_argument("--all", action="store_true", help="every mesh of --psb (overrides --ids)")
    ap.add_argument("--coarse", type=int, default=4000)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    meshes = Path(args.psb) / "meshes"
    ids = sorted(int(p.name.split(".")[0]) for p in meshes.glob("*.off*")) if args.all else args.ids
    rows, tot, n_points, n_diff, worst, n_same = [], [0.0, 0.0], 0, 0, 0.0, 0
    for mid in ids:
        fine = clean_mesh(load_mesh(next(meshes.glob(f"{mid}.off*"))))
        if len(fine.faces) <= DECIMATE_ABOVE * args.coarse:
            continue
        coarse = clean_mesh(decimate(fine, args.coarse))
        pts = np.concatenate([fine.vertices, fine.vertices[fine.faces].mean(axis=1)])
        best = {"samples": np.inf, "aabb": np.inf}
        out = {}
        for r in range(args.repeat):     # interleaved, the order alternating
            for search in (("samples", "aabb") if r % 2 == 0 else ("aabb", "samples")):
                t, out[search] = timed(lambda: SurfaceIndex(coarse.vertices, coarse.faces, search=search).locate(pts))
                best[search] = min(best[search], t)
        a, b = out["samples"], out["aabb"]
        diff = (a.face != b.face) | (a.bary != b.bary).any(axis=1) | (a.distance != b.distance)
        gap = float(np.abs(a.distance - b.distance).max())
        n_points += len(pts)
        n_diff += int(diff.sum())
        worst = max(worst, gap)
        n_same += int(not diff.any())
        tot[0] += best["samples"]
        tot[1] += best["aabb"]
        rows.append(f"| {mid} | {len(fine.faces):,} | {len(pts):,} | {best['samples'] * 1e3:.0f} | "
                    f"{best['aabb'] * 1e3:.0f} | {best['samples'] / best['aabb']:.2f}x | {int(diff.sum())} | "
                    f"{gap:.1e} |")
        print(rows[-1], flush=True)
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    text = "\n".join([
        "# Surface map: libigl's AABB search against the sample kd-tree",
        "",
        f"- {stamp}; process CPU time, best of {args.repeat} interleaved, each search timed from "
        f"building its index; IGL_NUM_THREADS={os.environ.get('IGL_NUM_THREADS', 'unset')}, "
        f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')} (experiments/pipeline/surface_map_aabb.py)",
        f"- points: the fine vertices and face barycenters of each cleaned PSB mesh, located on it "
        f"decimated to {args.coarse} faces (what `coarse_mesh` does)",
        "",
        "| mesh | faces | points | samples ms | aabb ms | samples / aabb | points that differ | max distance gap |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
        *rows,
        f"| **total** ({len(rows)} meshes) | | {n_points:,} | {tot[0] * 1e3:.0f} | {tot[1] * 1e3:.0f} | "
        f"**{tot[0] / max(tot[1], 1e-12):.2f}x** | {n_diff} | {worst:.1e} |",
        "",
        f"Answers bitwise equal on {n_same} of {len(rows)} meshes; {n_diff} of {n_points:,} points differ.",
        ""])
    print(text)
    if args.out:
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
