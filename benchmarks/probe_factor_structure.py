"""Two ways to make the CPU factor of ``R - σS1`` cheaper, probed against the engine's (issue 13):
CHOLMOD's simplicial LDLᵀ with AMD on the operator's own graph.

R = A + 2 Dᵀ S0⁻¹ D (killing.py): A couples edges sharing a face (1-ring), the Dᵀ S0⁻¹ D term
every two edges sharing a vertex (2-ring), and that is R's pattern. So:

1. **Augmented system** ``K = [[A - σS1, Ďᵀ], [Ď, -I]]`` with Ď = diag(sqrt(2 / a_v)) D, so
   that Ďᵀ Ď = 2 Dᵀ S0⁻¹ D: order E + V, 1-ring pattern, and its Schur complement on the edges
   is ``R - σS1``. Reported: fill, flops, factor and 4-column solve times, the residual of K x = b,
   and the negative pivots against what Sylvester's law requires (V + those of R - σS1).
2. **Orderings of a sparser graph**: AMD and METIS computed on the 1-ring graph (edges sharing
   a face), applied to ``R - σS1`` as a given permutation; AMD and METIS on R's own graph for
   comparison.

One thread; σ = 160 (the Krylov solver's interior shift at n = 32); PSB meshes cleaned as
``ta.akvf`` cleans them, at full resolution.

    OMP_NUM_THREADS=1 python benchmarks/probe_factor_structure.py --out benchmarks/results/probe_factor_structure.md
"""
from __future__ import annotations

import argparse
import ctypes as C
import platform
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch

from torchakvf.evaluate.psb import default_psb_root
from torchakvf.fields.akvf import as_batch
from torchakvf.io import load_mesh
from torchakvf.operators import dec, killing
from torchakvf.solvers import cholmod
from timing import one_thread_on_psb, write_report

SIGMA = 160.0
#: CHOLMOD_NATURAL: the matrix's own order (a permutation applied beforehand).
NATURAL = 0


def lower(m) -> sp.csc_matrix:
    low = sp.tril(m).tocsc()
    low.sort_indices()
    return low


def factor(m, ordering):
    """(CholmodFactor analysed with ``ordering`` (a name, or NATURAL), analysis seconds, Perm)."""
    low = lower(m)
    saved = dict(cholmod.ORDERINGS)
    try:
        cholmod.ORDERINGS["natural"] = NATURAL
        t = time.perf_counter()
        f = cholmod.CholmodFactor(m.shape[0], low.indptr, low.indices, low.data,
                                  ordering="natural" if ordering == NATURAL else ordering)
        seconds = time.perf_counter() - t
    finally:
        cholmod.ORDERINGS.clear()
        cholmod.ORDERINGS.update(saved)
    perm = np.ctypeslib.as_array(C.cast(f._factor.contents.Perm, C.POINTER(C.c_int)), shape=(m.shape[0],)).copy()
    return f, seconds, perm


def numeric(f, m, repeat: int = 2) -> float:
    low = lower(m)
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        f.factorize(low.data, indefinite=True)
        best = min(best, time.perf_counter() - t)
    return best


def operator_parts(path: Path):
    """(R - σS1 as CSC, A - σS1, Ď, the mesh's face_edges) of a cleaned full-resolution mesh."""
    seen = {}
    gram = dec.weighted_gram

    def recording(dmat, weights):
        seen["d"], seen["w"] = dmat, weights
        return gram(dmat, weights)

    batch = as_batch(load_mesh(path))
    killing.dec.weighted_gram = recording
    try:
        system = killing.killing_operator(batch)
    finally:
        killing.dec.weighted_gram = gram
    idx = system.stiffness.indices().numpy()
    n = system.stiffness.shape[0]
    r = sp.csr_matrix((system.stiffness.values().numpy(), (idx[0], idx[1])), shape=(n, n))
    s = sp.diags(system.mass.numpy())
    d_idx = seen["d"].indices().numpy()
    d = sp.csr_matrix((seen["d"].values().numpy(), (d_idx[0], d_idx[1])), shape=seen["d"].shape)
    w = seen["w"].numpy()                        # 1 / a_v: R's vertex term is 2 Dᵀ diag(w) D
    a = (r - 2.0 * (d.T @ sp.diags(w) @ d)).tocsr()
    scaled_d = sp.diags(np.sqrt(2.0 * w)) @ d    # Ďᵀ Ď = 2 Dᵀ diag(w) D
    return (r - SIGMA * s).tocsc(), (a - SIGMA * s).tocsr(), scaled_d.tocsr(), batch.face_edges.numpy()


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--psb", type=Path, default=default_psb_root())
    ap.add_argument("--ids", default="21,301,1")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    one_thread_on_psb(ap, args)
    aug_rows, order_rows = [], []
    rng = np.random.default_rng(0)
    for mid in [int(v) for v in args.ids.split(",")]:
        m, a, dd, fe = operator_parts(args.psb / "meshes" / f"{mid}.off.gz")
        e, v = m.shape[0], dd.shape[0]
        k = sp.bmat([[a, dd.T], [dd, -sp.eye(v)]]).tocsc()
        for name, mat, size in (("R - σS1", m, e), ("augmented", k, e + v)):
            f, t_order, _ = factor(mat, "amd")
            t_fac = numeric(f, mat)
            b = rng.standard_normal((4, size))
            f.usable = True                     # solve even past the pivot floor, to report it
            t = time.perf_counter()
            x = f.solve_rows(torch.from_numpy(b)).numpy()
            t_solve = time.perf_counter() - t
            res = float(np.abs(mat @ x.T - b.T).max() / np.abs(b).max())
            aug_rows.append(f"| {mid} | {name} | {size} | {mat.nnz:,} | {f.factor_nonzeros / 1e6:.2f}M | "
                            f"{f.factor_flops / 1e6:.0f} | {1e3 * t_order:.0f} | {1e3 * t_fac:.0f} | "
                            f"{1e3 * t_solve:.1f} | {res:.0e} | {f.negative_pivots:,} |")
        # the 1-ring graph: edges sharing a face (and the diagonal)
        rows = np.repeat(fe, 3, axis=1).ravel()
        cols = np.tile(fe, (1, 3)).ravel()
        ring1 = sp.csc_matrix((np.ones(len(rows)), (rows, cols)), shape=(e, e))
        ring1.data[:] = 1.0
        ring1 = (ring1 + 10.0 * sp.eye(e)).tocsc()
        for name, graph, ordering in (("AMD on R", m, "amd"), ("METIS on R", m, "metis"),
                                      ("AMD on the 1-ring graph", ring1, "amd"),
                                      ("METIS on the 1-ring graph", ring1, "metis")):
            f, t_order, perm = factor(graph, ordering)
            if graph is not m:
                permuted = m[perm][:, perm].tocsc()
                f, _, _ = factor(permuted, NATURAL)
                t_fac = numeric(f, permuted, repeat=1)
            else:
                t_fac = numeric(f, m)
            order_rows.append(f"| {mid} | {name} | {f.factor_nonzeros / 1e6:.2f}M | {f.factor_flops / 1e6:,.0f} | "
                              f"{1e3 * t_order:.0f} | {1e3 * t_fac:,.0f} |")
        print(mid, "done", flush=True)
    text = "\n".join([
        "# The CPU factor of R - σS1: an augmented 1-ring system, and orderings of the 1-ring graph",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, {platform.machine()}, "
        f"one thread; σ = {SIGMA:g}; CHOLMOD simplicial LDLᵀ (benchmarks/probe_factor_structure.py)",
        "",
        "## 1. The augmented system [[A - σS1, Ďᵀ], [Ď, -I]] against R - σS1 (AMD both)",
        "",
        "| mesh | matrix | order | nnz | nnz(L) | MFLOP | analyse ms | factor ms | solve4 ms | rel. residual | negative pivots |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
        *aug_rows,
        "",
        "## 2. Orderings applied to R - σS1",
        "",
        "| mesh | ordering | nnz(L) | MFLOP | order ms | factor ms |",
        "|---:|---|---:|---:|---:|---:|",
        *order_rows,
        "",
    ])
    write_report(text, args.out)


if __name__ == "__main__":
    main()
