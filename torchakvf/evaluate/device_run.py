"""The batched evaluation's stage names, kept for their importers: the evaluation now runs as
:class:`~torchakvf.evaluate.eval_task.EvalTask` on the corpus runner, whose batched path is
:mod:`torchakvf.pipeline.batched_run` over :mod:`torchakvf.pipeline.overlap`."""
from __future__ import annotations

from ..errors import TorchAKVFError
from ..pipeline.overlap import LOOKAHEAD, OverlapTimes, PreparedMesh, pack, prepare_mesh, solver_threads

__all__ = ["prepare_mesh", "PreparedMesh", "DeviceRunTimes", "LOOKAHEAD", "pack", "solver_threads"]

#: The stage seconds of a batched run: :class:`~torchakvf.pipeline.overlap.OverlapTimes`.
DeviceRunTimes = OverlapTimes

_MOVED = {
    "predict_on_device": "torchakvf.evaluate.harness.evaluate_psb(..., batched=True) (EvalTask on the corpus runner)",
    "cut_and_score": "torchakvf.evaluate.eval_task.EvalTask.cut and .write",
    "EvalOverlap": "torchakvf.evaluate.eval_task.EvalTask (run by torchakvf.pipeline.runner.run_corpus)",
}


def __getattr__(name: str):
    if name in _MOVED:
        raise TorchAKVFError(f"torchakvf.evaluate.device_run.{name} is gone: use {_MOVED[name]}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
