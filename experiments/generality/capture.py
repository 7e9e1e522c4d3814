"""Capture what the merge decision sees on every labelled shape (PSB and the procedural corpus).

For each shape, as the default pipeline runs it (coarse ``--coarse-faces`` faces, refine off)
under an over-segmentation variant (:data:`OVERSEG`) and, with ``--weights``, the merge weights
fitted without the shape's group (the final labels are then held out): the over-segmentation the merge starts
from at each k (labels on the fine cleaned mesh after the clean-up, unit feature rows, face
areas), the default's final labels at each k, the cleaned mesh and the truths. merge_cv.py then
redoes only the merge on exactly these over-segmentations.

    PYTHONPATH=$PWD nice python3 experiments/generality/capture.py --variant crease60 \\
        --corpus /tmp/corpus --out /tmp/capture_crease60 --workers 2

``--graphcut "smoothness=5"`` segments with other boundary-step parameters (the final labels
change; the over-segmentations do not).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import sys
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "segmentation"))
from items import items as all_items  # noqa: E402
from items import read_truth
from merge_capture import capture_rounds

#: over-segmentation variants: OverSegmentation changes (the merge weights do not matter here).
#: Those measured before a crease patch's fragments were united keep them apart, and those
#: measured before every piece was cut where a crease crosses it cut by the surface's patches.
_WHOLE = dict(crease_per_piece=False)
_APART = dict(unite_fragments=False, **_WHOLE)
OVERSEG = {
    "base": dict(crease_split=None),
    **{name: dict(crease_split=math.radians(angle), crease_rings=rings, crease_concave=concave, **_APART)
       for name, angle, rings, concave in (("crease60", 60, 3, False), ("crease45", 45, 3, False),
                                           ("crease75", 75, 3, False), ("crease60r2", 60, 2, False),
                                           ("crease60r4", 60, 4, False), ("concave60", 60, 3, True),
                                           ("concave45", 45, 3, True), ("concave60r4", 60, 4, True))},
    # the over-segmentation's size, k' = min(ceil(ratio max(k, 8)), max(k, 8) + extra_max), the cap
    # 8 ratio - 8 so that the ratio acts up to k = 8; the variants above take the package's ratio
    **{f"concave60_ratio{r}": dict(crease_split=math.radians(60), crease_rings=3, crease_concave=True,
                                   ratio=float(r), extra_max=8 * r - 8, **_APART) for r in (3, 4, 5, 6)},
    # a crease patch of at least the part floor cut by k-means into pieces all below it made one
    # piece (the default since; experiments/results/generality_unite_fragments.md)
    "concave60_ratio5_unite": dict(crease_split=math.radians(60), crease_rings=3, crease_concave=True,
                                   ratio=5.0, extra_max=32, unite_fragments=True, **_WHOLE),
    # every k-means piece cut where a crease crosses it, not only by the patches a crease encloses
    # (experiments/results/generality_crease_per_piece.md)
    "concave60_ratio5_piece": dict(crease_split=math.radians(60), crease_rings=3, crease_concave=True,
                                   ratio=5.0, extra_max=32, unite_fragments=True, crease_per_piece=True),
}


def options(variant: str, merge_changes: dict | None = None, graphcut: dict | None = None):
    from torchakvf.options import GraphCut, MergeWeights, OverSegmentation, SegmentOptions

    return SegmentOptions(refine=False, merge=MergeWeights(**(merge_changes or {})),
                          overseg=OverSegmentation(**OVERSEG[variant]), graphcut=GraphCut(**(graphcut or {})))


def parse_graphcut(text: str | None) -> dict | None:
    """``--graphcut "smoothness=5,beta=10"`` -> {name: number} of GraphCut fields (None: default)."""
    if not text:
        return None
    out = {}
    for item in text.split(","):
        name, value = item.split("=")
        out[name.strip()] = int(value) if name.strip() in ("band", "cycles") else float(value)
    return out


def capture_item(args) -> str:
    item, out, variant, coarse_faces, rings, weights, graphcut = args
    import torch

    from torchakvf.operators import killing

    if rings is not None:
        killing.CURVATURE_RINGS["smooth"] = rings

    torch.set_num_threads(1)
    from torchakvf.io import load_mesh
    from torchakvf.mesh import MeshBatch
    from torchakvf.parts.field_counts import akvf_count
    from torchakvf.parts.solve import solve_akvfs

    path = Path(out) / f"{item.key.replace(':', '_')}.pkl"
    if path.exists():
        return f"{item.key} cached"
    t0 = time.perf_counter()
    opts = options(variant, weights.get(item.group, weights.get("*")) if weights else None, graphcut)
    try:
        mesh = load_mesh(item.mesh_path)
        gts = [read_truth(s) for s in item.truths]
        ks = sorted({int(g.max()) + 1 for g in gts})
        mb = MeshBatch.from_meshes([mesh], coarse_faces=coarse_faces or None)
        # the eval's fixed AKVF count for the PSB, the segment command's for the corpus
        n_akvf = 36 if item.source == "psb" else akvf_count([ks], None, opts.method, opts.merge_min_k)
        fields, _ = solve_akvfs(mb, n_akvf, opts)
    except Exception as exc:                         # noqa: BLE001 - recorded, the run goes on
        return f"{item.key} FAILED {type(exc).__name__}: {exc}"
    record = capture_rounds(fields, ks, opts, np.int32)
    record.update(key=item.key, group=item.group, kind=item.kind, gts=[g.astype(np.int32) for g in gts],
                  variant=variant, coarse_faces=coarse_faces, remedy=fields.remedies[0], rings=rings,
                  seconds=time.perf_counter() - t0)
    with open(path, "wb") as fh:
        pickle.dump(record, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return f"{item.key} {item.group} ks {ks} {record['seconds']:.1f}s"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--variant", default="base", choices=sorted(OVERSEG))
    ap.add_argument("--corpus", default=None, help="procedural corpus folder (index.json)")
    ap.add_argument("--no-psb", action="store_true")
    ap.add_argument("--keys", default=None, help="comma-separated item keys (default: all)")
    ap.add_argument("--per-family", type=int, default=None,
                    help="only the first N shapes of each corpus family (the PSB's meshes all)")
    ap.add_argument("--coarse-faces", type=int, default=4000)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--weights", default=None,
                    help="JSON file {group or '*': MergeWeights fields}: the merge each group's shapes are "
                         "segmented with (held-out weights per group)")
    ap.add_argument("--curvature-rings", type=int, default=None,
                    help="rings of the 'smooth' remedy's curvature averaging (default: the package's)")
    ap.add_argument("--graphcut", default=None,
                    help="GraphCut fields for the boundary step, e.g. 'smoothness=5,beta=10' (default: the package's)")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    todo = all_items(psb=not a.no_psb, corpus=a.corpus)
    if a.keys:
        want = set(a.keys.split(","))
        todo = [i for i in todo if i.key in want]
    if a.per_family is not None:
        seen: dict = {}
        todo = [i for i in todo if i.source == "psb"
                or seen.setdefault(i.group, []).append(i) or len(seen[i.group]) <= a.per_family]
    weights = json.loads(Path(a.weights).read_text()) if a.weights else None
    if weights and "folds" in weights:      # merge_weights_folds.json: {source, meaning, folds}
        weights = weights["folds"]
    jobs = [(i, str(out), a.variant, a.coarse_faces, a.curvature_rings, weights, parse_graphcut(a.graphcut))
            for i in todo]
    os.environ.update({v: "1" for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
    if a.workers == 1:
        for j in jobs:
            print(capture_item(j), flush=True)
        return
    with get_context("fork").Pool(a.workers, maxtasksperchild=50) as pool:
        for line in pool.imap_unordered(capture_item, jobs):
            print(line, flush=True)


if __name__ == "__main__":
    main()
