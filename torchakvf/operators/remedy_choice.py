"""Moved: the remedy decision of ``remedy="auto"`` needs a factorization, so it lives with the
factorizations, in :mod:`torchakvf.solvers.remedy` (the operators do not import the solvers)."""
from __future__ import annotations

_MOVED = ("AUTO_REMEDY", "choose_remedies", "has_spurious_modes")


def __getattr__(name: str):
    if name in _MOVED:
        raise ImportError(f"torchakvf.operators.remedy_choice.{name} moved to torchakvf.solvers.remedy.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
