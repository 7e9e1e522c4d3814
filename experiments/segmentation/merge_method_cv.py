"""Sweep the part-merging parameters on the cached PSB subset and cross-validate them across
categories (issue 12). Reads experiments/segmentation/quality_cache.py's files; writes a markdown report.

Protocol: by-segmentation (each human segmentation is compared with the prediction at its own
segment count); a mesh's score is the mean over its humans, a category's the mean over its
cached meshes, "overall" the mean over categories. Cross-validation: the 15 labelled
categories in 3 folds of 5 (category c in fold c mod 3, in PSB order); for each fold the
parameters are chosen on the other 10 categories (held-in) and scored on the fold's 5
(held-out). Every category is held out once; the held-out table is the CV estimate.

    PYTHONPATH=$PWD python experiments/segmentation/merge_method_cv.py --cache /tmp/quality_cache \
        --out experiments/results/merge_method_cv.md
"""
from __future__ import annotations

import argparse
import itertools
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from torchakvf.evaluate.psb import category_of
from torchakvf.parts.merge import MergeWeights, RegionGraph, greedy_merge


@dataclass(frozen=True)
class SweptWeights(MergeWeights):
    """Merge weights with the over-segmentation ratio they merge: the candidates of these sweeps
    (and of merge_terms_cv, graph_cut, k_auto), which cache one over-segmentation per (k, ratio)
    and choose the weights and the ratio together. The package keeps the ratio in
    OverSegmentation; a candidate's weights are these fields without it."""

    ratio: float = 3.0

    def __new__(cls, *args, **changes):
        return object.__new__(cls)    # ratio is a field here, not a moved name


RATIOS = (1.5, 2.0, 3.0)
SYMMETRY = (0.0, 1.0)
CONCAVITY = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
SIZE = (0.0, 0.25, 0.5, 1.0, 2.0)
N_FOLDS = 3


def rand_error(a: np.ndarray, b: np.ndarray) -> float:
    """1 - RI (faces counted, unordered pairs), as torchakvf.evaluate.metrics.rand_index_error."""
    n = a.size   # labels 0..K-1 (empty labels are harmless: C(0, 2) = 0)
    nb = int(b.max()) + 1
    cell = np.bincount(a * nb + b).astype(np.float64)
    sa = np.bincount(a).astype(np.float64)
    sb = np.bincount(b).astype(np.float64)
    c2 = lambda x: (x * (x - 1) / 2).sum()
    return float((c2(sa) + c2(sb) - 2 * c2(cell)) / (n * (n - 1) / 2))


def load_cache(folder: Path) -> dict:
    meshes = {}
    for f in sorted(folder.glob("*.npz"), key=lambda p: int(p.stem)):
        z = np.load(f)
        gts = [z[f"gt{i}"].astype(np.int64) for i in range(int(z["n_gt"]))]
        combos = {}
        for k in z["ks"].tolist():
            for r in (1.0,) + RATIOS:
                key = f"k{k}_r{r:g}"
                combos[(k, r)] = RegionGraph(z[key + "_labels"].astype(np.int64), z[key + "_area"],
                                             z[key + "_mean"], z[key + "_length"], z[key + "_concave"])
        meshes[int(f.stem)] = dict(gts=gts, combos=combos, gk=[int(g.max()) + 1 for g in gts])
    return meshes


def mesh_score(m: dict, weights: MergeWeights | None) -> float:
    """Mean 1-RI over the mesh's humans; weights None = paper mode (k-means at k)."""
    preds = {}
    for k in set(m["gk"]):
        if weights is None:
            g = m["combos"][(k, 1.0)]
            preds[k] = g.labels
        else:
            g = m["combos"][(k, weights.ratio)]
            new_id, _ = greedy_merge(g, k, weights)
            preds[k] = new_id[g.labels]
    return float(np.mean([rand_error(preds[k], gt) for k, gt in zip(m["gk"], m["gts"])]))


def category_table(meshes: dict, weights) -> dict:
    by_cat = {}
    for mid, m in meshes.items():
        by_cat.setdefault(category_of(mid), []).append(mesh_score(m, weights))
    return {c: float(np.mean(v)) for c, v in by_cat.items()}


def overall(table: dict, cats) -> float:
    return float(np.mean([table[c] for c in cats]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--cache", default="/tmp/quality_cache")
    ap.add_argument("--out", default="/tmp/merge_method_cv.md")
    ap.add_argument("--ratios", default=",".join(f"{r:g}" for r in RATIOS),
                    help="over-segmentation ratios allowed in the choice (e.g. those within the time budget)")
    a = ap.parse_args()
    ratios = tuple(float(r) for r in a.ratios.split(","))
    t0 = time.perf_counter()
    meshes = load_cache(Path(a.cache))
    cats = sorted({category_of(i) for i in meshes}, key=lambda c: min(i for i in meshes if category_of(i) == c))
    paper = category_table(meshes, None)
    grid = [SweptWeights.hand_set(symmetry=s, concavity=c, size=z, ratio=r)
            for r, s, c, z in itertools.product(ratios, SYMMETRY, CONCAVITY, SIZE)
            if (s, c, z) != (0.0, 0.0, 0.0)]
    tables = {w: category_table(meshes, w) for w in grid}
    print(f"{len(grid)} settings swept in {time.perf_counter() - t0:.0f} s", flush=True)

    folds = [[c for i, c in enumerate(cats) if i % N_FOLDS == f] for f in range(N_FOLDS)]
    cv_rows, held_out = [], {}
    for f, test in enumerate(folds):
        train = [c for c in cats if c not in test]
        best = min(grid, key=lambda w: (overall(tables[w], train), repr(w)))
        cv_rows.append((f, test, best, overall(paper, train), overall(tables[best], train),
                        overall(paper, test), overall(tables[best], test)))
        for c in test:
            held_out[c] = tables[best][c]
    chosen = min(grid, key=lambda w: (overall(tables[w], cats), repr(w)))

    def fmt_w(w):
        return f"ratio {w.ratio:g}, w_sym {w.symmetry:g}, w_cav {w.concavity:g}, w_size {w.size:g}"

    lines = ["# Part merging (issue 12): parameters by cross-validation across categories", "",
             f"- cache: {a.cache}, {len(meshes)} meshes "
             f"({', '.join(f'{c} {sum(category_of(i) == c for i in meshes)}' for c in cats)})",
             "- protocol: by-segmentation, 1-RI faces counted; mesh = mean over humans, category = mean "
             "over its meshes, overall = mean over categories",
             f"- grid: ratio {ratios}, w_sym {SYMMETRY}, w_cav {CONCAVITY}, w_size {SIZE} ({len(grid)} settings)",
             f"- folds (category i in PSB order -> fold i mod {N_FOLDS}): " +
             "; ".join(f"{f}: {', '.join(t)}" for f, t in enumerate(folds)), "",
             "## Cross-validation", "",
             "| fold | chosen on the other 10 | held-in paper | held-in merge | held-out paper | held-out merge |",
             "|---|---|---:|---:|---:|---:|"]
    for f, test, w, pi, mi, po, mo in cv_rows:
        lines.append(f"| {f} ({', '.join(test)}) | {fmt_w(w)} | {pi:.4f} | {mi:.4f} | {po:.4f} | {mo:.4f} |")
    lines += ["", f"CV estimate over all {len(cats)} (each category scored with parameters chosen without it): "
              f"**{overall(held_out, cats):.4f}** vs paper {overall(paper, cats):.4f}.", "",
              f"Chosen on all {len(cats)} (the default): {fmt_w(chosen)} -> {overall(tables[chosen], cats):.4f}.", "",
              "## Per category", "",
              "| category | paper | merge, CV held-out | merge, chosen on all |", "|---|---:|---:|---:|"]
    for c in cats:
        lines.append(f"| {c} | {paper[c]:.4f} | {held_out[c]:.4f} | {tables[chosen][c]:.4f} |")
    lines.append(f"| **overall** | **{overall(paper, cats):.4f}** | **{overall(held_out, cats):.4f}** | "
                 f"**{overall(tables[chosen], cats):.4f}** |")
    # Ablation: each term off at the chosen setting (the others kept), and the ratio.
    lines += ["", "## Ablation (at the setting chosen on all; one change at a time)", "",
              "| setting | overall | " + " | ".join(cats) + " |", "|---|---:|" + "---:|" * len(cats)]
    variants = [("chosen", chosen),
                ("w_sym = 0", SweptWeights.hand_set(symmetry=0.0, concavity=chosen.concavity, size=chosen.size,
                                                    ratio=chosen.ratio)),
                ("w_cav = 0", SweptWeights.hand_set(symmetry=chosen.symmetry, concavity=0.0, size=chosen.size,
                                                    ratio=chosen.ratio)),
                ("w_size = 0", SweptWeights.hand_set(symmetry=chosen.symmetry, concavity=chosen.concavity, size=0.0,
                                                     ratio=chosen.ratio))]
    variants += [(f"ratio {r:g}", SweptWeights.hand_set(symmetry=chosen.symmetry, concavity=chosen.concavity,
                                                        size=chosen.size, ratio=r))
                 for r in RATIOS if r != chosen.ratio]   # all cached ratios, also those not allowed
    lines.append(f"| paper (no merging) | {overall(paper, cats):.4f} | "
                 + " | ".join(f"{paper[c]:.3f}" for c in cats) + " |")
    for name, w in variants:
        t = tables.get(w) or category_table(meshes, w)
        lines.append(f"| {name} | {overall(t, cats):.4f} | " + " | ".join(f"{t[c]:.3f}" for c in cats) + " |")
    top = sorted(grid, key=lambda w: overall(tables[w], cats))[:10]
    lines += ["", f"## Best 10 settings on all {len(cats)}", "", "| setting | overall |", "|---|---:|"]
    lines += [f"| {fmt_w(w)} | {overall(tables[w], cats):.4f} |" for w in top]
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
