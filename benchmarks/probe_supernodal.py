"""Probe (issue 13): would CHOLMOD's *supernodal* factor speed up the full-resolution solve?

``torchakvf.solvers.cholmod`` asks CHOLMOD for its simplicial LDLᵀ factor only (the supernodal
module is GPL; the package uses the LGPL modules). cholespy's extension module has the
supernodal module compiled in, linked to its own reference BLAS. This probe measures, on the
matrix the engine factors (R - σS1 at σ = -1 of a cleaned full-resolution PSB mesh, remedy
"smooth"), one thread, wall time:

* the analysis, the first numeric factor and a second one (the same pattern, new values, as a
  trial shift would make), and one solve of 1, 4 and 8 right-hand sides (best of 7), for the
  simplicial factor (what the engine uses) and the supernodal LLᵀ factor;
* with ``--mkl``, the same after loading torch's ``libtorch_cpu`` with RTLD_GLOBAL first, so the
  supernodal factor's BLAS calls (dgemm, dsyrk, dtrsm, dpotrf) bind to torch's MKL instead of
  cholespy's reference BLAS (a process-wide side effect: a probe, not something the package
  could do);
* the largest entry of A X - B for the 4-column solve, as a check that both factors solve.

The Krylov solver makes about 34 four-column solves per full-resolution mesh (136 right-hand
sides on PSB 21), so the factor's time and 34 x the 4-column solve's are what to compare.

Usage::

    OMP_NUM_THREADS=1 python benchmarks/probe_supernodal.py --ids 21 301
    OMP_NUM_THREADS=1 python benchmarks/probe_supernodal.py --ids 21 301 --mkl
"""
from __future__ import annotations

import argparse
import ctypes as C
import glob
import os
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402
import torch  # noqa: E402

_SUPERNODAL = 2


def _load_mkl_globally() -> None:
    lib = glob.glob(os.path.join(os.path.dirname(torch.__file__), "lib", "libtorch_cpu.so"))
    if not lib:
        sys.exit("libtorch_cpu.so not found next to torch")
    C.CDLL(lib[0], mode=C.RTLD_GLOBAL)


def _shifted_lower(mesh_path: str) -> sp.csc_matrix:
    """The lower triangle (CSC, diagonal first in each column) of R + S1 (σ = -1)."""
    import torchakvf as ta
    from torchakvf.mesh.batch import MeshBatch
    from torchakvf.operators.killing import killing_operator
    from torchakvf.solvers.factor import _lower_pattern

    system = killing_operator(MeshBatch.from_meshes([ta.load_mesh(mesh_path)]))
    r, c, v, n = system.block(0)
    n, rows, cols, base = _lower_pattern(r, c, v, n)
    values = torch.cat([base, system.mass.to(torch.float64)])          # + S1 on the diagonal
    lower = sp.csc_matrix((values.numpy(), (rows.numpy(), cols.numpy())), shape=(n, n))
    lower.sum_duplicates()
    lower.sort_indices()
    return lower


def _measure(lower: sp.csc_matrix, supernodal: bool) -> dict:
    from torchakvf.solvers import cholmod as ch

    lib = ch.library()
    if lib is None:
        sys.exit("CHOLMOD is not usable through cholespy here")
    n = lower.shape[0]
    common = ch._Common()
    lib.cholmod_start(C.byref(common))
    common.print = 0
    common.supernodal = _SUPERNODAL if supernodal else ch._SIMPLICIAL
    common.final_ll = 1 if supernodal else 0
    indptr = np.ascontiguousarray(lower.indptr, dtype=np.int32)
    indices = np.ascontiguousarray(lower.indices, dtype=np.int32)
    values = np.ascontiguousarray(lower.data, dtype=np.float64)
    a = ch._Sparse(n, n, len(values), indptr.ctypes.data, indices.ctypes.data, None,
                   values.ctypes.data, None, -1, ch._INT, ch._REAL, ch._DOUBLE, 1, 1)
    out = {}
    t = time.perf_counter()
    factor = lib.cholmod_analyze(C.byref(a), C.byref(common))
    out["analyse ms"] = 1e3 * (time.perf_counter() - t)
    for name in ("factor ms", "refactor ms"):
        t = time.perf_counter()
        lib.cholmod_factorize(C.byref(a), factor, C.byref(common))
        out[name] = 1e3 * (time.perf_counter() - t)
    out["is_super"] = int(factor.contents.is_super)
    x_, y_, e_ = (C.POINTER(ch._Dense)() for _ in range(3))
    full = lower + sp.tril(lower, -1).T
    for k in (1, 4, 8):
        b = np.random.default_rng(0).standard_normal((k, n))
        dense = ch._Dense(n, k, n * k, n, b.ctypes.data, None, ch._REAL, ch._DOUBLE)
        best = np.inf
        for _ in range(7):
            t = time.perf_counter()
            lib.cholmod_solve2(ch._SYS_A, factor, C.byref(dense), None, C.byref(x_), None,
                               C.byref(y_), C.byref(e_), C.byref(common))
            best = min(best, time.perf_counter() - t)
        out[f"solve{k} ms"] = 1e3 * best
        if k == 4:
            x = np.ctypeslib.as_array(C.cast(x_.contents.x, C.POINTER(C.c_double)), shape=(k, n))
            out["max |AX - B|"] = float(np.abs(full @ x.T - b.T).max())
    for d in (x_, y_, e_):
        lib.cholmod_free_dense(C.byref(d), C.byref(common))
    lib.cholmod_free_factor(C.byref(factor), C.byref(common))
    lib.cholmod_finish(C.byref(common))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ids", type=int, nargs="+", default=[21, 301])
    ap.add_argument("--psb", default=None)
    ap.add_argument("--mkl", action="store_true", help="bind the BLAS calls to torch's MKL first")
    a = ap.parse_args(argv)
    if a.mkl:
        _load_mkl_globally()
    torch.set_num_threads(1)
    from torchakvf.evaluate.psb import default_psb_root

    root = a.psb or default_psb_root()
    if root is None:
        print("no PSB folder (set TORCHAKVF_PSB)", file=sys.stderr)
        return 2
    blas = "torch's MKL" if a.mkl else "cholespy's reference BLAS"
    print("| mesh | edges | factor | BLAS | analyse ms | factor ms | refactor ms | solve1 ms | "
          "solve4 ms | solve8 ms | 34 x solve4 + refactor ms | max abs(AX - B) |")
    print("|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for mid in a.ids:
        lower = _shifted_lower(os.path.join(str(root), "meshes", f"{mid}.off.gz"))
        for supernodal in (False, True):
            m = _measure(lower, supernodal)
            kind = "supernodal LLᵀ" if supernodal else "simplicial LDLᵀ (engine)"
            print(f"| {mid} | {lower.shape[0]} | {kind} | {blas if supernodal else '-'} | "
                  f"{m['analyse ms']:.0f} | {m['factor ms']:.0f} | {m['refactor ms']:.0f} | "
                  f"{m['solve1 ms']:.1f} | {m['solve4 ms']:.1f} | {m['solve8 ms']:.1f} | "
                  f"{34 * m['solve4 ms'] + m['refactor ms']:.0f} | {m['max |AX - B|']:.1e} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
