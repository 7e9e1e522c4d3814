"""Which meshes of a batch get the mesh-quality remedy: the decision of ``remedy="auto"``.

The paper's operator (remedy "none") is the right one on a well-shaped mesh: its spectrum is
that of the Killing energy, >= 0 up to discretization error. Badly shaped triangles and
cone-like vertices give it modes localized on a few edges far below zero (spurious: below
``SPURIOUS_BELOW``, λ·area = -1, where the solver skips modes under a remedy), and those meshes
need the "smooth" remedy. "auto" asks exactly that of each mesh: is ``R - σ S1`` positive
definite at σ = ``SPURIOUS_BELOW``? (Sylvester's law of inertia: it is if and only if every
eigenvalue of ``R w = λ S1 w`` lies above σ.) One sparse Cholesky of the paper's operator per
mesh, on the CPU on every device, so a mesh gets the same decision on any device and in any
batch. No geometric statistic separated the two kinds of mesh as well (docs/design.md).
"""
from __future__ import annotations

import torch

#: The remedy "auto" applies where the paper's operator has a spurious mode.
AUTO_REMEDY = "smooth"


def has_spurious_modes(system, b: int) -> bool:
    """Whether mesh b of ``system`` (a :class:`~torchakvf.operators.killing.KillingSystem`) has
    an eigenvalue below ``SPURIOUS_BELOW``: its ``R_b - σ S1_b`` at σ = ``SPURIOUS_BELOW`` has
    no Cholesky factor."""
    # The solvers build on the operators: imported here, where a decision needs a factor.
    from ..errors import SolverError
    from ..solvers.akvf_solver import SPURIOUS_BELOW
    from ..solvers.factor import ShiftedFactor

    rows, cols, vals, _ = system.block(b)
    lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
    cpu = torch.device("cpu")
    try:
        ShiftedFactor(rows.to(cpu), cols.to(cpu), vals.to(cpu, torch.float64),
                      system.mass[lo:hi].to(cpu, torch.float64), shifts=(SPURIOUS_BELOW,))
    except SolverError:
        return True
    return False


def choose_remedies(paper_system) -> list[str]:
    """[B] the remedy "auto" gives each mesh, from the batch's paper operator ``paper_system``
    (a :class:`~torchakvf.operators.killing.KillingSystem` built with remedy "none"):
    :data:`AUTO_REMEDY` where :func:`has_spurious_modes`, "none" elsewhere."""
    return [AUTO_REMEDY if has_spurious_modes(paper_system, b) else "none"
            for b in range(paper_system.n_meshes)]


__all__ = ["AUTO_REMEDY", "has_spurious_modes", "choose_remedies"]
