"""Train the merge decision's weights on the 15 labelled PSB categories (the package's defaults).

The logistic regression of experiments/segmentation/merge_learned_cv.py ("the two adjacent parts lie in one
human segment", soft target per human, on the states the default merge passes through, rows
weighted by their Rand-index stake), fitted on every labelled mesh, and printed as the
:class:`~torchakvf.options.MergeWeights` fields it sets (the cost weights are -beta; the
intercept is the log-odds of one part where the weighted sum is 0; ``rand_gamma`` is the
exponent chosen by leave-one-category-out, see experiments/results/merge_learned_cv.md).
Its reported figures come from merge_learned_cv.py, which fits the same model once per held-out
category on the other 14.

    PYTHONPATH=$PWD nice python3 experiments/segmentation/merge_capture.py --out /tmp/merge_capture --workers 2
    PYTHONPATH=$PWD nice python3 experiments/segmentation/train_merge.py --capture /tmp/merge_capture \
        --prep /tmp/merge_prep --gamma 0.5 --out experiments/results/merge_weights.json
"""
from __future__ import annotations

import argparse
import json
from multiprocessing import get_context
from pathlib import Path

try:
    import merge_learned_cv as cv
except ImportError:
    from experiments import merge_learned_cv as cv

from torchakvf.parts.merge import FIELD_OF_TERM
from torchakvf.parts.merge_terms import TERM_NAMES


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True)
    ap.add_argument("--prep", required=True)
    ap.add_argument("--gamma", type=float, default=0.5)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    prep = Path(a.prep)
    prep.mkdir(parents=True, exist_ok=True)
    mids = sorted(int(p.stem) for p in Path(a.capture).glob("*.pkl"))
    with get_context("fork").Pool(a.workers) as pool:
        for _ in pool.imap_unordered(cv.prepare, [(a.capture, str(prep), m) for m in mids]):
            pass
    cv.load_prep(prep)
    with get_context("fork").Pool(a.workers) as pool:
        w, b0 = cv.learned_weights(sorted(cv.PREP), cv.default_vector(), pool)
    fields = {FIELD_OF_TERM[name]: float(f"{x:.4g}") for name, x in zip(TERM_NAMES, w)}
    fields.update(size=0.0, intercept=float(f"{b0:.4g}"), rand_gamma=a.gamma)
    text = json.dumps(dict(trained_on=f"{len(cv.PREP)} meshes of {len({d['category'] for d in cv.PREP.values()})}"
                           " labelled PSB categories", merge_weights=fields), indent=1)
    print(text)
    print("MergeWeights(" + ", ".join(f"{k}={v!r}" for k, v in fields.items()) + ")")
    if a.out:
        Path(a.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
