"""The segment stage of this checkout against a baseline copy of the whole package, in one
process, interleaved per mesh, process CPU time (issue 13).

The baseline is the package at a git revision extracted under another top-level name
(``git archive REV torchakvf`` renamed to ``torchakvf_base``; every import inside the package
is relative). Both get the same AKVFs per mesh (n = 36, coarse 4000 faces, as eval solves
them), every human segment count of the mesh as its k's, ``refine=False`` as eval segments
(``--refine``: refine=True, and the refined meshes are compared bitwise too). Reported: CPU
seconds per side and whether the labels (and costs) of every (mesh, k) agree.

    mkdir -p /tmp/segbase && git archive main torchakvf | tar -x -C /tmp/segbase \
        && mv /tmp/segbase/torchakvf /tmp/segbase/torchakvf_base
    PYTHONPATH=$PWD:/tmp/segbase OMP_NUM_THREADS=1 nice -n 5 python benchmarks/compare_segment.py \
        --ids 1,21,41,... [--profile new|base]
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import torch

from segment_compare_common import AnswerComparison, segment_answers, solved_psb_meshes
from torchakvf.parts import engine as new_engine


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ids", required=True)
    ap.add_argument("--profile", choices=["new", "base"], default=None)
    ap.add_argument("--top", type=int, default=40)
    ap.add_argument("--callers", default="", help="comma-separated function names whose callers to print")
    ap.add_argument("--refine", action="store_true", help="segment with refine=True (the refined "
                    "meshes are compared bitwise too); default refine=False, as eval")
    a = ap.parse_args()
    torch.set_num_threads(1)
    import torchakvf_base.parts.engine as base_engine
    engines = {"base": base_engine, "new": new_engine}
    secs = {"base": 0.0, "new": 0.0}
    prof = cProfile.Profile() if a.profile else None
    comparison = AnswerComparison()
    for j, i, ks, fields in solved_psb_meshes([int(v) for v in a.ids.split(",")], new_engine):
        res = {}
        for name in (["base", "new"] if j % 2 == 0 else ["new", "base"]):
            res[name], s = segment_answers(engines[name], fields, [ks], engines[name].SegmentOptions(refine=a.refine),
                                           prof if a.profile == name else None, clock=time.process_time)
            secs[name] += s
        for d in comparison.add(res["base"], res["new"]):
            print(f"  mesh {i} k {d.key[1]}: label ids differ on {d.changed:.4f} of faces, "
                  f"1-RI between the two {d.rand_error:.4f}", flush=True)
        print(f"mesh {i} ks {ks}: base {secs['base']:.2f}s new {secs['new']:.2f}s", flush=True)
    c = comparison
    print(f"TOTAL base {secs['base']:.2f}s new {secs['new']:.2f}s ratio {secs['base'] / secs['new']:.3f}x; "
          f"labels identical {c.same_labels}/{c.total}, costs identical {c.same_cost}/{c.total}"
          + (f", refined meshes identical {c.same_refined}/{c.total}" if a.refine else ""))
    if prof is not None:
        pstats.Stats(prof).sort_stats("tottime").print_stats(a.top)
        for name in filter(None, a.callers.split(",")):
            pstats.Stats(prof).sort_stats("tottime").print_callers(name)


if __name__ == "__main__":
    main()
