"""Per-category 1-RI of several `torchakvf eval` output folders on the meshes they all scored.

    python benchmarks/quality_compare.py old=/tmp/quality_eval_old new=/tmp/quality_eval_new2
"""
from __future__ import annotations

import csv
import sys

import numpy as np


def main():
    runs = dict(a.split("=", 1) for a in sys.argv[1:])
    scores = {}
    for name, folder in runs.items():
        rows = list(csv.DictReader(open(f"{folder}/scores.csv")))
        scores[name] = {int(r["id"]): (r["category"], float(r["rand_index_error"])) for r in rows
                        if r["rand_index_error"] not in ("", "nan")}
    common = sorted(set.intersection(*[set(s) for s in scores.values()]))
    first = next(iter(scores.values()))
    cats = list(dict.fromkeys(first[i][0] for i in common))
    print(f"{len(common)} meshes scored by every run: {','.join(map(str, common))}\n")
    print("| category | meshes | " + " | ".join(runs) + " |")
    print("|---|---:|" + "---:|" * len(runs))
    for c in cats:
        ids = [i for i in common if first[i][0] == c]
        print(f"| {c} | {len(ids)} | " + " | ".join(f"{np.mean([scores[n][i][1] for i in ids]):.4f}" for n in runs) + " |")
    print("| **overall (meshes)** | " + f"{len(common)} | " + " | ".join(
        f"**{np.mean([scores[n][i][1] for i in common]):.4f}**" for n in runs) + " |")
    print("| **overall (categories)** | | " + " | ".join(
        f"**{np.mean([np.mean([scores[n][i][1] for i in common if first[i][0] == c]) for c in cats]):.4f}**"
        for n in runs) + " |")


if __name__ == "__main__":
    main()
