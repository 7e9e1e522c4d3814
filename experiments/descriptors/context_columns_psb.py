"""Does the neighbourhood of every package column help beside the classical ones, and how much
of the gain's spread over categories is the model's seed? Tried, not shipped
(experiments/results/boundary_probability.md).

Per face of each cached PSB mesh (descriptor_pass cache version 6), beside the classical and the
48 package columns: ``pool`` adds the 48 columns diffused over the dual graph (lazy random walk,
P = (I + D⁻¹A)/2, after 2 and 8 steps: 96 columns); ``grad`` adds, per face, the largest
absolute difference of each of the 41 AKVF columns to an edge neighbour (41 columns);
``package`` and ``classical`` are learn_boundaries.py's rows. Each variant is fitted with the
model seeds given (learn_boundaries.py's protocol, seed 0 its own); the gains are paired with
the classical row of the same seed. Run from the repository root::

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice python experiments/descriptors/context_columns_psb.py \\
        CACHE PSB_DIR --seeds 0,1,2
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import descriptor_pass as dp  # noqa: E402
import learn_boundaries as lb  # noqa: E402

from torchakvf.parts.concavity import dual_edges  # noqa: E402
from torchakvf.parts.creases import dual_graph  # noqa: E402


def dual_adjacency(d: dict) -> sp.csr_matrix:
    """[F, F] 0/1 adjacency of faces sharing an edge."""
    v, f = d["packed_vertices"], d["packed_faces"].astype(np.int64)
    return dual_graph(dual_edges(v, f).pairs, len(f))


def classical(d):
    return np.concatenate([d[k] for k in lb.CLASSICAL], axis=1)


def package(d):
    return np.concatenate([d["akvf"], d["akvf_parts"], d["cues"], d["akvf_boundary"]], axis=1)


def pooled(d, steps=(2, 8)):
    adj = dual_adjacency(d)
    walk = 0.5 * (sp.eye(adj.shape[0]) + sp.diags(1 / np.asarray(adj.sum(1)).ravel().clip(1)) @ adj)
    x, done, out = package(d).astype(np.float64), 0, []
    for t in steps:
        for _ in range(t - done):
            x = walk @ x
        done = t
        out.append(x)
    return np.concatenate(out, axis=1)


def gradients(d):
    adj = dual_adjacency(d).tocoo()
    x = package(d)[:, :41].astype(np.float64)
    g = np.zeros_like(x)
    np.maximum.at(g, adj.row, np.abs(x[adj.row] - x[adj.col]))
    return g


VARIANTS = {
    "classical": classical,
    "package": lambda d: np.concatenate([classical(d), package(d)], axis=1),
    "pool": lambda d: np.concatenate([classical(d), package(d), pooled(d)], axis=1),
    "grad": lambda d: np.concatenate([classical(d), package(d), gradients(d)], axis=1),
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("cache")
    ap.add_argument("psb")
    ap.add_argument("--seeds", default="0,1,2")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    data, _ = dp.load_all(args.psb, Path(args.cache), compute=False)
    data = [d for d in data if "target" in d]
    seeds = [int(s) for s in args.seeds.split(",")]
    ap_of = {}
    for name, cols in VARIANTS.items():
        for s in seeds:
            lb.SEED = s
            ap_of[name, s] = {c: r["majority"] for c, r in lb.leave_one_category_out(data, cols).items()}
    cats = list(ap_of["classical", seeds[0]])
    for name in list(VARIANTS)[1:]:
        gains = np.array([[ap_of[name, s][c] - ap_of["classical", s][c] for c in cats] for s in seeds])
        for s, g in zip(seeds, gains):
            print(f"{name} seed {s}: {g.mean():+.3f} ± {g.std():.3f}, {(g > 0).sum()} of {len(g)} improved")
        mean = gains.mean(axis=0)
        print(f"{name}, per category over seeds: {mean.mean():+.3f} ± {mean.std():.3f}; "
              f"seed-to-seed std of a category's gain {gains.std(axis=0).mean():.3f}; "
              + ", ".join(f"{c} {g:+.3f}" for c, g in zip(cats, mean)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
