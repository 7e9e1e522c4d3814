"""Profile of the pack stage (load, clean-up, decimation, surface map, packing), this checkout
against a baseline commit, measured in the same process, interleaved mesh by mesh.

The baseline's ``torchakvf`` package is extracted with ``git archive`` into a temporary folder
as ``torchakvf_base`` and imported next to this checkout's, so both run on the same inputs in
the same run. Each sub-stage is timed as the best of ``--repeat`` runs; outputs are compared.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python benchmarks/profile_pack.py --psb ../shared/psb \\
        --per-category 2 --baseline 0cc7d7a --out benchmarks/results/pack_stage.md
"""
from __future__ import annotations

import argparse
import importlib
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from timing import best_of

ROOT = Path(__file__).resolve().parents[1]
#: PSB categories (first id of each, 20 meshes each); 261-280 are not in the benchmark.
CATEGORY_STARTS = [1, 21, 41, 61, 81, 101, 121, 141, 161, 181, 201, 221, 241, 281, 301, 321, 341, 361, 381]
STAGES = ["load", "clean", "decimate", "clean_coarse", "surface_map", "pack", "total"]


def baseline_package(rev: str, into: Path):
    """Import ``torchakvf`` as of git revision ``rev`` under the name ``torchakvf_base``."""
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "torchakvf"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    (into / "torchakvf").rename(into / "torchakvf_base")
    sys.path.insert(0, str(into))
    return importlib.import_module("torchakvf_base")


def stages(pkg, path: str, repeat: int, faces: int):
    """Seconds per sub-stage and the outputs of ``pkg`` (a torchakvf package) on one mesh."""
    from importlib import import_module
    load = import_module(pkg.__name__ + ".io.load").load_mesh
    clean_mod = import_module(pkg.__name__ + ".mesh.clean")
    coarse_mod = import_module(pkg.__name__ + ".mesh.coarse")
    batch_mod = import_module(pkg.__name__ + ".mesh.batch")
    t, out = {}, {}
    t["load"], out["mesh"] = best_of(lambda: load(path), repeat, time.process_time)
    t["clean"], out["clean"] = best_of(lambda: clean_mod.clean_mesh(out["mesh"]), repeat, time.process_time)
    t["decimate"], out["decimated"] = best_of(lambda: coarse_mod.decimate(out["clean"], faces), repeat, time.process_time)
    t["clean_coarse"], out["coarse"] = best_of(lambda: clean_mod.clean_mesh(out["decimated"]), repeat, time.process_time)
    fine, coarse = out["clean"], out["coarse"]
    centers = fine.vertices[fine.faces].mean(axis=1)
    if hasattr(coarse_mod, "SurfaceIndex"):
        def surface_map():
            index = coarse_mod.SurfaceIndex(coarse.vertices, coarse.faces)
            return index.locate(fine.vertices), index.locate(centers)
    else:
        def surface_map():
            return (coarse_mod.locate_on_surface(coarse.vertices, coarse.faces, fine.vertices),
                    coarse_mod.locate_on_surface(coarse.vertices, coarse.faces, centers))
    t["surface_map"], out["map"] = best_of(surface_map, repeat, time.process_time)
    t["pack"], _ = best_of(lambda: batch_mod.MeshBatch.from_meshes([coarse]), repeat, time.process_time)
    t["total"], _ = best_of(lambda: batch_mod.MeshBatch.from_meshes([load(path)], coarse_faces=faces), repeat, time.process_time)
    return t, out


def same_clean(a, b) -> bool:
    return (np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
            and np.array_equal(a.face_index, b.face_index) and a.report == b.report
            and np.array_equal(a.face_component, b.face_component))


def compare(new, old) -> dict:
    """What differs between the outputs of this checkout (new) and the baseline (old)."""
    c = {"load": np.array_equal(new["mesh"].vertices, old["mesh"].vertices)
         and np.array_equal(new["mesh"].faces, old["mesh"].faces),
         "clean": same_clean(new["clean"], old["clean"]),
         "decimate": np.array_equal(new["decimated"].faces, old["decimated"].faces)
         and np.array_equal(new["decimated"].vertices, old["decimated"].vertices)}
    if c["decimate"]:
        nm, om = new["map"], old["map"]
        face_new = np.concatenate([m.face for m in nm])
        face_old = np.concatenate([m.face for m in om])
        d_new = np.concatenate([m.distance for m in nm])
        d_old = np.concatenate([m.distance for m in om])
        differ = face_new != face_old
        c["map_points"] = len(face_new)
        c["map_other_face"] = int(differ.sum())
        # Where the faces differ, the baseline's was farther (its fixed 8 nearest-barycenter
        # candidates missed the closest face) or equally far (a tie).
        tol = 1e-12 * np.abs(new["coarse"].vertices).max()              # round-off: a tie
        c["map_baseline_farther"] = int((d_old > d_new + tol).sum())
        c["map_new_farther"] = int((d_new > d_old + tol).sum())
    else:
        dv = new["decimated"].vertices
        ov = old["decimated"].vertices
        c["decimate_note"] = ("same faces, vertices differ by <= %.2e" % np.abs(dv - ov).max()
                              if dv.shape == ov.shape and np.array_equal(new["decimated"].faces,
                                                                         old["decimated"].faces)
                              else "different faces")
    return c


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--psb", default=str(ROOT.parent / "shared" / "psb"))
    ap.add_argument("--per-category", type=int, default=2)
    ap.add_argument("--baseline", default="0cc7d7a")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--faces", type=int, default=4000)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    import torch
    torch.set_num_threads(1)
    import torchakvf
    with tempfile.TemporaryDirectory() as tmp:
        base = baseline_package(args.baseline, Path(tmp))
        ids = [s + j for s in CATEGORY_STARTS for j in range(args.per_category)]
        tot = {"new": dict.fromkeys(STAGES, 0.0), "old": dict.fromkeys(STAGES, 0.0)}
        rows, faces_total = [], 0
        for n, i in enumerate(ids):
            path = f"{args.psb}/meshes/{i}.off.gz"
            # Alternate which goes first, so neither always runs on a warm cache.
            order = [("new", torchakvf), ("old", base)] if n % 2 == 0 else [("old", base), ("new", torchakvf)]
            res = {}
            for tag, pkg in order:
                res[tag] = stages(pkg, path, args.repeat, args.faces)
            for tag in tot:
                for s in STAGES:
                    tot[tag][s] += res[tag][0][s]
            c = compare(res["new"][1], res["old"][1])
            nf = len(res["new"][1]["mesh"].faces)
            faces_total += nf
            rows.append((i, nf, res["new"][0], res["old"][0], c,
                         res["new"][1]["clean"].report.get("flipped_faces", 0)))
            print(i, nf, {s: round(res["old"][0][s] / max(res["new"][0][s], 1e-9), 2) for s in STAGES}, c,
                  flush=True)
    lines = [f"# Pack stage: this checkout against {args.baseline}, same run", "",
             f"{len(ids)} PSB meshes ({args.per_category} per category, ids {ids[0]}..{ids[-1]}), "
             f"{faces_total} faces in all, decimated to {args.faces} faces; one thread, "
             f"best of {args.repeat} per sub-stage, baseline and new interleaved mesh by mesh "
             "(`benchmarks/profile_pack.py`).", "",
             "| sub-stage | baseline s | new s | baseline / new |", "|---|---|---|---|"]
    for s in STAGES:
        lines.append(f"| {s} | {tot['old'][s]:.3f} | {tot['new'][s]:.3f} | "
                     f"{tot['old'][s] / max(tot['new'][s], 1e-12):.2f}x |")
    parts = [s for s in STAGES if s != "total"]
    so, sn = sum(tot["old"][s] for s in parts), sum(tot["new"][s] for s in parts)
    lines += [f"| sum of sub-stages | {so:.3f} | {sn:.3f} | {so / sn:.2f}x |", "",
              "`total` is `MeshBatch.from_meshes([load_mesh(path)], coarse_faces=...)`, the path "
              "`eval`/`bench` take (load + the bench's 'pack'); `surface_map` locates the fine "
              "vertices and face barycenters on the coarse mesh; `decimate` includes the "
              "fast_simplification (unchanged, most of it) and the relaxation, which keeps the former "
              "nearest-barycenter search (`EXACT_RELAXATION = False`) so the decimated meshes are "
              "bit-identical.", "",
              "## Outputs against the baseline", "",
              "| mesh | faces | load same | clean same | decimation same | map points | other face | "
              "baseline farther | new farther |", "|---|---|---|---|---|---|---|---|---|"]
    for i, nf, tn, to, c, flipped in rows:
        lines.append(f"| {i} | {nf} | {c['load']} | {c['clean']} | {c.get('decimate_note', c['decimate'])} | "
                     f"{c.get('map_points', '')} | {c.get('map_other_face', '')} | "
                     f"{c.get('map_baseline_farther', '')} | {c.get('map_new_farther', '')} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
