"""The package's one exception family.

Every error a user can cause (a bad file, a bad parameter, a mesh the method cannot handle)
is a :class:`TorchAKVFError`, with a message that names the input and says what to do.
"""
from __future__ import annotations


class TorchAKVFError(Exception):
    """Base class of every error torchakvf raises on purpose."""


class MeshError(TorchAKVFError):
    """A mesh (from a file or from arrays) cannot be used; the message names it and the problem."""

    def __init__(self, source: str, problem: str):
        self.source = source
        self.problem = problem
        super().__init__(f"{source}: {problem}")


class SolverError(TorchAKVFError):
    """The eigensolver could not produce the requested eigenpairs for a mesh."""


class FieldCountError(SolverError):
    """More fields were asked for than a mesh has edges (a mesh too small for ``n``): no remedy
    or other solver helps, only fewer fields."""


class ParameterError(TorchAKVFError, ValueError):
    """A parameter is out of its documented range."""


class ConvergenceWarning(UserWarning):
    """A result was returned but did not meet its tolerance (e.g. an eigensolve whose residual
    stayed above ``tol``); the result object flags the meshes concerned."""
