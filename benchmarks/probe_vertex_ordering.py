"""Probe: could a fill-reducing ordering of the *vertex* graph order the Killing operator's edges
better or sooner than CHOLMOD's AMD on the edge graph?

Why: on PSB 21 METIS's order of the edge graph has 0.85x AMD's nonzeros and 0.56x its flops
(benchmarks/results/cholmod_ordering.md), but computing it takes 270 ms against AMD's 22. The
vertex graph has a third of the nodes and half the entries per row. R couples the edges that
share a vertex. So a vertex separator S gives an edge separator: the edges with an end in S.
Ordering each edge by the later of its two vertices, ties by the earlier,
carries a vertex order to the edges at the cost of one sort.

Per PSB mesh (full resolution, cleaned, ``remedy="smooth"`` operator at σ = -1), one thread,
best of ``--repeat`` rounds, wall ms:

* **AMD (edge)** — what ``ta.akvf`` uses: CHOLMOD's AMD on the edge graph;
* **METIS (edge)** — METIS's nested dissection on the edge graph;
* **AMD / METIS / NESDIS (vertex)** — that ordering of the vertex graph, carried to the edges
  as above and given to CHOLMOD (``cholmod_analyze_p``, ordering GIVEN; CHOLMOD still
  postorders it). Analyse = the vertex ordering + the sort + the symbolic analysis.

nnz(L) and MFLOP are CHOLMOD's own prediction for each order.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/probe_vertex_ordering.py --out benchmarks/results/probe_vertex_ordering.md
"""
from __future__ import annotations

import argparse
import ctypes as C
import os
import platform
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch

from torchakvf.evaluate.psb import default_psb_root
from torchakvf.fields.akvf import as_batch
from torchakvf.io import load_mesh
from torchakvf.mesh import clean_mesh
from torchakvf.operators.killing import killing_operator
from torchakvf.solvers import cholmod as ch
from torchakvf.solvers.factor import _lower_pattern
from timing import write_report

REPO = Path(__file__).resolve().parents[1]


def lower_csc(n: int, rows, cols, vals) -> sp.csc_matrix:
    m = sp.csc_matrix((vals, (rows, cols)), shape=(n, n))
    m.sum_duplicates()
    m.sort_indices()
    return m


def analyse(lib, m: sp.csc_matrix, ordering: str | None = None, perm: np.ndarray | None = None,
            numeric: bool = True) -> dict:
    """Symbolic analysis (and numeric factor) of the lower-triangular CSC matrix m: ms, nnz(L),
    MFLOP and the permutation CHOLMOD chose."""
    common = ch._Common()
    lib.cholmod_start(C.byref(common))
    common.print = 0
    common.supernodal = ch._SIMPLICIAL
    ip = np.ascontiguousarray(m.indptr, np.int32)
    ii = np.ascontiguousarray(m.indices, np.int32)
    xx = np.ascontiguousarray(m.data, np.float64)
    a = ch._Sparse(m.shape[0], m.shape[0], len(xx), ip.ctypes.data, ii.ctypes.data, None,
                   xx.ctypes.data, None, -1, ch._INT, ch._REAL, ch._DOUBLE, 1, 1)
    p = None
    t = time.perf_counter()
    if perm is not None:
        common.nmethods = 1
        common.method[0].ordering = ch._GIVEN
        p = np.ascontiguousarray(perm, np.int32)
        factor = lib.cholmod_analyze_p(C.byref(a), p.ctypes.data, None, 0, C.byref(common))
    else:
        if ordering is not None:
            common.nmethods = 1
            common.method[0].ordering = ch.ORDERINGS[ordering]
        factor = lib.cholmod_analyze(C.byref(a), C.byref(common))
    t_analyse = time.perf_counter() - t
    f = factor.contents
    chosen = np.ctypeslib.as_array(C.cast(f.Perm, C.POINTER(C.c_int)), shape=(m.shape[0],)).copy()
    method = common.method[common.selected]
    t_numeric = float("nan")
    if numeric:
        t = time.perf_counter()
        lib.cholmod_factorize(C.byref(a), factor, C.byref(common))
        t_numeric = time.perf_counter() - t
    out = dict(analyse=t_analyse * 1e3, numeric=t_numeric * 1e3, nnz=float(method.lnz),
               mflop=float(method.fl) / 1e6, perm=chosen)
    lib.cholmod_free_factor(C.byref(factor), C.byref(common))
    lib.cholmod_finish(C.byref(common))
    return out


def edge_order_from_vertices(lib, edges: np.ndarray, n_vertices: int, ordering: str) -> np.ndarray:
    """The edges ordered by (later vertex, earlier vertex) in ``ordering``'s order of the vertex
    graph (its pattern: the mesh's edges and the diagonal)."""
    v = np.arange(n_vertices)
    graph = lower_csc(n_vertices, np.concatenate([edges.max(1), v]), np.concatenate([edges.min(1), v]),
                      np.concatenate([-np.ones(len(edges)), np.full(n_vertices, 20.0)]))
    rank = np.empty(n_vertices, np.int64)
    rank[analyse(lib, graph, ordering, numeric=False)["perm"]] = np.arange(n_vertices)
    a, b = rank[edges[:, 0]], rank[edges[:, 1]]
    return np.lexsort((np.minimum(a, b), np.maximum(a, b)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--psb", type=Path, default=default_psb_root())
    p.add_argument("--ids", type=int, nargs="+", default=[1, 21, 121, 181, 301])
    p.add_argument("--repeat", type=int, default=2)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    if args.psb is None or not (args.psb / "meshes").is_dir():
        p.error(f"no PSB meshes at {args.psb}: pass --psb or set TORCHAKVF_PSB")
    lib = ch.library()
    if lib is None:
        p.error("CHOLMOD cannot be called directly here (cholmod.library() is None)")
    lib.cholmod_analyze_p.restype = C.POINTER(ch._Factor)
    lib.cholmod_analyze_p.argtypes = [C.c_void_p, C.c_void_p, C.c_void_p, C.c_size_t, C.c_void_p]
    torch.set_num_threads(1)
    sides = ["AMD (edge)", "METIS (edge)", "AMD (vertex)", "METIS (vertex)", "NESDIS (vertex)"]
    rows = []
    for i in args.ids:
        batch = as_batch(clean_mesh(load_mesh(args.psb / "meshes" / f"{i}.off.gz")))
        system = killing_operator(batch, remedy="smooth")
        idx, vals = system.stiffness.indices(), system.stiffness.values()
        n, r, c, v = _lower_pattern(idx[0], idx[1], vals, len(system.mass))
        shifted = lower_csc(n, r.numpy(), c.numpy(), torch.cat([v, system.mass.to(torch.float64)]).numpy())
        edges = batch.edges.numpy()
        best: dict = {}
        for _ in range(args.repeat):
            for side in sides:
                name, graph = side.split(" (")
                if graph == "edge)":
                    res = analyse(lib, shifted, name.lower())
                else:
                    t = time.perf_counter()
                    order = edge_order_from_vertices(lib, edges, len(batch.verts), name.lower())
                    t_order = (time.perf_counter() - t) * 1e3
                    res = analyse(lib, shifted, perm=order)
                    res["analyse"] += t_order
                b = best.setdefault(side, dict(res))
                for key in ("analyse", "numeric"):
                    b[key] = min(b[key], res[key])
        rows.append((i, n, best))
        print(i, n, {s: (round(b["analyse"]), round(b["numeric"]), int(b["nnz"])) for s, b in best.items()},
              flush=True)

    lines = [
        "# Probe: the edges ordered from a vertex ordering, against AMD and METIS on the edge graph",
        "",
        f"- {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; torch {torch.__version__}, numpy "
        f"{np.__version__}, python {platform.python_version()}, {os.cpu_count()} CPUs, one thread; "
        f"best of {args.repeat} interleaved rounds, wall ms (benchmarks/probe_vertex_ordering.py)",
        "- matrix: R - σS1 at σ = -1 of the full-resolution mesh (remedy smooth), simplicial LDLᵀ; "
        "'(vertex)': that ordering of the vertex graph carried to the edges (each edge at its later "
        "vertex), analyse includes the vertex ordering",
        "",
        "| mesh | edges | ordering | analyse ms | numeric ms | total ms | nnz(L) | MFLOP | total / AMD (edge) |",
        "|---:|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for i, n, best in rows:
        base = best["AMD (edge)"]["analyse"] + best["AMD (edge)"]["numeric"]
        for side in sides:
            b = best[side]
            total = b["analyse"] + b["numeric"]
            lines.append(f"| {i} | {n} | {side} | {b['analyse']:.0f} | {b['numeric']:.0f} | {total:.0f} | "
                         f"{b['nnz']:,.0f} | {b['mflop']:.0f} | {total / base:.2f} |")
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
