"""Small parts merged first (not adopted: experiments/results/generality_not_adopted.md, "Small
parts first").

At a small k a sliver left as one of the k parts forces two true parts together (a tee at k = 2
comes back as its body and the floor of one socket). Here a pair whose smaller part holds less
than f / k of the area is merged before any other pair (the cheapest such pair first, by the
shipped cost), for each f given; the merge is redone on merge_cv.py's preparation of the
captures with the shipped weights (no refit: the rule is not fitted), merged labels scored by
group.

    PYTHONPATH=$PWD python3 experiments/generality/small_first_cv.py --prep /tmp/capture_prep --fractions 0.1,0.2,0.35
"""
from __future__ import annotations

import argparse
import sys
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "segmentation"))
import merge_cv as M  # noqa: E402
import merge_learned_cv as L  # noqa: E402

from torchakvf.options import MergeWeights  # noqa: E402


class SmallFirst(M.Cost):
    """The shipped cost, less a constant that puts every pair with a part under f / k first."""

    def __init__(self, base: M.Cost, fraction: float):
        super().__init__(base.w, base.b, base.gamma)
        self.fraction, self.k = fraction, 1

    def __call__(self, terms, state, rows):
        cost = super().__call__(terms, state, rows)
        share = state.area / state.total
        return np.where(np.minimum.outer(share[rows], share) < self.fraction / self.k, cost - 1e6, cost)


PACKAGE_GREEDY = L.greedy


def greedy(state, k, cost, record=None):
    if isinstance(cost, SmallFirst):
        cost.k = k
    return PACKAGE_GREEDY(state, k, cost, record)


# merged_errors (merge_learned_cv) calls the module's greedy
L.greedy = greedy


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--prep", required=True, help="merge_cv.py's preparation of the captures")
    ap.add_argument("--fractions", default="0.1,0.2,0.35")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    M.load_prep(Path(a.prep))
    keys = sorted(M.PREP)
    shipped = M.Cost.of(MergeWeights())
    results = {}
    with get_context("fork").Pool(2) as pool:
        results["shipped weights, merged"] = M.group_scores(keys, shipped, pool)
        for f in a.fractions.split(","):
            results[f"parts under {f} / k first, merged"] = M.group_scores(keys, SmallFirst(shipped, float(f)), pool)
    M.report(results, a.out)


if __name__ == "__main__":
    main()
