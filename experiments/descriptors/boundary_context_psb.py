"""Does neighbourhood context of the boundary probability help a PSB-trained model? Tried, not
shipped (experiments/results/boundary_probability.md).

Per face of each cached PSB mesh (descriptor_pass cache version 6): the max and the mean of
``boundary_probability`` over the faces within 2 and 4 dual rings (4 columns), added to the 48
package columns, alone and beside the classical ones, in learn_boundaries.py's protocol; gains
against the classical row of benchmarks/results/learn_boundaries.json. Run from the repository
root::

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 nice python experiments/descriptors/boundary_context_psb.py CACHE PSB_DIR
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import descriptor_pass as dp  # noqa: E402
import learn_boundaries as lb  # noqa: E402

from torchakvf.parts.concavity import dual_edges  # noqa: E402
from torchakvf.parts.creases import dual_ball  # noqa: E402


def context(d: dict) -> np.ndarray:
    """[F, 4] float32: max and mean of the probability over the distinct faces within 2, then 4
    dual rings (the face itself included). The figures in the result file were made with an
    earlier gathering of the rings (a neighbour table, since removed from the package) whose mean
    counted a face once per walk reaching it; the max is the same."""
    v, f = d["packed_vertices"], d["packed_faces"].astype(np.int64)
    pairs = dual_edges(v, f).pairs
    p = d["akvf_boundary"][:, 0].astype(np.float64)
    cols = []
    for r in (2, 4):
        ball = dual_ball(pairs, len(f), r)                     # every row holds its own face
        cols += [np.maximum.reduceat(p[ball.indices], ball.indptr[:-1]), (ball @ p) / np.diff(ball.indptr)]
    return np.column_stack(cols).astype(np.float32)


def main() -> None:
    torch.set_num_threads(1)
    data, _ = dp.load_all(sys.argv[2], Path(sys.argv[1]), compute=False)
    data = [d for d in data if "target" in d]
    for d in data:
        d["ctx"] = context(d)
    ref = json.loads((ROOT / "benchmarks" / "results" / "learn_boundaries.json").read_text())["rows"]
    cats = list(ref[lb.CLASSICAL_ROW]["per_category"])
    cl = np.array([ref[lb.CLASSICAL_ROW]["per_category"][c]["majority"] for c in cats])
    package = ("akvf", "akvf_parts", "cues", "akvf_boundary", "ctx")
    for name, cols in (("48 + context", lb._columns(*package)),
                       ("classical + 48 + context", lb._columns(*lb.CLASSICAL, *package))):
        per = lb.leave_one_category_out(data, cols)
        m = np.array([per[c]["majority"] for c in cats])
        g = m - cl
        print(f"{name}: AP {m.mean():.3f} ± {m.std():.3f}; against classical {g.mean():+.3f} ± {g.std():.3f} "
              f"({(g > 0).sum()} of 15):", " ".join(f"{c} {x:+.3f}" for c, x in zip(cats, g)), flush=True)


if __name__ == "__main__":
    main()
