"""The graph cut's engine: gco (research-only licence) against alpha-expansion on
scipy.sparse.csgraph.maximum_flow (BSD), on the cuts the default segmentation makes.

    # 1. the cuts: every potts_expansion call of `torchakvf eval` on the given meshes, saved
    PYTHONPATH=$PWD python experiments/graph_cut_engine.py capture --ids 1,21,... --out /tmp/gc_cuts
    # 2. per-cut times of each engine (same process, interleaved, best of --repeat) and labels compared
    PYTHONPATH=$PWD python experiments/graph_cut_engine.py time --cuts /tmp/gc_cuts
    # 3. the cut stage's share of segment time (a profile of one eval run)
    PYTHONPATH=$PWD python experiments/graph_cut_engine.py share --ids 1,21,... --engine scipy
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
    stage (graphcut_labels) timed with each engine and start on the same inputs, interleaved."""
    import dataclasses
    from torchakvf.parts import cut as cut_module
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    inner, stage = gc.potts_expansion, cut_module.graphcut_labels
    count = [0]
    times = {"scipy, parts": 0.0, "gco, parts": 0.0, "gco, first": 0.0}
    differ = {"gco, parts": 0, "gco, first": 0}

    def saving(unary, pairs, weights, cycles=gc.EXPANSION_CYCLES, allowed=None, **kw):
        if kw.get("engine", "scipy") == "scipy" and saving.on:
            np.savez_compressed(out / f"cut{count[0]:04d}.npz", unary=unary, pairs=pairs, weights=weights,
                                cycles=cycles, allowed=allowed, initial=kw.get("initial"))
            count[0] += 1
        return inner(unary, pairs, weights, cycles, allowed=allowed, **kw)
    saving.on = True

    def first_start(unary, pairs, weights, cycles=gc.EXPANSION_CYCLES, allowed=None, **kw):
        kw.pop("initial", None)           # gco's own start: every site at its component's first label
        return inner(unary, pairs, weights, cycles, allowed=allowed, **kw)

    def timed(labels, distances, dual, face_area, opts=None, **kw):
        opts = gc.GraphCut() if opts is None else opts
        runs = {}
        for name, engine in (("scipy, parts", "scipy"), ("gco, parts", "gco"), ("gco, first", "gco")):
            gc.potts_expansion = first_start if name.endswith("first") else saving
            saving.on = name == "scipy, parts"
            t0 = time.perf_counter()
            runs[name] = stage(labels, distances, dual, face_area, dataclasses.replace(opts, engine=engine), **kw)
            times[name] += time.perf_counter() - t0
        gc.potts_expansion = saving
        for name in differ:
            differ[name] += not np.array_equal(runs[name], runs["scipy, parts"])
        return runs["scipy, parts"]

    gc.potts_expansion = saving
    cut_module.graphcut_labels = timed
    t0 = time.perf_counter()
    _eval(args.ids, str(out / "eval"))
    wall = time.perf_counter() - t0
    own = wall - times["gco, parts"] - times["gco, first"]     # the run without the extra solves
    print(f"{count[0]} potts_expansion calls saved to {out}; eval wall {own:.1f} s without the extra solves")
    for name, t in times.items():
        print(f"  graph-cut stage, {name}: {t:.2f} s ({100 * t / own:.1f}% of the scipy run)"
              + (f", stage labels differ from scipy-parts on {differ[name]} cuts" if name in differ else ""))


def _load(folder: Path):
    for p in sorted(folder.glob("cut*.npz")):
        z = np.load(p, allow_pickle=True)
        allowed = z["allowed"]
        initial = z["initial"] if "initial" in z.files and z["initial"].ndim else None
        yield p.name, z["unary"], z["pairs"], z["weights"], int(z["cycles"]), (None if allowed.ndim == 0 else allowed), initial


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
                t0 = time.perf_counter()
                got[e] = solve[e](unary, pairs, weights, cycles, allowed=allowed, initial=initial)
                best[e] = min(best[e], time.perf_counter() - t0)
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


def share(args) -> None:
    """The graph-cut stage's share of one eval run's time (cumulative, from a profile)."""
    prof = cProfile.Profile()
    prof.enable()
    t0 = time.perf_counter()
    _eval(args.ids, args.out, ("--graph-cut", "on"))
    wall = time.perf_counter() - t0
    prof.disable()
    st = pstats.Stats(prof)
    cum = {f"{fn[0].split('torchakvf/')[-1]}:{fn[2]}": v[3] for fn, v in st.stats.items()}
    pick = {k: v for k, v in cum.items() if k.endswith((":graphcut_labels", ":potts_expansion", ":segment",
                                                         ":cut_parts"))}
    print(f"wall {wall:.1f} s")
    for k, v in sorted(pick.items(), key=lambda kv: -kv[1]):
        print(f"  {k}: {v:.2f} s ({100 * v / wall:.1f}% of the run)")


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
    s = sub.add_parser("share")
    s.add_argument("--ids", required=True)
    s.add_argument("--out", required=True)
    args = ap.parse_args()
    {"capture": capture, "time": time_engines, "profile": profile, "share": share}[args.cmd](args)


if __name__ == "__main__":
    main()
