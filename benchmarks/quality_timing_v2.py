"""Wall time the merge (and graph-cut) stages add to the whole pipeline (issue 12), measured
in one process, interleaved: per mesh the AKVFs once (coarse 4000 faces, as ``torchakvf eval``),
then segment_rounds over the mesh's human k's with each configuration in turn, twice (the
better of the two kept). One thread. Whole pipeline = AKVF solve + the paper's segmentation.

    PYTHONPATH=$PWD python benchmarks/quality_timing_v2.py --out benchmarks/results/quality_v2_timing.md
"""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import torch

from torchakvf.evaluate import psb as P
from torchakvf.fields.akvf import akvf_falling_back
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch
from torchakvf.parts.engine import SegmentOptions, akvf_count, segment_rounds
from torchakvf.parts.graphcut import GraphCut
from torchakvf.parts.merge import MergeWeights

CONFIGS = {
    "paper": SegmentOptions(method="paper"),
    "former merge default (ratio 2, w_cav 16, 20 restarts)": SegmentOptions(merge=MergeWeights(
        ratio=2.0, concavity=16.0, convexity=0.0, cut=0.0, part_size=0.0), graphcut=None,
        kmeans_restarts=20),
    "new merge default, no graph cut": SegmentOptions(graphcut=None),
    "new merge default + graph cut (the default)": SegmentOptions(),
}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ids", default="5,25,45,65,85,105,125,165,185,205,225,285,305,325,365")
    ap.add_argument("--out", default="benchmarks/results/quality_v2_timing.md")
    a = ap.parse_args()
    torch.set_num_threads(1)
    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    tot = {name: 0.0 for name in CONFIGS}
    t_akvf = 0.0
    for mid in [int(x) for x in a.ids.split(",")]:
        e = entries[mid]
        ks = sorted({int(P.read_seg(s).max()) + 1 for s in e.seg_paths})
        t0 = time.perf_counter()
        mb = MeshBatch.from_meshes([load_mesh(e.mesh_path)], coarse_faces=4000)
        fields, _ = akvf_falling_back(mb, n=akvf_count([ks]), seed=0, remedy="smooth")
        t_akvf += time.perf_counter() - t0
        best = {name: math.inf for name in CONFIGS}
        for _ in range(2):
            for name, opts in CONFIGS.items():
                t1 = time.perf_counter()
                for _r in segment_rounds(fields, [ks], opts):
                    pass
                best[name] = min(best[name], time.perf_counter() - t1)
        for name in CONFIGS:
            tot[name] += best[name]
        print(mid, {n: round(v, 2) for n, v in best.items()}, flush=True)
    whole = t_akvf + tot["paper"]
    L = ["# Time the new stages add (issue 12)", "",
         f"- meshes {a.ids} (one unseen mesh per labelled category), all their human k's, coarse 4000 "
         "faces, one thread, one process, configurations interleaved, best of 2; the machine shared "
         "(absolute seconds are noisy, the ratios less so)", "",
         "| configuration | segmentation s | added to the whole pipeline (AKVF + paper segmentation) |",
         "|---|---:|---:|"]
    for name, s in tot.items():
        L.append(f"| {name} | {s:.1f} | {100 * (s - tot['paper']) / whole:+.1f}% |")
    L += ["", f"AKVF solves: {t_akvf:.1f} s; whole paper pipeline {whole:.1f} s."]
    Path(a.out).write_text("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
