"""Field and cluster counts of the merge method (issue 12's time budget): can the k's of a mesh
share untanglings and over-segmentations without a worse score?

Each k of a mesh today gets its own untangling (n = 3k clamped to [16, 32]) and its own k-means
into k' = min(3k, k + 16) clusters. The PSB protocol asks 4.3 distinct k's per mesh, so these
rules make ~1.2 untanglings and 4.3 k-means runs per mesh. Variants (``--variants``):

* ``base``       every k its own rules (OverSegmentation.min_k 1, options.FIELDS_STEP["merge"] 1);
* ``floorF``     min_k F: every k < F is treated as F for both rules (k' and n of k = F), so
                 all k <= F of a mesh share one untangling and one over-segmentation, merged
                 down to each k;
* ``u8``         FIELDS_STEP 8: n rounded up to a multiple of 8 (16, 24, 32): fewer distinct n;
* ``floorF+u8``  both.

The variants set these explicitly (they do not depend on the engine's defaults).

Runs ``evaluate_psb`` (by-segmentation 1-RI, coarse 4000 faces, seed 0, one worker, defaults)
per variant on 4 meshes of each labelled category (ids 20c+1..20c+4), the AKVFs solved once and
shared (they do not depend on these rules: eval solves n = 36 always). Reports 1-RI overall /
per category / per cross-validation fold (category index mod 3), the segment-stage CPU seconds
(with the engine's k-means reuse across rounds of equal (n, k') when present), and the number of
untanglings and k-means runs the rules imply over the 300 labelled PSB meshes' protocol k's.

    TORCHAKVF_PSB=/work/shared/psb OMP_NUM_THREADS=1 PYTHONPATH=$PWD nice -n 5 python \
        experiments/segmentation/field_counts.py --variants base,floor6,floor8+u8 --json /tmp/fc.json
"""
from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import torch
from kmeans_restarts import BLOCKS, LABELLED, StageClock

from torchakvf import options as O
from torchakvf.evaluate import harness as H
from torchakvf.evaluate import psb as P
from torchakvf.options import OverSegmentation
from torchakvf.parts import field_counts as FC


def rules(variant: str) -> tuple[int, int]:
    """(OverSegmentation.min_k, options.FIELDS_STEP["merge"]) of a variant name: floorF -> min_k F,
    q8/u8 -> step 8 (u8 rounds up, as the package does; q8, rounding to the nearest multiple,
    was measured with an earlier version of this script and is not the package's rule)."""
    m = re.fullmatch(r"(base|floor(\d+))?(\+?u8)?", variant)
    if not m:
        raise SystemExit(f"unknown variant {variant!r} (base, floorF, u8, floorF+u8)")
    return (int(m.group(2)) if m.group(2) else 1), (8 if m.group(3) else 1)


def implied_counts(variant: str) -> tuple[int, int]:
    """(untanglings, k-means runs) over the labelled PSB meshes' protocol k's, method merge:
    distinct n per mesh, distinct (n, k') per mesh (cluster_safe_n ignored)."""
    min_k, step = rules(variant)
    keep, O.FIELDS_STEP["merge"] = O.FIELDS_STEP["merge"], step
    opts = O.SegmentOptions(overseg=OverSegmentation(min_k=min_k))
    unt = km = 0
    for e in P.find_psb_meshes(P.default_psb_root()):
        ks = sorted(set(P.human_segment_counts(e)))
        ns = {k: FC.default_n_fields(k, "merge", min_k) for k in ks}
        unt += len(set(ns.values()))
        km += len({(ns[k], FC.cluster_count(k, 10 ** 9, opts)) for k in ks})
    O.FIELDS_STEP["merge"] = keep
    return unt, km


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/field_counts")
    ap.add_argument("--variants", default="base,floor6,floor8+u8")
    ap.add_argument("--per-category", type=int, default=4)
    ap.add_argument("--json", default="/tmp/field_counts.json")
    a = ap.parse_args()
    torch.set_num_threads(1)
    ids = [20 * c + i for c in BLOCKS for i in range(1, a.per_category + 1)]
    clock = StageClock(True)
    res = {}
    for v in a.variants.split(","):
        min_k, step = rules(v)
        O.FIELDS_STEP["merge"] = step
        clock.akvf = clock.segment = 0.0
        t0 = time.process_time()
        s = H.evaluate_psb(P.default_psb_root(), Path(a.out) / v, ids=ids, metrics="rand", workers=1,
                           plot=False, progress=False, coarse_faces=4000, overseg=OverSegmentation(min_k=min_k))
        unt, km = implied_counts(v)
        res[v] = {"overall": s.overall_categories["rand_index_error"],
                  "per_category": {c: val["rand_index_error"] for c, val in s.per_category.items()},
                  "cpu_total": time.process_time() - t0, "cpu_akvf": clock.akvf, "cpu_segment": clock.segment,
                  "corpus_untanglings": unt, "corpus_kmeans_runs": km}
        print(v, json.dumps(res[v]), flush=True)
        Path(a.json).write_text(json.dumps({"ids": ids, "results": res}, indent=1))
    names = list(res)
    print("| variant | 1-RI | " + " | ".join(f"fold {f}" for f in range(3))
          + " | segment CPU s | untanglings | k-means runs |")
    for v in names:
        pc = res[v]["per_category"]
        folds = [sum(pc[c] for i, c in enumerate(LABELLED) if i % 3 == f) / 5 for f in range(3)]
        print(f"| {v} | {res[v]['overall']:.4f} | " + " | ".join(f"{x:.4f}" for x in folds)
              + f" | {res[v]['cpu_segment']:.1f} | {res[v]['corpus_untanglings']} | {res[v]['corpus_kmeans_runs']} |")


if __name__ == "__main__":
    main()
