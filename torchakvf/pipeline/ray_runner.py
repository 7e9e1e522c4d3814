"""Optional Ray executor for the corpus runner (``pip install 'torchakvf[ray]'``).

The driver does what :func:`~torchakvf.pipeline.run_corpus` does before and after the work
(resume check, size peek, face-budget batches, the manifest); the batches themselves are mapped
with ``ray.data`` (``map_batches`` with a callable class on a fixed ``ActorPoolStrategy``) over
``workers`` warm actors, one per slot (e.g. one per GPU). Each actor runs the same
:func:`~torchakvf.pipeline.execute.run_batch` and writes the outputs atomically into
``out_dir``, a folder every worker can reach (one machine, or a shared file system on a
cluster). Workers return the manifest records; the driver alone appends them to
``manifest.jsonl`` as they stream in, so the outputs, the manifest and resume are those of
:func:`run_corpus` (only the order of the manifest lines may differ).

Tested with ray 2.60 in Ray's local mode by tests/test_ray_runner.py (features and segment
against run_corpus, resume, the CLI's ``--ray-workers``) and tests/test_pipeline.py
(``test_ray_runner_local``, a task class defined in a test module); both skip without ray.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from ..errors import TorchAKVFError
from ..progress import progress
from .execute import Item, run_batch
from .outdir import OutputLock, check_output_dir
from .runner import RunSummary, plan_run, record_batch, recording


class _BatchWorker:
    """A ray.data actor, warm for the whole run: one row = one batch of meshes (as JSON)."""

    def __init__(self, task, out_dir: str, device: str, seed: int, threads: int):
        if threads > 0:
            import torch

            torch.set_num_threads(threads)
        self.task, self.out_dir, self.device, self.seed = task, Path(out_dir), device, seed

    def __call__(self, rows: dict) -> dict:
        out = []
        for spec in rows["batch"]:
            items = [Item(Path(p), k, s, f if f >= 0 else None) for p, k, s, f in json.loads(str(spec))]
            out.append(json.dumps(run_batch(items, self.task, self.out_dir, self.device, self.seed)))
        return {"records": out}


def _ship_task_class(task) -> None:
    """Pickle a task class defined outside torchakvf (a script, a test module) by value, so
    workers that cannot import its module can still run it."""
    mod = type(task).__module__
    if mod != "__main__" and mod.split(".")[0] != "torchakvf" and mod in sys.modules:
        from ray import cloudpickle

        cloudpickle.register_pickle_by_value(sys.modules[mod])


def run_corpus_ray(paths, out_dir, task, *, batch_faces: int | None = None, device: str = "cpu",
                   seed: int = 0, resume: bool = True, workers: int = 1, cpus_per_worker: float = 1.0,
                   on_batch=None, **removed) -> RunSummary:
    """:func:`run_corpus` with the batches spread over ``workers`` Ray actors.

    ``ray.init()`` is called unless Ray is already initialized (it joins the cluster named by
    ``RAY_ADDRESS`` or started on this machine with ``ray start``, else starts a local one).
    Each actor reserves ``cpus_per_worker`` CPUs (and runs torch with that many threads) and,
    with a CUDA ``device``, one GPU: one actor per GPU (Ray gives each actor its own GPU, seen
    there as ``cuda``). Largest batches are submitted first, so
    the workers finish together. ``on_batch(n, records)``, as for :func:`run_corpus`, after each
    batch's manifest lines (its records as read back from JSON).
    """
    if removed:
        name = next(iter(removed))
        hint = (": with device='cuda' each actor reserves one GPU" if name == "gpus_per_worker"
                else "")
        raise TorchAKVFError(f"run_corpus_ray got an unknown argument {name!r}{hint}")
    cuda = str(device).startswith("cuda")
    device = "cuda" if cuda else device          # each actor's own GPU is its "cuda"
    try:
        import ray
    except ImportError:
        raise TorchAKVFError("the Ray runner needs ray: pip install 'torchakvf[ray]'") from None
    t0 = time.perf_counter()
    workers = int(workers)
    if workers < 1:
        raise TorchAKVFError(f"Ray workers must be an integer >= 1, got {workers}")
    out_dir = check_output_dir(out_dir)
    with OutputLock(out_dir):
        plan = plan_run(paths, out_dir, task, batch_faces=batch_faces, device=device, seed=seed,
                        resume=resume)
        summary = plan.summary
        batches = plan.batches[::-1]
        if batches:
            _run_on_ray(ray, batches, out_dir, task, summary, device=device, seed=seed,
                        workers=workers, cpus_per_worker=cpus_per_worker, gpus_per_worker=1.0 if cuda else 0.0,
                        on_batch=on_batch)
    summary.elapsed = time.perf_counter() - t0
    return summary


def _run_on_ray(ray, batches, out_dir: Path, task, summary: RunSummary, *, device, seed, workers,
                cpus_per_worker, gpus_per_worker, on_batch=None) -> None:
    if not ray.is_initialized():
        ray.init()
    _ship_task_class(task)
    specs = [json.dumps([[str(it.path), it.key, it.stem, -1 if it.faces is None else it.faces]
                         for it in b]) for b in batches]
    # One block per batch: a batch's records reach the manifest as soon as it is written.
    ds = ray.data.from_items([{"batch": s} for s in specs], override_num_blocks=len(specs))
    resources = {"num_cpus": cpus_per_worker}
    if gpus_per_worker:
        resources["num_gpus"] = gpus_per_worker
    ds = ds.map_batches(
        _BatchWorker, batch_size=1, batch_format="numpy",
        compute=ray.data.ActorPoolStrategy(size=min(workers, len(specs))),
        fn_constructor_kwargs=dict(task=task, out_dir=str(out_dir), device=device, seed=seed,
                                   threads=max(int(cpus_per_worker), 1)),
        **resources)
    start_bar = lambda: progress(sum(len(b) for b in batches), f"torchakvf {task.name} (ray)",  # noqa: E731
                                 "meshes")
    n_batch = 0
    with recording(out_dir, summary, start_bar) as (writer, bar):
        for row in ds.iter_rows():
            records = json.loads(str(row["records"]))
            record_batch(records, writer, summary, bar, task.name)
            bar.update(len(records))
            if on_batch is not None:
                n_batch += 1
                on_batch(n_batch, records)
