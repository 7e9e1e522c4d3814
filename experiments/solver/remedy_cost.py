"""What the remedy decision costs: ta.segment of PSB meshes (decimated as eval solves them,
k = 6) with remedy "smooth" and with "auto" (the default), alternating in one process; the
summed wall time of each and their ratio.

    PYTHONPATH=$PWD nice python3 experiments/solver/remedy_cost.py --ids 3,23,63,83,123,163,183,223 --repeats 2
"""
from __future__ import annotations

import argparse
import time

import torch

import torchakvf as ta
from torchakvf.evaluate.psb import default_psb_root, find_psb_meshes


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--ids", default="3,23,63,83,123,163,183,223")
    p.add_argument("--repeats", type=int, default=2)
    a = p.parse_args()
    torch.set_num_threads(1)
    entries = {e.mesh_id: e for e in find_psb_meshes(default_psb_root())}
    batches = [ta.MeshBatch.from_meshes([ta.load_mesh(entries[int(i)].mesh_path)], coarse_faces=4000)
               for i in a.ids.split(",")]
    total = {"smooth": 0.0, "auto": 0.0}
    for rep in range(a.repeats):
        for batch in batches:
            for remedy in (("smooth", "auto") if rep % 2 == 0 else ("auto", "smooth")):
                t0 = time.perf_counter()
                ta.segment(batch, k=6, seed=0, remedy=remedy)
                total[remedy] += time.perf_counter() - t0
    print(f"{len(batches)} meshes x {a.repeats}: smooth {total['smooth']:.1f} s, auto {total['auto']:.1f} s, "
          f"auto / smooth = {total['auto'] / total['smooth']:.3f}")


if __name__ == "__main__":
    main()
