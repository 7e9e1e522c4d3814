"""CPU seconds of ``interop.face_features`` (all 41 descriptor columns) per mesh, for a cost
ratio between two checkouts measured in the same run (docs/descriptors.md, Cost).

One call times every mesh once in this process (one thread) and prints a JSON line; run it
alternately with PYTHONPATH at each checkout, several rounds, and compare per-mesh minima:

    for r in 1 2 3; do for t in /tmp/desc_base $PWD; do
      PYTHONPATH=$t OMP_NUM_THREADS=1 nice python experiments/descriptor_cost.py --tag $t; done; done
"""
from __future__ import annotations

import argparse
import json
import time

import torchakvf
from torchakvf import MeshBatch, load_mesh
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.interop import face_features

PSB_IDS = (1, 21, 121)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tag", default="")
    ap.add_argument("--ids", type=int, nargs="*", default=list(PSB_IDS))
    args = ap.parse_args()
    root = default_psb_root()
    face_features(MeshBatch.from_meshes([load_mesh(root / "meshes" / "1.off.gz")], coarse_faces=1000), 8)  # warm-up
    out = {"tag": args.tag, "package": torchakvf.__file__, "cpu": {}}
    for i in args.ids:
        mesh = load_mesh(root / "meshes" / f"{i}.off.gz")
        t = time.process_time()
        face_features(MeshBatch.from_meshes([mesh], coarse_faces=4000), 32)
        out["cpu"][i] = time.process_time() - t
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
