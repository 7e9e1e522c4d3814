"""The device check's evaluation (benchmarks/device_check.sh step 2): one batched ``eval`` of the
PSB meshes given (40-60 with mesh 114 on a GPU), then the same few meshes batched and one at a
time, in one process; writes one JSON file of figures.

* **eval**: ``evaluate_psb(..., batched=True)`` on ``--device``: wall seconds, the run's stage
  timings (settings.json: pack / akvf / rounds in the solving process, prepare / cut / score in
  the host workers, the share of wall time the solving process waited for host work), peak
  reserved device memory (``torch.cuda.max_memory_reserved``), host synchronizations of the
  solving process counted in CUDA's sync debug mode (``torch.cuda.set_sync_debug_mode("warn")``:
  one warning per synchronizing call; 0 and "n/a" on the CPU), meshes failed, overall 1-RI.
* **ratio**: the first ``--ratio-meshes`` meshes (114 among them) batched (the default memory
  budget) and one mesh per batch (a budget of one byte), same process, same settings:
  one-at-a-time seconds / batched seconds (> 1: batching is faster).

    python benchmarks/device_eval.py --psb .psb_subset --device cuda --out results.json
"""
from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import torch

from torchakvf.evaluate.harness import evaluate_psb
from torchakvf.evaluate.plan import find_entries


class SyncCounter:
    """Counts CUDA's synchronizing calls in this process (sync debug mode "warn")."""

    def __init__(self, device: str):
        self.on = str(device).startswith("cuda")
        self.count = 0

    def __enter__(self):
        if self.on:
            self._catch = warnings.catch_warnings()
            self._catch.__enter__()
            warnings.simplefilter("always")
            self._show = warnings.showwarning
            warnings.showwarning = self._seen
            torch.cuda.set_sync_debug_mode("warn")
        return self

    def _seen(self, message, category, *args, **kwargs):
        if "synchroniz" in str(message):
            self.count += 1
        else:
            self._show(message, category, *args, **kwargs)

    def __exit__(self, *exc):
        if self.on:
            torch.cuda.set_sync_debug_mode(0)
            warnings.showwarning = self._show
            self._catch.__exit__(*exc)
        return False


def eval_run(psb, out, ids, device, common, **extra) -> dict:
    if str(device).startswith("cuda"):
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    with SyncCounter(device) as syncs:
        summary = evaluate_psb(psb, out, progress=False, ids=ids, device=device, batched=True, **common, **extra)
    wall = time.perf_counter() - t0
    run = json.loads((Path(out) / "settings.json").read_text())["run"]
    return {"meshes": len(summary.rows), "failed": sum(r.status.startswith("failed") for r in summary.rows),
            "wall_seconds": wall, "rand_index_error": summary.rand_index_error,
            "timings": run.get("timings"), "batch_faces": run.get("batch_faces"),
            "syncs": syncs.count if syncs.on else "n/a",
            "peak_reserved_mib": (torch.cuda.max_memory_reserved() / 2**20
                                  if str(device).startswith("cuda") else "n/a")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--psb", required=True)
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--out", required=True, help="the JSON file of figures")
    ap.add_argument("--ids", default=None, help="mesh ids (default: every mesh under --psb)")
    ap.add_argument("--ratio-meshes", type=int, default=8)
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--coarse-faces", type=int, default=4000)
    ap.add_argument("--n-fields", type=int, default=None)
    ap.add_argument("--protocol", default="by-segmentation")
    args = ap.parse_args()
    entries, _ = find_entries(Path(args.psb))
    ids = sorted(e.mesh_id for e in entries) if args.ids is None else [int(i) for i in args.ids.split(",")]
    common = dict(coarse_faces=args.coarse_faces or None, n_fields=args.n_fields, protocol=args.protocol,
                  metrics="rand", plot=False, workers=args.workers)
    work = Path(tempfile.mkdtemp(prefix="device_eval_"))
    figures = {"device": args.device, "ids": ids, "settings": {k: v for k, v in common.items()},
               "torch": torch.__version__,
               "gpu": torch.cuda.get_device_name() if args.device.startswith("cuda") else None}
    try:
        t0 = time.perf_counter()
        figures["eval"] = eval_run(args.psb, work / "eval", ids, args.device, common)
        print("eval", json.dumps(figures["eval"]), flush=True)
        Path(args.out).write_text(json.dumps(figures, indent=1))    # kept if the ratio runs time out
        sub = ([114] if 114 in ids else []) + [i for i in ids if i != 114][:max(args.ratio_meshes - 1, 1)]
        figures["ratio_ids"] = sub
        batched = eval_run(args.psb, work / "batched", sub, args.device, common)
        alone = eval_run(args.psb, work / "alone", sub, args.device, common, batch_bytes=1)
        figures["ratio"] = {"batched": batched, "one_at_a_time": alone,
                            "one_at_a_time_over_batched": alone["wall_seconds"] / batched["wall_seconds"]}
        figures["seconds"] = time.perf_counter() - t0
    finally:
        shutil.rmtree(work, ignore_errors=True)
        Path(args.out).write_text(json.dumps(figures, indent=1))
    print("ratio one at a time / batched", figures["ratio"]["one_at_a_time_over_batched"])


if __name__ == "__main__":
    main()
