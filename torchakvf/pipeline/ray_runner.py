"""Optional Ray executor for the corpus runner (``pip install torchakvf[ray]``).

The driver does what :func:`~torchakvf.pipeline.run_corpus` does before and after the work
(resume check, size peek, face-budget batches, the manifest); the batches themselves are mapped
with ``ray.data`` over a pool of actors, one per slot (e.g. one per GPU), each running the same
:func:`~torchakvf.pipeline.runner.process_batch` and writing the outputs atomically into
``out_dir`` (a folder every worker can reach: local mode or a shared file system). Workers return
the manifest records; the driver appends them as they stream in.

Status: written against the ray.data API of ray >= 2.9 (``map_batches`` with a callable class and
``concurrency``); ray is not installed where this was written, so it is exercised only by the
``pytest.importorskip("ray")`` test in tests/test_pipeline.py.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from .runner import (ManifestWriter, RunSummary, check_output_dir, default_batch_faces, Item,
                     log, peek_faces, plan_batches, prepare, process_batch)


class _BatchWorker:
    """A ray.data actor: loads, computes and writes one batch of meshes per row."""

    def __init__(self, task, out_dir: str, device: str, seed: int):
        self.task, self.out_dir, self.device, self.seed = task, Path(out_dir), device, seed

    def __call__(self, rows: dict) -> dict:
        out = []
        for spec in rows["batch"]:
            items = [Item(Path(p), k, s, f if f >= 0 else None) for p, k, s, f in json.loads(spec)]
            out.append(json.dumps(process_batch(items, self.task, self.out_dir, self.device, self.seed)))
        return {"records": out}


def run_corpus_ray(paths, out_dir, task, *, batch_faces: int | None = None, device: str = "cpu",
                   seed: int = 0, resume: bool = True, workers: int = 1,
                   gpus_per_worker: float = 0.0) -> RunSummary:
    """:func:`run_corpus` with the batches spread over ``workers`` Ray actors.

    ``ray.init()`` is called (local) unless Ray is already initialized; set
    ``gpus_per_worker=1`` and ``device="cuda"`` for one actor per GPU.
    """
    try:
        import ray
    except ImportError:
        from ..errors import TorchAKVFError

        raise TorchAKVFError("the Ray runner needs ray: pip install 'torchakvf[ray]'") from None
    t0 = time.perf_counter()
    out_dir = check_output_dir(out_dir)
    batch_faces = int(batch_faces) if batch_faces is not None else default_batch_faces(device)
    todo, skipped = prepare(list(paths), out_dir, task, seed=seed, resume=resume)
    for it in todo:
        it.faces = peek_faces(it.path)
    batches = plan_batches(todo, batch_faces)
    summary = RunSummary(skipped=len(skipped), manifest=out_dir / "manifest.jsonl")
    if not batches:
        summary.elapsed = time.perf_counter() - t0
        return summary
    if not ray.is_initialized():
        ray.init()
    specs = [json.dumps([[str(it.path), it.key, it.stem, -1 if it.faces is None else it.faces]
                         for it in b]) for b in batches]
    ds = ray.data.from_items([{"batch": s} for s in specs])
    extra = {"num_gpus": gpus_per_worker} if gpus_per_worker else {}
    ds = ds.map_batches(_BatchWorker, batch_size=1, concurrency=max(int(workers), 1),
                        fn_constructor_kwargs=dict(task=task, out_dir=str(out_dir), device=device, seed=seed),
                        **extra)
    writer = ManifestWriter(out_dir)
    try:
        for row in ds.iter_rows():
            for rec in json.loads(row["records"]):
                writer.append(rec)
                if rec["status"] == "ok":
                    summary.ok += 1
                    summary.cached += bool(rec.get("cached"))
                    summary.faces += rec.get("faces") or 0
                else:
                    summary.failed += 1
                    summary.failures.append((rec["path"], rec["error"]))
                    log.warning("%s failed: %s", rec["path"], rec["error"])
    finally:
        writer.close()
        summary.elapsed = time.perf_counter() - t0
    return summary
