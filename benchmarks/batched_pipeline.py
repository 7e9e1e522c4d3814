"""The batched evaluation's host/device overlap on the CPU: the same PSB meshes and batches through

* ``base``: the code before the batched pipeline (``--base-code DIR``: a checkout of it), its
  batched path in one process (load, clean, decimate, solve, cut one after another);
* ``inline``: this code's batched path with ``workers=1`` (every stage in the solving process);
* ``overlap``: this code's batched path with ``workers=W`` (W - 1 host workers feed the solving
  process and cut its batches);

interleaved (base, inline, overlap, base, ...) ``--repeats`` times, each run a fresh process and
output folder. ``--threads 1`` gives every run's solving process one BLAS thread (the host workers
have one either way): without it the overlap runs' solving process may read the workers' thread
setting (it is in the environment while their pool runs) and the runs differ by more than the
overlap. Prints one JSON line per run (wall seconds; the run's own stage timings from its
settings.json) and a summary: median walls, the same-run ratios base / overlap and inline /
overlap, and the share of wall time the solving process spent on host work or waiting for it.

    python benchmarks/batched_pipeline.py --psb ../shared/psb --ids 1-24 --base-code /tmp/base \
        --out /tmp/bp --workers 2 --repeats 2 --threads 1
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

RUN = """
import json, sys, time
from torchakvf.evaluate.harness import evaluate_psb
a = json.loads(sys.argv[1])
t = time.perf_counter()
evaluate_psb(a.pop("psb"), a.pop("out"), progress=False, **a)
print("WALL", time.perf_counter() - t)
"""


#: Thread-count variables of the BLAS/OpenMP runtimes (set for every run alike with --threads).
THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def run(code_dir: str, kwargs: dict, threads: int | None) -> float:
    env = dict(os.environ, PYTHONPATH=code_dir)
    if threads:
        env.update({v: str(threads) for v in THREAD_VARS})
    # run in code_dir: ``python -c`` puts the working folder first on sys.path
    res = subprocess.run([sys.executable, "-c", RUN, json.dumps(kwargs)], env=env, capture_output=True,
                         text=True, check=True, cwd=code_dir)
    return float([ln for ln in res.stdout.splitlines() if ln.startswith("WALL")][-1].split()[1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--psb", required=True)
    ap.add_argument("--ids", required=True)
    ap.add_argument("--base-code", required=True, help="folder holding the baseline's torchakvf/")
    ap.add_argument("--out", required=True)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--coarse-faces", type=int, default=1000)
    ap.add_argument("--n-fields", type=int, default=16)
    ap.add_argument("--batch-faces", type=int, default=8000)
    ap.add_argument("--threads", type=int, default=None,
                    help="BLAS/OpenMP threads of every run's solving process (default: the runtime's)")
    args = ap.parse_args()
    here = str(Path(__file__).resolve().parents[1])
    common = dict(psb=args.psb, ids=args.ids, coarse_faces=args.coarse_faces, n_fields=args.n_fields,
                  batch_faces=args.batch_faces, metrics="rand", plot=False, batched=True)
    configs = {"base": (args.base_code, dict(workers=1)),
               "inline": (here, dict(workers=1, batch_bytes=2**40)),
               "overlap": (here, dict(workers=args.workers, batch_bytes=2**40))}
    walls: dict = {name: [] for name in configs}
    shares: dict = {name: [] for name in configs}
    for rep in range(args.repeats):
        for name, (code, extra) in configs.items():
            out = Path(args.out) / f"{name}-{rep}"
            wall = run(code, dict(common, out=str(out), **extra), args.threads)
            timings = json.loads((out / "settings.json").read_text())["run"].get("timings")
            walls[name].append(wall)
            if timings:
                shares[name].append(timings["host_share"])
            print(json.dumps({"run": name, "repeat": rep, "wall": round(wall, 2), "timings": timings,
                              "at": time.strftime("%H:%M:%S")}), flush=True)
    med = {n: statistics.median(w) for n, w in walls.items()}
    print(json.dumps({"median_wall": med,
                      "ratio_base_over_overlap": [b / o for b, o in zip(walls["base"], walls["overlap"])],
                      "ratio_inline_over_overlap": [i / o for i, o in zip(walls["inline"], walls["overlap"])],
                      "median_host_share": {n: statistics.median(s) for n, s in shares.items() if s}}))


if __name__ == "__main__":
    main()
