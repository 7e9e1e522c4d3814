"""Segment every shape of the procedural corpus at its true part count and score it (1 - Rand
index against its part labels), as ``torchakvf segment shape.off -k K`` does with its defaults
(decimated to ``--coarse-faces`` faces, seed 0), under named settings.

    PYTHONPATH=$PWD nice python3 experiments/generality/corpus_eval.py --corpus /tmp/corpus \\
        --settings default,hand-set,paper --out /tmp/corpus_eval.csv --workers 2

Prints a table per family (mean over its shapes) and writes one CSV row per (shape, setting).
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from items import corpus_items, read_truth  # noqa: E402

#: The merge weights fitted on the 15 labelled PSB categories alone, without the lines of sight
#: (torchakvf/parts/merge_weights.json at a724fd4): setting "psb-fit", the baseline the corpus's
#: share in the fit and the sight terms are measured against.
PSB_FIT = dict(symmetry=4.099, concavity=28.69, convexity=-0.206, cut=-0.4207, part_size=0.7441, size_ratio=0.3394,
               short_cut=-0.2115, thickness=1.718, thin=-0.1241, centricity=-0.1763, sight=0.0, sight_excess=0.0,
               size=0.0, intercept=3.038, rand_gamma=0.5)


def setting_options(name: str):
    """SegmentOptions overrides of a named setting: "default", "hand-set" (the hand-set merge
    weights), "psb-fit" (:data:`PSB_FIT`), "paper" (the paper's method), or a JSON object of
    MergeWeights and OverSegmentation changes (each field to its own class; the sheet rule's
    fields, ``sheet_*``, go to the second merge's weights as well: ``{"sheet_flatness": null}``
    is the rule off)."""
    from torchakvf.options import OVERSEG_FIELDS, ConcaveChoice, MergeWeights, OverSegmentation

    if name == "default":
        return {}
    if name == "hand-set":
        return dict(merge=MergeWeights.hand_set())
    if name == "psb-fit":
        return dict(merge=MergeWeights(**PSB_FIT))
    if name == "paper":
        return dict(method="paper")
    changes = json.loads(name)
    over = {k: v for k, v in changes.items() if k in OVERSEG_FIELDS}
    weights = {k: v for k, v in changes.items() if k not in OVERSEG_FIELDS}
    out = dict(merge=MergeWeights(**weights), **({"overseg": OverSegmentation(**over)} if over else {}))
    sheet = {k: v for k, v in changes.items() if k.startswith("sheet_")}
    if sheet:
        # the sheet rule is both merges' (the second merge's hand-set cost takes it too)
        out["merge_choice"] = ConcaveChoice(weights=MergeWeights.hand_set(**sheet))
    return out


def score_item(args):
    item, settings, coarse_faces = args
    import torch

    torch.set_num_threads(1)
    import torchakvf as ta
    from torchakvf.evaluate.metrics import rand_index_error

    truth = read_truth(item.truths[0])
    k = int(truth.max()) + 1
    mesh = ta.load_mesh(item.mesh_path)
    rows = []
    for name in settings:
        t0 = time.perf_counter()
        try:
            seg = ta.segment([mesh], k=k, seed=0, coarse_faces=coarse_faces or None, **setting_options(name))
            err = rand_index_error(seg[0].labels, truth)
        except Exception as exc:                     # noqa: BLE001 - recorded, the run goes on
            print(f"{item.key} {name} FAILED {type(exc).__name__}: {exc}", flush=True)
            err = float("nan")
        rows.append(dict(key=item.key, family=item.group, kind=item.kind, k=k, setting=name, error=err,
                         seconds=time.perf_counter() - t0))
    return rows


def family_table(rows, settings) -> str:
    fams = sorted({(r["kind"], r["family"]) for r in rows})
    by = {}
    for r in rows:
        by.setdefault((r["family"], r["setting"]), []).append(r["error"])
    lines = ["| family | kind | shapes | " + " | ".join(settings) + " |", "|---|---|---:|" + "---:|" * len(settings)]
    for kind, fam in fams:
        n = len(by[(fam, settings[0])])
        cells = " | ".join(f"{np.nanmean(by[(fam, s)]):.3f}" for s in settings)
        lines.append(f"| {fam} | {kind} | {n} | {cells} |")
    for kind in ("organic", "mechanical"):
        vals = {s: [np.nanmean(by[(f, s)]) for k_, f in fams if k_ == kind] for s in settings}
        if vals[settings[0]]:
            cells = " | ".join(f"{np.mean(vals[s]):.3f}" for s in settings)
            lines.append(f"| **{kind} families** | | | {cells} |")
    allv = {s: [np.nanmean(by[(f, s)]) for _, f in fams] for s in settings}
    lines.append("| **all families** | | | " + " | ".join(f"{np.mean(allv[s]):.3f}" for s in settings) + " |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpus", required=True)
    ap.add_argument("--settings", default="default,hand-set,paper", help="';'-separated if any is JSON")
    ap.add_argument("--coarse-faces", type=int, default=4000)
    ap.add_argument("--families", default=None)
    ap.add_argument("--per-family", type=int, default=None)
    ap.add_argument("--skip-per-family", type=int, default=0,
                    help="leave out each family's first N shapes (those a fit was made on)")
    ap.add_argument("--out", default=None)
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args()
    settings = a.settings.split(";") if ";" in a.settings else a.settings.split(",")
    todo = corpus_items(a.corpus)
    if a.families:
        todo = [i for i in todo if i.group in a.families.split(",")]
    if a.skip_per_family:
        skipped: dict = {}
        todo = [i for i in todo
                if skipped.setdefault(i.group, []).append(i) or len(skipped[i.group]) > a.skip_per_family]
    if a.per_family:
        seen: dict = {}
        todo = [i for i in todo if seen.setdefault(i.group, []).append(i) or len(seen[i.group]) <= a.per_family]
    os.environ.update({v: "1" for v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")})
    jobs = [(i, settings, a.coarse_faces) for i in todo]
    rows = []
    with get_context("fork").Pool(a.workers, maxtasksperchild=20) as pool:
        for r in pool.imap_unordered(score_item, jobs):
            rows += r
    rows.sort(key=lambda r: (r["key"], settings.index(r["setting"])))
    if a.out:
        with open(a.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    print(family_table(rows, settings))


if __name__ == "__main__":
    main()
