"""Warm-started k-means rounds (issue 13): each round's k-means of a mesh with its last restart
seeded from the previous round's clusters (SegmentOptions.kmeans_seeded_restarts), against the
default (every round from scratch), in one process, interleaved per mesh, process CPU time.

Every variant gets the same AKVFs per mesh (n = 36, coarse 4000 faces, as eval solves them),
every human segment count of the mesh as its k's (ascending), refine=False. Reported per
variant: CPU seconds of the segment stage and of spherical_kmeans inside it, how often the
seeded restart is the one kept (rounds after a mesh's first), and the kept cost against the
default's on the same round.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice -n 5 python benchmarks/seed_rounds.py --ids 1,21,... \
        --variants 0,5,6,3
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from torchakvf.evaluate import psb as P
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch
from torchakvf.parts import engine


class KMeansRecorder:
    """Wraps engine.spherical_kmeans: CPU seconds spent in it and each call's result."""

    def __init__(self, inner):
        self.inner, self.seconds, self.results = inner, 0.0, []

    def __call__(self, *args, **kwargs):
        t0 = time.process_time()
        km = self.inner(*args, **kwargs)
        self.seconds += time.process_time() - t0
        self.results.append((km, kwargs.get("init") is not None))
        return km


def run_variant(fields, ks, m):
    """(segment seconds, k-means seconds, [(seeded?, kept index, restarts, kept cost)] per round)."""
    saved = engine.spherical_kmeans
    rec = KMeansRecorder(saved)
    engine.spherical_kmeans = rec
    try:
        t0 = time.process_time()
        for _ in engine.segment_rounds(fields, [ks], engine.SegmentOptions(refine=False, kmeans_seeded_restarts=m)):
            pass
        total = time.process_time() - t0
    finally:
        engine.spherical_kmeans = saved
    rounds = []
    for km, seeded in rec.results:
        rc = km.restart_costs[0]
        rounds.append((seeded, int(rc.argmin()), len(rc), float(km.cost[0])))
    return total, rec.seconds, rounds


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ids", required=True)
    ap.add_argument("--variants", default="0,5,6,3", help="kmeans_seeded_restarts values (0: the default)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    variants = [int(v) for v in a.variants.split(",")]
    ents = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    seg = {m: 0.0 for m in variants}
    kms = {m: 0.0 for m in variants}
    wins = {m: [0, 0] for m in variants}
    cost_ratio = {m: [] for m in variants}
    for j, i in enumerate(int(v) for v in a.ids.split(",")):
        e = ents[i]
        ks = sorted(set(P.human_segment_counts(e)))
        mb = MeshBatch.from_meshes([load_mesh(e.mesh_path)], coarse_faces=4000)
        fields, _ = engine.solve_akvfs(mb, 36, engine.SegmentOptions(refine=False))
        order = variants if j % 2 == 0 else variants[::-1]
        res = {}
        for m in order:
            s, k, rounds = run_variant(fields, ks, m)
            seg[m] += s
            kms[m] += k
            res[m] = rounds
        for m in variants:
            for r, (seeded, kept, nr, cost) in enumerate(res[m]):
                if seeded:
                    wins[m][0] += kept == nr - 1
                    wins[m][1] += 1
                if r > 0 and 0 in res:
                    cost_ratio[m].append(cost / res[0][r][3])
        print(f"mesh {i} ks {ks}: " + "  ".join(f"m={m} seg {seg[m]:.2f}s km {kms[m]:.2f}s" for m in variants),
              flush=True)
    for m in variants:
        cr = np.array(cost_ratio[m]) if cost_ratio[m] else np.array([np.nan])
        print(f"TOTAL m={m}: segment {seg[m]:.2f}s (x{seg[m] / seg[variants[0]]:.3f} of m={variants[0]}), "
              f"k-means {kms[m]:.2f}s (x{kms[m] / kms[variants[0]]:.3f}); seeded restart kept "
              f"{wins[m][0]}/{wins[m][1]}; kept cost / default's on rounds after the first: "
              f"mean {np.nanmean(cr):.4f}, min {np.nanmin(cr):.4f}, max {np.nanmax(cr):.4f}, "
              f"<= 1 on {int(np.sum(cr <= 1))}/{len(cr)}")


if __name__ == "__main__":
    main()
