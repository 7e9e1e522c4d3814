"""k-means++ restarts of the merge method (issue 12's time budget): does the over-segmentation
into 3k, merged afterwards, need the 5 restarts of the paper mode?

Runs ``evaluate_psb`` (by-segmentation 1-RI, coarse 4000 faces, seed 0, one worker, everything
else default, i.e. method "merge") once per restart count on 4 meshes of each labelled
category (ids 20c+1..20c+4), one configuration after the other in this process, and reports
1-RI overall / per category / per cross-validation fold (category index mod 3 in the PSB order
of the 15 labelled categories) with the process CPU seconds of each run and of its segment
stage (``segment_rounds``, timed with time.process_time around each round).

The AKVFs do not depend on the restart count: with ``--share-akvf`` (default) the first run's
solves are kept and handed to the later runs (the same objects, so the same fields), which
then cost only their segment stage; the AKVF CPU seconds are those of the first run.

    TORCHAKVF_PSB=/work/shared/psb OMP_NUM_THREADS=1 PYTHONPATH=$PWD nice -n 5 \
        python experiments/segmentation/kmeans_restarts.py \
        --out /tmp/restarts --restarts 5,3,2 --json /tmp/kmeans_restarts.json
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from torchakvf.evaluate import harness as H
from torchakvf.evaluate import predict as PR
from torchakvf.evaluate import psb as P

#: the 15 labelled categories in PSB order (their 20-blocks: every c but 7, 12, 13, 17, 19)
LABELLED = ["Human", "Cup", "Glasses", "Airplane", "Ant", "Chair", "Octopus", "Teddy", "Hand",
            "Plier", "Fish", "Armadillo", "Bust", "Mech", "Vase"]
BLOCKS = [0, 1, 2, 3, 4, 5, 6, 8, 9, 10, 11, 14, 15, 16, 18]


class StageClock:
    """Process CPU seconds of the AKVF solves and of the segment rounds (wrapping predict's
    ``solve_akvfs`` and ``segment_rounds``); optionally keeps the solves for later runs."""

    def __init__(self, share_akvf: bool):
        self.share = share_akvf
        self.cache = {}
        self.akvf = self.segment = 0.0
        self._solve, self._rounds = PR.solve_akvfs, PR.segment_rounds
        PR.solve_akvfs, PR.segment_rounds = self.solve_akvfs, self.segment_rounds

    def solve_akvfs(self, mb, n, opts):
        key = (n, tuple((len(m.faces), float(m.vertices.sum())) for m in mb.meshes))
        if self.share and key in self.cache:
            return self.cache[key]
        t0 = time.process_time()
        out = self._solve(mb, n, opts)
        self.akvf += time.process_time() - t0
        if self.share:
            self.cache[key] = out
        return out

    def segment_rounds(self, *args, **kwargs):
        it = self._rounds(*args, **kwargs)
        while True:
            t0 = time.process_time()
            try:
                rnd = next(it)
            except StopIteration:
                self.segment += time.process_time() - t0
                return
            self.segment += time.process_time() - t0
            yield rnd


def folds_view(per_cat: dict, configs: list, base) -> list[str]:
    """Per fold (category index mod 3): mean 1-RI of each config; the config chosen on the
    other two folds (lowest mean) and whether it is no worse than ``base`` on this fold."""
    lines = ["| fold | categories | " + " | ".join(f"R={r}" for r in configs)
             + " | chosen on the other folds | held-out delta vs R=" + str(base) + " |",
             "|---|---|" + "---:|" * len(configs) + "---|---:|"]
    for f in range(3):
        cats = [c for i, c in enumerate(LABELLED) if i % 3 == f]
        rest = [c for i, c in enumerate(LABELLED) if i % 3 != f]
        mean = {r: sum(per_cat[r][c] for c in cats) / len(cats) for r in configs}
        other = {r: sum(per_cat[r][c] for c in rest) / len(rest) for r in configs}
        pick = min(configs, key=lambda r: (other[r], -r))
        lines.append(f"| {f} | {', '.join(cats)} | " + " | ".join(f"{mean[r]:.4f}" for r in configs)
                     + f" | R={pick} | {mean[pick] - mean[base]:+.4f} |")
    return lines


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/restarts")
    ap.add_argument("--restarts", default="5,3,2")
    ap.add_argument("--per-category", type=int, default=4)
    ap.add_argument("--no-share-akvf", action="store_true")
    ap.add_argument("--json", default="/tmp/kmeans_restarts.json")
    a = ap.parse_args()
    torch.set_num_threads(1)
    ids = [20 * c + i for c in BLOCKS for i in range(1, a.per_category + 1)]
    configs = [int(r) for r in a.restarts.split(",")]
    clock = StageClock(not a.no_share_akvf)
    res = {}
    for i, r in enumerate(configs):
        clock.akvf = clock.segment = 0.0
        t0, w0 = time.process_time(), time.perf_counter()
        s = H.evaluate_psb(P.default_psb_root(), Path(a.out) / f"{i}_R{r}", ids=ids, metrics="rand", workers=1,
                           plot=False, progress=False, coarse_faces=4000, kmeans_restarts=r)
        res[f"{i}_R{r}"] = {"overall": s.overall_categories["rand_index_error"],
                  "overall_meshes": s.overall_meshes["rand_index_error"] if hasattr(s, "overall_meshes") else None,
                  "per_category": {c: v["rand_index_error"] for c, v in s.per_category.items()},
                  "cpu_total": time.process_time() - t0, "cpu_akvf": clock.akvf, "cpu_segment": clock.segment,
                  "wall": time.perf_counter() - w0}
        print(r, json.dumps(res[f"{i}_R{r}"]), flush=True)
        Path(a.json).write_text(json.dumps({"ids": ids, "results": res}, indent=1))
    # a restart count run twice: the fold view shows its last run
    per_cat = {r: res[f"{i}_R{r}"]["per_category"] for i, r in enumerate(configs)}
    print("\n".join(folds_view(per_cat, list(dict.fromkeys(configs)), configs[0])))


if __name__ == "__main__":
    main()
