"""The shipped merge weights with terms switched off or another Rand exponent, on capture.py's
over-segmentations: merged labels before the graph cut, per group, and the oracle merge (each
piece joined to the truth part holding most of its area) as the bound any merge has.

In-sample for the weights (the shipped ones were fitted on these shapes): a direction, not a
held-out score. experiments/results/generality_not_adopted.md, "Where the wheels and pipe
fittings are lost".

    PYTHONPATH=$PWD python3 experiments/generality/merge_ablation.py '/tmp/capture/corpus_*.pkl'
"""
from __future__ import annotations

import dataclasses
import glob
import pickle
import sys
from multiprocessing import Pool

import numpy as np

from torchakvf.evaluate.metrics import rand_index_error
from torchakvf.options import MergeWeights
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.merge import greedy_merge, mesh_sums_inputs, region_graph
from torchakvf.parts.sightlines import SightLines

#: name -> MergeWeights changes
VARIANTS = {"shipped": {}, "no_sight": dict(sight=0.0, sight_excess=0.0), "gamma0": dict(rand_gamma=0.0),
            "gamma0.25": dict(rand_gamma=0.25)}


def oracle_labels(over: np.ndarray, truth: np.ndarray, area: np.ndarray) -> np.ndarray:
    """[F] each piece of ``over`` labelled with the truth part holding most of its area."""
    out = np.empty_like(truth)
    for p in np.unique(over):
        m = over == p
        out[m] = np.bincount(truth[m], weights=area[m]).argmax()
    return out


def shape_scores(path: str) -> tuple[str, dict]:
    rec = pickle.load(open(path, "rb"))
    mesh = rec["mesh"]
    V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    dual, sight = dual_edges(V, F), SightLines(V, F)
    shipped = MergeWeights()
    centroids, thickness = mesh_sums_inputs(V, F, shipped)
    scores: dict = {}
    for truth in rec["gts"]:
        truth = truth.astype(np.int64)
        k = int(truth.max()) + 1
        over = rec["overs"][rec["k_over"][k]]
        for name, changes in VARIANTS.items():
            w = dataclasses.replace(shipped, **changes)
            g = region_graph(over["labels"], dual, over["unit"], over["area"], w.crease_angle,
                             centroids=centroids, thickness=thickness, sight=sight)
            new_id, _ = greedy_merge(g, k, w)
            merged = mesh.labels_to_input_faces(np.where(g.labels >= 0, new_id[np.maximum(g.labels, 0)], -1))
            scores.setdefault(name, []).append(rand_index_error(np.maximum(merged, 0), truth))
        pieces = mesh.labels_to_input_faces(np.asarray(over["labels"]))
        area = mesh.to_input_faces(np.asarray(over["area"]))
        scores.setdefault("oracle", []).append(rand_index_error(oracle_labels(pieces, truth, area), truth))
    return rec["group"], {name: float(np.mean(v)) for name, v in scores.items()}


def main() -> None:
    files = sorted(glob.glob(sys.argv[1]))
    with Pool(2) as pool:
        rows = pool.map(shape_scores, files, chunksize=4)
    groups: dict = {}
    for group, scores in rows:
        groups.setdefault(group, []).append(scores)
    names = list(VARIANTS) + ["oracle"]
    print("| group | shapes | " + " | ".join(names) + " |")
    print("|---|---:|" + "---:|" * len(names))
    for group, rows_g in sorted(groups.items()):
        cells = " | ".join(f"{np.mean([r[n] for r in rows_g]):.3f}" for n in names)
        print(f"| {group} | {len(rows_g)} | {cells} |")
    means = [np.mean([np.mean([r[n] for r in g]) for g in groups.values()]) for n in names]
    print("| **mean over groups** | | " + " | ".join(f"{m:.4f}" for m in means) + " |")


if __name__ == "__main__":
    main()
