"""Train the merge decision's weights on the labelled PSB categories and the procedural corpus
(the package's defaults).

The logistic regression of experiments/generality/merge_cv.py ("the two adjacent parts lie in one
true part", soft target per truth, on the states the hand-set merge passes through, rows weighted
by their Rand-index stake, every shape weighing alike within its data set and the corpus weighing
``--corpus-share`` of the fit), fitted on every captured shape, and written as the package's
learned-weights file, torchakvf/parts/merge_weights.json (:func:`weights_record`; the
:class:`~torchakvf.options.MergeWeights` defaults are read from it): the cost weights are -beta,
the intercept is the log-odds of one part where the weighted sum is 0, ``rand_gamma`` the Rand
exponent. Its reported figures come from merge_cv.py, which fits the same model once per held-out
PSB category or corpus family on the other groups (experiments/results/generality_sight.md). The
package file is the one copy: rewriting it changes the defaults (tests/test_merge_options.py
checks that it is in this script's format and that MergeWeights() reads it).

    python datasets_scripts/make_parts_corpus.py --out /tmp/corpus --per-family 30 --seed 0
    PYTHONPATH=$PWD nice python3 experiments/generality/capture.py --variant concave60 \\
        --corpus /tmp/corpus --per-family 10 --out /tmp/capture --workers 2   # the PSB's 300, 150 shapes
    PYTHONPATH=$PWD nice python3 experiments/segmentation/train_merge.py --capture /tmp/capture \\
        --prep /tmp/capture_prep --corpus-share 0.5 --out torchakvf/parts/merge_weights.json
"""
from __future__ import annotations

import argparse
import json
import sys
from multiprocessing import get_context
from pathlib import Path

from torchakvf.options import merge_weights_record
from torchakvf.parts.merge import FIELD_OF_TERM
from torchakvf.parts.merge_terms import TERM_NAMES

#: The package's learned-weights file, which this script writes.
PACKAGE_FILE = Path(__file__).resolve().parents[2] / "torchakvf" / "parts" / "merge_weights.json"


def trained_on(n_psb: int, n_categories: int, n_corpus: int, n_families: int, corpus_share: float) -> str:
    """The file's line on what it was fitted on."""
    return (f"{n_psb} PSB meshes of {n_categories} labelled categories and {n_corpus} procedural shapes "
            f"of {n_families} families (corpus share {corpus_share:g})")


def weights_record(w, b0: float, gamma: float, fitted_on: str) -> dict:
    """The learned-weights file's content from a fit: w [T] the cost weights of
    :data:`~torchakvf.parts.merge_terms.TERM_NAMES` (-beta), b0 the intercept, gamma the Rand
    exponent; 4 significant digits each (the fit's noise across folds is larger)."""
    fields = {FIELD_OF_TERM[name]: float(f"{x:.4g}") for name, x in zip(TERM_NAMES, w)}
    fields.update(size=0.0, intercept=float(f"{b0:.4g}"), rand_gamma=float(gamma))
    return merge_weights_record(fields, fitted_on)


def write_weights(record: dict, path) -> str:
    """Writes ``record`` (:func:`weights_record`) as the package file's JSON; returns the text."""
    text = json.dumps(record, indent=1)
    Path(path).write_text(text + "\n")
    return text


def main():
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generality"))
    import merge_cv as cv

    from torchakvf.options import MergeWeights

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True, help="capture.py's files (PSB meshes and corpus shapes)")
    ap.add_argument("--prep", required=True)
    ap.add_argument("--gamma", type=float, default=0.5)
    ap.add_argument("--corpus-share", type=float, default=0.5)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(PACKAGE_FILE))
    a = ap.parse_args()
    prep = Path(a.prep)
    prep.mkdir(parents=True, exist_ok=True)
    with get_context("fork").Pool(a.workers) as pool:
        for _ in pool.imap_unordered(cv.prepare, [(f, str(prep)) for f in sorted(Path(a.capture).glob("*.pkl"))]):
            pass
    cv.load_prep(prep)
    keys = sorted(cv.PREP)
    with get_context("fork").Pool(a.workers) as pool:
        cost = cv.fitted_cost(keys, cv.Cost.of(MergeWeights.hand_set()), pool, a.corpus_share, gamma=a.gamma)
    psb = [d for d in cv.PREP.values() if d["kind"] == "psb"]
    corpus = [d for d in cv.PREP.values() if d["kind"] != "psb"]
    fitted_on = trained_on(len(psb), len({d["group"] for d in psb}), len(corpus), len({d["group"] for d in corpus}),
                           a.corpus_share)
    print(write_weights(weights_record(cost.w, cost.b, a.gamma, fitted_on), a.out))


if __name__ == "__main__":
    main()
