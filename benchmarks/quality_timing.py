"""Wall time the merge stage adds to the pipeline (issue 12), from benchmarks/quality_cache.py's
stage timings plus the merge itself timed here on each cached mesh.

paper pipeline per mesh = AKVFs (load, clean, decimate, solve) + untangling + segment at every
human k; added = segment at k' = ceil(ratio k) minus segment at k (k-means and isolines with more
centers) + merge_parts at every k (dual graph, region graph, greedy merges).

    PYTHONPATH=$PWD python benchmarks/quality_timing.py --cache /tmp/qcache \
        --weights ratio=4,concavity=32,convexity=4,cut=0.5,part_size=0.1
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from torchakvf.evaluate import psb as P
from torchakvf.io import load_mesh
from torchakvf.mesh.clean import face_areas
from torchakvf.parts.merge import MergeWeights, merge_parts


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", default="/tmp/qcache")
    ap.add_argument("--weights", default="ratio=2", help="MergeWeights as name=value,...")
    a = ap.parse_args()
    w = MergeWeights(**{kv.split("=")[0]: float(kv.split("=")[1]) for kv in a.weights.split(",")})
    a.ratio = w.ratio
    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    paper = added = merge = 0.0
    for js in sorted(Path(a.cache).glob("*.json"), key=lambda p: int(p.stem)):
        t = json.loads(js.read_text())
        z = np.load(js.with_suffix(".npz"))
        ks = z["ks"].tolist()
        paper += t["akvf"] + t["untangle"] + sum(t["segment"][f"k{k}_r1"] for k in ks)
        added += sum(t["segment"][f"k{k}_r{a.ratio:g}"] - t["segment"][f"k{k}_r1"] for k in ks)
        mesh = load_mesh(entries[int(js.stem)].mesh_path)
        area = face_areas(mesh.vertices, mesh.faces)
        for k in ks:
            labels = z[f"k{k}_r{a.ratio:g}_labels"].astype(np.int64)
            feats = np.random.default_rng(0).random((len(labels), 32))
            t0 = time.perf_counter()
            merge_parts(labels, mesh.faces, mesh.vertices, feats, area, k, w)
            merge += time.perf_counter() - t0
    print(f"paper pipeline {paper:.1f} s; k-means/isolines at k' add {added:.1f} s; merge_parts {merge:.1f} s; "
          f"stage total {added + merge:.1f} s = {100 * (added + merge) / paper:.1f}% of the paper pipeline")


if __name__ == "__main__":
    main()
