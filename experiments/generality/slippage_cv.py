"""Rigid motions a union of two parts loses (slippage) as a merge term, held out by group.

A surface slides along itself under a rigid motion (ω, t) where the velocity ω × x + t is
tangent everywhere: a cylinder under a turn about and a shift along its axis, a surface of
revolution under the turn, a plane under three (Gelfand & Guibas, "Shape segmentation using
local slippage analysis", 2004). With u_f = [c_f × n_f / R, n_f] at each face (centroid c_f
from the surface's area centroid, R its RMS radius, n_f the unit normal), a part's slippage
matrix is C = Σ a_f u_f u_fᵀ (a_f the face's share of the surface's area; [6, 6], additive
over faces: a union's is the sum of its parts'), and its j-th motion is as free as λ_j(C) / A
is small (A the part's share of the area). Uniting two arcs of one wheel rim keeps
the turn about the axle; uniting a spoke with the hub, or two coaxial cylinders of a stepped
shaft, loses a motion that both had. The term, for the ``motions`` smallest eigenvalues
m = 1..M:

    slip = Σ_m log((λ_m(C_i + C_j) + ε A) / (λ_m(C_i) + λ_m(C_j) + ε A)),   A = A_i + A_j

(>= 0 for m = 1 by Weyl's inequality), beside TERM_NAMES.

    PYTHONPATH=$PWD python3 experiments/generality/slippage_cv.py --capture /tmp/capture \\
        --prep /tmp/capture_prep --variants "1:1e-3,2:1e-3"

With ``--unseen-capture`` and ``--unseen-prep`` (the captures of shapes no fit saw, e.g. a corpus
of another seed), the weights are fitted on every shape of ``--capture`` instead, with and
without the term, and their merged labels scored on the unseen shapes by family.
"""
from __future__ import annotations

import argparse
import pickle
import sys
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "segmentation"))
import merge_cv as M  # noqa: E402
import merge_learned_cv as L  # noqa: E402

from torchakvf.mesh.clean import face_cross_products  # noqa: E402
from torchakvf.parts.grouping import compact_labels  # noqa: E402
from torchakvf.parts.merge_terms import TERM_NAMES, MergeState  # noqa: E402
from torchakvf.parts.merge_terms import pair_terms as package_terms  # noqa: E402

NAMES = TERM_NAMES + ("slippage",)
PACKAGE_STATE = L.new_state
SPEC = {"motions": 1, "eps": 1e-3}


def slip_sums(cap_file, prefix: str = "") -> tuple[str, list]:
    """(prefix + key, [[K, 6, 6] slippage matrices of each over-segmentation's parts]) of a capture."""
    rec = pickle.load(open(cap_file, "rb"))
    V = np.asarray(rec["mesh"].vertices, dtype=np.float64)
    F = np.asarray(rec["mesh"].faces, dtype=np.int64)
    cross = face_cross_products(V, F)
    dbl = np.linalg.norm(cross, axis=1)
    area = dbl / dbl.sum()               # unit total, as the merge state's part areas
    n = cross / np.maximum(dbl, 1e-300)[:, None]
    c = V[F].mean(axis=1)
    center = (area[:, None] * c).sum(axis=0)
    radius = float(np.sqrt((area * ((c - center) ** 2).sum(axis=1)).sum()))
    u = np.concatenate([np.cross(c - center, n) / radius, n], axis=1)          # [F, 6]
    outer = area[:, None, None] * u[:, :, None] * u[:, None, :]              # [F, 6, 6]
    out = []
    for o in rec["overs"]:
        lab, K = compact_labels(o["labels"])
        ok = lab >= 0
        C = np.zeros((K, 36))
        np.add.at(C, lab[ok], outer[ok].reshape(-1, 36))
        out.append(C.reshape(K, 6, 6))
    return prefix + rec["key"], out


class SlipState(MergeState):
    """A merge state that also sums the parts' slippage matrices (``slip`` [K, 6, 6])."""

    slip = None

    def merge(self, i, j):
        super().merge(i, j)
        self.slip[i] += self.slip[j]
        self.slip[j] = 0.0


def new_state(over: dict) -> SlipState:
    base = PACKAGE_STATE(over)
    state = SlipState(**{f: getattr(base, f) for f in base.__dataclass_fields__})
    state.slip = over["slip"].copy()
    return state


def pair_terms(state, rows, k):
    T, adjacent = package_terms(state, rows, k)
    m, eps = SPEC["motions"], SPEC["eps"]
    rows = np.asarray(rows)
    lam = np.linalg.eigvalsh(state.slip)[:, :m]                                # [K, m]
    union = np.linalg.eigvalsh(state.slip[rows][:, None] + state.slip[None, :])[..., :m]   # [R, K, m]
    a = (state.area[rows][:, None] + state.area[None, :])[..., None] * eps
    parts = lam[rows][:, None] + lam[None, :]
    s = np.log((np.maximum(union, 0.0) + a) / (np.maximum(parts, 0.0) + a)).sum(axis=-1)
    return np.concatenate([T, np.where(adjacent, s, 0.0)[..., None]], axis=-1), adjacent


UNSEEN = "unseen "


def unseen(train: list, policy, a, ctx) -> None:
    """Weights fitted on every ``train`` shape without the term and with each variant; merged
    labels of the unseen shapes by family."""
    test = sorted(k for k in M.PREP if k.startswith(UNSEEN))
    results, base = {}, None
    for spec in a.variants.split(","):
        motions, eps = spec.split(":")
        SPEC.update(motions=int(motions), eps=float(eps))
        M.ROWS.clear()
        with ctx.Pool(2) as pool:
            if base is None:
                cost = M.fitted_cost(train, policy, pool, a.corpus_share, cols=list(range(len(TERM_NAMES))))
                base = np.array(pool.starmap(M.shape_error, [(m, cost) for m in test]))
                results["without slippage (unseen)"] = M.group_scores(test, cost, pool)
            cost = M.fitted_cost(train, policy, pool, a.corpus_share)
            errs = np.array(pool.starmap(M.shape_error, [(m, cost) for m in test]))
            results[f"slippage, {motions} motion(s), eps {eps} (unseen)"] = M.group_scores(test, cost, pool)
        d = errs - base
        print(f"{spec}: shapes' mean {errs.mean():.4f} against {base.mean():.4f}, paired {d.mean():+.4f} "
              f"± {d.std(ddof=1) / np.sqrt(len(d)):.4f} (standard error; {int((d < 0).sum())} better, "
              f"{int((d > 0).sum())} worse of {len(d)})", flush=True)
    M.report(results, a.out)


# the shared merge loop and row recorder read this script's terms
M.use_terms(pair_terms, new_state, len(NAMES))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True)
    ap.add_argument("--prep", required=True, help="merge_cv.py's preparation of the same captures")
    ap.add_argument("--variants", default="1:1e-3", help="comma-separated motions:eps")
    ap.add_argument("--corpus-share", type=float, default=0.5)
    ap.add_argument("--unseen-capture", default=None)
    ap.add_argument("--unseen-prep", default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    M.load_prep(Path(a.prep))
    keys = sorted(M.PREP)
    tasks = [(f, "") for f in sorted(Path(a.capture).glob("*.pkl"))]
    if a.unseen_prep:
        for f in sorted(Path(a.unseen_prep).glob("*.pkl")):
            d = pickle.load(open(f, "rb"))
            d["key"], d["group"] = UNSEEN + d["key"], UNSEEN + d["group"]
            M.PREP[d["key"]] = d
        tasks += [(f, UNSEEN) for f in sorted(Path(a.unseen_capture).glob("*.pkl"))]
    ctx = get_context("fork")
    with ctx.Pool(2) as pool:
        for key, sums in pool.starmap(slip_sums, tasks):
            for over, C in zip(M.PREP[key]["overs"], sums):
                assert len(C) == len(over["graph"][0]), key
                over["slip"] = C
    policy = M.hand_set_policy(1)
    if a.unseen_prep:
        unseen(keys, policy, a, ctx)
        return

    def setup(spec: str) -> str:
        motions, eps = spec.split(":")
        SPEC.update(motions=int(motions), eps=float(eps))
        return f"slippage, {motions} motion(s), eps {eps}"

    results = M.held_out_with_term("slippage", NAMES, a.variants.split(","), setup, policy, ctx, a.corpus_share)
    M.report(results, a.out)


if __name__ == "__main__":
    main()
