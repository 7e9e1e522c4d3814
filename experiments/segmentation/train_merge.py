"""Train the merge decision's weights on the 15 labelled PSB categories (the package's defaults).

The logistic regression of experiments/segmentation/merge_learned_cv.py ("the two adjacent parts lie in one
human segment", soft target per human, on the states the default merge passes through, rows
weighted by their Rand-index stake), fitted on every labelled mesh, and written as the package's
learned-weights file, torchakvf/parts/merge_weights.json (:func:`weights_record`; the
:class:`~torchakvf.options.MergeWeights` defaults are read from it): the cost weights are -beta,
the intercept is the log-odds of one part where the weighted sum is 0, ``rand_gamma`` is the
exponent chosen by leave-one-category-out (see experiments/results/merge_learned_cv.md).
Its reported figures come from merge_learned_cv.py, which fits the same model once per held-out
category on the other 14. The package file is the one copy: rewriting it changes the defaults
(tests/test_merge_options.py checks that it is in this script's format and that MergeWeights()
reads it).

    PYTHONPATH=$PWD nice python3 experiments/segmentation/merge_capture.py --out /tmp/merge_capture --workers 2
    PYTHONPATH=$PWD nice python3 experiments/segmentation/train_merge.py --capture /tmp/merge_capture \
        --prep /tmp/merge_prep --gamma 0.5 --out torchakvf/parts/merge_weights.json
"""
from __future__ import annotations

import argparse
import json
from multiprocessing import get_context
from pathlib import Path

from torchakvf.options import merge_weights_record
from torchakvf.parts.merge import FIELD_OF_TERM
from torchakvf.parts.merge_terms import TERM_NAMES

#: The package's learned-weights file, which this script writes.
PACKAGE_FILE = Path(__file__).resolve().parents[2] / "torchakvf" / "parts" / "merge_weights.json"


def weights_record(w, b0: float, gamma: float, n_meshes: int, n_categories: int) -> dict:
    """The learned-weights file's content from a fit: w [T] the cost weights of
    :data:`~torchakvf.parts.merge_terms.TERM_NAMES` (-beta), b0 the intercept, gamma the Rand
    exponent; 4 significant digits each (the fit's noise across folds is larger)."""
    fields = {FIELD_OF_TERM[name]: float(f"{x:.4g}") for name, x in zip(TERM_NAMES, w)}
    fields.update(size=0.0, intercept=float(f"{b0:.4g}"), rand_gamma=float(gamma))
    return merge_weights_record(fields, f"{n_meshes} meshes of {n_categories} labelled PSB categories")


def write_weights(record: dict, path) -> str:
    """Writes ``record`` (:func:`weights_record`) as the package file's JSON; returns the text."""
    text = json.dumps(record, indent=1)
    Path(path).write_text(text + "\n")
    return text


def main():
    try:
        import merge_learned_cv as cv
    except ImportError:
        from experiments.segmentation import merge_learned_cv as cv
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True)
    ap.add_argument("--prep", required=True)
    ap.add_argument("--gamma", type=float, default=0.5)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(PACKAGE_FILE))
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
    record = weights_record(w, b0, a.gamma, len(cv.PREP), len({d["category"] for d in cv.PREP.values()}))
    print(write_weights(record, a.out))


if __name__ == "__main__":
    main()
