"""Cross-validation report of experiments/merge_weights_cv.py's scores (issue 12).

Candidates: every merge configuration swept (or those whose name contains --only); per fold
(category index mod 3) the one best on the other 10 categories, scored on the fold's 5; the
"old default" is Config() (today's defaults), "paper" the paper mode.

    PYTHONPATH=$PWD python experiments/merge_weights_cv_report.py --scores /tmp/qv3_sweep.pkl --out /tmp/merge_weights_cv.md
"""
from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from merge_weights_cv import CATS, FOLDS, Config, cross_validate, overall, per_category  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scores", default="/tmp/qv3_sweep.pkl")
    ap.add_argument("--out", default=None)
    ap.add_argument("--title", default="v3 sweep")
    ap.add_argument("--top", type=int, default=15)
    a = ap.parse_args()
    res = pickle.load(open(a.scores, "rb"))
    common = set.intersection(*[set(v) for v in res.values()])
    tables = {c: per_category({m: s for m, s in v.items() if m in common}) for c, v in res.items()}
    paper, old = Config(merge=None), Config()
    cands = [c for c in tables if c.merge is not None]
    rows, held = cross_validate(tables, cands)
    n_cat = {c: sum(1 for m in common if __import__("torchakvf.evaluate.psb", fromlist=["x"]).category_of(m) == c) for c in CATS}
    L = [f"# {a.title} (issue 12)", "",
         f"- {len(common)} meshes ({', '.join(f'{c} {n_cat[c]}' for c in CATS)}); coarse 4000 faces, n = 36 AKVFs as "
         "`torchakvf eval`; by-segmentation 1-RI (faces), mesh = mean over its humans, category = mean over its "
         "meshes, overall = mean over categories", f"- {len(cands)} merge configurations; folds (category index mod 3): "
         + "; ".join(f"{f}: {', '.join(t)}" for f, t in enumerate(FOLDS)),
         "- old = the v2 defaults (n 2k, sym 1, cav 32, cvx 4, cut 0.5, graph cut λ 10 β 10 band 6 crease 45°); "
         "old, no cut = the same without the graph cut (the like-for-like baseline of candidates marked 'no cut')", "",
         "## Cross-validation", "",
         "| fold (held out) | chosen on the other 10 | held-out paper | held-out old | held-out old, no cut | held-out chosen | all 15: chosen |",
         "|---|---|---:|---:|---:|---:|---:|"]
    nocut = Config(graphcut=None)
    oc = (lambda t: f"{overall(tables[nocut], t):.4f}") if nocut in tables else (lambda t: "-")
    for f, w in rows:
        t = FOLDS[f]
        L.append(f"| {f} ({', '.join(t)}) | {w.name()} | {overall(tables[paper], t):.4f} | {overall(tables[old], t):.4f} | {oc(t)} | "
                 f"{overall(tables[w], t):.4f} | {overall(tables[w], CATS):.4f} |")
    L += ["", f"CV estimate over the 15 (each category scored by the choice made without it): **{overall(held, CATS):.4f}** "
          f"(old default {overall(tables[old], CATS):.4f}, old without the cut {oc(CATS)}, paper {overall(tables[paper], CATS):.4f}).", "",
          f"## Best {a.top} on all 15", "", "| setting | overall | " + " | ".join(CATS) + " |", "|---|---:|" + "---:|" * len(CATS)]
    show = sorted(cands, key=lambda c: overall(tables[c], CATS))[:a.top]
    for c in [paper, old] + ([nocut] if nocut in tables else []) + [c for c in show if c not in (old, nocut)]:
        t = tables[c]
        L.append(f"| {c.name()} | {overall(t, CATS):.4f} | " + " | ".join(f"{t[x]:.3f}" for x in CATS) + " |")
    text = "\n".join(L) + "\n"
    if a.out:
        Path(a.out).write_text(text)
    print(text)


if __name__ == "__main__":
    main()
