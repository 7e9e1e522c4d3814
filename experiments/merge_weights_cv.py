"""v3 sweep of the merge method (issue 12) on experiments/merge_weights_cv_cache.py's files: field-count
rule x merge weights x graph cut x a fallback guard, scored as ``torchakvf eval`` scores
(by-segmentation 1-RI, faces counted; mesh = mean over its humans; category = mean over its
meshes; overall = mean over categories), cross-validated across categories (3 folds, category
index mod 3 in PSB order: choose on 10, report on the other 5).

A configuration: Config(rule, MergeWeights, GraphCut or None, guard). ``guard`` tau: when the
greedy merge's most expensive merge costs more than tau, the mesh keeps the paper mode's
k-means-at-k parts instead (None: never).

    PYTHONPATH=$PWD python experiments/merge_weights_cv.py --cache /tmp/qv3 --stage 1
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import time
from dataclasses import dataclass, replace
from multiprocessing import Pool
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np

from torchakvf.evaluate.psb import category_of
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.graphcut import GraphCut, graphcut_labels
from torchakvf.parts.merge import MergeWeights, greedy_merge, merged_distances, region_graph

CATS = ["Human", "Cup", "Glasses", "Airplane", "Ant", "Chair", "Octopus", "Teddy", "Hand", "Plier",
        "Fish", "Armadillo", "Bust", "Mech", "Vase"]
FOLDS = [[c for i, c in enumerate(CATS) if i % 3 == f] for f in range(3)]


#: the v2 defaults (before this sweep): Config() is the former default; names are relative to it
V2_WEIGHTS = MergeWeights(symmetry=1.0, concavity=32.0, size=0.0, ratio=3.0, part_size=0.0, convexity=4.0, cut=0.5,
                          crease_angle=math.pi, extra_max=16)


@dataclass(frozen=True)
class Config:
    rule: str = "2k"
    merge: MergeWeights | None = V2_WEIGHTS   # None: the paper mode (k-means into k)
    graphcut: GraphCut | None = GraphCut()
    guard: float | None = None

    def name(self) -> str:
        if self.merge is None:
            return "paper"
        w, d = self.merge, V2_WEIGHTS
        s = [f"n {self.rule}"] + [f"{f} {getattr(w, f):g}" for f in ("symmetry", "concavity", "convexity", "cut", "part_size", "size")
                                  if getattr(w, f) != getattr(d, f)]
        if self.graphcut is None:
            s.append("no cut")
        elif self.graphcut != GraphCut():
            g = self.graphcut
            s.append(f"cut λ {g.smoothness:g} β {g.beta:g} band {g.band} crease {math.degrees(g.crease_angle):.0f}°")
        if self.guard is not None:
            s.append(f"guard {self.guard:g}")
        return ", ".join(s)


def rand_error(a: np.ndarray, b: np.ndarray) -> float:
    a = np.where(a < 0, a.max() + 1, a).astype(np.int64)
    b = b.astype(np.int64)
    n, nb = a.size, int(b.max()) + 1
    c2 = lambda x: (x * (x - 1) / 2).sum()
    cell = np.bincount(a * nb + b).astype(np.float64)
    return float((c2(np.bincount(a).astype(np.float64)) + c2(np.bincount(b).astype(np.float64)) - 2 * c2(cell))
                 / (n * (n - 1) / 2))


CACHE = "/tmp/qv3"


def to_input(clean, labels):
    """clean.labels_to_input_faces, without its search for dropped faces when none was dropped."""
    if len(clean.face_index) == clean.n_input_faces:
        out = np.empty(clean.n_input_faces, dtype=np.int64)
        out[clean.face_index] = labels
        return out
    return clean.labels_to_input_faces(labels)


def mesh_scores(args) -> tuple[int, list]:
    """[score per config] of one mesh."""
    mid, configs = args
    with open(Path(CACHE) / f"{mid}.pkl", "rb") as f:
        d = pickle.load(f)
    gts = [g.astype(np.int64) for g in d["gts"]]
    gk = [int(g.max()) + 1 for g in gts]
    area = d["area"]
    duals, graphs, preds = {}, {}, {}
    out = []
    for c in configs:
        pred = {}
        for k in d["ks"]:
            if c.merge is None:
                pred[k] = d["paper"][k]
                continue
            cap = d["rules"][c.rule][k]
            clean = cap["clean"]
            if id(clean) not in duals:
                duals[id(clean)] = dual_edges(clean.vertices, clean.faces)
            dual = duals[id(clean)]
            gkey = (c.rule, k, c.merge.crease_angle)
            if gkey not in graphs:
                graphs[gkey] = region_graph(cap["over"].astype(np.int64), dual, d["feats"][cap["n"]], area,
                                            c.merge.crease_angle)
            g = graphs[gkey]
            pkey = (c.rule, k, c.merge, c.graphcut)
            if pkey not in preds:
                new_id, hist = greedy_merge(g, k, c.merge)
                labels = np.where(g.labels >= 0, new_id[np.maximum(g.labels, 0)], -1)
                if c.graphcut is not None:
                    over = cap["over"].astype(np.int64)
                    vd = merged_distances(cap["vdist"].astype(np.float64), over, labels)
                    labels = graphcut_labels(labels, vd[clean.faces].mean(axis=1), dual, area, c.graphcut)
                preds[pkey] = (to_input(clean, labels), max(hist, default=0.0))
            lab, top = preds[pkey]
            pred[k] = d["paper"][k] if (c.guard is not None and top > c.guard) else lab
        out.append(float(np.mean([rand_error(pred[k].astype(np.int64), g) for k, g in zip(gk, gts)])))
    return mid, out


def sweep(configs: list, ids: list, workers: int = 2) -> dict:
    """{config: {mesh id: 1-RI}}"""
    res = {c: {} for c in configs}
    with Pool(workers) as pool:
        for mid, sc in pool.imap_unordered(mesh_scores, [(i, configs) for i in ids]):
            for c, s in zip(configs, sc):
                res[c][mid] = s
    return res


def per_category(scores: dict) -> dict:
    by = {}
    for mid, s in scores.items():
        by.setdefault(category_of(mid), []).append(s)
    return {c: float(np.mean(v)) for c, v in by.items()}


def overall(t: dict, cats) -> float:
    return float(np.mean([t[c] for c in cats]))


def cross_validate(tables: dict, candidates: list) -> tuple[list, dict]:
    """Per fold: the candidate best on the other 10 categories; returns ([(fold, chosen)], held-out
    per-category table of the choices)."""
    rows, held = [], {}
    for f, test in enumerate(FOLDS):
        train = [c for c in CATS if c not in test]
        w = min(candidates, key=lambda c: (overall(tables[c], train), c.name()))
        rows.append((f, w))
        held.update({c: tables[w][c] for c in test})
    return rows, held


def cached_ids(cache: str) -> list:
    return sorted(int(p.stem) for p in Path(cache).glob("*.pkl"))


def main():
    global CACHE
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", default="/tmp/qv3")
    ap.add_argument("--out", default="/tmp/qv3_sweep.pkl")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--max-index", type=int, default=20, help="only meshes 20c+1..20c+this")
    ap.add_argument("--grid", required=True, help="python expression: list of Config (names: Config, MergeWeights, GraphCut, math)")
    a = ap.parse_args()
    CACHE = a.cache
    os.environ["QV3_CACHE"] = a.cache
    configs = list(dict.fromkeys(eval(a.grid, {"Config": Config, "MergeWeights": MergeWeights, "GraphCut": GraphCut,
                                               "math": math, "replace": replace, "V2": V2_WEIGHTS})))
    old = pickle.load(open(a.out, "rb")) if Path(a.out).exists() else {}
    # meshes already scored for every config are not redone (sweeps can grow with the cache)
    ids = [i for i in cached_ids(a.cache) if (i - 1) % 20 < a.max_index
           and not all(i in old.get(c, {}) for c in configs)]
    t0 = time.perf_counter()
    res = sweep(configs, ids, a.workers)
    for c in configs:
        old.setdefault(c, {}).update(res[c])
    pickle.dump(old, open(a.out, "wb"))
    res = {c: old[c] for c in configs}
    print(f"{len(configs)} configs x {len(ids)} meshes in {time.perf_counter() - t0:.0f}s", flush=True)
    for c in sorted(res, key=lambda c: overall(per_category(res[c]), CATS)):
        t = per_category(res[c])
        print(f"{overall(t, CATS):.4f}  {c.name()}  " + " ".join(f"{t[x]:.3f}" for x in CATS))


if __name__ == "__main__":
    main()
