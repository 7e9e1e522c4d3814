"""Does decimation flatten thin parts? The share of a fine surface's area whose faces point
against the decimated face under their barycentre (normals' dot product < 0): a part thinner
than the decimated edges (a disc, a fin, a cup's wall) collapsed into a sheet puts one of its
sides there.

    python experiments/generality/thin_parts.py --budgets 4000,8000,16000 MESH [MESH ...]
    python experiments/generality/thin_parts.py --thin-hub 0.03 --out /tmp/thin_hub_0.03.off

The first prints one line per mesh: for each budget the share with dot < 0 and with dot < 0.5 ("-" where
the mesh has at most 1.25x the budget and is not decimated). The second writes a flanged hub
(a disc of radius 1 and thickness 2 HALF, a hub of radius 0.3 to z = 0.7; marching cubes at a
step of min(0.03, HALF / 1.5)) and its two-part truth (.seg beside it). Result:
experiments/results/generality_decimation.md.
"""
from __future__ import annotations

import argparse
import warnings

import numpy as np

from torchakvf.io import load_mesh
from torchakvf.io.outputs import write_off
from torchakvf.mesh.clean import clean_mesh
from torchakvf.mesh.coarse import DECIMATE_ABOVE, coarse_mesh_at, folded_share
from torchakvf.shapes.marching import marching_cubes
from torchakvf.shapes.sdf import Union, cylinder


def flipped_shares(path: str, budget: int) -> tuple[float, float] | None:
    """(area share with dot < 0, with dot < 0.5) of ``path`` decimated to ``budget`` faces
    (once: not made again where it folds, as the pipeline's :func:`coarse_mesh` does)."""
    fine = clean_mesh(load_mesh(path))
    if len(fine.faces) <= DECIMATE_ABOVE * budget:
        return None
    cm = coarse_mesh_at(fine, budget)
    return folded_share(cm), folded_share(cm, 0.5)


def write_thin_hub(half: float, out: str) -> None:
    """The flanged hub of disc half-thickness ``half`` to ``out`` (OFF) and its truth (.seg)."""
    disc, hub = cylinder((0, 0, -half), (0, 0, half), 1.0), cylinder((0, 0, -half), (0, 0, 0.7), 0.3)
    v, f = marching_cubes(Union((disc, hub)), (-1.1, -1.1, -half - 0.1), (1.1, 1.1, 0.8), min(0.03, half / 1.5))
    centers = v[f].mean(axis=1)
    labels = (hub(centers) < disc(centers)).astype(int)          # the nearer part's surface
    write_off(out, v, f)
    np.savetxt(out.rsplit(".", 1)[0] + ".seg", labels, fmt="%d")
    print(out, len(f), "faces, parts", np.bincount(labels).tolist())


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--budgets", default="4000", help="comma-separated face budgets (default 4000)")
    p.add_argument("--thin-hub", type=float, metavar="HALF", help="write a flanged hub instead (see above)")
    p.add_argument("--out", help="where --thin-hub writes its OFF")
    p.add_argument("meshes", nargs="*")
    args = p.parse_args()
    warnings.simplefilter("ignore")
    if args.thin_hub is not None:
        write_thin_hub(args.thin_hub, args.out)
        return
    budgets = [int(b) for b in args.budgets.split(",")]
    for path in args.meshes:
        cells = []
        for b in budgets:
            r = flipped_shares(path, b)
            cells.append(f"{b}: -" if r is None else f"{b}: {r[0]:.4f}/{r[1]:.4f}")
        print(path.split("/")[-1], *cells, flush=True)


if __name__ == "__main__":
    main()
