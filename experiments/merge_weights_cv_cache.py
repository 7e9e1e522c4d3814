"""Cache what the v3 quality sweep needs on the 15 labelled PSB categories (issue 12).

Per mesh: the AKVFs once, as ``torchakvf eval`` computes them (n = 36, coarse 4000 faces), then
for every distinct human k and every field-count rule of RULES the default merge pipeline
(engine.segment_rounds, method "merge"), recording what its merge stage starts from: the
over-segmentation's labels on the cut mesh, the per-vertex distances to its k-means centres and
the per-face untangled features; plus the pipeline's own output (input faces) and the paper
mode's (k-means into k). experiments/merge_weights_cv.py re-runs merge + graph cut from these.

    PYTHONPATH=$PWD nice -n 5 python experiments/merge_weights_cv_cache.py --out /tmp/qv3 --workers 2
"""
from __future__ import annotations

import argparse
import functools
import os
import pickle
import time
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np
import torch

from torchakvf.evaluate import psb as P
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch
from torchakvf.parts import engine as E
from torchakvf.parts.merge import oversegment_k

LABELLED = [c for c in range(20) if c not in (7, 12, 13, 17, 19)]   # 20-blocks; 13 = Spring (no gt)


def _clamp(n):
    return int(min(max(n, 16), 32))


#: field-count rules n(k) of the merge method (then engine.cluster_safe_n as today)
RULES = {
    "2k": lambda k: _clamp(2 * k),                                   # today's (the paper's N)
    "3k": lambda k: _clamp(3 * k),
    "2kp": lambda k: _clamp(2 * oversegment_k(k, 3.0, 10 ** 9, 16)),   # 2 k' (k' clusters)
}
ORIGINAL_N = E.default_n_fields
CAPTURE: dict = {}
_orig_merge, _orig_md, _orig_cut = E.merge_parts, E.merged_distances, E.cut_parts


def _merge(over, faces, vertices, feats, area, k, weights=None, dual=None):
    CAPTURE.update(over=np.asarray(over).astype(np.int16), feats=np.asarray(feats, dtype=np.float32),
                   area=np.asarray(area, dtype=np.float64))
    return _orig_merge(over, faces, vertices, feats, area, k, weights, dual=dual)


def _md(vdist, over, labels):
    CAPTURE["vdist"] = np.asarray(vdist, dtype=np.float32)
    return _orig_md(vdist, over, labels)


def _cut(batch, fields, unt, km, b, k, opts, cache=None):
    CAPTURE.clear()
    seg = _orig_cut(batch, fields, unt, km, b, k, opts, cache)
    co = batch.coarse_of(b)
    CAPTURE["clean"] = co.fine if co is not None else batch.meshes[b]
    CAPTURE["out"] = np.asarray(seg.labels).astype(np.int16)
    CAPTURE["n"] = int(unt.n_fields[b])
    return seg


E.merge_parts, E.merged_distances, E.cut_parts = _merge, _md, _cut


def run_rounds(fields, ks, opts):
    got = {}
    for rnd in E.segment_rounds(fields, [ks], opts):
        got[rnd.ks[0]] = dict(CAPTURE)
    return got


def cache_mesh(entry, out: Path):
    torch.set_num_threads(1)
    if (out / f"{entry.mesh_id}.pkl").exists():
        return entry.mesh_id, 0.0
    t0 = time.process_time()
    mesh = load_mesh(entry.mesh_path)
    gts = [P.read_seg(s).astype(np.int64) for s in entry.seg_paths]
    ks = sorted({int(g.max()) + 1 for g in gts})
    mb = MeshBatch.from_meshes([mesh], coarse_faces=4000)
    opts = E.SegmentOptions(refine=False)
    fields, _ = E.solve_akvfs(mb, ORIGINAL_N(10 ** 6) + E.SPARE_FIELDS, opts)
    secs = {"akvf": time.process_time() - t0}
    data = {"gts": [g.astype(np.int16) for g in gts], "ks": ks, "rules": {}, "paper": {}, "seconds": secs, "feats": {}}
    t1 = time.process_time()
    E.default_n_fields = ORIGINAL_N
    for k, cap in run_rounds(fields, ks, E.SegmentOptions(refine=False, method="paper")).items():
        data["paper"][k] = cap["out"]
    secs["paper"] = time.process_time() - t1
    for name, rule in RULES.items():
        t1 = time.process_time()
        E.default_n_fields = rule
        try:
            caps = run_rounds(fields, ks, opts)
        finally:
            E.default_n_fields = ORIGINAL_N
        secs[name] = time.process_time() - t1
        for cap in caps.values():   # features depend on n alone, areas on the mesh alone: stored once
            data["feats"].setdefault(cap["n"], cap.pop("feats"))
            data["area"] = cap.pop("area")
        data["rules"][name] = caps
    with open(out / f"{entry.mesh_id}.tmp", "wb") as f:
        pickle.dump(data, f, protocol=4)
    os.replace(out / f"{entry.mesh_id}.tmp", out / f"{entry.mesh_id}.pkl")
    return entry.mesh_id, time.process_time() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/qv3")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--per-category", type=int, default=20)
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    # interleaved (mesh 1 of every category, then mesh 2, ...): a partial cache stays balanced
    ids = [c * 20 + i for i in range(1, a.per_category + 1) for c in LABELLED]
    ids = [i for i in ids if i in entries]
    with Pool(a.workers) as pool:
        for mid, s in pool.imap_unordered(functools.partial(cache_mesh, out=out), [entries[i] for i in ids]):
            print(mid, P.category_of(mid), f"{s:.1f}s", flush=True)


if __name__ == "__main__":
    main()
