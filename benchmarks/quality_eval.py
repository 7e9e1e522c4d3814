"""The merge stage through the real evaluation harness on PSB meshes NOT used to choose its
parameters (issue 12): meshes 20c+5..20c+8 of each labelled category (the sweep's cache holds
20c+1..20c+4), both methods, coarse-to-fine at 4000 faces as ``torchakvf eval``, seed 0,
one worker. Writes <out>/<method>/ (the harness's own reports) and a comparison table.

    PYTHONPATH=$PWD python benchmarks/quality_eval.py --out /tmp/quality_eval \
        --report benchmarks/results/quality_eval_unseen.md
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch

from torchakvf.evaluate import psb as P
from torchakvf.evaluate.harness import evaluate_psb

try:
    from quality_cache import subset_ids
except ImportError:
    from benchmarks.quality_cache import subset_ids


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/quality_eval")
    ap.add_argument("--report", default="benchmarks/results/quality_eval_unseen.md")
    ap.add_argument("--first", type=int, default=5)
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--methods", default="paper,merge")
    a = ap.parse_args()
    torch.set_num_threads(1)
    starts = [i + a.first - 1 for i in subset_ids(1)]      # 20c + first
    ids = [s + j for s in starts for j in range(a.count)]
    res = {}
    for method in a.methods.split(","):
        res[method] = evaluate_psb(P.default_psb_root(), Path(a.out) / method, ids=ids, metrics="rand",
                                   workers=1, plot=False, progress=False, coarse_faces=4000, method=method)
        print(method, res[method].rand_index_error, res[method].predict_seconds, flush=True)
    methods = list(res)
    cats = list(res[methods[0]].per_category)
    lines = ["# Merge stage on PSB meshes not used for tuning (issue 12)", "",
             f"- meshes: {len(ids)} (ids 20c+{a.first}..20c+{a.first + a.count - 1} of each labelled category), "
             "by-segmentation 1-RI, coarse 4000 faces, seed 0, evaluate_psb (one worker)",
             "- method paper = today's output; merge = segment(method='merge') with the cross-validated "
             "MergeWeights defaults", "",
             "| category | " + " | ".join(methods) + " |", "|---|" + "---:|" * len(methods)]
    for c in cats:
        lines.append(f"| {c} | " + " | ".join(f"{res[m].per_category[c]['rand_index_error']:.4f}" for m in methods) + " |")
    lines.append("| **overall (categories)** | " + " | ".join(
        f"**{res[m].overall_categories['rand_index_error']:.4f}**" for m in methods) + " |")
    lines += ["", "| method | predict seconds (this run; resumed predictions count 0) | wall seconds |", "|---|---:|---:|"]
    lines += [f"| {m} | {res[m].predict_seconds:.1f} | {res[m].wall_seconds:.1f} |" for m in methods]
    Path(a.report).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
