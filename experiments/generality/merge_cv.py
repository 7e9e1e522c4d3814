"""The merge decision fitted on the PSB and the procedural corpus together, reported held out.

Reads capture.py's files (one variant of the over-segmentation) and redoes only the merge. A
candidate cost is a weight vector on :data:`~torchakvf.parts.merge_terms.TERM_NAMES` read as the
log-odds that two adjacent parts lie in one true part, p = sigmoid(b - terms . w), merged by the
expected change of the Rand disagreement (a_i a_j)^γ (1 - 2p) (the package's cost,
:func:`torchakvf.parts.merge.state_costs`).

The weights are a logistic regression of "one true part" (soft target: the share of the face
pairs of the two parts that one truth puts together) on the pairs the merge meets as it merges
under a policy (the weights being evaluated, or the hand-set ones), every mesh weighing alike
within its data set and the two data sets weighing ``--corpus-share`` and 1 - it. Every score
is held out: a PSB category (or a corpus family) is scored with weights fitted without it.
Scores are 1 - Rand index of the merged labels (before the graph cut) on the input faces, per
shape the mean over its truths, per group the mean over its shapes.

    PYTHONPATH=$PWD nice python3 experiments/generality/merge_cv.py --capture /tmp/capture_crease60 \\
        --prep /tmp/prep_crease60 --out /tmp/merge_cv_crease60.md
    PYTHONPATH=$PWD nice python3 experiments/generality/merge_cv.py --capture /tmp/capture_concave60 \\
        --prep /tmp/prep_concave60 --corpus-share 0.5 --drop "sight,sight_excess;sight_excess;sight" \\
        --weights-out /tmp/folds.json      # experiments/results/generality_sight.md
    PYTHONPATH=$PWD nice python3 experiments/generality/merge_cv.py --capture /tmp/capture_r5_unite \\
        --prep /tmp/prep_r5_unite --corpus-share 0.5 --gammas 0,0.15,0.25,0.35,0.5,0.65,0.8 \\
        --out /tmp/gammas.md               # experiments/results/generality_not_adopted.md
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from torchakvf.evaluate.metrics import rand_index_error as rand_error
from torchakvf.options import MergeWeights
from torchakvf.parts.merge import FIELD_OF_TERM, term_weights
from torchakvf.parts.merge_terms import TERM_NAMES, face_thickness

# the capture preparation, merge state and pair recorder of the PSB sweep, shared
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "segmentation"))
from merge_learned_cv import Recorder as PairRecorder  # noqa: E402
from merge_learned_cv import fit_logistic, greedy, merged_errors, new_state, over_graphs, truth_rows  # noqa: E402

T = len(TERM_NAMES)
PREP: dict = {}


# ---------------------------------------------------------------- preparation (once per shape)

def prepare(args) -> str:
    cap_file, prep = args
    out = Path(prep) / cap_file.name
    if out.exists():
        return f"{cap_file.stem} cached"
    rec = pickle.load(open(cap_file, "rb"))
    mesh = rec["mesh"]
    overs = over_graphs(rec, face_thickness(mesh.vertices, mesh.faces))
    data = dict(key=rec["key"], group=rec["group"], kind=rec["kind"], overs=overs,
                gts=truth_rows(rec, overs, rand_error))
    with open(out, "wb") as fh:
        pickle.dump(data, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return f"{rec['key']} prepared"


def load_prep(prep: Path, keep=None) -> None:
    PREP.clear()
    for f in sorted(prep.glob("*.pkl")):
        d = pickle.load(open(f, "rb"))
        if keep is None or keep(d):
            PREP[d["key"]] = d


# ---------------------------------------------------------------- the merge under a cost

class Cost:
    """A merge cost: weights w [T] on the terms, intercept b, Rand exponent gamma (None: the
    weighted sum itself is the cost, as the hand-set merge)."""

    def __init__(self, w, b=0.0, gamma=0.5):
        self.w, self.b, self.gamma = np.asarray(w, dtype=np.float64), float(b), gamma

    @classmethod
    def of(cls, weights: MergeWeights, k: int = 1) -> "Cost":
        return cls(term_weights(weights, k), weights.intercept, weights.rand_gamma)

    def __call__(self, terms, state, rows):
        s = terms @ self.w
        if self.gamma is None:
            return s
        a = state.area / state.total
        return np.outer(a[rows], a) ** self.gamma * np.tanh(0.5 * (s - self.b))


def shape_error(key: str, cost: Cost) -> float:
    """Mean 1-RI over the shape's truths of its merged labels."""
    return float(np.mean(merged_errors(PREP[key], cost, rand_error)))


def final_error(key: str) -> float:
    return float(np.mean([g["final_err"] for g in PREP[key]["gts"]]))


# ---------------------------------------------------------------- training rows

class Recorder(PairRecorder):
    """(terms, soft target, Rand stake) of each adjacent pair as the merge meets it; its
    ``__call__`` takes no merge state (this file's :func:`greedy` passes none)."""

    def __call__(self, terms, adj, rows):
        n = self.counts.sum(axis=1)
        for r_i, r in enumerate(rows):
            js = np.flatnonzero(adj[r_i])
            js = js[js > r] if len(rows) > 1 else js
            nn = n[r] * n[js]
            js, nn = js[nn > 0], nn[nn > 0]
            if len(js) == 0:
                continue
            self.X.append(terms[r_i, js])
            self.y.append((self.counts[js] @ self.counts[r]) / nn)
            self.wt.append(nn / self.n2)


def shape_rows(key: str, policy: Cost):
    """Training rows of one shape under the policy's merges; its weights sum to 1."""
    d = PREP[key]
    X, y, wt = [], [], []
    for g in d["gts"]:
        rec = Recorder(g["counts"], len(g["gt"]))
        greedy(new_state(d["overs"][g["over"]]), g["k"], policy, record=rec)
        if rec.X:
            X.append(np.concatenate(rec.X))
            y.append(np.concatenate(rec.y))
            wt.append(np.concatenate(rec.wt))
    if not X:
        return np.zeros((0, T)), np.zeros(0), np.zeros(0)
    wt = np.concatenate(wt)
    return np.concatenate(X), np.concatenate(y), wt / max(wt.sum(), 1e-300)


ROWS: dict = {}


def training_rows(train: list, policy: Cost, pool, corpus_share: float) -> tuple:
    """(X, y, wt): the training shapes' rows under the policy's merges, each shape weighing alike
    in its data set and the corpus ``corpus_share`` of the whole (rows made once per shape)."""
    missing = [m for m in train if (m, id(policy)) not in ROWS]
    for m, r in zip(missing, pool.starmap(shape_rows, [(m, policy) for m in missing])):
        ROWS[(m, id(policy))] = r
    n_psb = sum(PREP[m]["kind"] == "psb" for m in train)
    n_cor = len(train) - n_psb
    share = {True: (1 - corpus_share) / max(n_psb, 1) if n_cor else 1.0 / max(n_psb, 1),
             False: corpus_share / max(n_cor, 1) if n_psb else 1.0 / max(n_cor, 1)}
    X = np.concatenate([ROWS[(m, id(policy))][0] for m in train])
    y = np.concatenate([ROWS[(m, id(policy))][1] for m in train])
    wt = np.concatenate([ROWS[(m, id(policy))][2] * share[PREP[m]["kind"] == "psb"] for m in train])
    return X, y, wt


def fitted_cost(train: list, policy: Cost, pool, corpus_share: float, cols=None, gamma=0.5) -> Cost:
    """Logistic fit on the training shapes' rows (each shape weighing alike in its data set)."""
    w, b = fit_logistic(*training_rows(train, policy, pool, corpus_share), cols=cols)
    return Cost(w, b, gamma)


def weight_fields(cost: Cost) -> dict:
    """The MergeWeights fields of a fitted cost (the "small" column is part_size)."""
    fields = {FIELD_OF_TERM[name]: float(f"{x:.4g}") for name, x in zip(TERM_NAMES, cost.w)}
    fields.update(size=0.0, intercept=float(f"{cost.b:.4g}"), rand_gamma=cost.gamma)
    return fields


def group_scores(keys: list, cost: Cost, pool) -> dict:
    errs = pool.starmap(shape_error, [(m, cost) for m in keys])
    by: dict = {}
    for m, e in zip(keys, errs):
        by.setdefault(PREP[m]["group"], []).append(e)
    return {g: float(np.mean(v)) for g, v in by.items()}


def groups_of(kind_filter) -> list:
    return sorted({d["group"] for d in PREP.values() if kind_filter(d["kind"])})


def held_out(policy: Cost, pool, corpus_share: float, cols=None, gamma=0.5, groups=None) -> tuple[dict, dict]:
    """({group: held-out score}, {group: Cost fitted without it})."""
    groups = sorted({d["group"] for d in PREP.values()}) if groups is None else groups
    scores, costs = {}, {}
    for g in groups:
        train = [m for m, d in PREP.items() if d["group"] != g]
        test = [m for m, d in PREP.items() if d["group"] == g]
        cost = fitted_cost(train, policy, pool, corpus_share, cols, gamma)
        scores[g] = group_scores(test, cost, pool)[g]
        costs[g] = cost
        print(f"  held out {g}: {scores[g]:.4f}", flush=True)
    return scores, costs


def use_terms(terms_fn, state_fn, n_terms: int) -> None:
    """Make the merge loop, the row recorder and this module read a script's terms: ``terms_fn``
    (state, rows, k) -> (terms [len(rows), K, n_terms], adjacent) and ``state_fn``, which builds
    the state they read. Called at a script's import, so that forked pool workers inherit it."""
    global new_state, T
    import merge_learned_cv

    merge_learned_cv.pair_terms, merge_learned_cv.new_state = terms_fn, state_fn
    new_state, T = state_fn, int(n_terms)


def hand_set_policy(n_extra: int = 0) -> Cost:
    """The hand-set weights as the policy the training rows are made under, extended by zeros on
    ``n_extra`` terms a script adds beside TERM_NAMES (its rows then follow the shipped merges)."""
    return Cost(np.r_[Cost.of(MergeWeights.hand_set()).w, np.zeros(n_extra)], 0.0, None)


def held_out_with_term(term: str, names: tuple, specs: list, setup, policy: Cost, ctx,
                       corpus_share: float) -> dict:
    """{setting: {group: held-out score}}: the package's terms alone, then ``term`` beside them
    under each of ``specs``. ``setup(spec)`` readies the term's sums in PREP (the pool forks after
    it, so the workers read them) and returns the setting's name; ``names`` label the weights
    fitted on every shape, printed per setting."""
    results = {}
    for spec in specs:
        name = setup(spec)
        ROWS.clear()
        with ctx.Pool(2) as pool:
            if not results:
                cols = list(range(len(TERM_NAMES)))
                results[f"without {term} (held out)"], _ = held_out(policy, pool, corpus_share, cols=cols)
            scores, _ = held_out(policy, pool, corpus_share)
            every = fitted_cost(sorted(PREP), policy, pool, corpus_share)
        print(name, "fitted on all:", {n: round(float(x), 3) for n, x in zip(names, every.w)},
              "intercept", round(every.b, 3), flush=True)
        results[f"{name} (held out)"] = scores
    return results


def held_out_gammas(policy: Cost, pool, corpus_share: float, gammas: list) -> dict:
    """{"learned, γ g (held out)": {group: score}}: each group's weights fitted once without it
    (the fit does not read γ) and its merge run at every γ of ``gammas``."""
    out = {g: {} for g in gammas}
    for grp in sorted({d["group"] for d in PREP.values()}):
        train = [m for m, d in PREP.items() if d["group"] != grp]
        test = [m for m, d in PREP.items() if d["group"] == grp]
        cost = fitted_cost(train, policy, pool, corpus_share)
        for g in gammas:
            out[g][grp] = group_scores(test, Cost(cost.w, cost.b, g), pool)[grp]
        print(f"  held out {grp}: " + " ".join(f"γ {g}: {out[g][grp]:.4f}" for g in gammas), flush=True)
    return {f"learned, γ {g}, corpus share {corpus_share} (held out)": sc for g, sc in out.items()}


def summary(scores: dict) -> dict:
    kinds = {g: PREP[next(m for m, d in PREP.items() if d["group"] == g)]["kind"] for g in scores}
    out = {}
    for name, sel in (("PSB", ("psb",)), ("organic", ("organic",)), ("mechanical", ("mechanical",)),
                      ("corpus", ("organic", "mechanical"))):
        vals = [s for g, s in scores.items() if kinds[g] in sel]
        if vals:
            out[name] = float(np.mean(vals))
    return out


def table(results: dict) -> str:
    groups = sorted({g for sc in results.values() for g in sc},
                    key=lambda g: (PREP[next(m for m, d in PREP.items() if d["group"] == g)]["kind"], g))
    names = ["PSB", "organic", "mechanical", "corpus"]
    lines = ["| setting | " + " | ".join(names) + " | " + " | ".join(groups) + " |",
             "|---|" + "---:|" * (len(names) + len(groups))]
    for name, sc in results.items():
        s = summary(sc)
        lines.append(f"| {name} | " + " | ".join(f"{s[n]:.4f}" if n in s else "" for n in names) + " | "
                     + " | ".join(f"{sc[g]:.3f}" if g in sc else "" for g in groups) + " |")
    return "\n".join(lines)


def report(results: dict, out=None) -> None:
    """Prints the :func:`table` of ``results`` and writes it to the file ``out`` (None: not written)."""
    text = table(results)
    print(text)
    if out:
        Path(out).write_text(text + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True)
    ap.add_argument("--prep", required=True)
    ap.add_argument("--out", default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--corpus-share", default="0,0.5", help="comma-separated shares of the corpus in the fit")
    ap.add_argument("--stage", default="all", choices=["prep", "all"])
    ap.add_argument("--drop", default="", help="semicolon-separated term sets to fit without, each "
                    "comma-separated TERM_NAMES (e.g. 'sight;sight,thin'); each is a row beside the fit on all")
    ap.add_argument("--gammas", default="",
                    help="comma-separated Rand exponents γ of the stake (a_i a_j)^γ: with it, only the "
                         "held-out table of each γ at the last corpus share (the weights fitted once "
                         "per group)")
    ap.add_argument("--weights-out", default=None,
                    help="write {group: weights fitted without it, '*': fitted on all} of the last share, "
                         "every term in the fit (JSON)")
    a = ap.parse_args()
    prep = Path(a.prep)
    prep.mkdir(parents=True, exist_ok=True)
    ctx = get_context("fork")
    t0 = time.time()
    with ctx.Pool(a.workers) as pool:
        for _ in pool.imap_unordered(prepare, [(f, str(prep)) for f in sorted(Path(a.capture).glob("*.pkl"))]):
            pass
    print(f"prepared in {time.time() - t0:.0f}s", flush=True)
    if a.stage == "prep":
        return
    load_prep(prep)
    keys = sorted(PREP)
    with ctx.Pool(a.workers) as pool:
        results = {}
        fin = {}
        for m in keys:
            fin.setdefault(PREP[m]["group"], []).append(final_error(m))
        results["captured default, merged + graph cut"] = {g: float(np.mean(v)) for g, v in fin.items()}
        results["package weights (MergeWeights()), merged"] = group_scores(keys, Cost.of(MergeWeights()), pool)
        results["hand-set weights, merged"] = group_scores(keys, Cost.of(MergeWeights.hand_set()), pool)
        policy = Cost.of(MergeWeights.hand_set())
        if a.gammas:
            share = float(a.corpus_share.split(",")[-1])
            results.update(held_out_gammas(policy, pool, share, [float(g) for g in a.gammas.split(",")]))
            report(results, a.out)
            return
        drops = [()] + [tuple(d.split(",")) for d in a.drop.split(";") if d]
        for share in [float(x) for x in a.corpus_share.split(",")]:
            for drop in drops:
                cols = [c for c, name in enumerate(TERM_NAMES) if name not in drop]
                name = f"learned{' without ' + '+'.join(drop) if drop else ''}, corpus share {share}"
                print(name, flush=True)
                sc, costs = held_out(policy, pool, share, cols=cols)
                results[f"{name} (held out)"] = sc
                everything = fitted_cost(keys, policy, pool, share, cols=cols)
                results[f"{name} (fitted on all: in-sample)"] = group_scores(keys, everything, pool)
                print(name, "fitted on all:", weight_fields(everything), flush=True)
                if a.weights_out and not drop:
                    out = {g: weight_fields(c) for g, c in costs.items()}
                    out["*"] = weight_fields(everything)
                    Path(a.weights_out).write_text(json.dumps(out, indent=1) + "\n")
    report(results, a.out)


if __name__ == "__main__":
    main()
