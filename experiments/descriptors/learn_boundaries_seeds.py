"""Is the spread of the descriptors' gain the categories' or the model's? The two rows of
``benchmarks/learn_boundaries.py`` whose paired gain is the descriptors' headline (classical; classical +
the package's 48 columns), trained with several model seeds, everything else as the benchmark.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 python experiments/descriptors/learn_boundaries_seeds.py \\
        --cache DIR --seeds 0,1,2,3,4 --out /tmp/learn_seeds.json

Prints each seed's gain (mean ± std over the held-out categories), the gain per category
averaged over the seeds, and how much one category's gain moves between seeds.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import descriptor_pass  # noqa: E402
import learn_boundaries as lb  # noqa: E402

WITH, WITHOUT = "classical + package descriptors", lb.CLASSICAL_ROW


def main(argv=None) -> int:
    ap = descriptor_pass.cache_parser(__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    data, _ = descriptor_pass.load_all(args.psb, Path(args.cache), compute=False)
    data = [d for d in data if "target" in d]
    seeds = [int(s) for s in args.seeds.split(",")]
    ap_of = {}
    for seed in seeds:
        lb.SEED = seed                      # fit_predict reads the module's seed
        for row in (WITHOUT, WITH):
            per_cat = lb.leave_one_category_out(data, lb.ROWS[row])
            ap_of[seed, row] = {c: v["majority"] for c, v in per_cat.items()}
        cats = list(ap_of[seed, WITHOUT])
        g = np.array([ap_of[seed, WITH][c] - ap_of[seed, WITHOUT][c] for c in cats])
        print(f"seed {seed}: gain {g.mean():+.3f} ± {g.std():.3f}", flush=True)
    gains = np.array([[ap_of[s, WITH][c] - ap_of[s, WITHOUT][c] for c in cats] for s in seeds])
    mean = gains.mean(0)
    print(f"averaged over seeds: {mean.mean():+.3f} ± {mean.std():.3f}; one category's gain moves by "
          f"{gains.std(0).mean():.3f} between seeds (std, mean over categories)")
    for c, m, s in zip(cats, mean, gains.std(0)):
        print(f"  {c}: {m:+.3f} (seed std {s:.3f})")
    if args.out:
        Path(args.out).write_text(json.dumps({f"{s}|{r}": v for (s, r), v in ap_of.items()}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
