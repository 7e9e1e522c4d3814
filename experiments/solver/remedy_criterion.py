"""Which meshes need the "smooth" remedy, and what tells them apart.

For the built-in shapes and PSB meshes (decimated as eval solves them, ~4000 faces): geometric
statistics one might decide by (fraction of edges with a negative cotangent weight star1, of
edges under the remedy's floor 0.1 mean |star1|, smallest corner angle, largest angle defect),
the decision of remedy="auto" (the paper's operator factors at σ = SPURIOUS_BELOW or not,
torchakvf.operators.remedy_choice) and its cost, and with --solve the outcome of the paper's
operator (remedy="none"): whether it solves, its smallest eigenvalue, how many of its n
eigenvalues lie below SPURIOUS_BELOW. Writes a CSV; summarise with remedy_criterion_report.py.

    PYTHONPATH=$PWD nice python3 experiments/solver/remedy_criterion.py --ids 1-400 --out /tmp/remedy_auto.csv
    PYTHONPATH=$PWD nice python3 experiments/solver/remedy_criterion.py --ids 1-400:4 --solve \\
        --out /tmp/remedy_solve.csv
"""
from __future__ import annotations

import argparse
import csv
import math
import time

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import SolverError
from torchakvf.evaluate.psb import category_of, default_psb_root, find_psb_meshes
from torchakvf.operators import batch_geometry, dec, killing_operator
from torchakvf.solvers.akvf_solver import SPURIOUS_BELOW, AKVFSolver

BUILTIN = {**shapes.BUILTIN_SHAPES, "ellipsoid": shapes.ellipsoid, "icosphere": shapes.icosphere,
           "torus": shapes.torus, "capped_cylinder": shapes.capped_cylinder, "table": shapes.table,
           "mug": shapes.mug, "hemisphere": shapes.hemisphere, "square_patch": shapes.square_patch}


def parse_ids(text: str) -> list[int]:
    rng, _, step = text.partition(":")
    lo, _, hi = rng.partition("-")
    return list(range(int(lo), int(hi or lo) + 1, int(step or 1)))


def mesh_quality(batch) -> dict:
    """Geometric statistics of a one-mesh batch."""
    geo = batch_geometry(batch)
    s1 = dec.star1(batch, geo)
    mean_abs = s1.abs().mean()
    theta = dec.angle_defect(batch, geo).abs()
    return dict(negative_fraction=float((s1 < -1e-9 * mean_abs).double().mean()),
                below_floor_fraction=float((s1 < 0.1 * mean_abs).double().mean()),
                min_angle_deg=math.degrees(float(geo.angle.min())),
                max_angle_defect=float(theta.max()))


def decision(batch) -> dict:
    t0 = time.perf_counter()
    killing_operator(batch, remedy="none")
    t1 = time.perf_counter()
    remedy = killing_operator(batch, remedy="auto").remedies[0]
    t2 = time.perf_counter()
    killing_operator(batch, remedy="smooth")
    t3 = time.perf_counter()
    return dict(auto=remedy, seconds_none=t1 - t0, seconds_auto=t2 - t1, seconds_smooth=t3 - t2)


def outcome(batch, n: int) -> dict:
    t0 = time.perf_counter()
    try:
        res = AKVFSolver(batch, remedy="none", full_resolution_fallback=False).solve(n)
        lam = res.eigenvalues[0]
        out = dict(solved=1, min_eig=float(lam.min()), below=int((lam < SPURIOUS_BELOW).sum()))
    except SolverError:
        out = dict(solved=0, min_eig=math.nan, below=-1)
    out["seconds_solve"] = time.perf_counter() - t0
    return out


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--ids", default="1-400")
    p.add_argument("--n", type=int, default=24)
    p.add_argument("--coarse-faces", type=int, default=4000, help="0: full resolution")
    p.add_argument("--solve", action="store_true", help="also solve the paper's operator")
    p.add_argument("--out", default="/tmp/remedy_auto.csv")
    a = p.parse_args()
    entries = {e.mesh_id: e for e in find_psb_meshes(default_psb_root())}
    items = [(f"builtin:{name}", fn) for name, fn in BUILTIN.items()]
    items += [(str(i), entries[i]) for i in parse_ids(a.ids) if i in entries]
    rows = []
    for name, src in items:
        if name.startswith("builtin:"):
            shape = src()
            batch, cat = ta.MeshBatch.from_meshes([ta.Mesh(shape.vertices, shape.faces, name=name)]), "builtin"
        else:
            mesh = ta.load_mesh(src.mesh_path)
            batch, cat = ta.MeshBatch.from_meshes([mesh], coarse_faces=a.coarse_faces or None), category_of(int(name))
        row = dict(mesh=name, category=cat, faces=len(batch.faces), decimated=int(batch.coarse_of(0) is not None),
                   **mesh_quality(batch), **decision(batch), **(outcome(batch, a.n) if a.solve else {}))
        print(row, flush=True)
        rows.append(row)
        with open(a.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader(), w.writerows(rows)


if __name__ == "__main__":
    main()
