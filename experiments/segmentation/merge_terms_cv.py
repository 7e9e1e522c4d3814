"""Second sweep of the part merging (issue 12): more ratios and more cost terms, cross-validated
across categories as experiments/segmentation/merge_method_cv.py (3 folds of 5 categories, c mod 3).

Reads experiments/segmentation/quality_cache.py's files (labels of the over-segmentation per (k, ratio), the
parts' areas and mean features, the dual graph's lengths and signed dihedrals) and recomputes the
region graph's crease sums for each crease angle. Stages (coordinate search, each stage's grid
around the previous stage's best on ALL categories; the CV choice is made over the union of
every grid point evaluated):

    PYTHONPATH=$PWD python experiments/segmentation/merge_terms_cv.py --cache /tmp/qcache \
        --out /tmp/merge_terms_cv.md
"""
from __future__ import annotations

import argparse
import math
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from torchakvf.evaluate.psb import category_of
from torchakvf.parts.concavity import crease_weights
from torchakvf.parts.merge import RegionGraph, greedy_merge

try:
    from merge_method_cv import SweptWeights, rand_error
except ImportError:
    from experiments.merge_method_cv import SweptWeights, rand_error

RATIOS = tuple(float(r) for r in __import__("os").environ.get("QUALITY_RATIOS", "2,2.5,3,4").split(","))
N_FOLDS = 3
MESHES: dict = {}


def load(folder: Path) -> dict:
    meshes = {}
    for f in sorted(folder.glob("*.npz"), key=lambda p: int(p.stem)):
        z = np.load(f)
        gts = [z[f"gt{i}"].astype(np.int64) for i in range(int(z["n_gt"]))]
        m = dict(gts=gts, gk=[int(g.max()) + 1 for g in gts], pairs=z["pairs"].astype(np.int64),
                 length=z["length"], dihedral=z["dihedral"], parts={})
        for k in z["ks"].tolist():
            for r in (1.0,) + RATIOS:
                key = f"k{k}_r{r:g}"
                if key + "_labels" in z:
                    m["parts"][(k, r)] = (z[key + "_labels"].astype(np.int64), z[key + "_area"], z[key + "_mean"])
        meshes[int(f.stem)] = m
    return meshes


def graph(m: dict, k: int, r: float, crease: float, memo: dict) -> RegionGraph:
    key = (k, r, crease)
    if key not in memo:
        labels, area, mean = m["parts"][(k, r)]
        K = len(area)
        la, lb = labels[m["pairs"][:, 0]], labels[m["pairs"][:, 1]]
        cut = (la != lb) & (la >= 0) & (lb >= 0)
        idx = la[cut] * K + lb[cut]
        cav, cvx = crease_weights(m["dihedral"], crease)
        mats = [np.bincount(idx, weights=(m["length"] * w)[cut], minlength=K * K).reshape(K, K)
                for w in (np.ones_like(cav), cav, cvx)]
        memo[key] = RegionGraph(labels, area, mean, *[x + x.T for x in mats])
    return memo[key]


def mesh_score(mid: int, w: SweptWeights | None) -> float:
    m = MESHES[mid]
    memo = m.setdefault("memo", {})
    preds = {}
    for k in set(m["gk"]):
        if w is None:
            preds[k] = m["parts"][(k, 1.0)][0]
        else:
            g = graph(m, k, w.ratio, w.crease_angle, memo)
            new_id, _ = greedy_merge(g, k, w)
            preds[k] = new_id[g.labels]
    return float(np.mean([rand_error(preds[k], gt) for k, gt in zip(m["gk"], m["gts"])]))


def table(w) -> dict:
    by = {}
    for mid in MESHES:
        by.setdefault(category_of(mid), []).append(mesh_score(mid, w))
    return {c: float(np.mean(v)) for c, v in by.items()}


def _init(folder):
    global MESHES
    MESHES = load(Path(folder))


def overall(t, cats):
    return float(np.mean([t[c] for c in cats]))


def fmt(w: SweptWeights) -> str:
    d = SweptWeights.hand_set(crease_angle=math.pi)
    parts = [f"ratio {w.ratio:g}", f"sym {w.symmetry:g}", f"cav {w.concavity:g}"]
    for name in ("size", "part_size", "convexity", "cut"):
        if getattr(w, name):
            parts.append(f"{name} {getattr(w, name):g}")
    if w.crease_angle != d.crease_angle:
        parts.append(f"crease {math.degrees(w.crease_angle):.0f}°")
    return ", ".join(parts)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", default="/tmp/qcache")
    ap.add_argument("--out", default="/tmp/merge_terms_cv.md")
    ap.add_argument("--ratios", default="2,2.5,3,4")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    t0 = time.perf_counter()
    _init(a.cache)
    ids = sorted(MESHES)
    cats = sorted({category_of(i) for i in ids}, key=lambda c: min(i for i in ids if category_of(i) == c))
    ratios = tuple(float(r) for r in a.ratios.split(","))
    tables: dict = {}
    pool = Pool(a.workers, initializer=_init, initargs=(a.cache,))

    def run(grid):
        grid = [w for w in dict.fromkeys(grid) if w not in tables]
        for w, t in zip(grid, pool.map(table, grid)):
            tables[w] = t
        return min(tables, key=lambda w: (overall(tables[w], cats), repr(w)))

    paper = table(None)
    # the former default (ratio 2, symmetry and concavity only); at the smallest ratio swept
    # when 2 is not among them
    old = SweptWeights.hand_set(symmetry=1.0, concavity=16.0, size=0.0, ratio=2.0 if 2.0 in ratios else min(ratios),
                       part_size=0.0, convexity=0.0, cut=0.0, crease_angle=math.pi)

    def with_(w, **kw):
        d = dict(vars(w))
        d.update(kw)
        return SweptWeights(**d)
    base = old
    # stage 1: ratio x concavity weight (the former terms)
    best = run([with_(old, concavity=c, ratio=r) for r in ratios for c in (4.0, 8.0, 16.0, 32.0)] + [base])
    print("stage 1", fmt(best), overall(tables[best], cats), time.perf_counter() - t0, flush=True)
    # stage 2: crease angle x convexity
    best = run([with_(best, convexity=x, crease_angle=math.radians(ca))
                for x in (0.0, 2.0, 4.0, 8.0) for ca in (180, 90, 45)])
    print("stage 2", fmt(best), overall(tables[best], cats), time.perf_counter() - t0, flush=True)
    # stage 3: size priors x boundary share
    best = run([with_(best, concavity=c, part_size=ps, cut=cu) for c in (best.concavity / 2, best.concavity,
                best.concavity * 2) for ps in (0.0, 0.1, 0.3) for cu in (0.0, 0.5, 1.0)])
    print("stage 3", fmt(best), overall(tables[best], cats), time.perf_counter() - t0, flush=True)
    # stage 4: best at every ratio (for the time budget) with the other terms kept
    run([with_(best, ratio=r) for r in ratios] + [with_(best, symmetry=s) for s in (0.5, 2.0)])
    pool.close()

    folds = [[c for i, c in enumerate(cats) if i % N_FOLDS == f] for f in range(N_FOLDS)]
    grid = list(tables)
    rows, held = [], {}
    for f, test in enumerate(folds):
        train = [c for c in cats if c not in test]
        w = min(grid, key=lambda w: (overall(tables[w], train), repr(w)))
        rows.append((f, test, w, overall(tables[base], train), overall(tables[w], train),
                     overall(tables[base], test), overall(tables[w], test), overall(paper, test)))
        for c in test:
            held[c] = tables[w][c]
    chosen = min(grid, key=lambda w: (overall(tables[w], cats), repr(w)))
    L = ["# Part merging v2 (issue 12): more ratios and cost terms, cross-validated across categories", "",
         f"- cache: {a.cache}, {len(ids)} meshes "
         f"({', '.join(f'{c} {sum(category_of(i) == c for i in ids)}' for c in cats)})",
         "- protocol: by-segmentation 1-RI (faces counted), mesh = mean over its humans, category = mean over "
         "its meshes, overall = mean over categories; labels before the boundary refinement (isoline faces)",
         f"- {len(grid)} settings (coordinate search in 4 stages, see the script); folds: " +
         "; ".join(f"{f}: {', '.join(t)}" for f, t in enumerate(folds)),
         f"- old default = {fmt(base)}", "",
         "## Cross-validation (choice among all settings evaluated, on the other two folds)", "",
         "| fold | chosen on the other 10 | held-in old | held-in new | held-out paper | held-out old | held-out new |",
         "|---|---|---:|---:|---:|---:|---:|"]
    for f, test, w, bi, wi, bo, wo, po in rows:
        L.append(f"| {f} ({', '.join(test)}) | {fmt(w)} | {bi:.4f} | {wi:.4f} | {po:.4f} | {bo:.4f} | {wo:.4f} |")
    L += ["", f"CV estimate over all {len(cats)}: **{overall(held, cats):.4f}** (old default "
          f"{overall(tables[base], cats):.4f}, paper {overall(paper, cats):.4f}).", "",
          f"Best on all {len(cats)}: {fmt(chosen)} -> {overall(tables[chosen], cats):.4f}.", "",
          "## Per category", "", "| category | paper | old default | new, CV held-out | new, chosen on all |",
          "|---|---:|---:|---:|---:|"]
    for c in cats:
        L.append(f"| {c} | {paper[c]:.4f} | {tables[base][c]:.4f} | {held[c]:.4f} | {tables[chosen][c]:.4f} |")
    L.append(f"| **overall** | **{overall(paper, cats):.4f}** | **{overall(tables[base], cats):.4f}** | "
             f"**{overall(held, cats):.4f}** | **{overall(tables[chosen], cats):.4f}** |")
    L += ["", "## Ablation around the best on all (one change at a time)", "",
          "| setting | overall | " + " | ".join(cats) + " |", "|---|---:|" + "---:|" * len(cats)]
    L.append(f"| paper | {overall(paper, cats):.4f} | " + " | ".join(f"{paper[c]:.3f}" for c in cats) + " |")
    var = [("best", chosen), ("old default", base)]
    var += [(f"{n} = {v:g}", with_(chosen, **{n: v})) for n, v in
            (("convexity", 0.0), ("cut", 0.0), ("part_size", 0.0), ("symmetry", 0.0))
            if getattr(chosen, n) != v]
    if chosen.crease_angle != math.pi:
        var.append(("crease 180°", with_(chosen, crease_angle=math.pi)))
    var += [(f"ratio {r:g}", with_(chosen, ratio=r)) for r in ratios if r != chosen.ratio]
    for n, w in var:
        t = tables.get(w) or table(w)
        L.append(f"| {n} | {overall(t, cats):.4f} | " + " | ".join(f"{t[c]:.3f}" for c in cats) + " |")
    L += ["", "## Best 12 on all", "", "| setting | overall |", "|---|---:|"]
    L += [f"| {fmt(w)} | {overall(tables[w], cats):.4f} |"
          for w in sorted(grid, key=lambda w: overall(tables[w], cats))[:12]]
    Path(a.out).write_text("\n".join(L) + "\n")
    print("\n".join(L))
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
