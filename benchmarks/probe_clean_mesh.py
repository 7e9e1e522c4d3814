"""Probe: ``clean_mesh`` of this checkout against a baseline revision's, on every PSB mesh.

Each mesh is loaded once (untimed) and cleaned by both versions, the order alternating from
mesh to mesh, process CPU time summed per side. Reported: both totals, their ratio, and how
many meshes' results differ (vertices, faces, face_index, face_component, report).

    python benchmarks/probe_clean_mesh.py --baseline 98dc6ee
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from torchakvf.io import load_mesh
from torchakvf.mesh.clean import clean_mesh
from timing import module_at_revision

ROOT = Path(__file__).resolve().parents[1]


def baseline_clean(rev: str):
    """torchakvf/mesh/clean.py as of git revision ``rev``, as a module of torchakvf.mesh."""
    return module_at_revision(rev, "torchakvf/mesh/clean.py", "torchakvf.mesh._baseline_clean")


def same(a, b) -> bool:
    return (np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
            and np.array_equal(a.face_index, b.face_index)
            and np.array_equal(a.face_component, b.face_component) and a.report == b.report)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--psb", default=str(ROOT.parent / "shared" / "psb"))
    ap.add_argument("--baseline", default="98dc6ee")
    args = ap.parse_args()
    base = baseline_clean(args.baseline)
    files = sorted((Path(args.psb) / "meshes").glob("*.off*"))
    t_new = t_old = 0.0
    differ = []
    for i, path in enumerate(files):
        mesh = load_mesh(path)
        for side in (("new", "old") if i % 2 == 0 else ("old", "new")):
            t = time.process_time()
            out = (clean_mesh if side == "new" else base.clean_mesh)(mesh)
            dt = time.process_time() - t
            if side == "new":
                t_new, a = t_new + dt, out
            else:
                t_old, b = t_old + dt, out
        if not same(a, b):
            differ.append(path.name)
    print(f"{len(files)} meshes: baseline {args.baseline} {t_old:.1f} s, this checkout {t_new:.1f} s "
          f"({t_old / t_new:.2f}x); results differ on {len(differ)} {differ[:5]}")


if __name__ == "__main__":
    main()
