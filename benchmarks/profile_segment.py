"""The segment stage (untangling, spherical k-means, cutting the parts) per sub-stage, the code of
a baseline git revision against this checkout's, in one process, interleaved per batch (issue 13).

Both runs get the same AKVFs (solved once per batch, as ``torchakvf eval`` solves them: n = 36,
coarse 4000 faces) and every human segment count of each mesh as its k's, through
``segment_rounds``. The baseline's engine, untangling and k-means modules are loaded from
``git show REV:path`` (the rest of the package is this checkout's). Per batch the order of the
two runs alternates. Reported: seconds per sub-stage and their ratios, and whether the labels and
costs of every (mesh, k) are identical.

``--new-restarts 20,8`` runs the new code at the baseline's restart counts (the changes that
keep the answer alone). ``--winrates`` instead records, at the baseline's restart counts, how
often each restart index wins (k-means: lowest cost of 20; untangling: highest objective of the
identity + 8 random starts) and what keeping only the first R would give (same winner, gap).

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice -n 5 python benchmarks/profile_segment.py --batch-meshes 1
    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice -n 5 python benchmarks/profile_segment.py --winrates

Figures: benchmarks/results/segment_profile.md.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from segment_compare_common import AnswerComparison, segment_answers
from timing import module_at_revision
from torchakvf.evaluate import psb as P
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch
from torchakvf.parts import engine as new_engine

#: The revision before this work (issue 13's segment stage): the baseline of every ratio.
BASELINE_REV = "0cc7d7a"
#: 2 meshes per labelled category that is not held back (Table, Bird, Bearing, FourLeg).
DEFAULT_IDS = [c * 20 + i for c in (0, 1, 2, 3, 4, 5, 6, 8, 9, 10, 11, 14, 15, 16, 18) for i in (1, 2)]
MODULES = {"engine": ("torchakvf.parts", "torchakvf/parts/engine.py"),
           "untangle": ("torchakvf.fields", "torchakvf/fields/untangle.py"),
           "kmeans": ("torchakvf.cluster", "torchakvf/cluster/spherical_kmeans.py")}


def load_revision(rev: str) -> dict:
    """{"engine", "untangle", "kmeans"} modules as they are at git revision ``rev``, the engine
    wired to that revision's untangle and spherical_kmeans."""
    mods = {key: module_at_revision(rev, path, f"{package}._baseline_{key}")
            for key, (package, path) in MODULES.items()}
    eng = mods["engine"]
    eng.spherical_kmeans = mods["kmeans"].spherical_kmeans
    if hasattr(eng, "untangle"):
        eng.untangle = mods["untangle"].untangle
    return mods


class StageClock:
    """Wraps an engine module's untangling, k-means and cut_parts with timers."""

    def __init__(self, eng):
        self.eng, self.seconds = eng, {"untangle": 0.0, "kmeans": 0.0, "cut": 0.0}
        for attr, stage in (("untangle", "untangle"), ("orthomax_rotations", "untangle"),
                            ("untangled_from_rotations", "untangle"),
                            ("spherical_kmeans", "kmeans"), ("cut_parts", "cut")):
            if hasattr(eng, attr):
                setattr(eng, attr, self._timed(getattr(eng, attr), stage))

    def _timed(self, fn, stage):
        def run(*a, **kw):
            t0 = time.perf_counter()
            out = fn(*a, **kw)
            self.seconds[stage] += time.perf_counter() - t0
            return out
        return run


def load_batches(ids, batch_meshes, coarse_faces, seed):
    entries = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    for i in range(0, len(ids), batch_meshes):
        part = ids[i:i + batch_meshes]
        meshes = [load_mesh(entries[j].mesh_path) for j in part]
        ks = [sorted(set(P.human_segment_counts(entries[j]))) for j in part]
        mb = MeshBatch.from_meshes(meshes, coarse_faces=coarse_faces)
        opts = new_engine.SegmentOptions(seed=seed)
        fields, _ = new_engine.solve_akvfs(mb, new_engine.default_n_fields(10 ** 6) + new_engine.SPARE_FIELDS, opts)
        yield part, ks, fields


def profile(a) -> dict:
    base = load_revision(a.baseline)
    clocks = {"baseline": StageClock(base["engine"]), "new": StageClock(new_engine)}
    engines = {"baseline": base["engine"], "new": new_engine}
    wall = {"baseline": 0.0, "new": 0.0}
    comparison = AnswerComparison()
    differ = []
    for j, (part, ks, fields) in enumerate(load_batches(a.ids, a.batch_meshes, a.coarse_faces, a.seed)):
        res = {}
        order = ["baseline", "new"] if j % 2 == 0 else ["new", "baseline"]
        for name in order:
            # refine=False as torchakvf eval segments (the refined mesh is not scored)
            opts = engines[name].SegmentOptions(seed=a.seed, refine=False)
            if name == "new" and a.new_restarts:
                km, unt = (int(v) for v in a.new_restarts.split(","))
                opts = engines[name].SegmentOptions(seed=a.seed, refine=False, kmeans_restarts=km,
                                                    untangle_restarts=unt)
            res[name], s = segment_answers(engines[name], fields, ks, opts, clock=time.perf_counter)
            wall[name] += s
        differ += [(part[d.key[0]], d.key[1], d.rand_error) for d in comparison.add(res["baseline"], res["new"])]
        print(f"batch {part}: baseline {clocks['baseline'].seconds} new {clocks['new'].seconds}", flush=True)
    return dict(wall=wall, stages={n: c.seconds for n, c in clocks.items()}, total=comparison.total,
                same_labels=comparison.same_labels, same_cost=comparison.same_cost, differ=differ)


def winrates(a) -> dict:
    """Per (mesh, k) at the baseline's restart counts (20 k-means, 1 + 8 untangling starts): the
    k-means cost of each restart and the untangling objective of each start (one mesh per batch,
    as eval runs them)."""
    km_rows, unt_rows = [], []
    eng = new_engine
    orig_km, orig_rot = eng.spherical_kmeans, eng.orthomax_rotations

    def km(*args, **kw):
        res = orig_km(*args, **kw)
        km_rows.append(res.restart_costs[0].tolist())
        return res

    def rot(*args, **kw):
        res = orig_rot(*args, **kw)
        unt_rows.extend(r.restart_scores.tolist() for r in res.values())
        return res

    eng.spherical_kmeans, eng.orthomax_rotations = km, rot
    try:
        for part, ks, fields in load_batches(a.ids, 1, a.coarse_faces, a.seed):
            opts = eng.SegmentOptions(seed=a.seed, refine=False, kmeans_restarts=20, untangle_restarts=8)
            for _ in eng.segment_rounds(fields, ks, opts):
                pass
            print(part, len(km_rows), len(unt_rows), flush=True)
    finally:
        eng.spherical_kmeans, eng.orthomax_rotations = orig_km, orig_rot
    return {"kmeans_costs": km_rows, "untangle_scores": unt_rows}


def winrate_report(w) -> str:
    out = []
    for name, rows, better, prefixes in (("k-means (cost, lower wins)", w["kmeans_costs"], np.argmin, (1, 2, 3, 5, 8, 10, 20)),
                                         ("untangling (objective, higher wins; 0 = identity start)",
                                          w["untangle_scores"], np.argmax, (1, 2, 3, 5, 9))):
        c = np.array(rows)
        sign = 1.0 if better is np.argmin else -1.0
        best = better(c, axis=1)
        wins = np.bincount(best, minlength=c.shape[1])
        out += [f"### {name}: {len(c)} problems", "",
                "| restart | " + " | ".join(str(i) for i in range(c.shape[1])) + " |",
                "|---|" + "---:|" * c.shape[1],
                "| wins | " + " | ".join(str(int(v)) for v in wins) + " |", "",
                "| first R kept | same winner | mean rel. gap | max rel. gap |", "|---:|---:|---:|---:|"]
        full = (sign * c).min(axis=1)
        for p in prefixes:
            part = (sign * c[:, :p]).min(axis=1)
            gap = (part - full) / np.abs(full)
            out.append(f"| {p} | {np.mean(best < p):.3f} | {gap.mean():.2e} | {gap.max():.2e} |")
        out.append("")
    return "\n".join(out) + "\n"


def report(a, r) -> str:
    sb, sn = r["stages"]["baseline"], r["stages"]["new"]
    lines = ["# Segment stage profile (issue 13)", "",
             f"`python benchmarks/profile_segment.py` — PSB ids {a.ids[0]}..{a.ids[-1]} ({len(a.ids)} meshes: "
             f"2 per labelled category, held-back categories excluded), coarse_faces={a.coarse_faces}, "
             f"{a.batch_meshes} meshes per batch, every human k of each mesh, seed {a.seed}, refine=False (as eval), one thread, "
             f"baseline = the engine/untangle/k-means code of {a.baseline} at its own defaults, new = this checkout at "
             f"{'restarts ' + a.new_restarts if a.new_restarts else 'its defaults'}; same process, interleaved.", "",
             "| sub-stage | baseline s | new s | baseline / new |", "|---|---:|---:|---:|"]
    for st in ("untangle", "kmeans", "cut"):
        lines.append(f"| {st} | {sb[st]:.1f} | {sn[st]:.1f} | {sb[st] / max(sn[st], 1e-9):.2f}x |")
    wb, wn = r["wall"]["baseline"], r["wall"]["new"]
    lines += [f"| **segment stage (wall)** | {wb:.1f} | {wn:.1f} | **{wb / wn:.2f}x** |", "",
              f"(mesh, k) pairs: {r['total']}; labels identical on {r['same_labels']}, cost identical on "
              f"{r['same_cost']}."]
    if r["differ"]:
        ri = [f for _, _, f in r["differ"]]
        lines.append(f"Rand index error between the baseline's and the new partition where they differ: "
                     f"mean {np.mean(ri):.4f}, max {np.max(ri):.4f} (0 = the same partition).")
        lines.append("Differing (mesh id, k, 1-RI between baseline and new labels): "
                     + ", ".join(f"({i}, {k}, {f:.3f})" for i, k, f in r["differ"]))
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ids", default=",".join(map(str, DEFAULT_IDS)))
    ap.add_argument("--batch-meshes", type=int, default=5, help="meshes per batch (bench's 20000 "
                    "faces at coarse 4000 hold 5)")
    ap.add_argument("--coarse-faces", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--baseline", default=BASELINE_REV)
    ap.add_argument("--out", default=None, help="write the markdown table here")
    ap.add_argument("--json", default=None)
    ap.add_argument("--new-restarts", default=None, metavar="KM,UNT",
                    help="k-means and untangling restarts of the new run (default: its defaults); "
                         "the baseline's are 20,8")
    ap.add_argument("--winrates", action="store_true", help="restart win rates instead of timings")
    a = ap.parse_args()
    a.ids = [int(x) for x in a.ids.split(",")]
    torch.set_num_threads(1)
    if a.winrates:
        r = winrates(a)
        md = winrate_report(r)
    else:
        r = profile(a)
        md = report(a, r)
    print(md)
    if a.out:
        Path(a.out).write_text(md)
    if a.json:
        Path(a.json).write_text(json.dumps(r, indent=1))


if __name__ == "__main__":
    main()
