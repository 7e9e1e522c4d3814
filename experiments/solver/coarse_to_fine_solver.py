"""Probe: coarse-to-fine as a *solver* (issue 13) — does a decimated mesh's solve, prolonged to
the full mesh's edges and refined there by the segmented LOBPCG, beat the full-resolution
factor-and-Krylov solve that ``ta.akvf`` does today?

Per PSB mesh (cleaned, full resolution), one thread, process CPU time:

1. **Today's path**: ``ta.akvf(mesh, n)`` (CHOLMOD factor of R - σS1 + block Krylov), timed.
2. **The coarse stage** a refinement would pay first: ``coarse_mesh(mesh, --coarse)``
   (decimation + surface map), ``ta.akvf`` on it with n + 16 fields, and the prolongation
   ``P`` [E_fine, E_coarse]: each fine edge i->j takes the coarse Whitney field at its midpoint
   (located on the coarse surface) dotted with p_j - p_i (docs/akvf_operator.md, Sec. 2).
3. **How good the prolonged fields are**: cosines of the S1-principal angles between their span
   and the fine eigenvectors (first 8, 16, 24, 32), and their Rayleigh quotients after a
   Rayleigh-Ritz on the fine (R, S1).
4. **A two-level preconditioner without a fine factorization** for A = R - σS1: ν steps of
   damped Jacobi (ω = 0.6), the Galerkin coarse correction P (PᵀAP)^{-1} Pᵀ (a small CHOLMOD
   factor), ν steps of Jacobi (a symmetric V(ν, ν) cycle). Its quality: PCG on A x = b (random
   b), iterations to a relative residual of 1e-8 and the mean reduction per iteration.
5. **Refinement**: ``segmented_lobpcg(system, n, tol)`` (the package's block solver, residuals
   as ``ta.akvf`` reports them) preconditioned by (a) the exact shift-invert factor from a
   random start (the solver as the batched path runs it), (b) the exact factor from the
   prolonged start (``start=``), (c) the two-level preconditioner from the prolonged start:
   iterations, CPU seconds, largest residual and largest eigenvalue difference to (1).

Usage::

    OMP_NUM_THREADS=1 python experiments/solver/coarse_to_fine_solver.py --ids 1 21 121 181 301 \\
        --out experiments/results/coarse_to_fine_solver.md
"""
from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import torch

import torchakvf as ta
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.io import load_mesh
from torchakvf.mesh import clean_mesh
from torchakvf.mesh.coarse import SurfaceIndex, coarse_mesh
from torchakvf.solvers.factor import mesh_factor
from torchakvf.solvers.lobpcg import segmented_lobpcg

JACOBI_WEIGHT = 0.6


def cpu() -> float:
    return time.process_time()


def prolongation(fine, coarse) -> sp.csr_matrix:
    """P [E_fine, E_coarse] from two one-mesh AKVF results: fine edge i->j gets X(m)·(p_j - p_i),
    X the coarse Whitney field at the edge's midpoint m located on the coarse surface (closest
    point), both meshes in their unit-area frames (the coarse geometry's ``grad_bary``; the
    frames differ by a constant factor, and only the span of P's columns is used)."""
    fine_v = fine.system.geometry.points.numpy()
    fine_edges = fine.batch.edges.numpy()
    coarse_v = coarse.system.geometry.points.numpy()
    coarse_f, coarse_fe = coarse.batch.faces.numpy(), coarse.batch.face_edges.numpy()
    coarse_fs = coarse.batch.face_edge_sign.numpy()
    mids = 0.5 * (fine_v[fine_edges[:, 0]] + fine_v[fine_edges[:, 1]])
    loc = SurfaceIndex(coarse_v, coarse_f).locate(mids)
    grad = coarse.system.geometry.grad_bary.numpy()[loc.face]             # [P, 3 (l_k), 3]
    d = fine_v[fine_edges[:, 1]] - fine_v[fine_edges[:, 0]]
    gd = np.einsum("pkc,pc->pk", grad, d)
    lam = loc.bary
    rows, cols, vals = [], [], []
    for k in range(3):
        k1 = (k + 1) % 3
        # Whitney basis of coarse edge v_k -> v_{k+1}: l_k ∇l_{k+1} - l_{k+1} ∇l_k
        vals.append(coarse_fs[loc.face, k] * (lam[:, k] * gd[:, k1] - lam[:, k1] * gd[:, k]))
        rows.append(np.arange(len(d)))
        cols.append(coarse_fe[loc.face, k])
    shape = (len(d), len(coarse.batch.edges))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=shape)


class TwoLevel:
    """V(ν, ν) two-level preconditioner of A = R - σS1: damped Jacobi, Galerkin coarse solve."""

    def __init__(self, a: sp.csr_matrix, p: sp.csr_matrix, sigma: float, sweeps: int):
        import cholespy
        self.a, self.p, self.sigma, self.sweeps = a, p, sigma, sweeps
        self.diag = a.diagonal()
        ac = (p.T @ a @ p).tocsr()
        # A coarse edge whose Whitney basis meets no fine midpoint has an empty column, and
        # nearly dependent columns make PᵀAP singular to round-off: a tiny diagonal lift.
        empty = np.asarray(abs(p).sum(axis=0)).ravel() == 0
        lift = 1e-10 * float(np.abs(ac.diagonal()).mean())
        ac = (ac + sp.diags(empty * max(ac.diagonal().max(), 1.0) + lift)).tocoo()
        low = ac.row >= ac.col
        self.coarse = cholespy.CholeskySolverD(
            ac.shape[0], torch.from_numpy(ac.row[low].astype(np.int32)),
            torch.from_numpy(ac.col[low].astype(np.int32)), torch.from_numpy(ac.data[low]),
            cholespy.MatrixType.COO)
        self.coarse_size = ac.shape[0]

    def _coarse_solve(self, r: np.ndarray) -> np.ndarray:
        rhs = torch.from_numpy(np.ascontiguousarray(self.p.T @ r))
        out = torch.zeros_like(rhs)
        self.coarse.solve(rhs, out)
        return self.p @ out.numpy()

    def apply(self, r: np.ndarray) -> np.ndarray:
        x = np.zeros_like(r)
        d = self.diag[:, None]
        for _ in range(self.sweeps):
            x += JACOBI_WEIGHT * (r - self.a @ x) / d
        x += self._coarse_solve(r - self.a @ x)
        for _ in range(self.sweeps):
            x += JACOBI_WEIGHT * (r - self.a @ x) / d
        return x

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        return torch.from_numpy(self.apply(rhs.detach().cpu().numpy().astype(np.float64)))


def pcg_rate(a: sp.csr_matrix, prec: TwoLevel, seed: int = 0, rtol: float = 1e-8, max_iter: int = 300):
    """(iterations to rtol, mean reduction per iteration) of PCG on A x = b, b random."""
    b = np.random.default_rng(seed).standard_normal((a.shape[0], 1))
    x = np.zeros_like(b)
    r = b.copy()
    z = prec.apply(r)
    p = z.copy()
    rz = float((r * z).sum())
    nb = np.linalg.norm(b)
    it = 0
    rel = 1.0
    for it in range(1, max_iter + 1):
        ap = a @ p
        alpha = rz / float((p * ap).sum())
        x += alpha * p
        r -= alpha * ap
        rel = np.linalg.norm(r) / nb
        if rel < rtol:
            break
        z = prec.apply(r)
        rz_new = float((r * z).sum())
        p = z + (rz_new / rz) * p
        rz = rz_new
    return it, rel ** (1.0 / it)


def s_orthonormal(x: np.ndarray, s: np.ndarray) -> np.ndarray:
    """An S-orthonormal basis [E, k] of span(x) (Cholesky of the S-Gram matrix)."""
    return np.linalg.solve(np.linalg.cholesky(x.T @ (s[:, None] * x)), x.T).T


def subspace_cosines(q: np.ndarray, w: np.ndarray, s: np.ndarray, counts) -> list[float]:
    """Smallest cosine of the S-principal angles between span(w[:, :c]) and span(q) (q
    S-orthonormal), per c."""
    wn = w / np.sqrt(np.einsum("en,e,en->n", w, s, w))
    return [float(np.linalg.svd(wn[:, :c].T @ (s[:, None] * q), compute_uv=False).min()) for c in counts]


def probe_mesh(path: Path, n: int, coarse_faces: int, sweeps: list[int], max_iter: int) -> dict:
    mesh = clean_mesh(load_mesh(path))
    row: dict = {"id": path.name.split(".")[0], "faces": len(mesh.faces)}
    t = cpu()
    ref = ta.akvf(mesh, n=n)
    row["akvf_s"] = cpu() - t
    row["edges"] = int(ref.forms.shape[0])

    t = cpu()
    cm = coarse_mesh(mesh, coarse_faces)
    row["decimate_s"] = cpu() - t
    t = cpu()
    coarse = ta.akvf(cm.coarse, n=n + 16)
    row["coarse_akvf_s"] = cpu() - t
    t = cpu()
    p = prolongation(ref, coarse)
    start = p @ coarse.forms.numpy()
    row["prolong_s"] = cpu() - t

    system = ref.system
    idx = system.stiffness.indices().numpy()
    r = sp.csr_matrix((system.stiffness.values().numpy(), (idx[0], idx[1])), shape=tuple(system.stiffness.shape))
    s = system.mass.numpy().astype(np.float64)
    w = ref.forms.numpy().astype(np.float64)
    q = s_orthonormal(start, s)
    row["cos"] = subspace_cosines(q, w, s, [8, 16, 24, n])
    # Rayleigh-Ritz of the prolonged span on the fine pencil.
    h = q.T @ (r @ q)
    row["rr"] = np.linalg.eigvalsh(0.5 * (h + h.T))[[0, n - 1]].tolist()
    row["lam"] = ref.eigenvalues[0, [0, n - 1]].tolist()

    t = cpu()
    exact = mesh_factor(system, 0, row["id"])
    row["factor_s"] = cpu() - t
    sigma = exact.sigma
    a = (r - sigma * sp.diags(s)).tocsr()
    runs = {}
    lam_ref = ref.eigenvalues[0].numpy()

    def refine(label, factor, warm):
        t0 = cpu()
        eig = segmented_lobpcg(system, n, tol=1e-6, factors=[factor], max_iter=max_iter,
                               start=None if warm is None else [warm])
        runs[label] = {"iters": int(eig.iterations[0]), "s": cpu() - t0,
                       "res": float(eig.residuals.max()), "conv": bool(eig.converged.all()),
                       "dlam": float(np.abs(eig.eigenvalues[0].numpy() - lam_ref).max()
                                     / max(1.0, np.abs(lam_ref).max()))}

    refine("exact, random start", exact, None)
    m = n + max(8, n // 2)
    refine("exact, prolonged start", exact, start[:, :m])
    row["pcg"] = {}
    for nu in sweeps:
        t = cpu()
        two = TwoLevel(a, p, sigma, nu)
        setup = cpu() - t
        row["pcg"][nu] = pcg_rate(a, two) + (setup, two.coarse_size)
        refine(f"two-level V({nu},{nu}), prolonged start", two, start[:, :m])
    row["runs"] = runs
    return row


def report(rows: list[dict], args) -> str:
    n = args.n
    out = ["# Probe: coarse-to-fine as a solver (prolong a decimated solve, refine at full resolution)", ""]
    out.append(f"- PSB meshes {', '.join(r['id'] for r in rows)} at full resolution (cleaned); n = {n}; "
               f"coarse mesh {args.coarse} faces (n + 16 fields solved there); process CPU time, "
               f"torch threads {torch.get_num_threads()}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '-')}")
    out.append(f"- torch {torch.__version__}, python {platform.python_version()}, {platform.machine()}; "
               f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; `experiments/solver/coarse_to_fine_solver.py`")
    out.append("")
    out.append("## What the coarse stage costs and how close its fields are")
    out.append("")
    out.append("| id | faces | edges | ta.akvf s | decimate s | coarse akvf s | prolong s | coarse total / ta.akvf | "
               "min cos (8 / 16 / 24 / n) | RR λ₁, λₙ of prolonged span | λ₁, λₙ |")
    out.append("|---|---:|---:|---:|---:|---:|---:|---:|---|---|---|")
    for r in rows:
        coarse_total = r["decimate_s"] + r["coarse_akvf_s"] + r["prolong_s"]
        out.append(f"| {r['id']} | {r['faces']} | {r['edges']} | {r['akvf_s']:.2f} | {r['decimate_s']:.2f} | "
                   f"{r['coarse_akvf_s']:.2f} | {r['prolong_s']:.2f} | {coarse_total / r['akvf_s']:.2f} | "
                   f"{' / '.join(f'{c:.3f}' for c in r['cos'])} | {r['rr'][0]:.1f}, {r['rr'][1]:.1f} | "
                   f"{r['lam'][0]:.1f}, {r['lam'][1]:.1f} |")
    out.append("")
    out.append("## The two-level preconditioner (no fine factorization): PCG on A x = b")
    out.append("")
    out.append("| id | V(ν,ν) | coarse size | setup s | PCG iterations to 1e-8 | mean reduction / iteration |")
    out.append("|---|---|---:|---:|---:|---:|")
    for r in rows:
        for nu, (its, rate, setup, size) in r["pcg"].items():
            out.append(f"| {r['id']} | V({nu},{nu}) | {size} | {setup:.2f} | {its} | {rate:.2f} |")
    out.append("")
    out.append("## Refinement by the segmented LOBPCG (tol 1e-6, residuals as ta.akvf reports them)")
    out.append("")
    out.append("| id | preconditioner, start | iterations | CPU s | s / iteration | converged | max residual | "
               "max Δλ vs ta.akvf | ta.akvf s | exact factor alone s |")
    out.append("|---|---|---:|---:|---:|---|---:|---:|---:|---:|")
    for r in rows:
        for label, run in r["runs"].items():
            out.append(f"| {r['id']} | {label} | {run['iters']} | {run['s']:.2f} | "
                       f"{run['s'] / max(run['iters'], 1):.3f} | {run['conv']} | {run['res']:.1e} | "
                       f"{run['dlam']:.1e} | {r['akvf_s']:.2f} | {r['factor_s']:.2f} |")
    out.append("")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--psb", default=None)
    ap.add_argument("--ids", type=int, nargs="+", default=[1, 21, 121, 181, 301])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--coarse", type=int, default=4000)
    ap.add_argument("--sweeps", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--max-iter", type=int, default=150)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    root = Path(args.psb) if args.psb else default_psb_root()
    if root is None:
        raise SystemExit("coarse_to_fine_solver: no PSB found; pass --psb or set TORCHAKVF_PSB")
    rows = []
    for i in args.ids:
        rows.append(probe_mesh(root / "meshes" / f"{i}.off.gz", args.n, args.coarse, args.sweeps, args.max_iter))
        print(f"mesh {i} done", flush=True)
    text = report(rows, args)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
