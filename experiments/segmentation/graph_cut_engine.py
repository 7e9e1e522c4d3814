"""The graph cut's engine: gco (research-only licence) against alpha-expansion on
scipy.sparse.csgraph.maximum_flow (BSD), on the cuts the default segmentation makes.

    # 1. the cuts: every potts_expansion call of `torchakvf eval` on the given meshes, saved
    PYTHONPATH=$PWD python experiments/segmentation/graph_cut_engine.py capture --ids 1,21,... --out /tmp/gc_cuts
    # 2. per-cut times of each engine (same process, interleaved, best of --repeat) and labels compared
    PYTHONPATH=$PWD python experiments/segmentation/graph_cut_engine.py time --cuts /tmp/gc_cuts
    # 3. whole-eval CPU seconds of two code trees, interleaved
    PYTHONPATH=$PWD python experiments/segmentation/graph_cut_engine.py ab --a /work/main --b $PWD \\
        --ids 1,21 --out /tmp/gc_ab
    # 4. the scores of two eval runs per category (e.g. main's against this branch's)
    PYTHONPATH=$PWD python experiments/segmentation/graph_cut_engine.py compare --base /work/eval_base \\
        --new /tmp/gc_eval
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path

import numpy as np

from torchakvf.parts import graphcut as gc

#: the first alpha-expansion on scipy (before the speed-ups), for the "before" column
PROTOTYPE_COMMIT = "cd615cf"


def _prototype():
    """potts_expansion with the prototype's potts_alpha_expansion (first-label start only)."""
    import subprocess
    import types
    src = subprocess.run(["git", "show", f"{PROTOTYPE_COMMIT}:torchakvf/parts/alpha_expansion.py"],
                         capture_output=True, text=True, check=True, cwd=Path(__file__).parent).stdout
    mod = types.ModuleType("alpha_expansion_prototype")
    exec(compile(src, "alpha_expansion_prototype", "exec"), mod.__dict__)

    def run(unary, pairs, weights, cycles, allowed=None, initial=None):
        assert initial is None, "the prototype starts at the first label only"
        saved = gc.potts_alpha_expansion
        gc.potts_alpha_expansion = lambda *a, initial=None, **kw: mod.potts_alpha_expansion(*a, **kw)
        try:
            return gc.potts_expansion(unary, pairs, weights, cycles, allowed=allowed, engine="scipy")
        finally:
            gc.potts_alpha_expansion = saved
    return run


def _engine(name: str):
    if name == "scipy-prototype":
        return _prototype()
    return lambda *a, **kw: gc.potts_expansion(*a, engine=name, **kw)


def _eval(ids: str, out: str, extra=()) -> None:
    from torchakvf.cli import main
    try:
        main(["eval", "--psb", "/work/shared/psb", "--ids", ids, "--out", out, "--quiet", "--workers", "1",
              "--metrics", "rand", *extra])
    except SystemExit:
        pass


def capture(args) -> None:
    """Every cut of an eval run (one process): the inputs of potts_expansion saved, and the
    stage (graphcut_labels) timed with each engine and start on the same inputs, interleaved,
    in CPU seconds of this process (the machine is shared)."""
    import dataclasses

    import torch

    from torchakvf.parts import cut as cut_module
    torch.set_num_threads(1)             # as eval's workers run (run with OMP_NUM_THREADS=1 too)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    inner, stage = gc.potts_expansion, cut_module.graphcut_labels
    count = [0]
    times = {"scipy, parts": 0.0, "gco, parts": 0.0, "gco, first": 0.0}
    differ = {"gco, parts": 0, "gco, first": 0}

    def saving(unary, pairs, weights, cycles=gc.EXPANSION_CYCLES, allowed=None, **kw):
        if kw.get("engine", "scipy") == "scipy" and saving.on:
            t0 = time.process_time()
            np.savez_compressed(out / f"cut{count[0]:04d}.npz", unary=unary, pairs=pairs, weights=weights,
                                cycles=cycles, allowed=allowed, initial=kw.get("initial"))
            saving.seconds += time.process_time() - t0          # not the stage's: taken out below
            count[0] += 1
        return inner(unary, pairs, weights, cycles, allowed=allowed, **kw)
    saving.on = True
    saving.seconds = 0.0

    def first_start(unary, pairs, weights, cycles=gc.EXPANSION_CYCLES, allowed=None, **kw):
        kw.pop("initial", None)           # gco's own start: every site at its component's first label
        return inner(unary, pairs, weights, cycles, allowed=allowed, **kw)

    def timed(labels, distances, dual, face_area, opts=None, **kw):
        opts = gc.GraphCut() if opts is None else opts
        runs = {}
        for name, engine in (("scipy, parts", "scipy"), ("gco, parts", "gco"), ("gco, first", "gco")):
            gc.potts_expansion = first_start if name.endswith("first") else saving
            saving.on = name == "scipy, parts"
            t0 = time.process_time()
            runs[name] = stage(labels, distances, dual, face_area, dataclasses.replace(opts, engine=engine), **kw)
            times[name] += time.process_time() - t0
        gc.potts_expansion = saving
        for name in differ:
            differ[name] += not np.array_equal(runs[name], runs["scipy, parts"])
        return runs["scipy, parts"]

    gc.potts_expansion = saving
    cut_module.graphcut_labels = timed
    t0 = time.process_time()
    _eval(args.ids, str(out / "eval"))
    cpu = time.process_time() - t0
    times["scipy, parts"] -= saving.seconds
    own = cpu - times["gco, parts"] - times["gco, first"] - saving.seconds   # the run alone
    print(f"{count[0]} potts_expansion calls saved to {out}; eval CPU time {own:.1f} s without the extra "
          f"solves and the saving (one process, one thread: CPU seconds, not the shared machine's wall time)")
    for name, t in times.items():
        print(f"  graph-cut stage, {name}: {t:.2f} s ({100 * t / own:.1f}% of the scipy run)"
              + (f", stage labels differ from scipy-parts on {differ[name]} cuts" if name in differ else ""))


def _load(folder: Path):
    for p in sorted(folder.glob("cut*.npz")):
        z = np.load(p, allow_pickle=True)
        allowed = z["allowed"]
        initial = z["initial"] if "initial" in z.files and z["initial"].ndim else None
        yield (p.name, z["unary"], z["pairs"], z["weights"], int(z["cycles"]),
               (None if allowed.ndim == 0 else allowed), initial)


def _start(how: str, unary, allowed, initial):
    if how == "first":
        return None
    if how == "nearest":      # a stand-in for the parts where a capture has none
        return np.argmin(np.where(allowed, unary, np.inf), axis=1)
    return initial


def time_engines(args) -> None:
    engines = args.engines.split(",")
    solve = {e: _engine(e) for e in engines}
    total = {e: 0.0 for e in engines}
    differ = 0
    n = 0
    rows = []
    for name, unary, pairs, weights, cycles, allowed, initial in _load(Path(args.cuts)):
        initial = _start(args.start, unary, allowed, initial)
        best = {e: np.inf for e in engines}
        got = {}
        for _ in range(args.repeat):
            for e in engines:            # interleaved: the engines see the same machine load
                t0 = time.process_time()        # CPU seconds: the machine is shared
                got[e] = solve[e](unary, pairs, weights, cycles, allowed=allowed, initial=initial)
                best[e] = min(best[e], time.process_time() - t0)
        same = all(np.array_equal(got[engines[0]], got[e]) for e in engines[1:])
        differ += not same
        n += 1
        for e in engines:
            total[e] += best[e]
        rows.append((name, len(unary), unary.shape[1], *[best[e] for e in engines], same))
    if args.verbose:
        for r in rows:
            print(*r)
    print(f"{n} cuts, sites per cut median {int(np.median([r[1] for r in rows]))}, max {max(r[1] for r in rows)}; "
          f"labels differ on {differ}")
    for e in engines:
        print(f"  {e}: total {total[e]:.3f} s, {1e3 * total[e] / max(n, 1):.2f} ms per cut, "
              f"{total[e] / total[engines[0]]:.2f}x {engines[0]}")


def profile(args) -> None:
    """cProfile of the scipy engine over the saved cuts (where its time goes)."""
    cuts = list(_load(Path(args.cuts)))
    prof = cProfile.Profile()
    prof.enable()
    for _, unary, pairs, weights, cycles, allowed, initial in cuts:
        gc.potts_expansion(unary, pairs, weights, cycles, allowed=allowed, engine="scipy",
                           initial=_start(args.start, unary, allowed, initial))
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(25)


def ab(args) -> None:
    """Whole-eval CPU seconds, two code trees interleaved (A B A B ...), each run a fresh process
    with one worker and one thread (the CPU seconds of the process and its children)."""
    import os
    import resource
    import subprocess
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    trees = {"A": args.a, "B": args.b}
    got = {"A": [], "B": []}
    for r in range(args.rounds):
        for name, tree in trees.items():
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run(["python3", "-m", "torchakvf.cli", "eval", "--psb", "/work/shared/psb", "--ids", args.ids,
                            "--out", f"{args.out}/{name}{r}", "--quiet", "--workers", "1", "--metrics", "rand"],
                           env=dict(env, PYTHONPATH=tree), cwd=tree, check=False, capture_output=True)
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            got[name].append(cpu)
            print(f"round {r} {name} ({tree}): CPU {cpu:.1f} s, wall {time.perf_counter() - t0:.1f} s", flush=True)
    a, b = np.median(got["A"]), np.median(got["B"])
    print(f"median CPU: A {a:.1f} s, B {b:.1f} s, B/A {b / a:.3f}")


def compare(args) -> None:
    """Per-category 1-RI of two eval runs on the meshes both scored (markdown table)."""
    import csv

    def read(folder):
        with open(Path(folder) / "scores.csv") as fh:
            return {r["id"]: r for r in csv.DictReader(fh) if r["status"] == "ok" and r["rand_index_error"]}
    base, new = read(args.base), read(args.new)
    ids = sorted(set(base) & set(new), key=int)
    cats = sorted({base[i]["category"] for i in ids},
                  key=lambda c: min(int(i) for i in ids if base[i]["category"] == c))
    print(f"| category | meshes | {args.base_name} | {args.new_name} | change | meshes better / worse |")
    print("|---|---:|---:|---:|---:|---:|")
    helps = hurts = 0
    allb, alln = [], []
    for c in cats:
        sel = [i for i in ids if base[i]["category"] == c]
        b = np.array([float(base[i]["rand_index_error"]) for i in sel])
        n = np.array([float(new[i]["rand_index_error"]) for i in sel])
        allb += list(b)
        alln += list(n)
        d = n.mean() - b.mean()
        helps += d < -5e-5
        hurts += d > 5e-5
        print(f"| {c} | {len(sel)} | {b.mean():.4f} | {n.mean():.4f} | {d:+.4f} | "
              f"{(n < b - 1e-6).sum()} / {(n > b + 1e-6).sum()} |")
    print(f"| all | {len(ids)} | {np.mean(allb):.4f} | {np.mean(alln):.4f} | {np.mean(alln) - np.mean(allb):+.4f} | |")
    print(f"\ncategories better: {helps}, worse: {hurts}, unchanged (|change| < 5e-5): {len(cats) - helps - hurts}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("capture")
    c.add_argument("--ids", required=True)
    c.add_argument("--out", required=True)
    t = sub.add_parser("time")
    t.add_argument("--cuts", required=True)
    t.add_argument("--engines", default="gco,scipy")
    t.add_argument("--repeat", type=int, default=3)
    t.add_argument("--verbose", action="store_true")
    t.add_argument("--start", choices=["first", "given", "nearest"], default="given",
                   help="first: gco's start (every site at its component's first label); given: the "
                        "captured start (the parts); nearest: each site's nearest allowed part")
    p = sub.add_parser("profile")
    p.add_argument("--cuts", required=True)
    p.add_argument("--start", choices=["first", "given", "nearest"], default="given")
    c = sub.add_parser("compare")
    c.add_argument("--base", required=True)
    c.add_argument("--new", required=True)
    c.add_argument("--base-name", default="base")
    c.add_argument("--new-name", default="new")
    x = sub.add_parser("ab")
    x.add_argument("--a", required=True, help="code tree A (e.g. /work/main)")
    x.add_argument("--b", required=True, help="code tree B (e.g. this worktree)")
    x.add_argument("--ids", required=True)
    x.add_argument("--out", required=True)
    x.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    {"capture": capture, "time": time_engines, "profile": profile, "compare": compare, "ab": ab}[args.cmd](args)


if __name__ == "__main__":
    main()
