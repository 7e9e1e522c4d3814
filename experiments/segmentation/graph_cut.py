"""The graph-cut boundary stage on the cached PSB subset (issue 12), cross-validated as the
merge sweep: for each mesh and human k, the merged parts (given MergeWeights), the data term
[F, k] = each face's 1 - cos to the nearest over-segment centre of each merged part (centres:
the over-segments' normalized mean features, as k-means'), then graphcut_labels; 1-RI with and
without the cut.

    PYTHONPATH=$PWD python experiments/segmentation/graph_cut.py --cache /tmp/qcache \
        --weights "ratio=3,concavity=16" --out experiments/results/graph_cut.md
"""
from __future__ import annotations

import argparse
import math
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from torchakvf.evaluate.psb import category_of
from torchakvf.parts.concavity import DualEdges
from torchakvf.parts.graphcut import GraphCut, graphcut_labels
from torchakvf.parts.merge import greedy_merge

try:
    import merge_terms_cv as V2
    from merge_method_cv import SweptWeights, rand_error
except ImportError:
    import experiments.merge_terms_cv as V2
    from experiments.merge_method_cv import SweptWeights, rand_error

N_FOLDS = 3
W: SweptWeights | None = None
EXTRA: dict = {}


def _init(folder, w):
    global W
    V2._init(folder)
    W = w
    for mid in V2.MESHES:
        z = np.load(Path(folder) / f"{mid}.npz")
        EXTRA[mid] = dict(area=z["area"], feats={k: z[f"k{k}_feats"].astype(np.float64) for k in z["ks"].tolist()},
                          dual=DualEdges(z["pairs"].astype(np.int64), z["length"], z["dihedral"]))


def mesh_scores(mid: int, cuts) -> list[float]:
    """[1 + len(cuts)] mean 1-RI over the mesh's humans: merged, then each graph cut."""
    m, x = V2.MESHES[mid], EXTRA[mid]
    memo = m.setdefault("memo", {})
    preds = {}
    for k in set(m["gk"]):
        g = V2.graph(m, k, W.ratio, W.crease_angle, memo)
        new_id, _ = greedy_merge(g, k, W)
        merged = new_id[g.labels]
        f = x["feats"][k]
        unit = f / np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-300)
        cen = g.mean / np.maximum(np.linalg.norm(g.mean, axis=1, keepdims=True), 1e-300)
        d_over = 1.0 - unit @ cen.T                       # [F, K'] distance to each over-segment
        kk = int(new_id.max()) + 1
        dist = np.full((len(merged), kk), np.inf)
        for p in range(len(new_id)):
            dist[:, new_id[p]] = np.minimum(dist[:, new_id[p]], d_over[:, p])
        preds[k] = [merged] + [graphcut_labels(merged, dist, x["dual"], x["area"], c) for c in cuts]
    return [float(np.mean([rand_error(preds[k][i], gt) for k, gt in zip(m["gk"], m["gts"])]))
            for i in range(1 + len(cuts))]


CUTS: list = []


def _job(mid):
    t = time.perf_counter()
    out = mid, mesh_scores(mid, CUTS)
    print(mid, f"{time.perf_counter() - t:.0f}s", [round(x, 4) for x in out[1]], flush=True)
    return out


def main():
    global CUTS
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", default="/tmp/qcache")
    ap.add_argument("--weights", default="ratio=3,concavity=16")
    ap.add_argument("--out", default="/tmp/graph_cut.md")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cuts", default="0.3:10,1:10,3:10,1:0", help="smoothness:beta,...")
    a = ap.parse_args()
    w = SweptWeights.hand_set(**{kv.split("=")[0]: float(kv.split("=")[1]) for kv in a.weights.split(",")})
    V2.RATIOS = (w.ratio,)
    CUTS = [GraphCut(smoothness=s, beta=b, crease_angle=math.radians(45), band=6)
            for s, b in [tuple(float(x) for x in c.split(":")) for c in a.cuts.split(",")]]
    t0 = time.perf_counter()
    with Pool(a.workers, initializer=_init, initargs=(a.cache, w)) as pool:
        ids = sorted(int(p.stem) for p in Path(a.cache).glob("*.npz"))
        res = dict(pool.map(_job, ids))
    cats = sorted({category_of(i) for i in ids}, key=lambda c: min(i for i in ids if category_of(i) == c))
    names = ["merged (no cut)"] + [f"cut λ {c.smoothness:g}, β {c.beta:g}" for c in CUTS]
    tab = [{c: float(np.mean([res[i][j] for i in ids if category_of(i) == c])) for c in cats}
           for j in range(len(names))]
    ov = lambda t, cs: float(np.mean([t[c] for c in cs]))
    folds = [[c for i, c in enumerate(cats) if i % N_FOLDS == f] for f in range(N_FOLDS)]
    L = ["# Graph-cut boundaries after merging (issue 12)", "",
         f"- cache {a.cache}, {len(ids)} meshes; merge weights: {V2.fmt(w)}; crease angle 45°, band 6 rings; "
         f"data term from the cached features (see the script); {time.perf_counter() - t0:.0f} s", "",
         "| setting | overall | " + " | ".join(cats) + " |", "|---|---:|" + "---:|" * len(cats)]
    for n, t in zip(names, tab):
        L.append(f"| {n} | {ov(t, cats):.4f} | " + " | ".join(f"{t[c]:.3f}" for c in cats) + " |")
    L += ["", "| fold | chosen on the other 10 (index 0 = no cut) | held-out no cut | held-out chosen |",
          "|---|---|---:|---:|"]
    held = {}
    for f, test in enumerate(folds):
        train = [c for c in cats if c not in test]
        j = min(range(len(names)), key=lambda j: ov(tab[j], train))
        L.append(f"| {f} ({', '.join(test)}) | {names[j]} | {ov(tab[0], test):.4f} | {ov(tab[j], test):.4f} |")
        held.update({c: tab[j][c] for c in test})
    L += ["", f"CV estimate: with the chosen cut {ov(held, cats):.4f} vs no cut {ov(tab[0], cats):.4f}."]
    Path(a.out).write_text("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
