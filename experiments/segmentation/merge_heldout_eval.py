"""The default segmentation scored held out, end to end: each labelled PSB category segmented by
``torchakvf eval``'s pipeline (merge, then the graph cut) with the learned merge weights fitted
without it, beside the shipped weights' scores (fitted on all) read from a
default ``torchakvf eval`` run's scores.csv (the same pipeline and meshes; scores are
deterministic).

The per-fold weights are data in ``results/merge_weights_folds.json`` (where they come from is
its "source"; its folds of procedural families are not PSB categories and are skipped). Run::

    PYTHONPATH=$PWD python3 -m torchakvf.cli eval --out /tmp/eval_default --quiet
    PYTHONPATH=$PWD nice python3 experiments/segmentation/merge_heldout_eval.py --out /tmp/heldout \
        --default /tmp/eval_default/scores.csv --workers 2
"""
from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

FOLDS = Path(__file__).resolve().parents[1] / "results" / "merge_weights_folds.json"


def main() -> None:
    from torchakvf.evaluate.harness import evaluate_psb
    from torchakvf.evaluate.psb import default_psb_root
    from torchakvf.evaluate.settings import EVAL_SEGMENT_DEFAULTS
    from torchakvf.options import MergeWeights, SegmentOptions

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--psb", default=default_psb_root())
    ap.add_argument("--out", required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--default", required=True, help="scores.csv of a default torchakvf eval run")
    a = ap.parse_args()
    folds = json.loads(FOLDS.read_text())["folds"]
    shipped = {}
    with open(a.default) as fh:
        for r in csv.DictReader(fh):
            if r["status"] == "ok" and r["rand_index_error"]:
                shipped.setdefault(r["category"], []).append(float(r["rand_index_error"]))
    rows = {}
    for cat, weights in sorted(folds.items()):
        if cat not in shipped:
            continue
        opts = SegmentOptions(**EVAL_SEGMENT_DEFAULTS, merge=MergeWeights(**weights))
        s = evaluate_psb(a.psb, Path(a.out) / cat, opts, categories=cat, workers=a.workers, plot=False,
                         metrics="rand", progress=False)
        rows[cat] = {"held out": s.per_category[cat]["rand_index_error"],
                     "shipped": sum(shipped[cat]) / len(shipped[cat]), "meshes": len(shipped[cat])}
        print(f"{cat:10s} held out {rows[cat]['held out']:.4f}  shipped {rows[cat]['shipped']:.4f}", flush=True)
    held = sum(r["held out"] for r in rows.values()) / len(rows)
    seen = sum(r["shipped"] for r in rows.values()) / len(rows)
    print(f"overall (mean of categories): held out {held:.4f}, shipped {seen:.4f}")
    (Path(a.out) / "heldout_eval.json").write_text(json.dumps({"rows": rows, "held_out": held, "shipped": seen},
                                                             indent=1))


if __name__ == "__main__":
    main()
