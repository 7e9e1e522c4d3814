"""k auto from the merge costs (issue 12), on the cached PSB subset's meshes.

build: per mesh, the AKVFs as ``torchakvf eval`` computes them (coarse 4000 faces), ONE field
count for every k (k auto's: default_n_fields(k_max), moved off eigenvalue clusters), and for each
k in k_range the paper-mode k-means labels at k' = ceil(r k) (r in RATIOS) with their region graph
on the input faces, and the k-means cost of the plain k-means at k (the "elbow" rule's curve).

sweep: rules that read the merge costs, each with one threshold chosen by 3-fold CV across
categories (as merge_method_cv.py):

* "next": at each k the merged parts' cheapest remaining merge c_next(k) (from the round at k);
  descending from k_max, stop at the first k whose next merge costs more than τ.
* "history": one over-segmentation (the round at k_max) merged greedily down to k_min; k = the
  part count before the first merge costing more than τ.
and the existing "elbow" rule on the plain k-means costs. Scored: by-model style (one prediction
per mesh, compared with every human, mean), hit rate of the mode of the humans' k's.

    PYTHONPATH=$PWD python experiments/segmentation/k_auto.py build --out /tmp/qkauto --ids 1,2,...
    PYTHONPATH=$PWD python experiments/segmentation/k_auto.py sweep --cache /tmp/qkauto --weights ratio=3
"""
from __future__ import annotations

import argparse
import time
from collections import Counter
from pathlib import Path

import numpy as np
import torch

from torchakvf.evaluate import psb as P
from torchakvf.evaluate.k_auto import pick_k
from torchakvf.evaluate.psb import category_of

RATIOS = (2.0, 3.0)
K_RANGE = (2, 10)
N_FOLDS = 3


def build(a):
    from torchakvf.fields.akvf import akvf_falling_back
    from torchakvf.fields.untangle import untangle
    from torchakvf.io import load_mesh
    from torchakvf.mesh import MeshBatch
    from torchakvf.mesh.clean import face_areas
    from torchakvf.options import SEGMENT_UNTANGLE_RESTARTS as UNTANGLE_RESTARTS
    from torchakvf.options import SPARE_FIELDS
    from torchakvf.parts import segment
    from torchakvf.parts.concavity import dual_edges
    from torchakvf.parts.field_counts import cluster_safe_n, default_n_fields
    from torchakvf.parts.merge import oversegment_k, region_graph
    torch.set_num_threads(1)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    lo, hi = K_RANGE
    for mid in [int(x) for x in a.ids.split(",")]:
        if (out / f"{mid}.npz").exists():
            continue
        t0 = time.perf_counter()
        e = entries[mid]
        mesh = load_mesh(e.mesh_path)
        mb = MeshBatch.from_meshes([mesh], coarse_faces=4000)
        n = default_n_fields(hi)
        fields, _ = akvf_falling_back(mb, n=n + SPARE_FIELDS, seed=0, remedy="smooth")
        ns = [cluster_safe_n(fields.eigenvalues[0].cpu(), n, floor=max(hi, n // 2))]
        unt = untangle(fields, n=ns, seed=0, restarts=UNTANGLE_RESTARTS)
        dual = dual_edges(mesh.vertices, mesh.faces)
        area = face_areas(mesh.vertices, mesh.faces)
        data = {"pairs": dual.pairs.astype(np.int32), "length": dual.length, "dihedral": dual.dihedral,
                "area": area, "n_gt": np.array(len(e.seg_paths))}
        for i, s in enumerate(e.seg_paths):
            data[f"gt{i}"] = P.read_seg(s).astype(np.int16)
        for k in range(lo, hi + 1):
            for r in (1.0,) + RATIOS:
                kp = oversegment_k(k, r, len(mesh.faces))
                seg = segment(fields, k=kp, seed=0, n_fields=ns, untangled=unt, refine=False, method="paper")[0]
                if r == 1.0:
                    data[f"k{k}_kmcost"] = np.array(seg.cost)
                g = region_graph(seg.labels, dual, seg.features, area)
                key = f"k{k}_r{r:g}"
                data[key + "_labels"] = g.labels.astype(np.int16)
                data[key + "_area"], data[key + "_mean"] = g.area, g.mean
        np.savez_compressed(out / f"{mid}.npz", **data)
        print(mid, e.category, f"{time.perf_counter() - t0:.1f}s", flush=True)


def sweep(a):
    import sys
    sys.path.insert(0, str(Path(__file__).parent))
    import merge_terms_cv as V2
    from merge_method_cv import SweptWeights, rand_error

    from torchakvf.parts.merge import greedy_merge, merge_costs
    w = SweptWeights(**{kv.split("=")[0]: float(kv.split("=")[1]) for kv in a.weights.split(",")})
    lo, hi = K_RANGE
    ks = list(range(lo, hi + 1))
    rows = {}
    for f in sorted(Path(a.cache).glob("*.npz"), key=lambda p: int(p.stem)):
        z = np.load(f)
        gts = [z[f"gt{i}"].astype(np.int64) for i in range(int(z["n_gt"]))]
        m = dict(pairs=z["pairs"].astype(np.int64), length=z["length"], dihedral=z["dihedral"],
                 parts={(k, w.ratio): (z[f"k{k}_r{w.ratio:g}_labels"].astype(np.int64), z[f"k{k}_r{w.ratio:g}_area"],
                                       z[f"k{k}_r{w.ratio:g}_mean"]) for k in ks})
        memo = {}
        pred, nxt, kmcost = {}, [], []
        for k in ks:
            g = V2.graph(m, k, w.ratio, w.crease_angle, memo)
            new_id, _ = greedy_merge(g, k, w)
            pred[k] = new_id[g.labels]
            # the merged parts' graph: its cheapest merge is the cost of going to k - 1
            gm = V2.graph(dict(m, parts={(k, 0.0): (pred[k], *merged_area_mean(g, new_id))}), k, 0.0,
                          w.crease_angle, {})
            c = merge_costs(gm, w, k)
            nxt.append(float(c.min()) if np.isfinite(c).any() else np.inf)
            kmcost.append(float(z[f"k{k}_kmcost"]))
        g = V2.graph(m, hi, w.ratio, w.crease_angle, memo)
        _, hist = greedy_merge(g, lo, w)
        K = g.n_parts
        hk = [K - i for i in range(len(hist))]    # parts before merge i
        score = {k: float(np.mean([rand_error(pred[k], gt) for gt in gts])) for k in ks}
        gk = [int(gt.max()) + 1 for gt in gts]
        cnt = Counter(gk)
        mode = min(c for c in cnt if cnt[c] == max(cnt.values()))
        rows[int(f.stem)] = dict(score=score, nxt=np.array(nxt), hist=np.array(hist), hk=np.array(hk),
                                 kmcost=np.array(kmcost), mode=mode, gk=gk)
    ids = sorted(rows)
    cats = sorted({category_of(i) for i in ids}, key=lambda c: min(i for i in ids if category_of(i) == c))

    def choose(r, rule, tau):
        if rule == "elbow":
            return pick_k(ks, r["kmcost"], "elbow")
        if rule == "next":
            above = [k for k, c in zip(ks, r["nxt"]) if c > tau]
            return max(above) if above else lo
        i = np.flatnonzero(r["hist"] > tau)     # history
        k = int(r["hk"][i[0]]) if len(i) else lo
        return int(min(max(k, lo), hi))

    taus = {"elbow": [0.0], "next": list(np.round(np.arange(0.05, 3.0, 0.05), 3)),
            "history": list(np.round(np.arange(0.05, 3.0, 0.05), 3))}

    def table(rule, tau):
        per = {}
        for i in ids:
            k = choose(rows[i], rule, tau)
            per.setdefault(category_of(i), []).append((rows[i]["score"][k], k == rows[i]["mode"], k))
        return {c: (float(np.mean([x[0] for x in v])), float(np.mean([x[1] for x in v]))) for c, v in per.items()}

    ov = lambda t, cs: float(np.mean([t[c][0] for c in cs]))
    hit = lambda t, cs: float(np.mean([t[c][1] for c in cs]))
    folds = [[c for i, c in enumerate(cats) if i % N_FOLDS == f] for f in range(N_FOLDS)]
    tabs = {(rule, t): table(rule, t) for rule in taus for t in taus[rule]}
    # oracle and the given-k baseline (merged parts at each human's own k, mode k as one prediction)
    oracle = {c: float(np.mean([min(rows[i]["score"].values()) for i in ids if category_of(i) == c])) for c in cats}
    at_mode = {c: float(np.mean([rows[i]["score"][min(max(rows[i]["mode"], lo), hi)] for i in ids
                                 if category_of(i) == c])) for c in cats}
    L = ["# k auto from the merge costs (issue 12)", "",
         f"- cache {a.cache}: {len(ids)} meshes, k in {K_RANGE}, one field count per mesh (k auto's), "
         f"merge weights {V2.fmt(w)}; one prediction per mesh, 1-RI against every human (mean); "
         "hit = chosen k equals the mode of the humans' k's (smallest on ties)", "",
         "| rule | τ (CV: chosen per fold on the other 10) | held-out 1-RI | held-out hit rate |",
         "|---|---|---:|---:|"]
    summary = {}
    for rule in taus:
        held, chosen_t = {}, []
        for f, test in enumerate(folds):
            train = [c for c in cats if c not in test]
            t = min(taus[rule], key=lambda t: (ov(tabs[(rule, t)], train), t))
            chosen_t.append(t)
            for c in test:
                held[c] = tabs[(rule, t)][c]
        summary[rule] = held
        L.append(f"| {rule} | {', '.join(f'{t:g}' for t in chosen_t)} | {ov(held, cats):.4f} | {hit(held, cats):.2f} |")
    L += [f"| the mode k given (not auto) | - | {float(np.mean(list(at_mode.values()))):.4f} | 1.00 |",
          f"| oracle (best k per mesh) | - | {float(np.mean(list(oracle.values()))):.4f} | - |", "",
          "## Per category (held-out)", "", "| category | " + " | ".join(f"{r} 1-RI | {r} hit" for r in taus) +
          " | mode k given | oracle |", "|---|" + "---:|---:|" * len(taus) + "---:|---:|"]
    for c in cats:
        L.append(f"| {c} | " + " | ".join(f"{summary[r][c][0]:.3f} | {summary[r][c][1]:.2f}" for r in taus) +
                 f" | {at_mode[c]:.3f} | {oracle[c]:.3f} |")
    Path(a.out).write_text("\n".join(L) + "\n")
    print("\n".join(L))


def merged_area_mean(g, new_id):
    kk = int(new_id.max()) + 1
    area = np.bincount(new_id, weights=g.area, minlength=kk)
    mean = np.zeros((kk, g.mean.shape[1]))
    np.add.at(mean, new_id, g.mean * g.area[:, None])
    return area, mean / np.maximum(area, 1e-300)[:, None]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=["build", "sweep"])
    ap.add_argument("--out", default="/tmp/qkauto")
    ap.add_argument("--ids", default="")
    ap.add_argument("--cache", default="/tmp/qkauto")
    ap.add_argument("--weights", default="ratio=3")
    a = ap.parse_args()
    if a.what == "build":
        build(a)
    else:
        if a.out == "/tmp/qkauto":
            a.out = "/tmp/k_auto.md"
        sweep(a)


if __name__ == "__main__":
    main()
