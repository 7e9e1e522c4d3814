"""Cache what the part-merging sweep needs on a PSB subset (issue 12).

For each mesh (default: 4 per labelled category, ids 20c+1..20c+4): the coarse-to-fine AKVFs
once (as ``torchakvf eval`` computes them: n = 36, coarse 4000 faces), then for every
distinct human segment count k the untangled fields at k's field count and the paper-mode
labels at k' = ceil(r k) for r in RATIOS (r = 1 is today's output). Per (k, k') it stores the
labels on the input faces and the region graph the merge needs, so a parameter sweep
(experiments/segmentation/merge_method_cv.py) runs in seconds. Timings of each stage are stored too.

    PYTHONPATH=$PWD nice -n 5 python experiments/segmentation/quality_cache.py --out /tmp/quality_cache
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from torchakvf.evaluate import psb as P
from torchakvf.fields.akvf import akvf_falling_back
from torchakvf.fields.untangle import untangle
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch
from torchakvf.mesh.clean import face_areas
from torchakvf.options import SEGMENT_UNTANGLE_RESTARTS as UNTANGLE_RESTARTS
from torchakvf.options import SPARE_FIELDS
from torchakvf.parts import segment
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.field_counts import default_n_fields, field_counts
from torchakvf.parts.merge import oversegment_k, region_graph

RATIOS = (1.0, 2.0, 2.5, 3.0, 4.0)


def subset_ids(per_category: int) -> list[int]:
    cats = [c for c in range(20) if c not in (7, 12, 13, 17, 19)]  # 20-blocks: 13 = Spring
    return [c * 20 + i for c in cats for i in range(1, per_category + 1)]


def cache_mesh(entry, out: Path, coarse_faces: int, seed: int = 0, ratios=RATIOS, restarts: int = 20) -> None:
    t0 = time.perf_counter()
    mesh = load_mesh(entry.mesh_path)
    gts = [P.read_seg(s) for s in entry.seg_paths]
    ks = sorted({int(g.max()) + 1 for g in gts})
    mb = MeshBatch.from_meshes([mesh], coarse_faces=coarse_faces)
    fields, _ = akvf_falling_back(mb, n=default_n_fields(10 ** 6) + SPARE_FIELDS, seed=seed, remedy="smooth")
    timing = {"akvf": time.perf_counter() - t0, "untangle": 0.0, "segment": {}}
    dual = dual_edges(mesh.vertices, mesh.faces)
    area = face_areas(mesh.vertices, mesh.faces)
    data = {"faces": mesh.faces.astype(np.int32), "vertices": mesh.vertices, "pairs": dual.pairs.astype(np.int32),
            "length": dual.length, "dihedral": dual.dihedral, "area": area, "ks": np.array(ks)}
    unts = {}
    for k in ks:
        ns = field_counts(fields, [k])
        t1 = time.perf_counter()
        if tuple(ns) not in unts:
            unts[tuple(ns)] = untangle(fields, n=ns, seed=seed, restarts=UNTANGLE_RESTARTS)
        timing["untangle"] += time.perf_counter() - t1
        for r in ratios:
            kp = oversegment_k(k, r, len(mesh.faces))
            key = f"k{k}_r{r:g}"
            t1 = time.perf_counter()
            seg = segment(fields, k=kp, seed=seed, n_fields=ns, untangled=unts[tuple(ns)], refine=False,
                          method="paper", kmeans_restarts=20 if r == 1.0 else restarts)[0]
            timing["segment"][key] = time.perf_counter() - t1
            g = region_graph(seg.labels, dual, seg.features, area)
            data[key + "_labels"] = g.labels.astype(np.int16)
            data[key + "_area"], data[key + "_mean"] = g.area, g.mean
            data[key + "_length"], data[key + "_concave"] = g.length, g.concave
            if r == 1.0:   # per-face untangled features on the input faces (graph-cut data terms)
                data[f"k{k}_feats"] = seg.features.astype(np.float16)
    for i, g in enumerate(gts):
        data[f"gt{i}"] = g.astype(np.int16)
    data["n_gt"] = np.array(len(gts))
    np.savez_compressed(out / f"{entry.mesh_id}.npz", **data)
    timing["total"] = time.perf_counter() - t0
    (out / f"{entry.mesh_id}.json").write_text(json.dumps(timing))
    print(entry.mesh_id, entry.category, f"faces {len(mesh.faces)} ks {ks} {timing['total']:.1f}s", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/quality_cache")
    ap.add_argument("--per-category", type=int, default=4)
    ap.add_argument("--ids", default=None, help="comma-separated mesh ids (default: the subset)")
    ap.add_argument("--coarse-faces", type=int, default=4000)
    ap.add_argument("--ratios", default=",".join(f"{r:g}" for r in RATIOS))
    ap.add_argument("--restarts", type=int, default=20, help="k-means restarts of the over-segmentations (r > 1)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    ids = [int(x) for x in a.ids.split(",")] if a.ids else subset_ids(a.per_category)
    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    for i in ids:
        if (out / f"{i}.npz").exists():
            continue
        cache_mesh(entries[i], out, a.coarse_faces, ratios=tuple(float(r) for r in a.ratios.split(",")),
                   restarts=a.restarts)


if __name__ == "__main__":
    main()
