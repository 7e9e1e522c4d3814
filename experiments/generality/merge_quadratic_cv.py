"""The merge's logistic model with the products of its terms (a quadratic log-odds), held out by
group, against the linear one (not adopted: experiments/results/generality_not_adopted.md).

    PYTHONPATH=$PWD python3 experiments/generality/merge_quadratic_cv.py --prep /tmp/prep_fin
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
from merge_learned_cv import fit_logistic  # noqa: E402

from torchakvf.options import MergeWeights  # noqa: E402

UPPER = np.triu_indices(M.T)


def quadratic(terms: np.ndarray) -> np.ndarray:
    """[..., T + T (T + 1) / 2] the terms and their products (each pair once, squares too)."""
    products = (terms[..., :, None] * terms[..., None, :])[..., UPPER[0], UPPER[1]]
    return np.concatenate([terms, products], axis=-1)


class QuadraticCost(M.Cost):
    def __call__(self, terms, state, rows):
        s = quadratic(terms) @ self.w
        a = state.area / state.total
        return np.outer(a[rows], a) ** self.gamma * np.tanh(0.5 * (s - self.b))


def fitted(train: list, policy, pool, share: float, quad: bool, l2: float) -> M.Cost:
    X, y, wt = M.training_rows(train, policy, pool, share)
    if quad:
        w, b = fit_logistic(quadratic(X), y, wt, l2=l2)
        return QuadraticCost(w, b, 0.5)
    w, b = fit_logistic(X, y, wt, l2=l2)
    return M.Cost(w, b, 0.5)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--prep", required=True, help="merge_cv.py's preparation folder")
    ap.add_argument("--l2", default="0.001", help="comma-separated ridge weights of the quadratic fit")
    ap.add_argument("--corpus-share", type=float, default=0.5)
    a = ap.parse_args()
    M.load_prep(Path(a.prep))
    policy = M.Cost.of(MergeWeights.hand_set())
    groups = sorted({d["group"] for d in M.PREP.values()})
    results = {}
    with get_context("fork").Pool(2) as pool:
        for quad, l2 in [(False, 1e-3)] + [(True, float(x)) for x in a.l2.split(",")]:
            scores = {}
            for g in groups:
                train = [m for m, d in M.PREP.items() if d["group"] != g]
                test = [m for m, d in M.PREP.items() if d["group"] == g]
                scores[g] = M.group_scores(test, fitted(train, policy, pool, a.corpus_share, quad, l2), pool)[g]
            results[f"{'quadratic' if quad else 'linear'}, l2 {l2:g} (held out)"] = scores
            print(M.table(results), flush=True)


if __name__ == "__main__":
    main()
