"""The hidden concavity term's definition, chosen held out by group (experiments/results/generality_hidden_creases.md).

A face's openness (:mod:`torchakvf.parts.openness`) is the share of its hemisphere rays that
travel a reach free; a concave dual edge bending more than a threshold is hidden by
1 - min(1, o / enough), o its two faces' mean openness. Each variant sets those constants
(rays, reach as a multiple of sqrt(area), "inf" for rays to infinity, enough, the bend in
degrees), recomputes the hidden sums of every captured over-segmentation (the package's code
with the variant's constants) and scores merge_cv.py's fit held out by group, beside the fit
without the term.

    PYTHONPATH=$PWD python3 experiments/generality/hidden_concavity_cv.py --capture /tmp/capture \\
        --prep /tmp/capture_prep --variants "16:0.25:0.5:10,16:0.25:1:10,16:0.25:0.25:10,16:inf:0.5:10"
"""
from __future__ import annotations

import argparse
import math
import pickle
import sys
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import merge_cv as M  # noqa: E402

from torchakvf.options import MergeWeights  # noqa: E402
from torchakvf.parts import openness  # noqa: E402
from torchakvf.parts.concavity import dual_edges  # noqa: E402
from torchakvf.parts.grouping import compact_labels  # noqa: E402
from torchakvf.parts.merge import boundary_bends  # noqa: E402
from torchakvf.parts.merge_terms import TERM_NAMES  # noqa: E402


def set_variant(spec: str) -> None:
    """Sets the openness constants of ``spec`` = "rays:reach:enough:bend degrees"."""
    rays, reach, enough, bend = spec.split(":")
    openness.OPEN_RAYS, openness.OPEN_ENOUGH = int(rays), float(enough)
    openness.OPEN_REACH = math.inf if reach == "inf" else float(reach)
    openness.HIDDEN_BEND = math.radians(float(bend))


def hidden_sums(args) -> tuple[str, list]:
    """(key, [K, K] hidden sums of each over-segmentation) of one capture under ``spec``."""
    cap_file, spec = args
    set_variant(spec)
    rec = pickle.load(open(cap_file, "rb"))
    mesh = rec["mesh"]
    dual = dual_edges(mesh.vertices, mesh.faces)
    cav, _ = boundary_bends(dual)
    faces_open = openness.FaceOpenness(mesh.vertices, mesh.faces)
    out = []
    for o in rec["overs"]:
        lab, K = compact_labels(o["labels"])
        la, lb = lab[dual.pairs[:, 0]], lab[dual.pairs[:, 1]]
        cut = (la != lb) & (la >= 0) & (lb >= 0)
        hid = faces_open.hidden_bends(dual, cav, cut)
        H = np.bincount(la[cut] * K + lb[cut], weights=hid[cut], minlength=K * K).reshape(K, K)
        out.append(H + H.T)
    return rec["key"], out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True)
    ap.add_argument("--prep", required=True, help="merge_cv.py's preparation of the same captures")
    ap.add_argument("--variants", required=True, help="comma-separated rays:reach:enough:bend")
    ap.add_argument("--corpus-share", type=float, default=0.5)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    M.load_prep(Path(a.prep))
    keys = sorted(M.PREP)
    files = sorted(Path(a.capture).glob("*.pkl"))
    policy = M.Cost.of(MergeWeights.hand_set())
    results = {}
    ctx = get_context("fork")
    with ctx.Pool(2) as pool:
        base = [c for c, name in enumerate(TERM_NAMES) if name != "hidden_concavity"]
        results["without hidden_concavity (held out)"], _ = M.held_out(policy, pool, a.corpus_share, cols=base)
    for spec in a.variants.split(","):
        with ctx.Pool(2) as pool:
            for key, sums in pool.map(hidden_sums, [(f, spec) for f in files]):
                for over, H in zip(M.PREP[key]["overs"], sums):
                    over["sums"]["hidden"] = H
        M.ROWS.clear()
        name = "rays {} reach {} enough {} bend {}°".format(*spec.split(":"))
        with ctx.Pool(2) as pool:           # forked after the sums are in: the workers read them
            scores, _ = M.held_out(policy, pool, a.corpus_share)
            every = M.fitted_cost(keys, policy, pool, a.corpus_share)
        print(name, "fitted on all:", M.weight_fields(every), flush=True)
        results[f"{name} (held out)"] = scores
    text = M.table(results)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
