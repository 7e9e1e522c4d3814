"""CPU seconds of ``interop.face_features`` (all 41 descriptor columns) per mesh, for a cost
ratio between two checkouts measured in the same run (docs/descriptors.md, Cost).

One call times every mesh once in this process (one thread; the batch's decimation included)
and prints a JSON line; run it alternately with PYTHONPATH at each checkout, several rounds, and
compare per-mesh minima (BASE: an export of the other revision, e.g. ``git archive main``)::

    for r in 1 2 3; do for t in $BASE $PWD; do
      PYTHONPATH=$t OMP_NUM_THREADS=1 nice python experiments/descriptors/descriptor_cost.py --tag $t; done; done

``--steps`` (this checkout only) times instead the steps stability adds, per mesh: the
descriptors' own canonical decimation (``descriptor_batch``), the canonical signs and the
canonical numbering of the full-resolution mesh the part columns are cut on.
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


def steps(mesh) -> dict:
    """CPU seconds of each step stability adds, on one mesh decimated to 4000 faces."""
    from torchakvf import akvf
    from torchakvf.fields.canonical import canonical_signs
    from torchakvf.parts.input_descriptors import descriptor_batch
    from torchakvf.parts.part_descriptors import fine_meshes_numbered_canonically

    batch = MeshBatch.from_meshes([mesh], coarse_faces=4000)
    out = {}
    t = time.process_time()
    batch = descriptor_batch(batch)
    out["descriptor_batch"] = time.process_time() - t
    fields = akvf(batch, n=32, seed=0)
    t = time.process_time()
    canonical_signs(fields)
    out["canonical_signs"] = time.process_time() - t
    t = time.process_time()
    fine_meshes_numbered_canonically(batch)
    out["fine_numbering"] = time.process_time() - t
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tag", default="")
    ap.add_argument("--ids", type=int, nargs="*", default=list(PSB_IDS))
    ap.add_argument("--steps", action="store_true")
    args = ap.parse_args()
    root = default_psb_root()
    face_features(MeshBatch.from_meshes([load_mesh(root / "meshes" / "1.off.gz")], coarse_faces=1000), 8)  # warm-up
    out = {"tag": args.tag, "package": torchakvf.__file__, "cpu": {}}
    for i in args.ids:
        mesh = load_mesh(root / "meshes" / f"{i}.off.gz")
        if args.steps:
            out["cpu"][i] = steps(mesh)
            continue
        t = time.process_time()
        face_features(MeshBatch.from_meshes([mesh], coarse_faces=4000), 32)
        out["cpu"][i] = time.process_time() - t
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
