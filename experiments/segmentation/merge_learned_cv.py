"""The merge decision, cross-validated by leave-one-category-out on the 15 labelled PSB categories.

Reads experiments/segmentation/merge_capture.py's files (the over-segmentation the default merges, per mesh
and k, on the fine cleaned mesh; the default's final labels; the human segmentations) and redoes
only the merge. Every cost compared is linear in the pair terms of
:func:`torchakvf.parts.merge_terms.pair_terms` (the default's too: its symmetry, concavity,
convexity, share and size terms are columns of it), so a candidate is a weight vector:

* ``default``: the hand-set cost (MergeWeights.hand_set(), the default before the learned one);
* ``learned``: weights fitted by logistic regression of "the two parts lie in one human segment"
  (soft target: the chance that a face of each lies in one segment, per human) on the states the
  merge passes through (every adjacent pair once, as it appears), rows weighted by the pair's
  share of the face pairs (its Rand-index stake); for each held-out category fitted on the other
  14 only (two rounds: states of the default's merge, then of round 1's merge added);
* ``grid``: the default plus one more term at a time, each weight chosen on the other 14
  categories from a grid scored on all 15 (the choice never sees the held-out category).

Scores are 1-RI by segmentation (each human's k, compared with that human), merged labels
before the graph cut (the captured over-segmentation's labels, merged, on the input faces),
category = mean over its meshes, overall = mean over categories.

    PYTHONPATH=$PWD nice python3 experiments/segmentation/merge_learned_cv.py --capture /tmp/merge_capture \
        --prep /tmp/merge_prep --out experiments/results/merge_learned_cv.md
"""
from __future__ import annotations

import argparse
import pickle
import time
from functools import partial
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from torchakvf.options import MergeWeights
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.merge import boundary_bends, region_graph
from torchakvf.parts.merge_terms import TERM_NAMES, MergeState, face_thickness, pair_terms, part_sums
from torchakvf.parts.sightlines import SightLines

T = len(TERM_NAMES)
PREP: dict = {}


def rand_error(a: np.ndarray, b: np.ndarray) -> float:
    """1 - RI (faces counted, unordered pairs) of two labellings with labels >= 0."""
    n = a.size
    nb = int(b.max()) + 1
    cell = np.bincount(a * nb + b).astype(np.float64)
    sa = np.bincount(a).astype(np.float64)
    sb = np.bincount(b).astype(np.float64)
    c2 = lambda x: (x * (x - 1) / 2).sum()
    total = n * (n - 1) / 2
    return float((c2(sa) + c2(sb) - 2 * c2(cell)) / total)


def default_vector(w: MergeWeights | None = None) -> np.ndarray:
    """The hand-set cost (the default before the learned one; None: MergeWeights.hand_set()) as
    weights on TERM_NAMES (its size terms are 0)."""
    w = MergeWeights.hand_set() if w is None else w
    v = np.zeros(T)
    v[0], v[1], v[2], v[3], v[4] = w.symmetry, w.concavity, w.convexity, w.cut, w.part_size
    return v


# ---------------------------------------------------------------- preparation (once per mesh)

def over_graphs(rec: dict, thick: np.ndarray) -> list[dict]:
    """Per over-segmentation of a capture (merge_capture.py's record): its region graph's arrays,
    its parts' sums (``thick`` [F] the face thickness; the lines of sight between the parts) and
    its labels on the input faces. Shared with experiments/generality/merge_cv.py."""
    mesh = rec["mesh"]
    dual = dual_edges(mesh.vertices, mesh.faces)
    sight = SightLines(mesh.vertices, mesh.faces)
    bends = boundary_bends(dual)
    cent = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)].mean(axis=1)
    overs = []
    for o in rec["overs"]:
        unit = o["unit"].astype(np.float64)
        g = region_graph(o["labels"], dual, unit, o["area"], unit=unit, bends=bends)
        sums = part_sums(g.labels, g.n_parts, o["area"], cent, thick)
        sums["seen"], sums["lines"] = sight.counts(g.labels, g.n_parts)
        lab_in = mesh.labels_to_input_faces(g.labels)
        overs.append(dict(graph=(g.area, g.mean, g.length, g.concave, g.convex), sums=sums, lab_in=lab_in))
    return overs


def truth_rows(rec: dict, overs: list[dict], error) -> list[dict]:
    """Per truth of a capture: its k, the over-segmentation merged to it, the faces of each part
    in each truth segment [K, k] and the captured final labels' ``error`` against it."""
    gts = []
    for gt in rec["gts"]:
        gt = gt.astype(np.int64)
        k = int(gt.max()) + 1
        oi = rec["k_over"][k]
        lab_in = overs[oi]["lab_in"]
        K = len(overs[oi]["graph"][0])
        ok = lab_in >= 0
        counts = np.bincount(lab_in[ok] * k + gt[ok], minlength=K * k).reshape(K, k).astype(np.float64)
        final = rec["final"][k].astype(np.int64)
        gts.append(dict(k=k, over=oi, gt=gt, counts=counts, final_err=error(np.maximum(final, 0), gt)))
    return gts


def prepare(args) -> str:
    cap, prep, mid = args
    out = Path(prep) / f"{mid}.pkl"
    if out.exists():
        return f"{mid} cached"
    rec = pickle.load(open(Path(cap) / f"{mid}.pkl", "rb"))
    mesh = rec["mesh"]
    t0 = time.perf_counter()
    thick = face_thickness(mesh.vertices, mesh.faces)
    t_thick = time.perf_counter() - t0
    overs = over_graphs(rec, thick)
    gts = truth_rows(rec, overs, rand_error)
    data = dict(mid=mid, category=rec["category"], overs=overs, gts=gts, t_thick=t_thick, faces=len(mesh.faces))
    with open(out, "wb") as fh:
        pickle.dump(data, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return f"{mid} {rec['category']} thickness {t_thick:.2f}s"


def load_prep(prep: Path) -> None:
    for f in sorted(prep.glob("*.pkl"), key=lambda p: int(p.stem)):
        PREP[int(f.stem)] = pickle.load(open(f, "rb"))


def new_state(over: dict) -> MergeState:
    area, mean, length, concave, convex = over["graph"]
    s = over["sums"]
    return MergeState(area.copy(), mean.copy(), length.copy(), concave.copy(), convex.copy(),
                      thick=s["thick"].copy(), thick_area=s["thick_area"].copy(), centroid=s["centroid"].copy(),
                      center=s["center"], radius=s["radius"], thick_median=s["thick_median"],
                      seen=None if s.get("seen") is None else s["seen"].copy(),
                      lines=None if s.get("lines") is None else s["lines"].copy())


# ---------------------------------------------------------------- the greedy merge on a state

def pair_cost(w, terms, state, rows):
    """[len(rows), K] merge costs: terms . w (w a vector), or with w = ("rand", beta, b0) the
    expected change of the Rand disagreement, a_i a_j / A^2 (1 - 2 sigmoid(b0 + terms . beta))."""
    if isinstance(w, tuple):
        _, beta, b0 = w[:3]
        gamma = w[3] if len(w) > 3 else 1.0
        p = 1.0 / (1.0 + np.exp(-(terms @ beta + b0)))
        a = state.area / state.total
        return np.outer(a[rows], a) ** gamma * (1.0 - 2.0 * p)
    return terms @ w


def greedy(state: MergeState, k: int, cost, record=None) -> np.ndarray:
    """Merge the cheapest adjacent pair until k parts remain; the owner [K] of each part.
    cost(terms, state, rows) -> [len(rows), K] merge costs (``partial(pair_cost, w)``, or
    experiments/generality/merge_cv.py's Cost); record(terms, adjacent, rows): each new row of
    terms (every pair at the start, the merged part's after each merge); record.merge(i, j):
    each merge."""
    K = len(state.area)
    rows = np.arange(K)
    terms, adj = pair_terms(state, rows, k)
    if record is not None:
        record(terms, adj, rows)
    c = np.where(adj, cost(terms, state, rows), np.inf)
    np.fill_diagonal(c, np.inf)
    owner = np.arange(K)
    for _ in range(K - k):
        i, j = divmod(int(np.argmin(c)), K)
        if not np.isfinite(c[i, j]):
            break
        i, j = min(i, j), max(i, j)
        state.merge(i, j)
        if record is not None:
            record.merge(i, j)
        owner[owner == j] = i
        c[j, :] = c[:, j] = np.inf
        t, a = pair_terms(state, np.array([i]), k)
        if record is not None:
            record(t, a, np.array([i]))
        row = np.where(a[0], cost(t, state, np.array([i]))[0], np.inf)
        row[i] = np.inf
        c[i, :] = c[:, i] = row
    return owner


def merged_errors(d: dict, cost, error) -> list[float]:
    """``error`` of the merged labels against each truth of a prepared shape ``d`` (the input
    faces): each over-segmentation merged to each truth's k once, by :func:`greedy` under
    ``cost``. Shared with experiments/generality/merge_cv.py."""
    errs, memo = [], {}
    for g in d["gts"]:
        key = (g["over"], g["k"])
        if key not in memo:
            owner = greedy(new_state(d["overs"][g["over"]]), g["k"], cost)
            lab = d["overs"][g["over"]]["lab_in"]
            memo[key] = np.where(lab >= 0, owner[np.maximum(lab, 0)], owner.max() + 1)
        errs.append(error(memo[key], g["gt"]))
    return errs


def mesh_errors(mid: int, w: np.ndarray) -> list[float]:
    return merged_errors(PREP[mid], partial(pair_cost, w), rand_error)


def category_scores(w: np.ndarray, pool=None) -> dict:
    mids = sorted(PREP)
    res = (pool.starmap if pool else lambda f, a: [f(*x) for x in a])(mesh_errors, [(m, w) for m in mids])
    by_cat: dict = {}
    for m, e in zip(mids, res):
        by_cat.setdefault(PREP[m]["category"], []).append(float(np.mean(e)))
    return {c: float(np.mean(v)) for c, v in by_cat.items()}


# ---------------------------------------------------------------- training rows

class Recorder:
    """Collects (terms, target, weight) of each adjacent pair as the merge meets it."""

    def __init__(self, counts: np.ndarray, n_faces: int):
        self.counts = counts.copy()          # [K, k] faces of each part in each human segment
        self.n2 = float(n_faces) ** 2
        self.X, self.y, self.wt = [], [], []

    def merge(self, i, j):
        self.counts[i] += self.counts[j]
        self.counts[j] = 0.0

    def __call__(self, terms, adj, rows):
        n = self.counts.sum(axis=1)
        for r_i, r in enumerate(rows):
            js = np.flatnonzero(adj[r_i])
            js = js[js > r] if len(rows) > 1 else js
            if len(js) == 0:
                continue
            nn = n[r] * n[js]
            ok = nn > 0
            js, nn = js[ok], nn[ok]
            same = (self.counts[js] @ self.counts[r]) / nn
            self.X.append(terms[r_i, js])
            self.y.append(same)
            self.wt.append(nn / self.n2)


def mesh_rows(mid: int, w: np.ndarray):
    d = PREP[mid]
    X, y, wt = [], [], []
    n_gt = len(d["gts"])
    for g in d["gts"]:
        rec = Recorder(g["counts"], len(g["gt"]))
        greedy(new_state(d["overs"][g["over"]]), g["k"], partial(pair_cost, w), record=rec)
        if rec.X:
            X.append(np.concatenate(rec.X))
            y.append(np.concatenate(rec.y))
            wt.append(np.concatenate(rec.wt) / n_gt)        # each mesh weighs alike
    return np.concatenate(X), np.concatenate(y), np.concatenate(wt)


def fit_logistic(X, y, wt, l2=1e-3, cols=None):
    """(w = -beta [T] cost weights, c): the weights (on standardized columns ``cols`` of X, the
    others 0, returned in raw units) and intercept minimizing the weighted cross-entropy of
    sigmoid(c + X beta) against the soft targets y, + l2 |beta|^2. The cost reads
    p = sigmoid(c - X w). Shared with experiments/generality/merge_cv.py."""
    cols = list(range(X.shape[1])) if cols is None else list(cols)
    Xc = X[:, cols]
    mu, sd = Xc.mean(axis=0), Xc.std(axis=0) + 1e-12
    Z = (Xc - mu) / sd
    wt = wt / wt.sum()

    def f(p):
        z = Z @ p[1:] + p[0]
        loss = np.sum(wt * (np.logaddexp(0, z) - y * z)) + l2 * p[1:] @ p[1:]
        r = wt * (1 / (1 + np.exp(-z)) - y)
        return loss, np.r_[r.sum(), Z.T @ r + 2 * l2 * p[1:]]

    p = minimize(f, np.zeros(len(cols) + 1), jac=True, method="L-BFGS-B").x
    beta = np.zeros(X.shape[1])
    beta[cols] = p[1:] / sd
    c = p[0] - mu @ beta[cols]
    return -beta, c


ROWS: dict = {}


def learned_weights(train_mids, policy_w, pool, rounds=1, cols=tuple(range(T))):
    """Cost weights (= -beta: the merge takes the most likely pair first) and intercept from rows
    of the training meshes; round 1's rows are the default merge's states (made once per mesh),
    round r's add those of the merges of round r - 1's weights."""
    missing = [m for m in train_mids if m not in ROWS]
    for m, r in zip(missing, pool.starmap(mesh_rows, [(m, policy_w) for m in missing])):
        ROWS[m] = r
    Xs, ys, ws = [ROWS[m][0] for m in train_mids], [ROWS[m][1] for m in train_mids], [ROWS[m][2] for m in train_mids]
    cols = list(cols)
    w = policy_w  # the weights whose merges make the next round's rows
    for r in range(rounds):
        if r > 0:
            rows = pool.starmap(mesh_rows, [(m, w) for m in train_mids])
            Xs += [x[0] for x in rows]
            ys += [x[1] for x in rows]
            ws += [x[2] for x in rows]
        w, b0 = fit_logistic(np.concatenate(Xs), np.concatenate(ys), np.concatenate(ws), cols=cols)
    return w, b0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True)
    ap.add_argument("--prep", required=True)
    ap.add_argument("--out", default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--stage", default="all", choices=["prep", "all"])
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--rounds", type=int, default=1, help="rounds of states (round 1: the default's merges)")
    a = ap.parse_args()
    prep = Path(a.prep)
    prep.mkdir(parents=True, exist_ok=True)
    mids = sorted(int(p.stem) for p in Path(a.capture).glob("*.pkl"))
    ctx = get_context("fork")
    with ctx.Pool(a.workers) as pool:
        for line in pool.imap_unordered(prepare, [(a.capture, str(prep), m) for m in mids]):
            pass
    if a.stage == "prep":
        return
    load_prep(prep)
    run_cv(a)


VARIANTS = {
    # name: (columns fitted, cost form)
    "learned": (tuple(range(T)), "linear"),
    "learned-rand": (tuple(range(T)), "rand"),
    "learned-no-thickness": (tuple(i for i in range(T) if TERM_NAMES[i] not in ("thickness", "thin")), "linear"),
    "learned-default-terms": (tuple(range(5)), "linear"),
}


def fold_weights(c, variant, pool, rounds):
    cols, form = VARIANTS[variant]
    train = [m for m, d in PREP.items() if d["category"] != c]
    w, b0 = learned_weights(train, default_vector(), pool, rounds=rounds, cols=cols)
    return (("rand", -w, b0) if form == "rand" else w), w, b0


GRID = {"small": (0.05, 0.1, 0.2, 0.4), "size_ratio": (0.1, 0.2, 0.4, 0.8), "short_cut": (-0.5, -0.25, 0.25, 0.5),
        "thickness": (0.5, 1, 2, 4), "thin": (-1, -0.5, 0.5, 1), "centricity": (-1, -0.5, 0.5, 1)}


def grid_cv(cats, pool, base):
    """The default plus one term at a time at each weight of GRID; for each held-out category
    the candidate (the default included) best on the other 14."""
    cands = [default_vector()]
    for name, ws in GRID.items():
        for x in ws:
            v = default_vector()
            v[TERM_NAMES.index(name)] += x
            cands.append(v)
    scores = [base] + [category_scores(v, pool) for v in cands[1:]]
    held, on, choice = {}, {}, {}
    for c in cats:
        others = [x for x in cats if x != c]
        best = int(np.argmin([np.mean([sc[x] for x in others]) for sc in scores]))
        held[c], on[c], choice[c] = scores[best][c], float(np.mean([scores[best][x] for x in others])), cands[best]
        print("grid", c, f"chose {cands[best]}: held-out {base[c]:.4f} -> {held[c]:.4f}", flush=True)
    lines = [f"{cands[i]}: overall {np.mean([sc[x] for x in cats]):.4f}" for i, sc in enumerate(scores)]
    print("\n".join(lines), flush=True)
    return held, on, choice


GAMMAS = (0.0, 0.5, 1.0)


def gamma_cv(cats, pool, base, fitted):
    """Rand cost (a_i a_j / A^2)^γ (1 - 2 p): for each held-out category its fold's logistic fit
    and the γ of GAMMAS best on the other 14 categories (scored on their meshes 1-8 each, to
    save time), then scored on the held-out category."""
    held, on, choice = {}, {}, {}
    for c in cats:
        _, w, b0 = fold_weights(c, "learned", pool, 1)
        sub = [m for m, d in PREP.items() if d["category"] != c and (m - 1) % 20 < 8]
        sc = []
        for g in GAMMAS:
            errs = pool.starmap(mesh_errors, [(m, ("rand", -w, b0, g)) for m in sub])
            by = {}
            for m, e in zip(sub, errs):
                by.setdefault(PREP[m]["category"], []).append(np.mean(e))
            sc.append(float(np.mean([np.mean(v) for v in by.values()])))
        gi = int(np.argmin(sc))
        choice[c], on[c] = GAMMAS[gi], sc[gi]
        test = [m for m, d in PREP.items() if d["category"] == c]
        test_errs = pool.starmap(mesh_errors, [(m, ("rand", -w, b0, GAMMAS[gi])) for m in test])
        held[c] = float(np.mean([np.mean(e) for e in test_errs]))
        fitted[("rand-gamma", c)] = (np.r_[w, GAMMAS[gi]], b0)
        print("rand-gamma", c, f"other 14 by γ {dict(zip(GAMMAS, np.round(sc, 4)))} chose {GAMMAS[gi]}:"
              f" held-out default {base[c]:.4f} -> {held[c]:.4f}", flush=True)
    return held, on, choice


def run_cv(a):
    cats = sorted({d["category"] for d in PREP.values()})
    ctx = get_context("fork")
    with ctx.Pool(a.workers) as pool:
        w0 = default_vector()
        base = category_scores(w0, pool)
        final: dict = {}
        for d in PREP.values():
            final.setdefault(d["category"], []).append(np.mean([g["final_err"] for g in d["gts"]]))
        final = {c: float(np.mean(v)) for c, v in final.items()}
        results = {"default, merged + graph cut (as eval)": final, "default, merged": base}
        chosen_on = {}
        fitted = {}
        for variant in a.variants.split(","):
            if variant == "rand-gamma":
                held, on, choice = gamma_cv(cats, pool, base, fitted)
                results["learned, Rand cost (a_i a_j)^γ, γ by LOCO (held out)"] = held
                chosen_on["rand-gamma"] = on
                continue
            if variant == "grid":
                held, on, choice = grid_cv(cats, pool, base)
                results["grid: default + one term (LOCO, held out)"] = held
                chosen_on["grid"] = on
                for c in cats:
                    fitted[("grid", c)] = (choice[c], 0.0)
                continue
            held = {}
            for c in cats:
                cost, w, b0 = fold_weights(c, variant, pool, a.rounds)
                fitted[(variant, c)] = (w, b0)
                test = [m for m, d in PREP.items() if d["category"] == c]
                held[c] = float(np.mean([np.mean(e) for e in pool.starmap(mesh_errors, [(m, cost) for m in test])]))
                print(variant, c, f"held-out: default {base[c]:.4f} -> {held[c]:.4f}", flush=True)
            cost, w, b0 = fold_weights(None, variant, pool, a.rounds)
            fitted[(variant, "all 15")] = (w, b0)
            results[variant + " (LOCO, held out)"] = held
            results[variant + " (fitted on all 15: chosen-on)"] = category_scores(cost, pool)
        report(results, cats, fitted, chosen_on, base, a.out)
        return results, fitted


def report(results, cats, fitted, chosen_on, base, out):
    head = "| setting | overall | " + " | ".join(cats) + " |"
    lines = [head, "|---|---:|" + "---:|" * len(cats)]
    for name, sc in results.items():
        lines.append(f"| {name} | {np.mean([sc[c] for c in cats]):.4f} | "
                     + " | ".join(f"{sc[c]:.3f}" for c in cats) + " |")
    for v, on in chosen_on.items():
        lines += ["", f"Chosen-on figures of {v}: each fold's choice scored on the 14 categories it was chosen on"
                  " (mean over categories), against the default merge on the same 14:", "",
                  "| held-out category | default, other 14 | chosen, other 14 |", "|---|---:|---:|"]
        for c in cats:
            lines.append(f"| {c} | {np.mean([base[x] for x in cats if x != c]):.4f} | {on[c]:.4f} |")
    lines += ["", "Fitted cost weights (-beta) per held-out category (terms: " + ", ".join(TERM_NAMES) + "):", ""]
    for (v, c), (w, b0) in fitted.items():
        lines.append(f"- {v}, {c}: " + ", ".join(f"{x:.3g}" for x in w) + f"; intercept {b0:.3g}")
    text = "\n".join(lines)
    print(text)
    if out:
        Path(out).write_text(text + "\n")


if __name__ == "__main__":
    main()
