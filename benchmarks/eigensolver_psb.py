"""Time torchakvf's eigensolver against scipy ``eigsh`` on the first mesh of every PSB category.

For each mesh (loaded and cleaned once, not timed):

* **torchakvf**: ``killing_operator`` (assembly, timed) + ``segmented_lobpcg(system, n, tol)``
  (timed). The factor's shift ``σ`` (``result.shifts``) is recorded.
* **scipy**: the *same* operator (``system.stiffness`` / ``system.mass`` converted to scipy CSC,
  timed as "conversion") then ``eigsh(R, k=n, M=diags(S1), sigma=σ, which='LM')`` with the default
  SuperLU factorization (timed). scipy gets torchakvf's assembly time too in its "total" column
  (it solves the operator torchakvf built), so the columns are

      solve only:  t_ta_solve = segmented_lobpcg          t_sp_solve = conversion + eigsh
      total:       t_ta_total = assembly + solve          t_sp_total = assembly + conversion + eigsh

Both results are checked: residuals ``||S1^{-1/2}(R w - λ S1 w)|| / max(|λ|, 1)`` (S1-normalized w,
as :func:`torchakvf.solvers.relative_residuals`) must be <= tol, and the eigenvalues are compared
(max |λ_ta - λ_sp| / max(|λ_sp|, 1)).

Also reported per mesh: the number of non-positive raw cotan weights (``system.star1_raw <= 0``)
and the number of negative eigenvalues among the n, with the chosen remedy and with
``remedy='none'`` (untimed extra solve; "SolverError" when no shift works there).

A mesh that fails is reported in the table, never fatal. ``--profile ID`` runs cProfile once on
torchakvf for that mesh and prints where the time goes.

The full-resolution ``ta.akvf`` figure (its defaults against the scipy pipeline) is
benchmarks/akvf_fullres.py.

Usage::

    python benchmarks/eigensolver_psb.py --method lanczos      # benchmarks/results/eigensolver_psb.md
    python benchmarks/eigensolver_psb.py                       # the 19 meshes, segmented LOBPCG
    python benchmarks/eigensolver_psb.py --remedy none --out /tmp/eigensolver_none.md
    python benchmarks/eigensolver_psb.py --ids 1 21 --profile 281
"""
from __future__ import annotations

import argparse
import cProfile
import io
import math
import os
import platform
import pstats
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

import torchakvf
from torchakvf.errors import SolverError
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch, clean_mesh
from torchakvf.operators.killing import REMEDIES, killing_operator
from torchakvf.solvers.lobpcg import segmented_lobpcg

try:  # the ARPACK-on-CHOLMOD alternative (newer torchakvf)
    from torchakvf.solvers.lanczos import shift_invert_lanczos
except ImportError:  # pragma: no cover
    shift_invert_lanczos = None

REPO = Path(__file__).resolve().parents[1]

#: The PSB categories in id order (category of mesh N = CATEGORIES[(N - 1) // 20]); Spring absent.
CATEGORIES = ["Human", "Cup", "Glasses", "Airplane", "Ant", "Chair", "Octopus", "Table", "Teddy",
              "Hand", "Plier", "Fish", "Bird", "Spring", "Armadillo", "Bust", "Mech", "Bearing",
              "Vase", "Fourleg"]
#: The first mesh of each of the 19 present categories.
FIRST_IDS = [20 * c + 1 for c in range(len(CATEGORIES)) if CATEGORIES[c] != "Spring"]

THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
              "OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "KMP_BLOCKTIME",
              "NUMEXPR_NUM_THREADS", "TORCHAKVF_PSB")


def category_of(mesh_id: int) -> str:
    return CATEGORIES[(mesh_id - 1) // 20]


# --------------------------------------------------------------------------------------------
# The two solvers on one operator
# --------------------------------------------------------------------------------------------

def to_scipy(system) -> tuple[sp.csc_matrix, np.ndarray]:
    """The torch operator (one mesh) as scipy CSC R and the numpy diagonal S1."""
    st = system.stiffness
    idx = st.indices().cpu().numpy()
    vals = st.values().detach().to(torch.float64).cpu().numpy()
    r = sp.csc_matrix((vals, (idx[0], idx[1])), shape=tuple(st.shape))
    return r, system.mass.detach().to(torch.float64).cpu().numpy()


def scipy_eigsh(r: sp.spmatrix, s1: np.ndarray, n: int, sigma: float, tol: float = 0.0):
    """``eigsh(R, k=n, M=diags(S1), sigma=σ, which='LM')``, default SuperLU, deterministic start."""
    m = sp.diags(s1).tocsc()
    v0 = np.random.default_rng(0).standard_normal(r.shape[0])
    return spla.eigsh(r, k=n, M=m, sigma=sigma, which="LM", v0=v0, tol=tol)


def residuals_np(r: sp.spmatrix, s1: np.ndarray, lam: np.ndarray, w: np.ndarray) -> np.ndarray:
    """[n] ||S1^{-1/2}(R w - λ S1 w)|| / max(|λ|, 1) for w S1-normalized (as relative_residuals)."""
    w = w / np.sqrt(np.einsum("en,e,en->n", w, s1, w))
    res = r @ w - s1[:, None] * w * lam[None, :]
    return np.sqrt(np.einsum("en,e->n", res ** 2, 1.0 / s1)) / np.maximum(np.abs(lam), 1.0)


def eigensolve(system, n: int, tol: float, max_iter: int, names, method: str = "lobpcg"):
    """torchakvf's eigensolve: ``segmented_lobpcg`` or ``shift_invert_lanczos``."""
    if method == "lanczos":
        if shift_invert_lanczos is None:
            raise RuntimeError("this torchakvf has no solvers.lanczos")
        return shift_invert_lanczos(system, n, tol=tol, names=names)
    if method == "krylov":
        from torchakvf.solvers.krylov import block_krylov
        return block_krylov(system, n, tol=tol, names=names)
    return segmented_lobpcg(system, n, tol=tol, names=names, max_iter=max_iter)


def torchakvf_solve(batch, n: int, remedy: str, tol: float, max_iter: int, method: str = "lobpcg"):
    """(system, eig, t_assembly, t_solve): the timed torchakvf path."""
    t0 = time.perf_counter()
    system = killing_operator(batch, remedy=remedy)
    t1 = time.perf_counter()
    eig = eigensolve(system, n, tol, max_iter, batch.names, method)
    t2 = time.perf_counter()
    return system, eig, t1 - t0, t2 - t1


# --------------------------------------------------------------------------------------------
# One mesh
# --------------------------------------------------------------------------------------------

@dataclass
class Row:
    mesh_id: int
    category: str
    faces: int = 0
    edges: int = 0
    neg_star1: int | None = None
    neg_eig: int | None = None          # chosen remedy (torchakvf)
    neg_eig_none: str = "-"             # remedy none: count, or "SolverError" / "not run"
    min_eig: float = math.nan
    iterations: int | None = None
    shift: float = math.nan
    converged: bool | None = None
    t_ta_asm: float = math.nan
    t_ta_solve: float = math.nan
    t_sp_conv: float = math.nan
    t_sp_eigsh: float = math.nan
    res_ta: float = math.nan
    res_sp: float = math.nan
    eig_diff: float = math.nan
    notes: list = field(default_factory=list)

    @property
    def t_ta_total(self):
        return self.t_ta_asm + self.t_ta_solve

    @property
    def t_sp_solve(self):
        return self.t_sp_conv + self.t_sp_eigsh

    @property
    def t_sp_total(self):
        return self.t_ta_asm + self.t_sp_solve

    @property
    def timed(self) -> bool:
        return all(math.isfinite(t) for t in (self.t_ta_asm, self.t_ta_solve, self.t_sp_conv,
                                              self.t_sp_eigsh))


def load_clean(psb: Path, mesh_id: int):
    path = psb / "meshes" / f"{mesh_id}.off.gz"
    if not path.exists():
        path = psb / "meshes" / f"{mesh_id}.off"
    return MeshBatch.from_meshes([clean_mesh(load_mesh(path))])


def bench_mesh(psb: Path, mesh_id: int, args) -> Row:
    row = Row(mesh_id, category_of(mesh_id))
    try:
        batch = load_clean(psb, mesh_id)
    except Exception as exc:  # noqa: BLE001 - reported, not fatal
        row.notes.append(f"load failed: {type(exc).__name__}: {exc}")
        return row
    row.faces, row.edges = len(batch.faces), len(batch.edges)
    tol, n = args.tol, args.n

    # (a) torchakvf, best of --repeat.
    system = eig = None
    try:
        for _ in range(args.repeat):
            system, eig, ta, ts = torchakvf_solve(batch, n, args.remedy, tol, args.max_iter,
                                                  args.method)
            row.t_ta_asm = min(row.t_ta_asm, ta) if math.isfinite(row.t_ta_asm) else ta
            row.t_ta_solve = min(row.t_ta_solve, ts) if math.isfinite(row.t_ta_solve) else ts
    except SolverError as exc:
        row.notes.append(f"torchakvf SolverError: {exc}")
    except Exception as exc:  # noqa: BLE001
        row.notes.append(f"torchakvf failed: {type(exc).__name__}: {exc}")
        traceback.print_exc()
    if system is None:
        try:
            system = killing_operator(batch, remedy=args.remedy)
        except Exception:  # noqa: BLE001
            pass
    if system is not None:
        row.neg_star1 = int((system.star1_raw <= 0).sum())
    if eig is not None:
        lam_ta = eig.eigenvalues[0].cpu().numpy()
        row.neg_eig = int((lam_ta < 0).sum())
        row.min_eig = float(lam_ta.min())
        row.iterations = int(eig.iterations[0])
        row.shift = float(eig.shifts[0])
        row.converged = bool(eig.converged[0])
        row.res_ta = float(eig.residuals.max())
        if not row.converged:
            row.notes.append(f"torchakvf not converged (res {row.res_ta:.1e})")
        if row.shift <= -64:
            row.notes.append(f"shift search went to {row.shift:g}")

    # (b) scipy eigsh on the same operator, same shift.
    if eig is not None:
        try:
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                r, s1 = to_scipy(system)
                t1 = time.perf_counter()
                lam_sp, w_sp = scipy_eigsh(r, s1, n, row.shift, tol=args.scipy_tol)
                t2 = time.perf_counter()
                row.t_sp_conv = min(row.t_sp_conv, t1 - t0) if math.isfinite(row.t_sp_conv) else t1 - t0
                row.t_sp_eigsh = (min(row.t_sp_eigsh, t2 - t1) if math.isfinite(row.t_sp_eigsh)
                                  else t2 - t1)
            order = np.argsort(lam_sp)
            lam_sp, w_sp = lam_sp[order], w_sp[:, order]
            row.res_sp = float(residuals_np(r, s1, lam_sp, w_sp).max())
            row.eig_diff = float(np.max(np.abs(lam_ta - lam_sp) / np.maximum(np.abs(lam_sp), 1.0)))
            if row.res_sp > tol:
                row.notes.append(f"scipy residual {row.res_sp:.1e} > tol")
            if row.eig_diff > 1e-6:
                row.notes.append(f"eigenvalue mismatch {row.eig_diff:.1e}")
            if lam_sp.min() <= row.shift:
                row.notes.append("shift not below the smallest eigenvalue")
        except Exception as exc:  # noqa: BLE001
            row.notes.append(f"scipy failed: {type(exc).__name__}: {exc}")

    # Negative eigenvalues with remedy none (untimed extra solve).
    if args.remedy == "none":
        row.neg_eig_none = "-" if row.neg_eig is None else str(row.neg_eig)
        if any("SolverError" in s for s in row.notes):
            row.neg_eig_none = "SolverError"
    elif args.with_none:
        try:
            sys0 = killing_operator(batch, remedy="none")
            e0 = eigensolve(sys0, n, tol, args.max_iter, batch.names, args.method)
            lam0 = e0.eigenvalues[0].cpu().numpy()
            txt = f"{int((lam0 < 0).sum())} (min {lam0.min():.3g}, σ {float(e0.shifts[0]):g})"
            if not bool(e0.converged[0]):
                txt += f" [not conv., res {float(e0.residuals.max()):.1e}]"
            row.neg_eig_none = txt
        except SolverError:
            row.neg_eig_none = "SolverError"
        except Exception as exc:  # noqa: BLE001
            row.neg_eig_none = f"{type(exc).__name__}"
    else:
        row.neg_eig_none = "not run"
    return row


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------

def _f(x, spec):
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


SOLVER_LABEL = {"lobpcg": "segmented_lobpcg (cholespy/CHOLMOD shift-invert preconditioner)",
                "lanczos": "shift_invert_lanczos (ARPACK on the CHOLMOD factor; iters = solves)",
                "krylov": "block_krylov (block shift-invert Krylov on the CHOLMOD factor; iters = "
                          "right-hand sides)"}


def header(args, psb: Path) -> str:
    env = ", ".join(f"{k}={os.environ[k]}" for k in THREAD_ENV if k in os.environ) or "(none set)"
    lines = [
        "# torchakvf vs scipy eigsh: first mesh of every PSB category",
        "",
        f"- n = {args.n}, tol = {args.tol:g}, remedy = {args.remedy}, torchakvf solver = {args.method}, "
        f"repeat = {args.repeat} (best of), "
        f"scipy eigsh tol = {args.scipy_tol:g} (0 = machine precision)",
        f"- torchakvf {torchakvf.__version__}, torch {torch.__version__}, scipy {scipy.__version__}, "
        f"numpy {np.__version__}, python {platform.python_version()}",
        f"- torch.get_num_threads() = {torch.get_num_threads()}, os.cpu_count() = {os.cpu_count()}, "
        f"env: {env}",
        f"- machine: {platform.machine()} {platform.processor() or ''} {platform.system()} "
        f"{platform.release()}",
        f"- PSB: {psb}",
        f"- t_ta = killing_operator + {SOLVER_LABEL[args.method]}; "
        "t_sp solve = CSC conversion + eigsh(sigma=σ of torchakvf, M=diags(S1), SuperLU); "
        "t_sp total = t_sp solve + torchakvf's assembly time",
        "- ratio = t_sp / t_ta (> 1: torchakvf faster); eig diff = max |λ_ta − λ_sp| / max(|λ_sp|, 1); "
        "res = max residual ||S1^{-1/2}(Rw − λS1w)|| / max(|λ|,1)",
        "- #neg S1 = raw cotan weights <= 0; #neg λ = negative eigenvalues among the n (chosen remedy / "
        "remedy none)",
    ]
    return "\n".join(lines)


def table(rows: list[Row], remedy: str) -> str:
    none_col = "#neg λ (none)" if remedy != "none" else "#neg λ (none, same run)"
    cols = ["id", "category", "faces", "edges", "#neg S1", f"#neg λ ({remedy})", none_col,
            "min λ", "iters", "σ", "t_ta asm", "t_ta solve", "t_ta total", "t_sp solve", "t_sp total",
            "ratio solve", "ratio total", "res ta", "res sp", "eig diff", "notes"]
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        ok = r.timed
        cells = [str(r.mesh_id), r.category, str(r.faces), str(r.edges), _f(r.neg_star1, "d"),
                 _f(r.neg_eig, "d"), r.neg_eig_none, _f(r.min_eig, ".4g"), _f(r.iterations, "d"),
                 _f(r.shift, "g"), _f(r.t_ta_asm, ".2f"), _f(r.t_ta_solve, ".2f"),
                 _f(r.t_ta_total, ".2f"), _f(r.t_sp_solve, ".2f"), _f(r.t_sp_total, ".2f"),
                 _f(r.t_sp_solve / r.t_ta_solve, ".2f") if ok else "-",
                 _f(r.t_sp_total / r.t_ta_total, ".2f") if ok else "-",
                 _f(r.res_ta, ".1e"), _f(r.res_sp, ".1e"), _f(r.eig_diff, ".1e"),
                 "; ".join(r.notes).replace("|", "/")]
        out.append("| " + " | ".join(cells) + " |")
    done = [r for r in rows if r.timed]
    if done:
        s = lambda attr: sum(getattr(r, attr) for r in done)  # noqa: E731
        out.append("| **total** | " + f"{len(done)}/{len(rows)} meshes timed | "
                   + f"{sum(r.faces for r in done)} | {sum(r.edges for r in done)} | | | | | | | "
                   + f"{s('t_ta_asm'):.2f} | {s('t_ta_solve'):.2f} | {s('t_ta_total'):.2f} | "
                   + f"{s('t_sp_solve'):.2f} | {s('t_sp_total'):.2f} | "
                   + f"**{s('t_sp_solve') / s('t_ta_solve'):.2f}** | "
                   + f"**{s('t_sp_total') / s('t_ta_total'):.2f}** | | | | |")
    return "\n".join(out)


def summary(rows: list[Row], tol: float) -> str:
    done = [r for r in rows if r.timed]
    if not done:
        return "No mesh was timed."
    s = lambda attr: sum(getattr(r, attr) for r in done)  # noqa: E731
    bad = [r.mesh_id for r in rows if not r.timed]
    lines = [
        f"Total over {len(done)} meshes: torchakvf {s('t_ta_total'):.2f} s "
        f"(assembly {s('t_ta_asm'):.2f} + solve {s('t_ta_solve'):.2f}), scipy {s('t_sp_total'):.2f} s "
        f"(solve {s('t_sp_solve'):.2f}).",
        f"Overall ratio scipy / torchakvf: total {s('t_sp_total') / s('t_ta_total'):.2f}x, "
        f"solve only {s('t_sp_solve') / s('t_ta_solve'):.2f}x.",
        f"All torchakvf residuals <= {tol:g}: {all(r.res_ta <= tol for r in done)}; all scipy residuals "
        f"<= {tol:g}: {all(r.res_sp <= tol for r in done)}; max eig diff "
        f"{max(r.eig_diff for r in done):.1e}.",
    ]
    if bad:
        lines.append(f"Not timed (see notes): {bad}.")
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Profile
# --------------------------------------------------------------------------------------------

PROFILE_KEYS = [
    ("killing_operator", "assembly (killing_operator)"),
    ("__init__", "factorization (ShiftedFactor.__init__, all shift trials)"),
    ("solve", "triangular solves (ShiftedFactor.solve)"),
    ("eigsh", "ARPACK eigsh (Lanczos path; includes the solves)"),
    ("_rayleigh_ritz", "dense Rayleigh-Ritz (_rayleigh_ritz: Gram, eigh, products)"),
    ("r_mul", "sparse R products in the iteration (r_mul)"),
    ("relative_residuals", "final residual check (relative_residuals)"),
    ("segmented_lobpcg", "segmented_lobpcg total"),
]


def profile_mesh(psb: Path, mesh_id: int, args) -> str:
    batch = load_clean(psb, mesh_id)
    prof = cProfile.Profile()
    t0 = time.perf_counter()
    prof.enable()
    system = killing_operator(batch, remedy=args.remedy)
    eig = eigensolve(system, args.n, args.tol, args.max_iter, batch.names, args.method)
    prof.disable()
    wall = time.perf_counter() - t0
    st = pstats.Stats(prof)
    files = {"killing_operator": "killing.py", "__init__": "factor.py", "solve": "factor.py",
             "_rayleigh_ritz": "lobpcg.py", "r_mul": "lobpcg.py", "relative_residuals": "lobpcg.py",
             "segmented_lobpcg": "lobpcg.py", "eigsh": "arpack.py"}
    cum = {}
    for (fname, _, func), (cc, nc, tt, ct, callers) in st.stats.items():
        if func in files and fname.endswith(files[func]):
            cum[func] = (cum.get(func, (0, 0.0))[0] + nc, cum.get(func, (0, 0.0))[1] + ct)
    lines = [f"## Profile of torchakvf on mesh {mesh_id} ({category_of(mesh_id)}, "
             f"{len(batch.faces)} faces, {len(batch.edges)} edges, remedy {args.remedy}, n {args.n})",
             "", f"wall {wall:.2f} s under cProfile; iterations {int(eig.iterations[0])}, "
             f"σ {float(eig.shifts[0]):g}", "", "| part | calls | cumulative s | % of wall |",
             "|---|---|---|---|"]
    for key, label in PROFILE_KEYS:
        calls, t = cum.get(key, (0, 0.0))
        lines.append(f"| {label} | {calls} | {t:.2f} | {100 * t / wall:.0f} |")
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(15)
    text = buf.getvalue()
    text = text[text.find("ncalls"):] if "ncalls" in text else text
    lines += ["", "Top functions by own time:", "", "```", text.rstrip(), "```"]
    return "\n".join(lines)


# --------------------------------------------------------------------------------------------

def warm_up(n: int):
    """Untimed: first-call costs (torch kernels, cholespy import, ARPACK) off the first mesh."""
    from torchakvf.shapes import icosphere
    ico = icosphere(2)
    from torchakvf.mesh import Mesh
    batch = MeshBatch.from_meshes([Mesh(ico.vertices, ico.faces, name="warmup")])
    system, eig, _, _ = torchakvf_solve(batch, min(n, 16), "none", 1e-6, 60)
    r, s1 = to_scipy(system)
    scipy_eigsh(r, s1, min(n, 16), float(eig.shifts[0]))


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--psb", type=Path, default=default_psb_root(),
                   help="PSB folder with meshes/N.off.gz (default: $TORCHAKVF_PSB or <repo>/../shared/psb)")
    p.add_argument("--n", type=int, default=32, help="eigenpairs per mesh (default 32)")
    p.add_argument("--tol", type=float, default=1e-6, help="residual tolerance (default 1e-6)")
    p.add_argument("--scipy-tol", type=float, default=0.0,
                   help="eigsh's own tol (default 0: machine precision, as a user would call it)")
    p.add_argument("--max-iter", type=int, default=60, help="segmented_lobpcg max_iter")
    p.add_argument("--method", default="lobpcg", choices=("lobpcg", "lanczos", "krylov"),
                   help="torchakvf eigensolver timed (default lobpcg = segmented_lobpcg)")
    p.add_argument("--remedy", default="smooth", choices=REMEDIES, help="operator remedy (default smooth)")
    p.add_argument("--ids", type=int, nargs="+", default=FIRST_IDS,
                   help="PSB mesh ids (default: the first mesh of each of the 19 categories)")
    p.add_argument("--repeat", type=int, default=1, help="timing repeats per mesh, best kept (default 1)")
    p.add_argument("--with-none", action=argparse.BooleanOptionalAction, default=True,
                   help="also solve with remedy 'none' (untimed) to count its negative eigenvalues")
    p.add_argument("--threads", type=int, default=None,
                   help="torch.set_num_threads(N) before timing (default: leave torch's setting)")
    p.add_argument("--profile", type=int, default=None, metavar="ID",
                   help="after the table, cProfile torchakvf once on this mesh id")
    p.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "eigensolver_psb.md",
                   help="markdown output (default benchmarks/results/eigensolver_psb.md)")
    return p.parse_args(argv)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parse_args(argv)
    if args.psb is None or not (args.psb / "meshes").is_dir():
        print(f"PSB not found at {args.psb} (expected {args.psb}/meshes/N.off.gz); set --psb or "
              "TORCHAKVF_PSB", file=sys.stderr)
        return 2
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    head = header(args, args.psb)
    print(head, flush=True)
    warm_up(args.n)
    rows = []
    for mesh_id in args.ids:
        t0 = time.perf_counter()
        row = bench_mesh(args.psb, mesh_id, args)
        rows.append(row)
        ratio = row.t_sp_total / row.t_ta_total if row.timed else math.nan
        print(f"[{len(rows)}/{len(args.ids)}] mesh {mesh_id} ({row.category}, {row.faces} faces): "
              f"ta {row.t_ta_total:.2f} s, sp {row.t_sp_total:.2f} s, ratio {ratio:.2f}, "
              f"iters {row.iterations}, σ {row.shift:g}, neg λ {row.neg_eig} / none {row.neg_eig_none}"
              f"{'; ' + '; '.join(row.notes) if row.notes else ''} "
              f"(mesh wall {time.perf_counter() - t0:.1f} s)", flush=True)
    body = table(rows, args.remedy)
    summ = summary(rows, args.tol)
    text = f"{head}\n\n{body}\n\n{summ}\n"
    print("\n" + body + "\n\n" + summ, flush=True)
    if args.profile is not None:
        try:
            prof = profile_mesh(args.psb, args.profile, args)
        except Exception as exc:  # noqa: BLE001
            prof = f"Profile of mesh {args.profile} failed: {type(exc).__name__}: {exc}"
        print("\n" + prof)
        text += "\n" + prof + "\n"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(f"\nwritten to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
