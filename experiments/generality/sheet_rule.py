"""The sheet rule (``MergeWeights.sheet_flatness``): where the merge leaves a flat part among the k
parts, the pieces are merged again with the pairs holding one first.

Runs one setting of the rule on the PSB (``torchakvf eval``'s defaults, the whole benchmark) or
on a procedural corpus (``corpus_eval.py``'s defaults: 4,000 faces, seed 0, the true k), and
compares runs: per PSB category and per corpus family, and the choice's objective, the mean
over groups (PSB categories and corpus families, each group's mean 1-RI).

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python experiments/generality/sheet_rule.py \\
        --psb PSB --out /tmp/sheet/psb_0.9 --flatness 0.9
    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python experiments/generality/sheet_rule.py \\
        --corpus /tmp/corpus_s0 --out /tmp/sheet/s0_0.9.csv --flatness 0.9
    python experiments/generality/sheet_rule.py --compare off=/tmp/sheet/psb_off/scores.csv \\
        0.9=/tmp/sheet/psb_0.9/scores.csv

``--flatness off`` is the rule off (both merges). A PSB run's scores are its ``scores.csv``; a
corpus run's CSV is ``corpus_eval.py``'s. ``--compare`` takes NAME=FILE pairs, all PSB or all
corpus, the first the reference.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import pandas as pd

HERE = Path(__file__).resolve().parent


def rule(flatness: str) -> dict:
    """The MergeWeights changes of one setting (both merges take them)."""
    return {"sheet_flatness": None if flatness == "off" else float(flatness)}


def run_psb(psb: str, out: str, changes: dict, workers: int) -> None:
    from torchakvf.evaluate.harness import evaluate_psb
    from torchakvf.options import ConcaveChoice, MergeWeights

    evaluate_psb(psb, out, merge=MergeWeights(**changes),
                 merge_choice=ConcaveChoice(weights=MergeWeights.hand_set(**changes)), workers=workers)


def run_corpus(corpus: str, out: str, changes: dict, workers: int) -> None:
    import json

    setting = json.dumps(changes)
    subprocess.run([sys.executable, str(HERE / "corpus_eval.py"), "--corpus", corpus, "--settings", setting,
                    "--workers", str(workers), "--out", out], check=True)


def compare(pairs: list[str]) -> str:
    """Per-group means of each run side by side, the mean over groups, and how many items
    changed against the first run."""
    runs = {}
    for pair in pairs:
        name, path = pair.split("=", 1)
        d = pd.read_csv(path)
        if "category" in d:                                     # a PSB eval's scores.csv
            d = d[d.status == "ok"].rename(columns={"category": "group", "rand_index_error": "error"})
            d["item"] = d["id"]
        else:                                                   # corpus_eval.py's rows
            d = d.rename(columns={"family": "group"})
            d["item"] = d["key"]
        runs[name] = d.set_index("item")
    names = list(runs)
    table = pd.DataFrame({n: runs[n].groupby("group").error.mean() for n in names})
    lines = ["| group | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for g, row in table.iterrows():
        lines.append(f"| {g} | " + " | ".join(f"{v:.4f}" for v in row) + " |")
    lines.append("| **mean over groups** | " + " | ".join(f"**{table[n].mean():.4f}**" for n in names) + " |")
    ref = runs[names[0]].error
    for n in names[1:]:
        diff = (runs[n].error - ref).dropna()
        lines.append(f"\n{n} against {names[0]}: {int((diff.abs() > 1e-12).sum())} of {len(diff)} items changed, "
                     f"{int((diff < -1e-12).sum())} better, {int((diff > 1e-12).sum())} worse")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--psb", help="run the PSB eval with this PSB folder")
    ap.add_argument("--corpus", help="run corpus_eval.py on this corpus")
    ap.add_argument("--out", help="the eval's folder (--psb) or the CSV (--corpus)")
    ap.add_argument("--flatness", default="0.9", help="sheet_flatness, or off")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--compare", nargs="+", metavar="NAME=FILE")
    a = ap.parse_args()
    if a.compare:
        print(compare(a.compare))
    elif a.psb:
        run_psb(a.psb, a.out, rule(a.flatness), a.workers)
    elif a.corpus:
        run_corpus(a.corpus, a.out, rule(a.flatness), a.workers)
    else:
        ap.error("give --psb, --corpus or --compare")


if __name__ == "__main__":
    main()
