"""Shapes made in code outside the corpus's families' ranges, each with its exact part labels, to
try the CLI defaults on as a new user's shapes would come (unions of cylinders and boxes meshed by
marching cubes, with no relaxation, so flat faces that lie on grid planes leave the round-off
vertex pairs such meshes have): thin and thick tables, round and tall tables, stepped shafts,
flanges with a hub on one or both sides, a disc exactly on the grid.

    PYTHONPATH=$PWD python experiments/generality/stress_shapes.py --out /tmp/stress
    for f in /tmp/stress/*.off; do torchakvf segment $f -k $(sort -u ${f%.off}.seg | wc -l) \\
        --out /tmp/stress/out --formats seg; done
    PYTHONPATH=$PWD python experiments/generality/stress_shapes.py --score /tmp/stress out

Writes NAME.off and NAME.seg (one label per face: the primitive nearest the face's centroid) per
shape; ``--score DIR SUB [SUB ...]`` prints 1 - Rand index of DIR/SUB/NAME.seg against each truth.
``--units MESH.off [...] --out DIR`` writes each mesh (with its NAME.seg beside it) as it is
(NAME_orig), turned by a seeded rotation and scaled by 250 and moved (NAME_big), and turned by
the same rotation and scaled by 0.004 (NAME_small): the same shape in other units of length.
Result: experiments/results/generality_stress_shapes.md.
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

from torchakvf.io.outputs import write_off
from torchakvf.shapes.marching import marching_cubes
from torchakvf.shapes.sdf import Box, Ellipsoid, Torus, Union, capsule, cylinder, frame


def _save(out: Path, name: str, parts: list, h: float, lo=None, hi=None) -> None:
    if lo is None:
        lo = np.min([p.bounds()[0] for p in parts], axis=0) - 2 * h
        hi = np.max([p.bounds()[1] for p in parts], axis=0) + 2 * h
    v, f = marching_cubes(Union(tuple(parts)), lo, hi, h)
    c = v[f].mean(axis=1)
    labels = np.stack([p(c) for p in parts], axis=1).argmin(axis=1)
    write_off(out / f"{name}.off", v, f)
    np.savetxt(out / f"{name}.seg", labels, fmt="%d")
    print(name, len(f), "faces, parts", np.bincount(labels).tolist())


def _table(out, name, top_t, leg_r, inset, h, round_top=False, height=0.7):
    if round_top:
        top = cylinder((0, 0, height), (0, 0, height + top_t), 0.9)
        feet = [(0.6 * np.cos(a), 0.6 * np.sin(a)) for a in np.arange(4) * np.pi / 2 + np.pi / 4]
    else:
        top = Box(center=(0, 0, height + top_t / 2), half=(1.0, 0.6, top_t / 2))
        feet = [(x, y) for x in (-1 + inset, 1 - inset) for y in (-0.6 + inset, 0.6 - inset)]
    _save(out, name, [top] + [cylinder((x, y, 0.0), (x, y, height), leg_r) for x, y in feet], h)


def _shaft(out, name, radii, z, h):
    _save(out, name, [cylinder((0, 0, z[i]), (0, 0, z[i + 1]), r) for i, r in enumerate(radii)], h)


def _flange(out, name, t, hub_r, hub_h, h, both=False):
    parts = [cylinder((0, 0, -t / 2), (0, 0, t / 2), 1.0), cylinder((0, 0, t / 2), (0, 0, t / 2 + hub_h), hub_r)]
    if both:
        parts.append(cylinder((0, 0, -t / 2 - hub_h), (0, 0, -t / 2), hub_r))
    _save(out, name, parts, h)


def write_all(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    _table(out, "table_thin", 0.04, 0.035, 0.1, 0.012)
    _table(out, "table_thick", 0.12, 0.08, 0.12, 0.02)
    _table(out, "table_round", 0.05, 0.05, 0.0, 0.015, round_top=True)
    _table(out, "table_tall", 0.06, 0.04, 0.08, 0.015, height=1.2)
    _shaft(out, "shaft3", [0.3, 0.45, 0.25], [0, 1.0, 1.6, 2.6], 0.02)
    _shaft(out, "shaft4", [0.2, 0.3, 0.4, 0.25], [0, 0.8, 1.5, 1.9, 2.8], 0.02)
    _shaft(out, "shaft3b", [0.35, 0.25, 0.15], [0, 0.7, 1.6, 2.8], 0.018)
    _flange(out, "hub_014", 0.14, 0.3, 0.5, 0.02)
    _flange(out, "hub_010b", 0.10, 0.25, 0.6, 0.015, both=True)
    _flange(out, "hub_020", 0.2, 0.4, 0.4, 0.025)
    # on the grid: the disc's top (z = 0.07) and the hub's end are grid planes
    disc, hub = cylinder((0, 0, -0.07), (0, 0, 0.07), 1.0), cylinder((0, 0, -0.07), (0, 0, 0.7), 0.3)
    _save(out, "hub_grid", [disc, hub], 0.03, (-1.1, -1.1, -0.17), (1.1, 1.1, 0.8))


def assemblies() -> dict:
    """{name: primitives} of the second set (``--more``): everyday assemblies, organic and
    mechanical, each part a primitive: spheres stacked, a dumbbell, an L bracket, a T of pipes,
    a mug with a ring handle, a four-legged creature, a lamp, a rocket with three fins, a chair."""
    fins = [Box(center=(0.35 * np.cos(a), 0.35 * np.sin(a), 0.25),
                rotation=frame((0, 0, 1), (np.cos(a), np.sin(a), 0)), half=(0.2, 0.03, 0.25))
            for a in (0, 2 * np.pi / 3, 4 * np.pi / 3)]
    return {
        "snowman": [Ellipsoid(axes=(0.5, 0.5, 0.5)), Ellipsoid(center=(0, 0, 0.7), axes=(0.35, 0.35, 0.35)),
                    Ellipsoid(center=(0, 0, 1.18), axes=(0.22, 0.22, 0.22))],
        "dumbbell": [Ellipsoid(center=(-1, 0, 0), axes=(0.4, 0.4, 0.4)), cylinder((-0.7, 0, 0), (0.7, 0, 0), 0.12),
                     Ellipsoid(center=(1, 0, 0), axes=(0.4, 0.4, 0.4))],
        "lbracket": [Box(center=(0, 0, 0.05), half=(0.8, 0.5, 0.05)),
                     Box(center=(-0.75, 0, 0.5), half=(0.05, 0.5, 0.5))],
        "tpipe": [cylinder((-1.2, 0, 0), (1.2, 0, 0), 0.25), cylinder((0, 0, 0), (0, 1.0, 0), 0.2)],
        "mug": [cylinder((0, 0, 0), (0, 0, 1.0), 0.4),
                Torus(center=(0.5, 0, 0.5), rotation=frame((0, 1, 0)), major=0.25, minor=0.06)],
        "creature": [Ellipsoid(center=(0, 0, 0.8), axes=(0.7, 0.3, 0.3)),
                     Ellipsoid(center=(0.85, 0, 1.1), axes=(0.22, 0.17, 0.17))]
        + [capsule((x, y, 0.75), (x, y, 0.05), 0.08) for x in (-0.45, 0.45) for y in (-0.17, 0.17)],
        "lamp": [cylinder((0, 0, 0), (0, 0, 0.08), 0.5), cylinder((0, 0, 0.08), (0, 0, 1.3), 0.04),
                 Ellipsoid(center=(0, 0, 1.4), axes=(0.35, 0.35, 0.15))],
        "rocket": [cylinder((0, 0, 0), (0, 0, 1.6), 0.25),
                   Ellipsoid(center=(0, 0, 1.6), axes=(0.25, 0.25, 0.5))] + fins,
        "chair": [Box(center=(0, 0, 0.5), half=(0.4, 0.4, 0.04)), Box(center=(0, -0.37, 0.95), half=(0.4, 0.03, 0.42))]
        + [cylinder((x, y, 0), (x, y, 0.46), 0.04) for x in (-0.33, 0.33) for y in (-0.33, 0.33)],
    }


def write_more(out: Path, spacings=(0.02, 0.04)) -> None:
    """The second set at each grid spacing (NAME_h002.off, NAME_h004.off, ...)."""
    out.mkdir(parents=True, exist_ok=True)
    for name, parts in assemblies().items():
        for h in spacings:
            _save(out, f"{name}_h{round(h * 100):03d}", parts, h)


def write_units(meshes: list, out: Path, seed: int = 7) -> None:
    """NAME_orig, NAME_big (rotated, x 250, moved) and NAME_small (rotated, x 0.004) of each mesh,
    its labels copied beside each (one seeded rotation per mesh, in the order given)."""
    import shutil

    import trimesh
    from scipy.spatial.transform import Rotation

    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for path in map(Path, meshes):
        m = trimesh.load(path, process=False)
        v, f = np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces)
        rot = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        copies = {"orig": v, "big": v @ rot.T * 250.0 + np.array([1000.0, -500.0, 30.0]),
                  "small": v @ rot.T * 0.004}
        for tag, vt in copies.items():
            write_off(out / f"{path.stem}_{tag}.off", vt, f)
            shutil.copy(path.with_suffix(".seg"), out / f"{path.stem}_{tag}.seg")


def score(folder: Path, subs: list) -> None:
    from torchakvf.evaluate.metrics import rand_index_error

    print("shape", *subs)
    for off in sorted(folder.glob("*.off")):
        truth = np.loadtxt(off.with_suffix(".seg"), dtype=int)
        cells = []
        for sub in subs:
            p = folder / sub / f"{off.stem}.seg"
            cells.append(f"{rand_index_error(np.loadtxt(p, dtype=int), truth):.3f}" if os.path.exists(p) else "-")
        print(off.stem, *cells)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, help="folder to write the shapes to")
    ap.add_argument("--more", action="store_true", help="write the second set (assemblies) instead")
    ap.add_argument("--score", nargs="+", metavar=("DIR", "SUB"), help="score DIR/SUB/*.seg against DIR/*.seg")
    ap.add_argument("--units", nargs="+", metavar="MESH", help="write these meshes in other units of length to --out")
    a = ap.parse_args()
    if a.units and not a.out:
        ap.error("--units needs --out")
    if a.units:
        write_units(a.units, a.out)
    elif a.out:
        (write_more if a.more else write_all)(a.out)
    if a.score:
        score(Path(a.score[0]), a.score[1:])


if __name__ == "__main__":
    main()
