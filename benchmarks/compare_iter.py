"""The segment stage of this checkout against a baseline copy of the package, in one process,
interleaved per mesh, process CPU time, for either segmentation method (issue 13: the
untangling and k-means fast paths).

A variant of benchmarks/compare_segment.py with ``--method`` (``SegmentOptions(method=...)``;
compare_segment.py runs the default method) and a process-CPU-clock profile of each side
(``cProfile.Profile(time.process_time)``) restricted to the functions of the iterations.

The baseline is the package at a git revision extracted as ``torchakvf_base``:

    mkdir -p /tmp/segbase && git archive main torchakvf | tar -x -C /tmp/segbase \
        && mv /tmp/segbase/torchakvf /tmp/segbase/torchakvf_base
    PYTHONPATH=$PWD:/tmp/segbase OMP_NUM_THREADS=1 nice -n 5 python benchmarks/compare_iter.py \
        --ids 2,22,42 [--method paper] [--profile]

Per mesh the AKVFs are solved once (n = 36, coarse 4000 faces, as eval solves them) and both
sides run ``segment_rounds`` on them at every human segment count, ``refine=False``; labels and
costs of every (mesh, k) are compared.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import torch

from torchakvf.evaluate import psb as P
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch
from torchakvf.parts import engine as new_engine

from segment_compare_common import AnswerComparison, segment_answers

#: functions whose process CPU time is reported per side (file suffix, function name)
WATCHED = [("untangle.py", "orthomax_rotations"), ("untangle.py", "_orthomax"),
           ("untangle.py", "_horst"), ("untangle.py", "_horst_one_mesh"), ("untangle.py", "_horst_batched"),
           ("untangle.py", "untangled_from_rotations"), ("spherical_kmeans.py", "spherical_kmeans"),
           ("spherical_kmeans.py", "_lloyd"), ("spherical_kmeans.py", "_lloyd_one_mesh"),
           ("spherical_kmeans.py", "_lloyd_batched"), ("spherical_kmeans.py", "_kmeanspp"),
           ("engine.py", "segment_rounds"), ("~", "<built-in method torch.matmul>"),
           ("~", "<built-in method torch._C._linalg.linalg_svd>"),
           ("~", "<method 'max' of 'torch._C.TensorBase' objects>"),
           ("~", "<method 'index_add_' of 'torch._C.TensorBase' objects>")]


def watched_table(stats: dict) -> list[str]:
    """Rows 'function calls tottime cumtime' of the WATCHED functions of pstats' stats dict."""
    rows = []
    for suffix, name in WATCHED:
        for (fname, _, func), (_, ncalls, tt, ct, _) in stats.items():
            if func == name and fname.endswith(suffix):
                rows.append(f"| {name} | {ncalls} | {tt:.3f} | {ct:.3f} |")
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ids", required=True)
    ap.add_argument("--method", default=new_engine.DEFAULT_METHOD)
    ap.add_argument("--profile", action="store_true", help="profile both sides (process CPU clock)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    import torchakvf_base.parts.engine as base_engine
    ents = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    engines = {"base": base_engine, "new": new_engine}
    secs = {"base": 0.0, "new": 0.0}
    profs = {name: cProfile.Profile(time.process_time) if a.profile else None for name in engines}
    comparison = AnswerComparison()
    for j, i in enumerate(int(v) for v in a.ids.split(",")):
        e = ents[i]
        ks = sorted(set(P.human_segment_counts(e)))
        mb = MeshBatch.from_meshes([load_mesh(e.mesh_path)], coarse_faces=4000)
        fields, _ = new_engine.solve_akvfs(mb, 36, new_engine.SegmentOptions(refine=False, method=a.method))
        res = {}
        for name in (["base", "new"] if j % 2 == 0 else ["new", "base"]):
            res[name], s = segment_answers(engines[name], fields, [ks],
                                           engines[name].SegmentOptions(refine=False, method=a.method), profs[name])
            secs[name] += s
        for d in comparison.add(res["base"], res["new"]):
            print(f"  mesh {i} k {d.key[1]}: labels differ on {d.changed:.4f} of faces", flush=True)
        print(f"mesh {i} ks {ks}: base {secs['base']:.2f}s new {secs['new']:.2f}s", flush=True)
    print(f"TOTAL method {a.method}: base {secs['base']:.2f}s new {secs['new']:.2f}s "
          f"ratio {secs['base'] / secs['new']:.3f}x; labels identical {comparison.same_labels}/{comparison.total}, "
          f"costs identical {comparison.same_cost}/{comparison.total}")
    if a.profile:
        for name, prof in profs.items():
            print(f"\n{name}: | function | calls | tottime s | cumtime s |")
            print("\n".join(watched_table(pstats.Stats(prof).stats)))


if __name__ == "__main__":
    main()
