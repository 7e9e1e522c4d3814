"""Probe (issue 13): would MKL PARDISO, a supernodal sparse Cholesky, make full-resolution
``ta.akvf`` faster than cholespy's simplicial CHOLMOD? Not a dependency of torchakvf: this
script needs ``pip install mkl`` (it calls ``libmkl_rt`` through ctypes) and exits 0 with a
message where that is missing.

Per PSB mesh (cleaned, full resolution, remedy "smooth", shift -1), in one process:

1. the factor alone: cholespy (CHOLMOD simplicial, nested dissection), and PARDISO (mtype 2,
   real SPD) with AMD (iparm(2) = 0) and METIS (iparm(2) = 2) orderings: analysis, numeric
   factor, and one solve of 4 right-hand sides (the Krylov solver's block); nnz(L) and MFLOP
   as PARDISO reports them;
2. end to end: ``ta.akvf(mesh, n=32)`` defaults on PSB 1, 21, 121, 181, 301, best of 3 rounds
   alternating the order, with the CHOLMOD factor and with a PARDISO factor (AMD) substituted
   for ``mesh_factor``; eigenvalues compared.

Usage::

    pip install mkl
    python experiments/solver/factor_engines_pardiso.py --threading seq --out /tmp/factor_engines_pardiso.md
"""
from __future__ import annotations

import argparse
import ctypes
import sys
import time
from pathlib import Path

import numpy as np
import torch

import torchakvf as ta
from torchakvf.bench.script_tools import best_of
from torchakvf.errors import SolverError
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.io import load_mesh
from torchakvf.mesh import clean_mesh
from torchakvf.operators import killing_operator
from torchakvf.solvers import factor as factor_module
from torchakvf.solvers.factor import SHIFTS, ShiftedFactor

_IP = ctypes.POINTER(ctypes.c_int32)


def _i(v: int):
    return ctypes.byref(ctypes.c_int32(v))


class PardisoFactor:
    """(R - σS1) factored by PARDISO at the first shift of SHIFTS that is definite (PARDISO's
    mtype 2 reports error -4 at a non-positive pivot); ``solve`` as ShiftedFactor's."""

    def __init__(self, mkl, rows, cols, vals, mass, name="mesh", ordering=0):
        self.mkl, self.n, self.device = mkl, len(mass), mass.device
        up = rows <= cols
        r, c, v = rows[up].numpy(), cols[up].numpy(), vals[up].numpy()
        crow = np.zeros(self.n + 1, np.int64)
        np.cumsum(np.bincount(r, minlength=self.n), out=crow[1:])
        diag = crow[:-1]                         # sorted COO: each upper row starts at its diagonal
        if not (c[diag] == np.arange(self.n)).all():
            raise SolverError(f"{name}: a zero diagonal entry")
        self.ia, self.ja = (crow + 1).astype(np.int32), (c + 1).astype(np.int32)
        m = mass.numpy()
        for sigma in SHIFTS:
            self.a = v.astype(np.float64).copy()
            self.a[diag] -= sigma * m
            self.pt, self.iparm = np.zeros(64, np.int64), np.zeros(64, np.int32)
            self.iparm[[0, 1, 9, 17, 18]] = [1, ordering, 13, -1, -1]
            if self.call(12, None, None, 1) == 0:
                self.sigma = sigma
                return
            self.call(-1, None, None, 1)
        raise SolverError(f"{name}: no shift made R - σS1 positive definite")

    def call(self, phase, b, x, nrhs):
        err = ctypes.c_int32(0)
        ptr = lambda a: None if a is None else a.ctypes.data_as(ctypes.c_void_p)  # noqa: E731
        self.mkl.pardiso(ptr(self.pt), _i(1), _i(1), _i(2), _i(phase), _i(self.n), ptr(self.a),
                         self.ia.ctypes.data_as(_IP), self.ja.ctypes.data_as(_IP), None, _i(nrhs),
                         self.iparm.ctypes.data_as(_IP), _i(0), ptr(b), ptr(x), ctypes.byref(err))
        return err.value

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        b = np.ascontiguousarray(rhs.numpy().T)        # PARDISO: column-major [n, k] = rows [k, n]
        x = np.empty_like(b)
        if self.call(33, b, x, b.shape[0]) != 0:
            raise SolverError("PARDISO solve failed")
        return torch.from_numpy(np.ascontiguousarray(x.T))

    def __del__(self):
        try:
            self.call(-1, None, None, 1)
        except Exception:
            pass


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--psb", type=Path, default=default_psb_root())
    p.add_argument("--threading", choices=["seq", "gnu"], default="seq",
                   help="MKL threading layer: sequential, or GNU OpenMP (torch's runtime)")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    if args.psb is None:
        p.error("no PSB found: pass --psb or set TORCHAKVF_PSB")
    try:
        mkl = ctypes.CDLL("libmkl_rt.so.3")
    except OSError:
        print("libmkl_rt not found (pip install mkl): nothing to probe")
        return 0
    mkl.MKL_Set_Threading_Layer(ctypes.c_int(1 if args.threading == "seq" else 3))
    lines = ["# Probe: MKL PARDISO against cholespy (CHOLMOD simplicial)", "",
             f"- torch {torch.__version__} ({torch.get_num_threads()} threads), MKL threading layer "
             f"{args.threading}; seconds are wall time, best of 5 (factor) / 10 (solves)", "",
             "| mesh | edges | cholespy factor ms | solve4 ms | PARDISO AMD analyse + numeric ms | solve4 ms "
             "| nnz(L) | MFLOP | PARDISO METIS analyse + numeric ms | solve4 ms | nnz(L) | MFLOP | max rel. diff |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for i in (21, 301):
        mesh = clean_mesh(load_mesh(args.psb / "meshes" / f"{i}.off.gz"))
        system = killing_operator(ta.MeshBatch.from_meshes([mesh]), remedy="smooth")
        r, c, v, n = system.block(0)
        t_chol, chol = best_of(lambda: ShiftedFactor(r, c, v, system.mass), 5)
        rhs = torch.randn(n, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        t_cs, ref = best_of(lambda: chol.solve(rhs), 10)
        row = [str(i), str(n), f"{t_chol * 1e3:.0f}", f"{t_cs * 1e3:.1f}"]
        diff = 0.0
        for ordering in (0, 2):
            pf = PardisoFactor(mkl, r, c, v, system.mass, ordering=ordering)
            t11 = t22 = float("inf")
            for _ in range(5):
                pf.call(-1, None, None, 1)
                pf.pt[:] = 0
                s = time.perf_counter()
                pf.call(11, None, None, 1)
                t11 = min(t11, time.perf_counter() - s)
                s = time.perf_counter()
                pf.call(22, None, None, 1)
                t22 = min(t22, time.perf_counter() - s)
            t_ps, x = best_of(lambda: pf.solve(rhs), 10)
            diff = max(diff, float((x - ref).abs().max() / ref.abs().max()))
            row += [f"{t11 * 1e3:.0f} + {t22 * 1e3:.0f}", f"{t_ps * 1e3:.1f}",
                    f"{int(pf.iparm[17]):,}", str(int(pf.iparm[18]))]
        lines.append("| " + " | ".join(row + [f"{diff:.0e}"]) + " |")
        print(lines[-1], flush=True)

    meshes = [load_mesh(args.psb / "meshes" / f"{i}.off.gz") for i in (1, 21, 121, 181, 301)]
    ta.akvf(meshes[0], n=8)
    akvf_module = sys.modules["torchakvf.solvers.akvf_solver"]
    original = factor_module.mesh_factor

    def pardiso_factor(system, b, name, device=None):
        r, c, v, _ = system.block(b)
        lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
        return PardisoFactor(mkl, r, c, v, system.mass[lo:hi], name)

    times, results = {"cholespy": float("inf"), "pardiso": float("inf")}, {}
    sides = [("cholespy", original), ("pardiso", pardiso_factor)]
    try:
        for rnd in range(3):
            for name, fac in (sides if rnd % 2 == 0 else sides[::-1]):
                akvf_module.mesh_factor = fac
                s = time.perf_counter()
                results[name] = [ta.akvf(m, n=32) for m in meshes]
                times[name] = min(times[name], time.perf_counter() - s)
    finally:
        akvf_module.mesh_factor = original
    dlam = max(float(((a.eigenvalues - b.eigenvalues).abs() / b.eigenvalues.abs().clamp(min=1)).max())
               for a, b in zip(results["pardiso"], results["cholespy"]))
    res = max(float(a.residuals.max()) for a in results["pardiso"])
    lines += ["", f"End to end, `ta.akvf(mesh, n=32)` defaults on PSB 1, 21, 121, 181, 301 (best of 3 "
              f"rounds, order alternating): cholespy {times['cholespy']:.2f} s, PARDISO (AMD) "
              f"{times['pardiso']:.2f} s: **{times['cholespy'] / times['pardiso']:.2f}x**; largest "
              f"eigenvalue difference {dlam:.1e}, largest PARDISO-side residual {res:.1e}."]
    print(lines[-1])
    if args.out:
        args.out.write_text("\n".join(lines) + "\n")
        print(f"written to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
