"""The lines of sight restricted to pieces adjacent in the over-segmentation, as merge terms,
held out by group (not adopted: experiments/results/generality_not_adopted.md).

The package's sight terms count the segments between every sample of one part and every sample
of the other; between two arcs of a ring, or the bend and an end of an elbow, they leave the
solid although the parts are one. Counted only between pieces that touch in the over-segmentation
(and within a piece), the same counts measure convexity across the shared boundary at the
pieces' scale. Terms added beside TERM_NAMES: ``sight_local`` (blocked share between adjacent
pieces), ``sight_local_excess`` (that less the parts' own local share), ``sight_far`` (blocked
share between pieces that do not touch). They are read from merge_cv.py's preparation (the
counts of every pair of pieces and the over-segmentation's adjacency), so no ray is cast again.

    PYTHONPATH=$PWD python3 experiments/generality/sight_local_cv.py --prep /tmp/prep_fin \\
        --drop "sight_local,sight_local_excess,sight_far;sight_far;sight,sight_excess,sight_far"
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

from torchakvf.parts.merge_terms import TERM_NAMES, MergeState  # noqa: E402
from torchakvf.parts.merge_terms import pair_terms as package_terms  # noqa: E402
from torchakvf.parts.sightlines import join_counts  # noqa: E402

EXTRA = ("sight_local", "sight_local_excess", "sight_far")
NAMES = TERM_NAMES + EXTRA
PACKAGE_STATE = L.new_state


class LocalState(MergeState):
    """A merge state that also sums the counts between adjacent pieces (seen_loc, lines_loc)."""

    seen_loc = None
    lines_loc = None

    def merge(self, i, j):
        super().merge(i, j)
        join_counts(self.seen_loc, i, j)
        join_counts(self.lines_loc, i, j)


def new_state(over: dict) -> LocalState:
    base = PACKAGE_STATE(over)
    state = LocalState(**{f: getattr(base, f) for f in base.__dataclass_fields__})
    touch = (over["graph"][2] > 0).astype(np.float64)
    np.fill_diagonal(touch, 1.0)
    state.seen_loc = over["sums"]["seen"] * touch
    state.lines_loc = over["sums"]["lines"] * touch
    return state


def pair_terms(state, rows, k):
    T, adjacent = package_terms(state, rows, k)
    E = np.zeros(T.shape[:-1] + (len(EXTRA),))
    lines = state.lines_loc[rows]
    blocked = np.where(lines > 0, 1.0 - state.seen_loc[rows] / np.maximum(lines, 1.0), 0.0)
    own_lines = np.diag(state.lines_loc)
    own = np.where(own_lines > 0, 1.0 - np.diag(state.seen_loc) / np.maximum(own_lines, 1.0), 0.0)
    far_lines = state.lines[rows] - lines
    far_seen = state.seen[rows] - state.seen_loc[rows]
    E[..., 0] = blocked
    E[..., 1] = blocked - 0.5 * (own[rows][:, None] + own[None, :])
    E[..., 2] = np.where(far_lines > 0, 1.0 - far_seen / np.maximum(far_lines, 1.0), blocked)
    E[~adjacent] = 0.0
    return np.concatenate([T, E], axis=-1), adjacent


# the shared merge loop and row recorder read this script's terms
M.use_terms(pair_terms, new_state, len(NAMES))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--prep", required=True, help="merge_cv.py's preparation folder")
    ap.add_argument("--drop", default="", help="semicolon-separated term sets to fit without, each comma-separated")
    ap.add_argument("--corpus-share", type=float, default=0.5)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    M.load_prep(Path(a.prep))
    keys = sorted(M.PREP)
    policy = M.hand_set_policy(len(EXTRA))
    results = {}
    with get_context("fork").Pool(2) as pool:
        for drop in a.drop.split(";"):
            cols = [c for c, name in enumerate(NAMES) if name not in set(drop.split(","))]
            scores, _ = M.held_out(policy, pool, a.corpus_share, cols=cols)
            every = M.fitted_cost(keys, policy, pool, a.corpus_share, cols=cols)
            print(f"without {drop or 'nothing'}: fitted on all",
                  {n: round(float(x), 3) for n, x in zip(NAMES, every.w) if x != 0}, flush=True)
            results[f"learned without {drop or 'nothing'} (held out)"] = scores
    M.report(results, a.out)


if __name__ == "__main__":
    main()
