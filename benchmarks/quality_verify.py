"""Check the merge stage through segment() itself (not the sweep's cache) on PSB meshes and time
it against the paper mode (issue 12).

For each mesh: the coarse-to-fine AKVFs once (as ``torchakvf eval``: n = 36, 4000 faces), then
per distinct human segment count k the untangled fields, ``segment(method="paper")`` and
``segment(method="merge")`` on the same fields, each timed. Scores by-segmentation (1-RI).

    PYTHONPATH=$PWD python benchmarks/quality_verify.py --per-category 2 \
        --weights 1,4,1,2 --out benchmarks/results/quality_verify.md
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from torchakvf.evaluate import psb as P
from torchakvf.evaluate.metrics import rand_index_error
from torchakvf.fields.akvf import akvf_falling_back
from torchakvf.fields.untangle import untangle
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch
from torchakvf.parts import segment
from torchakvf.parts.merge import MergeWeights
from torchakvf.parts.segment import SPARE_FIELDS, UNTANGLE_RESTARTS, default_n_fields, field_counts

try:
    from quality_cache import subset_ids
except ImportError:  # run as a module from the repository root
    from benchmarks.quality_cache import subset_ids


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--per-category", type=int, default=2)
    ap.add_argument("--weights", default=None, help="symmetry,concavity,size,ratio (default: MergeWeights())")
    ap.add_argument("--out", default="benchmarks/results/quality_verify.md")
    a = ap.parse_args()
    torch.set_num_threads(1)
    w = MergeWeights(*[float(x) for x in a.weights.split(",")]) if a.weights else MergeWeights()
    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    rows = []
    for mid in subset_ids(a.per_category):
        e = entries[mid]
        t0 = time.perf_counter()
        mesh = load_mesh(e.mesh_path)
        gts = [P.read_seg(s) for s in e.seg_paths]
        gk = [int(g.max()) + 1 for g in gts]
        mb = MeshBatch.from_meshes([mesh], coarse_faces=4000)
        fields, _ = akvf_falling_back(mb, n=default_n_fields(10 ** 6) + SPARE_FIELDS, seed=0, remedy="smooth")
        t_common = time.perf_counter() - t0
        t = {"paper": 0.0, "merge": 0.0}
        preds = {"paper": {}, "merge": {}}
        unts = {}
        for k in sorted(set(gk)):
            ns = field_counts(fields, [k])
            t1 = time.perf_counter()
            if tuple(ns) not in unts:
                unts[tuple(ns)] = untangle(fields, n=ns, seed=0, restarts=UNTANGLE_RESTARTS)
            t_common += time.perf_counter() - t1
            for method in ("paper", "merge"):
                t1 = time.perf_counter()
                seg = segment(fields, k=k, seed=0, untangled=unts[tuple(ns)], method=method, merge=w,
                              refine=False)[0]
                t[method] += time.perf_counter() - t1
                preds[method][k] = seg.labels
        score = {m: float(np.mean([rand_index_error(preds[m][k], g) for k, g in zip(gk, gts)])) for m in preds}
        rows.append(dict(id=mid, category=e.category, common=t_common, **{f"t_{m}": t[m] for m in t},
                         **{f"ri_{m}": score[m] for m in score}))
        print(json.dumps(rows[-1]), flush=True)
    cats = list(dict.fromkeys(r["category"] for r in rows))
    lines = ["# Merge stage through segment() (issue 12)", "",
             f"- meshes: {len(rows)} ({a.per_category} per labelled category, ids 20c+1..), coarse 4000 faces, "
             f"seed 0, by-segmentation 1-RI", f"- merge weights: {w}", "",
             "| category | paper | merge |", "|---|---:|---:|"]
    for c in cats:
        rs = [r for r in rows if r["category"] == c]
        lines.append(f"| {c} | {np.mean([r['ri_paper'] for r in rs]):.4f} | {np.mean([r['ri_merge'] for r in rs]):.4f} |")
    cat_mean = lambda key: np.mean([np.mean([r[key] for r in rows if r["category"] == c]) for c in cats])
    lines.append(f"| **overall (categories)** | **{cat_mean('ri_paper'):.4f}** | **{cat_mean('ri_merge'):.4f}** |")
    common = sum(r["common"] for r in rows)
    tp, tm = sum(r["t_paper"] for r in rows), sum(r["t_merge"] for r in rows)
    lines += ["", "## Wall time (1 thread, shared 2-core machine)", "",
              f"- AKVFs + untangling (shared by both): {common:.1f} s",
              f"- segment, paper mode (all k): {tp:.1f} s; merge mode: {tm:.1f} s",
              f"- added by the merge stage: {tm - tp:.1f} s = {100 * (tm - tp) / (common + tp):.1f}% of the "
              f"paper pipeline ({common + tp:.1f} s)"]
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
