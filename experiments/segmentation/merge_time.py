"""Time of the learned merge against the hand-set one, same run, same meshes, as `torchakvf eval`
runs them (coarse 4000 faces, every human k): per mesh the AKVF solve once, then all its k's
segmented with each weight set (alternating which goes first), one thread.

    PYTHONPATH=$PWD nice python3 experiments/segmentation/merge_time.py --ids 1,2,21,22,...
"""
from __future__ import annotations

import argparse
import time

import torch


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ids", required=True)
    a = ap.parse_args()
    torch.set_num_threads(1)
    from torchakvf.evaluate import psb as P
    from torchakvf.evaluate.predict import PredictSettings, eval_akvf_count
    from torchakvf.io import load_mesh
    from torchakvf.mesh import MeshBatch
    from torchakvf.options import MergeWeights, SegmentOptions
    from torchakvf.parts.rounds import segment_rounds
    from torchakvf.parts.solve import solve_akvfs

    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    sets = {"hand-set": SegmentOptions(refine=False, merge=MergeWeights.hand_set()),
            "learned (default)": SegmentOptions(refine=False)}
    total = {"solve": 0.0, **{n: 0.0 for n in sets}}
    for i, mid in enumerate(int(x) for x in a.ids.split(",")):
        e = entries[mid]
        ks = sorted({int(P.read_seg(s).max()) + 1 for s in e.seg_paths})
        t0 = time.perf_counter()
        mb = MeshBatch.from_meshes([load_mesh(e.mesh_path)], coarse_faces=4000)
        settings = PredictSettings(auto=False, n_fields=None, k_range=None, k_rule=None, coarse_faces=4000,
                                   options=sets["learned (default)"])
        fields, _ = solve_akvfs(mb, eval_akvf_count(settings), sets["learned (default)"])
        total["solve"] += time.perf_counter() - t0
        order = list(sets) if i % 2 == 0 else list(sets)[::-1]
        for name in order:
            t0 = time.perf_counter()
            for _ in segment_rounds(fields, [ks], sets[name]):
                pass
            total[name] += time.perf_counter() - t0
    base = total["solve"] + total["hand-set"]
    for name in sets:
        print(f"{name}: segment {total[name]:.2f} s; solve + segment {total['solve'] + total[name]:.2f} s"
              f" ({(total['solve'] + total[name]) / base:.3f} x the hand-set's)")


if __name__ == "__main__":
    main()
