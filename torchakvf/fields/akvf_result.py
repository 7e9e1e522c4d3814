"""The result of an AKVF solve, :class:`~torchakvf.solvers.akvf_result.AKVFResult`: the solver
returns it, so it is defined with the solvers; importable from here too."""
from ..solvers.akvf_result import AKVFResult

__all__ = ["AKVFResult"]
