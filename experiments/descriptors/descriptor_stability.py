"""How much the per-face descriptor columns (48 at the default counts) move under another seed,
another solver path and a rigid motion with renumbered vertices and faces (docs/descriptors.md,
Stability).

For each mesh (PSB meshes decimated to 4000 faces, built-in shapes and three procedural corpus
shapes decimated the same way) the descriptors of ``interop.face_features`` on the input faces are computed for

* ``base``: seed 0, the default solver;
* ``seed``: seed 1 (the eigensolver's start and the untangling's restarts);
* ``solver``: seed 0, the other CPU eigensolver ("lobpcg" against the default "auto");
* ``motion``: seed 0 on a copy rotated and translated, with vertices and faces renumbered
  (rows mapped back to the base's faces before comparing).

Relative difference of a column a against its base column a0 (both [F], on the input faces):
rel(a, a0) = ||a - a0|| / ||a0|| (Euclidean norms over the faces, each face weighted by its
area in the unit-area frame, so a finely tessellated region does not count more). The
descriptor matrix's relative difference is the worst column's. We also report
``rel_c`` = ||a - a0|| / ||a0 - mean(a0)||, the difference against the column's spread, which
an additive offset (log columns) cannot hide.

    PYTHONPATH=. TORCHAKVF_PSB=/work/shared/psb OMP_NUM_THREADS=1 nice python \
        experiments/descriptors/descriptor_stability.py --out experiments/results/descriptor_stability.md

Also records the process CPU seconds of each ``face_features`` call (one thread).

``--evenness ID ...`` instead compares how evenly the segmentation's decimation (the input's
frame and numbering) and the descriptors' canonical one cut PSB meshes to 4000 faces: the
coefficient of variation of the coarse faces' areas, per mesh and on average (the result file
used every 13th mesh from 3: ``--evenness $(seq 3 13 400)``).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from torchakvf import Mesh, MeshBatch, load_mesh
from torchakvf.evaluate.psb import default_psb_root
from torchakvf.mesh.clean import face_areas
from torchakvf.shapes.procedural import procedural_shape

PSB_IDS = (1, 21, 121)
SHAPES = ("quadruped", "table", "fish", "dumbbell", "three_blobs", "sphere_with_two_ellipsoids", "torus_chain")
#: Shapes of the procedural corpus (family, seed) outside the boundary probability's fitted ten.
PROCEDURAL = (("humanoid", 123), ("chair", 123), ("octopus", 321))
COARSE = 4000
#: Built-in shapes with exact symmetries (surfaces of revolution, mirror and rotation
#: symmetric arrangements): their principal axes, fields and segmentations have ties that
#: round-off decides, reported apart.
SYMMETRIC = ("table", "dumbbell", "three_blobs", "sphere_with_two_ellipsoids", "torus_chain")


def moved_renumbered(mesh: Mesh, seed: int = 3) -> tuple[Mesh, np.ndarray]:
    """(a rigidly moved (rotated, translated), renumbered copy, pf: its face i is the input's
    face pf[i])."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    v = np.asarray(mesh.vertices, dtype=np.float64) @ q.T + np.array([1.0, -2.0, 0.5])
    pv = rng.permutation(len(v))
    pf = rng.permutation(len(mesh.faces))
    return Mesh(v[pv], np.argsort(pv)[np.asarray(mesh.faces)][pf]), pf


def descriptors(mesh: Mesh, seed: int = 0, solver: str = "auto") -> tuple[np.ndarray, list, float]:
    """([F, d] descriptors on the input faces, names, CPU seconds)."""
    import importlib

    from torchakvf.interop import face_features
    akvf_mod = importlib.import_module("torchakvf.fields.akvf")

    t = time.process_time()
    batch = MeshBatch.from_meshes([mesh], coarse_faces=COARSE)
    if solver == "auto":
        ff = face_features(batch, 32, seed=seed)[0]
    else:
        original = akvf_mod.akvf_falling_back

        def with_solver(b, n=32, **kw):
            return original(b, n=n, solver=solver, **kw)
        akvf_mod.akvf_falling_back = with_solver
        try:
            ff = face_features(batch, 32, seed=seed)[0]
        finally:
            akvf_mod.akvf_falling_back = original
    return ff.descriptors, ff.descriptor_names, time.process_time() - t


def rel(a: np.ndarray, a0: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[d] rel and rel_c of each column (module docstring)."""
    diff = np.sqrt(w @ (a - a0) ** 2)
    norm = np.sqrt(w @ a0 ** 2)
    spread = np.sqrt(w @ (a0 - w @ a0) ** 2)
    return diff / np.maximum(norm, 1e-300), diff / np.maximum(spread, 1e-300)


def meshes():
    from torchakvf import shapes
    root = default_psb_root()
    out = []
    if root is not None:
        for i in PSB_IDS:
            out.append((f"psb{i}", load_mesh(root / "meshes" / f"{i}.off.gz")))
    for name in SHAPES:
        s = getattr(shapes, name)()
        out.append((name, Mesh(np.asarray(s.vertices), np.asarray(s.faces))))
    for family, seed in PROCEDURAL:
        s = procedural_shape(family, seed)
        out.append((f"{family}{seed}", Mesh(np.asarray(s.vertices), np.asarray(s.faces))))
    return out


def group(name: str) -> str:
    return name.split("@")[0].rsplit("_", 1)[0] if name.startswith(("contrast", "coherence", "cut_share")) \
        else name.split("@")[0]


def evenness(ids) -> None:
    from torchakvf.mesh.clean import clean_mesh
    from torchakvf.mesh.coarse import DECIMATE_ABOVE, decimate
    root = default_psb_root()
    cv = {False: [], True: []}
    for i in ids:
        path = root / "meshes" / f"{i}.off.gz"
        if not path.exists():
            continue
        m = clean_mesh(load_mesh(path))
        if len(m.faces) <= DECIMATE_ABOVE * COARSE:
            continue
        for canonical in cv:
            d = decimate(m, COARSE, canonical=canonical)
            a = face_areas(np.asarray(d.vertices), np.asarray(d.faces))
            cv[canonical].append(a.std() / a.mean())
        print(f"PSB {i}: input frame {cv[False][-1]:.3f}, canonical {cv[True][-1]:.3f}", flush=True)
    print(f"{len(cv[True])} meshes, mean (median): input frame {np.mean(cv[False]):.3f} "
          f"({np.median(cv[False]):.3f}), canonical {np.mean(cv[True]):.3f} ({np.median(cv[True]):.3f})")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--evenness", type=int, nargs="*", default=None)
    ap.add_argument("--out", default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--from-json", default=None, help="rewrite the report of an earlier --json")
    args = ap.parse_args()
    if args.evenness:
        evenness(args.evenness)
        return
    if args.from_json:
        saved = json.loads(Path(args.from_json).read_text())
        names, cpu = saved.pop("names"), saved.pop("cpu", [])
        rows = {tuple(k.split("/")): (np.array(v[0]), np.array(v[1])) for k, v in saved.items()}
        report(rows, names, cpu, args)
        return
    rows = {}
    cpu = []
    names = None
    for label, mesh in meshes():
        if args.only and label not in args.only:
            continue
        v = np.asarray(mesh.vertices, dtype=np.float64)
        a = face_areas(v, np.asarray(mesh.faces))
        w = a / a.sum()
        base, names, t0 = descriptors(mesh, 0)
        cpu.append(t0)
        other, _, _ = descriptors(mesh, 1)
        rows[(label, "seed")] = rel(other, base, w)
        other, _, _ = descriptors(mesh, 0, solver="lobpcg")
        rows[(label, "solver")] = rel(other, base, w)
        moved, pf = moved_renumbered(mesh)
        other, _, _ = descriptors(moved, 0)
        back = np.empty_like(other)
        back[pf] = other
        rows[(label, "motion")] = rel(back, base, w)
        print(label, {k: float(rows[(label, k)][0].max()) for k in ("seed", "solver", "motion")}, f"{t0:.2f}s",
              flush=True)
    report(rows, names, cpu, args)


def report(rows, names, cpu, args):
    kinds = ("seed", "solver", "motion")
    every = list(dict.fromkeys(k[0] for k in rows))
    plain = [m for m in every if m not in SYMMETRIC]
    text = "Worst over all meshes:\n\n" + group_table(rows, names, every) + \
        f"\n\nWorst over the meshes without exact symmetries ({', '.join(plain)}):\n\n" + \
        group_table(rows, names, plain)
    per_mesh = ["| mesh | " + " | ".join(kinds) + " |", "|---|" + "---:|" * len(kinds)]
    for lab in every:
        per_mesh.append(f"| {lab} | " + " | ".join(f"{rows[(lab, k)][0].max():.2g}" for k in kinds) + " |")
    text += "\n\nworst column per mesh (rel):\n\n" + "\n".join(per_mesh) + \
        f"\n\nCPU seconds per face_features call (seed 0): {', '.join(f'{c:.2f}' for c in cpu)}\n"
    print(text)
    if args.out:
        Path(args.out).write_text(text)
    if args.json:
        Path(args.json).write_text(json.dumps({f"{a}/{b}": [r[0].tolist(), r[1].tolist()]
                                               for (a, b), r in rows.items()} | {"names": names, "cpu": cpu}))


def group_table(rows, names, labels) -> str:
    groups = list(dict.fromkeys(group(n) for n in names))
    kinds = ("seed", "solver", "motion")
    lines = ["| column group | " + " | ".join(f"{k} rel (rel_c)" for k in kinds) + " |",
             "|---|" + "---:|" * len(kinds)]
    for g in groups:
        cols = [i for i, n in enumerate(names) if group(n) == g]
        cells = []
        for k in kinds:
            r = max(rows[(lab, k)][0][cols].max() for lab in labels)
            rc = max(rows[(lab, k)][1][cols].max() for lab in labels)
            cells.append(f"{r:.2g} ({rc:.2g})")
        lines.append(f"| {g} | " + " | ".join(cells) + " |")
    cells = [f"{max(rows[(lab, k)][0].max() for lab in labels):.2g} "
             f"({max(rows[(lab, k)][1].max() for lab in labels):.2g})" for k in kinds]
    lines.append(f"| **all {len(names)} (worst column)** | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
