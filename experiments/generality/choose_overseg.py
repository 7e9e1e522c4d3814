"""Choose the over-segmentation variant leave-one-group-out, from captures of the default
pipeline (capture.py) under each variant.

For each group (a PSB category or a corpus family) the variant is chosen by the mean error of
the *other* groups (PSB categories and corpus families weigh alike), and the group is reported
under the variant so chosen: the held-out score of the choice. Only shapes captured under every
variant are compared (paired). Error: 1 - Rand index of the default's final labels at each human
segmentation's part count, averaged over the segmentations of a shape, then over a group's shapes.

    PYTHONPATH=$PWD python3 experiments/generality/choose_overseg.py \\
        base=/tmp/cap_base,/tmp/ccap_base_r4 concave60=/tmp/cap_concave60,/tmp/ccap_concave60 \\
        --out experiments/results/generality_overseg.md
"""
from __future__ import annotations

import argparse
import pickle
from pathlib import Path

import numpy as np

from torchakvf.evaluate.metrics import rand_index_error


def shape_errors(folders: list[str]) -> dict:
    """{key: (group, is PSB, error)} of every capture in ``folders``."""
    out = {}
    for folder in folders:
        for f in Path(folder).glob("*.pkl"):
            with open(f, "rb") as fh:
                r = pickle.load(fh)
            errs = [rand_index_error(np.maximum(r["final"][int(g.max()) + 1], 0).astype(np.int64), g.astype(np.int64))
                    for g in r["gts"]]
            out[r["key"]] = (r["group"], r["key"].startswith("psb:"), float(np.mean(errs)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("variants", nargs="+", help="name=folder[,folder...] of each variant's captures")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    names, errors = [], []
    for spec in a.variants:
        name, folders = spec.split("=", 1)
        names.append(name)
        errors.append(shape_errors(folders.split(",")))
    common = sorted(set.intersection(*(set(e) for e in errors)))
    groups = sorted({errors[0][k][0] for k in common}, key=lambda g: (not errors[0][next(
        k for k in common if errors[0][k][0] == g)][1], g))
    table = {g: np.array([[np.mean([e[k][2] for k in common if e[k][0] == g]) for e in errors]])[0]
             for g in groups}
    psb = {g: errors[0][next(k for k in common if errors[0][k][0] == g)][1] for g in groups}
    count = {g: sum(errors[0][k][0] == g for k in common) for g in groups}
    lines = [f"Paired shapes: {len(common)} ({sum(count[g] for g in groups if psb[g])} PSB, "
             f"{sum(count[g] for g in groups if not psb[g])} procedural corpus), {len(groups)} groups.", "",
             "| group | set | n | " + " | ".join(names) + " | chosen without it | held-out error |",
             "|---|---|---:|" + "---:|" * len(names) + "---|---:|"]
    held = {}
    for g in groups:
        others = np.mean([table[h] for h in groups if h != g], axis=0)
        pick = int(np.argmin(others))
        held[g] = table[g][pick]
        lines.append(f"| {g} | {'PSB' if psb[g] else 'corpus'} | {count[g]} | "
                     + " | ".join(f"{x:.4f}" for x in table[g]) + f" | {names[pick]} | {held[g]:.4f} |")
    for label, sel in (("PSB categories", [g for g in groups if psb[g]]),
                       ("corpus families", [g for g in groups if not psb[g]]), ("all groups", groups)):
        if not sel:
            continue
        means = np.mean([table[g] for g in sel], axis=0)
        lines.append(f"| **mean, {label}** | | {sum(count[g] for g in sel)} | "
                     + " | ".join(f"{x:.4f}" for x in means) + f" | | {np.mean([held[g] for g in sel]):.4f} |")
    text = "\n".join(lines)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
