"""The merge method's extra cost over the paper mode, for a baseline copy of the package and this
checkout, in one process, interleaved per mesh, process CPU time (issues 12 and 13).

Per mesh: the AKVFs are solved once (n = 36, coarse 4000 faces, as eval solves them; this
checkout's solver, not timed), then ``segment_rounds`` over every human segment count of the mesh
runs four times: {baseline, this checkout} x {SegmentOptions() (method "merge"),
SegmentOptions(method="paper")}, all with ``refine=False`` as eval segments; the order of the four
rotates with the mesh. Reported: CPU seconds of each, the merge / paper ratio of each side,
baseline / checkout per method, whether the labels and costs of every (mesh, k) agree, and with
``--profile`` a per-function cProfile (process clock) of all four (profiling slows call-heavy
code more: take the ratios from a run without it).

The baseline is the package at a git revision extracted as ``torchakvf_base`` (see
benchmarks/compare_segment.py for the ``git archive`` recipe):

    PYTHONPATH=$PWD:/tmp/segbase OMP_NUM_THREADS=1 nice -n 5 python benchmarks/merge_overhead.py \
        --ids 2,22,42,... [--profile]
"""
from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time

import torch

from torchakvf.parts import engine as new_engine

from segment_compare_common import AnswerComparison, segment_answers, solved_psb_meshes

#: Functions whose per-call cost the report lists (cumulative process CPU seconds).
WATCH = ("segment_rounds", "_round_untangled", "spherical_kmeans", "cut_parts", "graphcut_labels", "potts_expansion", "expansion", "allowed_labels", "merge_parts",
         "region_graph", "greedy_merge", "next_merge_cost", "partition_cost", "remove_small_parts",
         "piece_neighbours", "labelled_pieces", "merged_distances", "part_generators", "barycenter_values",
         "isoline_face_labels", "vertex_distances")


def cumulative(prof: cProfile.Profile) -> dict:
    """{function name: (calls, cumulative s)} of the watched functions (summed over same names)."""
    stats = pstats.Stats(prof, stream=io.StringIO()).stats
    out = {}
    for (_, _, name), (_, ncalls, _, cum, _) in stats.items():
        if name in WATCH:
            c, s = out.get(name, (0, 0.0))
            out[name] = (c + ncalls, s + cum)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ids", required=True)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--top", type=int, default=0, help="also print the top N functions by tottime per side")
    a = ap.parse_args()
    torch.set_num_threads(1)
    import torchakvf_base.parts.engine as base_engine
    engines = {"base": base_engine, "new": new_engine}
    runs = [(side, method) for side in ("base", "new") for method in ("merge", "paper")]
    secs = {r: 0.0 for r in runs}
    profs = {r: cProfile.Profile(time.process_time) for r in runs} if a.profile else {}
    comparisons = {m: AnswerComparison() for m in ("merge", "paper")}
    for j, i, ks, fields in solved_psb_meshes([int(v) for v in a.ids.split(",")], new_engine):
        res = {}
        for r in runs[j % 4:] + runs[:j % 4]:
            side, method = r
            prof = profs.get(r)
            res[r], s = segment_answers(engines[side], fields, [ks],
                                        engines[side].SegmentOptions(refine=False, method=method), prof)
            secs[r] += s
        for method in ("merge", "paper"):
            for d in comparisons[method].add(res[("base", method)], res[("new", method)]):
                print(f"  mesh {i} k {d.key[1]} {method}: labels differ on {d.changed:.4f} of faces", flush=True)
        print(f"mesh {i} ({len(fields.batch.meshes[0].faces)} faces) ks {ks}: "
              + " ".join(f"{s}/{m} {secs[(s, m)]:.2f}s" for s, m in runs), flush=True)
    print()
    print("| side | merge s | paper s | merge / paper |")
    print("|---|---|---|---|")
    for side in engines:
        mg, pp = secs[(side, "merge")], secs[(side, "paper")]
        print(f"| {side} | {mg:.2f} | {pp:.2f} | {mg / pp:.3f} |")
    for method in ("merge", "paper"):
        b, n = secs[("base", method)], secs[("new", method)]
        c = comparisons[method]
        print(f"{method}: base / new {b / n:.3f}x; labels identical {c.same_labels}/{c.total}, "
              f"costs identical {c.same_cost}/{c.total}")
    if profs:
        cum = {r: cumulative(p) for r, p in profs.items()}
        print()
        print("| function | " + " | ".join(f"{s}/{m} calls | {s}/{m} cum s" for s, m in runs) + " |")
        print("|---" * (1 + 2 * len(runs)) + "|")
        for name in WATCH:
            cells = []
            for r in runs:
                c, t = cum[r].get(name, (0, 0.0))
                cells += [str(c), f"{t:.3f}"]
            print(f"| {name} | " + " | ".join(cells) + " |")
        if a.top:
            for r, p in profs.items():
                if r[1] == "merge":
                    print(f"\n--- {r[0]}/merge: top {a.top} by tottime")
                    pstats.Stats(p).sort_stats("tottime").print_stats(a.top)


if __name__ == "__main__":
    main()
