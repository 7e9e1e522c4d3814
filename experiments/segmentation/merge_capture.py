"""Capture what the merge decision sees on every labelled PSB mesh, as `torchakvf eval` runs it.

For each mesh with human segmentations: the AKVFs as eval solves them (default options, coarse
4000 faces, refine off), then every human k through :func:`~torchakvf.parts.rounds.segment_rounds`
with the merge step recorded: the over-segmentation it merges (labels on the fine cleaned mesh
after the clean-up of small pieces, the unit feature rows, the face areas), the default's
final labels (after the graph cut, on the input faces) and the cleaned mesh (to map labels to
the input faces). A sweep of the merge decision (experiments/segmentation/merge_learned_cv.py) then only
redoes the merge, on exactly the over-segmentation the default merges.

    PYTHONPATH=$PWD nice python3 experiments/segmentation/merge_capture.py --out /tmp/merge_capture --workers 2
"""
from __future__ import annotations

import argparse
import os
import pickle
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np


def capture_rounds(fields, ks: list, opts, label_dtype) -> dict:
    """Segment one mesh's AKVFs at each of ``ks``, recording what the merge starts from at each
    k: {"overs": [{labels, unit rows, area, n_clusters, n_patches}] (one per over-segmentation),
    "k_over": {k: index into overs}, "final": {k: the segmentation's labels}, "mesh": the cleaned
    mesh}. Records at :func:`torchakvf.parts.cut.segmentation_labels`, the one place an
    over-segmentation becomes k parts. Shared with experiments/generality/capture.py."""
    from torchakvf.parts import cut as C
    from torchakvf.parts.rounds import segment_rounds

    record = {"overs": [], "k_over": {}, "final": {}}
    original = C.segmentation_labels

    def recording(over, cache, o, k, floor, cost, n_solved, **kw):
        ids = [i for i, s in enumerate(record["overs"]) if s["labels"] is over.labels]
        if not ids:
            record["overs"].append({"labels": over.labels, "unit": over.unit.astype(np.float32),
                                    "area": over.area, "n_clusters": int(over.source[1].shape[0]),
                                    "n_patches": int(over.n_patches)})
            ids = [len(record["overs"]) - 1]
        record["k_over"][int(k)] = ids[0]
        record["mesh"] = over.mesh
        return original(over, cache, o, k, floor, cost, n_solved, **kw)

    C.segmentation_labels = recording
    try:
        for rnd in segment_rounds(fields, [ks], opts):
            for b in rnd.active:
                record["final"][int(rnd.ks[b])] = rnd.meshes[b].labels.astype(label_dtype)
    finally:
        C.segmentation_labels = original
    return record

def capture_mesh(args) -> str:
    entry, out, coarse_faces = args
    import torch

    torch.set_num_threads(1)
    from torchakvf.evaluate import psb as P
    from torchakvf.evaluate.predict import PredictSettings, eval_akvf_count
    from torchakvf.io import load_mesh
    from torchakvf.mesh import MeshBatch
    from torchakvf.options import SegmentOptions
    from torchakvf.parts.solve import solve_akvfs

    path = Path(out) / f"{entry.mesh_id}.pkl"
    if path.exists():
        return f"{entry.mesh_id} cached"
    t0 = time.perf_counter()
    opts = SegmentOptions(refine=False)
    settings = PredictSettings(auto=False, n_fields=None, k_range=None, k_rule=None,
                               coarse_faces=coarse_faces, options=opts)
    mesh = load_mesh(entry.mesh_path)
    gts = [P.read_seg(s) for s in entry.seg_paths]
    ks = sorted({int(g.max()) + 1 for g in gts})
    mb = MeshBatch.from_meshes([mesh], coarse_faces=coarse_faces)
    fields, _ = solve_akvfs(mb, eval_akvf_count(settings), opts)
    record = capture_rounds(fields, ks, opts, np.int16)
    record.update(mesh_id=entry.mesh_id, category=entry.category, gts=[g.astype(np.int16) for g in gts],
                  seconds=time.perf_counter() - t0)
    with open(path, "wb") as fh:
        pickle.dump(record, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return f"{entry.mesh_id} {entry.category} ks {ks} {record['seconds']:.1f}s"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--ids", default=None, help="comma-separated mesh ids (default: every labelled mesh)")
    ap.add_argument("--coarse-faces", type=int, default=4000)
    ap.add_argument("--workers", type=int, default=1)
    a = ap.parse_args()
    from torchakvf.evaluate import psb as P

    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    entries = [e for e in P.find_psb_meshes(P.default_psb_root()) if e.has_gt]
    if a.ids:
        want = {int(x) for x in a.ids.split(",")}
        entries = [e for e in entries if e.mesh_id in want]
    jobs = [(e, str(out), a.coarse_faces) for e in entries]
    os.environ.update({v: "1" for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
    if a.workers == 1:
        for j in jobs:
            print(capture_mesh(j), flush=True)
        return
    with get_context("fork").Pool(a.workers) as pool:
        for line in pool.imap_unordered(capture_mesh, jobs):
            print(line, flush=True)


if __name__ == "__main__":
    main()
