"""Full-resolution AKVFs: ``ta.akvf`` defaults against scipy ``eigsh`` shift-invert (SuperLU),
measured in the same run, one thread, interleaved (issue 13, "Full-resolution AKVFs ≥ 3x").

Per PSB mesh (loaded from disk once, untimed), best of ``--repeat`` rounds, every round running
the sides one after another:

* **ta** — ``torchakvf.akvf(mesh, n)`` with its defaults (remedy "smooth", solver "auto"):
  cleaning, operator assembly, shift search + CHOLMOD factor, eigensolve, Whitney vectors.
* **ta cholespy** — the same call with the CPU factors made by cholespy's constructor
  (``torchakvf.solvers.cholmod.disabled()``: NESDIS ordering, a new analysis per trial shift),
  the engine before CHOLMOD was called directly, for the before/after ratio of the factor path.
* **scipy ref** — the independent plain pipeline of :mod:`torchakvf.scipy_reference` on the
  cleaned mesh (cleaning not charged to it): ``killing_operator_scipy(V, F, remedy="smooth")``,
  then ``eigsh(R, k=n, M=diags(S1), sigma=-1, which='LM')`` with SuperLU and its Rayleigh-Ritz
  (``solve_akvf``), as a user would write it.
* **decimate** — ``coarse_mesh(cleaned mesh, --decimate)`` alone: the first step any
  coarse-to-fine solve would pay before its coarse solve, prolongation and fine refinement.
* **eigsh only** — ``eigsh`` (SuperLU) on torchakvf's own operator at torchakvf's shift, the
  solve alone (so assembly speed does not enter that ratio).

Checks per mesh: residuals ``||S1^{-1/2}(Rw − λS1w)|| / max(|λ|,1)`` of both sides (ta's as
reported, scipy's recomputed), and the largest ``|λ_ta − λ_sp| / max(|λ_sp|, 1)`` against the
eigsh-only solve of the same operator, next to its bound from the residuals: for a symmetric
pencil an eigenvalue with relative residual r is off by at most ~ r² max(|λ|,1) / gap (gap to
the rest of the spectrum), and never more than r·max(|λ|,1).

Also: the 5 meshes as one batch (``ta.akvf(meshes)``) against one call per mesh, each side in
fresh processes (two each, alternating; best of ``--repeat`` calls in each), and the same
interleaved in this process (where the batched side measured ~10% slower than in fresh ones).

Usage::

    OMP_NUM_THREADS=1 python benchmarks/akvf_fullres.py            # PSB 1 21 121 181 301
    python benchmarks/akvf_fullres.py --ids 1 21 --repeat 1 --out /tmp/x.md
    python benchmarks/akvf_fullres.py --device cuda --clock wall --ids 21 301   # a GPU machine

With ``--device cuda`` the ta side runs ``ta.akvf(mesh, n, device="cuda")`` (its defaults
there: the batched LOBPCG with CHOLMOD's factor solved on the GPU), timed on the wall clock
with the device synchronized; the scipy sides stay on the CPU and "ta cholespy" (a CPU
comparison) is not run.
"""
from __future__ import annotations

import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import scipy
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

import torchakvf as ta
from torchakvf import scipy_reference as ref
from torchakvf import shapes
from torchakvf.bench.script_tools import psb_parser, write_report
from torchakvf.fields.akvf import KRYLOV_MIN_EDGES, solver_for
from torchakvf.io import load_mesh
from torchakvf.mesh import clean_mesh
from torchakvf.mesh.coarse import coarse_mesh
from torchakvf.solvers import cholmod
from torchakvf.solvers.factor import mesh_factor

REPO = Path(__file__).resolve().parents[1]
IDS = [1, 21, 121, 181, 301]


def residuals_np(r, s1, lam, w):
    w = w / np.sqrt(np.einsum("en,e,en->n", w, s1, w))
    res = r @ w - s1[:, None] * w * lam[None, :]
    return np.sqrt(np.einsum("en,e->n", res ** 2, 1.0 / s1)) / np.maximum(np.abs(lam), 1.0)


def scipy_ref(v, f, n):
    """The independent scipy pipeline: assembly + eigsh shift-invert (SuperLU) + Rayleigh-Ritz."""
    r, s1, _, _ = ref.killing_operator_scipy(v, f, remedy="smooth")
    lam, w = ref.solve_akvf(r, ref.clamp_mass(s1), n, -1.0)
    return r, s1, lam, w


def eigsh_only(system, n, sigma):
    st = system.stiffness.cpu()
    idx = st.indices().numpy()
    r = sp.csc_matrix((st.values().numpy(), (idx[0], idx[1])), shape=tuple(st.shape))
    s1 = system.mass.cpu().numpy()
    v0 = np.random.default_rng(0).standard_normal(r.shape[0])
    lam, w = spla.eigsh(r, k=n, M=sp.diags(s1).tocsc(), sigma=sigma, which="LM", v0=v0)
    order = np.argsort(lam)
    return r, s1, lam[order], w[:, order]


#: Which clock the table uses: "cpu" (process CPU time, default) or "wall".
CLOCK = {"name": "cpu"}
WALL: dict = {}


def timed(fn, *a, **k):
    """(fn's result, seconds on CLOCK). Process CPU time by default: on a machine shared with
    other jobs, wall time measures their load as much as ours (seen: the same call 1.2 s and
    4.3 s in consecutive rounds), while one thread's CPU time does not. Wall time is also
    kept (WALL, summed) for the totals line."""
    w0, c0 = time.perf_counter(), time.process_time()
    out = fn(*a, **k)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    WALL[getattr(fn, "__name__", "?")] = WALL.get(getattr(fn, "__name__", "?"), 0.0) + wall
    return out, (cpu if CLOCK["name"] == "cpu" else wall)


#: One side of the batched row, in a fresh process: load the meshes, one warm-up solve, then
#: the side's best of ``repeat`` calls on the clock; prints the seconds.
_FRESH_SIDE = """
import sys, time, torch
import torchakvf as ta
from torchakvf.io import load_mesh
torch.set_num_threads(1)
psb, mode, n, repeat = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
clock, device = sys.argv[5], sys.argv[6]
ids = [int(v) for v in sys.argv[7].split(",")]
meshes = [load_mesh(f"{psb}/meshes/{i}.off.gz") for i in ids]
dev = torch.device(device)
sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
ta.akvf(meshes[0], n=n, device=dev)
tick = time.process_time if clock == "cpu" else time.perf_counter
best = float("inf")
for _ in range(repeat):
    t = tick()
    if mode == "batched":
        ta.akvf(meshes, n=n, device=dev)
    else:
        for m in meshes:
            ta.akvf(m, n=n, device=dev)
    sync()
    best = min(best, tick() - t)
print(best)
"""


def fresh_process_sides(psb: Path, ids, n: int, repeat: int, clock: str, device: str,
                        per_side: int = 2) -> dict | None:
    """{"batched": s, "alone": s}: each side timed in ``per_side`` fresh processes (alternating,
    best of ``repeat`` calls in each), so neither inherits the other's heap (None when
    per_side is 0). In one long-lived process the batched call measured 0.88-0.89x of one call
    per mesh twice, while fresh processes gave 0.92-1.08x (the same work, profiled:
    eigensolver_fullres_v6.md, v7)."""
    if per_side <= 0:
        return None
    out = {"batched": math.inf, "alone": math.inf}
    modes = [("batched", "alone") if i % 2 == 0 else ("alone", "batched") for i in range(per_side)]
    for mode in (m for pair in modes for m in pair):
        run = subprocess.run([sys.executable, "-c", _FRESH_SIDE, str(psb), mode, str(n), str(repeat), clock,
                              device, ",".join(map(str, ids))], capture_output=True, text=True, check=True,
                             env={**os.environ, "OMP_NUM_THREADS": "1"})
        out[mode] = min(out[mode], float(run.stdout.strip().splitlines()[-1]))
    return out


def gap_bound(lam_ref: np.ndarray, res: np.ndarray, n: int) -> float:
    """Largest a-posteriori bound on |Δλ|/max(|λ|,1) over the first n pairs: min(r, r² / relgap),
    relgap the distance to the nearest other eigenvalue (clusters within 1e-8 count as one)."""
    out = 0.0
    scale = np.maximum(np.abs(lam_ref), 1.0)
    for i in range(n):
        others = np.delete(lam_ref, i)
        d = np.abs(others - lam_ref[i])
        d = d[d > 1e-8 * scale[i]]
        gap = (d.min() if len(d) else np.inf) / scale[i]
        out = max(out, min(res[i], res[i] ** 2 / gap))
    return out


def main(argv=None) -> int:
    p = psb_parser(__doc__.split("\n")[0], IDS, REPO / "benchmarks" / "results" / "akvf_fullres.md")
    p.add_argument("--decimate", type=int, default=4000,
                   help="also time coarse_mesh(cleaned mesh, faces) alone (0: skip; default 4000)")
    p.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                   help="process CPU time (default; robust to other jobs' load) or wall time")
    p.add_argument("--threads", type=int, default=1,
                   help="torch threads (default 1, with OMP_NUM_THREADS=1 for numpy's BLAS); 0: "
                        "torch's default, as a plain Python session has (set no OMP_NUM_THREADS "
                        "then, so that numpy's BLAS keeps its default too)")
    p.add_argument("--device", default="cpu",
                   help="device of the ta side (default cpu; cuda needs --clock wall)")
    p.add_argument("--fresh", type=int, default=2,
                   help="fresh processes per side for the batched row (default 2; 0: only the "
                        "in-process figure, e.g. on a GPU machine's short budget)")
    args = p.parse_args(argv)
    dev = torch.device(args.device)
    if dev.type == "cuda" and args.clock != "wall":
        p.error("--device cuda needs --clock wall (process CPU time does not see the GPU's work)")
    if dev.type == "cuda" and not torch.cuda.is_available():
        p.error("--device cuda: torch.cuda.is_available() is False on this machine")

    def ta_akvf(mesh, **kw):
        out = ta.akvf(mesh, device=dev, **kw)
        if dev.type == "cuda":
            torch.cuda.synchronize()
        return out
    ta_akvf.__name__ = "akvf"

    def akvf_cholespy(mesh, **kw):
        with cholmod.disabled():
            return ta.akvf(mesh, **kw)
    on_cpu = dev.type == "cpu"
    if args.psb is None or not (args.psb / "meshes").is_dir():
        p.error(f"no PSB meshes at {args.psb}: pass --psb or set TORCHAKVF_PSB")
    CLOCK["name"] = args.clock
    if args.threads:
        torch.set_num_threads(args.threads)
    n = args.n
    meshes = {i: load_mesh(args.psb / "meshes" / f"{i}.off.gz") for i in args.ids}
    clean = {i: clean_mesh(m) for i, m in meshes.items()}
    # Warm-up (first-call costs of torch kernels, cholespy, ARPACK, SuperLU), untimed.
    warm = ta.Mesh(shapes.icosphere(2).vertices, shapes.icosphere(2).faces, "warm")
    ta_akvf(warm, n=8)
    if on_cpu:
        with cholmod.disabled():
            ta.akvf(warm, n=8)
    cm = clean_mesh(warm)
    scipy_ref(cm.vertices, cm.faces, 8)

    best: dict = {i: {} for i in args.ids}
    info: dict = {i: {} for i in args.ids}
    definite: dict = {}
    for rnd in range(args.repeat):
        for i in args.ids:
            m, c = meshes[i], clean[i]
            res, t = timed(ta_akvf, m, n=n)
            best[i]["ta"] = min(best[i].get("ta", math.inf), t)
            res_l, t = timed(akvf_cholespy, m, n=n) if on_cpu else (res, math.nan)
            best[i]["cholespy"] = min(best[i].get("cholespy", math.inf), t) if on_cpu else math.nan
            (r, s1, lam_ref, w_ref), t = timed(scipy_ref, c.vertices, c.faces, n)
            best[i]["ref"] = min(best[i].get("ref", math.inf), t)
            if args.decimate:
                _, t = timed(coarse_mesh, c, args.decimate)
                best[i]["decimate"] = min(best[i].get("decimate", math.inf), t)
            # eigsh's shift: the definite ladder's (below the spectrum, as a user would pick
            # it; ta's own shift may lie inside the wanted eigenvalues), found untimed
            if i not in definite:
                definite[i] = mesh_factor(res.system, 0, str(i)).sigma
            sigma = definite[i]
            # eigsh solves the pairs ta skipped as spurious too (the lowest; a user of eigsh
            # would have to), and is compared on the rest
            skip = int(res.dropped[0])
            (r2, s2, lam_e, w_e), t = timed(eigsh_only, res.system, n + skip, sigma)
            best[i]["eigsh"] = min(best[i].get("eigsh", math.inf), t)
            lam_e, w_e = lam_e[skip:], w_e[:, skip:]
            if rnd == 0:
                lam_ta = res.eigenvalues[0].double().cpu().numpy()
                res_e = residuals_np(r2, s2, lam_e, w_e)
                info[i] = dict(
                    faces=len(res.batch.faces), edges=len(res.batch.edges), sigma=float(res.shifts[0]),
                    sigma_eigsh=sigma,
                    solves=int(res.iterations[0]), solves_l=int(res_l.iterations[0]),
                    d_before=float(np.max(np.abs(lam_ta - res_l.eigenvalues[0].double().cpu().numpy())
                                          / np.maximum(np.abs(lam_ta), 1))) if on_cpu else math.nan,
                    res_ta=float(res.residuals.max()), res_l=float(res_l.residuals.max()),
                    res_ref=float(residuals_np(r, ref.clamp_mass(s1), lam_ref, w_ref).max()),
                    res_e=float(res_e.max()),
                    d_eigsh=float(np.max(np.abs(lam_ta - lam_e) / np.maximum(np.abs(lam_e), 1))),
                    d_ref=float(np.max(np.abs(lam_ta - lam_ref) / np.maximum(np.abs(lam_ref), 1))),
                    bound=gap_bound(lam_e, np.maximum(res.residuals[0].cpu().numpy(), res_e), n),
                    dropped=int(res.dropped[0]), converged=bool(res.converged.all()))
            print(f"round {rnd} mesh {i}: " + ", ".join(f"{k} {v:.2f}" for k, v in best[i].items()),
                  flush=True)
    # Batched against one at a time (best of --repeat, interleaved).
    all_m = [meshes[i] for i in args.ids]
    t_batch = t_alone = math.inf
    for rnd in range(args.repeat):
        for side in ((0, 1) if rnd % 2 == 0 else (1, 0)):      # alternate which goes first
            if side == 0:
                rb, t = timed(ta_akvf, all_m, n=n)
                t_batch = min(t_batch, t)
            else:
                alone, t = timed(lambda: [ta_akvf(m, n=n) for m in all_m])
                t_alone = min(t_alone, t)
    same = max(float(np.max(np.abs(rb.eigenvalues[b].cpu().numpy() - a.eigenvalues[0].cpu().numpy())
                            / np.maximum(np.abs(a.eigenvalues[0].cpu().numpy()), 1)))
               for b, a in enumerate(alone))
    fresh = fresh_process_sides(args.psb, args.ids, n, args.repeat, args.clock, args.device, args.fresh)

    tot = {k: sum(best[i][k] for i in args.ids) for k in ("ta", "cholespy", "ref", "eigsh")}
    clock_note = ("process CPU time, one thread: robust to the other jobs on this shared machine" if args.clock == "cpu"
                  else "wall clock")
    lines = [
        "# Full-resolution AKVFs: `ta.akvf` defaults vs scipy eigsh (SuperLU)",
        "",
        f"- PSB meshes {', '.join(map(str, args.ids))} at full resolution (cleaned, not decimated); "
        f"n = {n}; best of {args.repeat} interleaved rounds; seconds are **{args.clock} time** "
        f"({clock_note}); torch threads "
        f"{torch.get_num_threads()}, OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '-')}",
        f"- torch {torch.__version__}, scipy {scipy.__version__}, numpy {np.__version__}, "
        f"python {platform.python_version()}, {os.cpu_count()} CPUs (shared with other jobs: "
        "absolute seconds are noisy, ratios within a round are what counts)",
        f"- device of the ta side: {dev}" + ("" if on_cpu else f" ({torch.cuda.get_device_name(dev)}; "
                                               "ta cholespy not run (a CPU comparison); "
                                               "the solves column counts LOBPCG iterations there)"),
        f"- ta = `ta.akvf(mesh, n={n})` defaults (solver auto: on CPU krylov for meshes from "
        f"{KRYLOV_MIN_EDGES} edges, lanczos below; column 'auto'; cleaning + operator + factor + "
        "solve + Whitney); ta cholespy = same with the CPU factors made by cholespy's constructor "
        "(the engine before CHOLMOD was called directly: NESDIS ordering, a new analysis per shift)",
        "- scipy ref = scipy_reference: killing_operator_scipy(remedy='smooth') + eigsh(sigma=-1, "
        "SuperLU) + Rayleigh-Ritz, on the cleaned mesh (cleaning not charged); eigsh only = eigsh "
        "(SuperLU) on torchakvf's operator at the definite shift of its ladder (below the spectrum), "
        "for n pairs plus those ta skipped as spurious (column dropped), compared on the rest; "
        "σ = the shift of ta's factor (interior: inside the wanted eigenvalues, see "
        "torchakvf.solvers.factor.InteriorFactor)",
        "- Δλ = max |λ_ta − λ| / max(|λ|,1) over the n pairs; bound = max over pairs of "
        "min(r, r²/relgap) from the larger of the two residuals r",
        "",
        "| id | faces | edges | auto | σ | ta s | ta cholespy s | scipy ref s | eigsh only s | "
        "ref/ta | eigsh/ta | cholespy/ta | solves ta / cholespy | res ta | res ref | res eigsh | "
        "Δλ vs eigsh | bound | Δλ vs ref | Δλ vs cholespy | dropped |",
        "|" + "---|" * 21,
    ]
    for i in args.ids:
        b, f = best[i], info[i]
        lines.append(
            f"| {i} | {f['faces']} | {f['edges']} | {solver_for(dev, f['edges'])} | {f['sigma']:g} | {b['ta']:.2f} | "
            f"{b['cholespy']:.2f} | {b['ref']:.2f} | {b['eigsh']:.2f} | {b['ref'] / b['ta']:.2f} | "
            f"{b['eigsh'] / b['ta']:.2f} | {b['cholespy'] / b['ta']:.2f} | {f['solves']} / "
            f"{f['solves_l']} | {f['res_ta']:.1e} | {f['res_ref']:.1e} | {f['res_e']:.1e} | "
            f"{f['d_eigsh']:.1e} | {f['bound']:.1e} | {f['d_ref']:.1e} | {f['d_before']:.1e} | {f['dropped']} |")
    lines.append(
        f"| **total** | | | | | {tot['ta']:.2f} | {tot['cholespy']:.2f} | {tot['ref']:.2f} | "
        f"{tot['eigsh']:.2f} | **{tot['ref'] / tot['ta']:.2f}** | **{tot['eigsh'] / tot['ta']:.2f}** "
        f"| **{tot['cholespy'] / tot['ta']:.2f}** | | | | | | | | | |")
    lines += [
        "",
        f"Batched (all {len(args.ids)} in one `ta.akvf` call) against one call per mesh"
        + (f", each side in fresh processes ({args.fresh} each, alternating, best of {args.repeat} calls "
           f"in each): {fresh['batched']:.2f} s against {fresh['alone']:.2f} s: "
           f"**{fresh['alone'] / fresh['batched']:.2f}x**. The same" if fresh else "")
        + f" in this long-lived process, interleaved: {t_batch:.2f} s against {t_alone:.2f} s "
        f"({t_alone / t_batch:.2f}x). Largest eigenvalue difference between the two {same:.1e}.",
        "",
        f"All ta residuals <= 1e-6: {all(info[i]['res_ta'] <= 1e-6 for i in args.ids)}; all converged: "
        f"{all(info[i]['converged'] for i in args.ids)}.",
    ]
    if args.decimate:
        dec = sum(best[i]["decimate"] for i in args.ids)
        lines += ["", f"Decimation alone (`coarse_mesh(cleaned, {args.decimate})`, the first step of any "
                  f"coarse-to-fine solve, timed in the same rounds): "
                  + ", ".join(f"{i}: {best[i]['decimate']:.2f} s ({best[i]['decimate'] / best[i]['ta']:.0%} of ta)"
                              for i in args.ids)
                  + f"; total {dec:.2f} s = {dec / tot['ta']:.0%} of ta's whole full-resolution solve."]
    write_report("\n".join(lines) + "\n", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
