"""Which meshes of a batch get the mesh-quality remedy: the decision of ``remedy="auto"``, made
where the factorizations are.

The paper's operator (remedy "none") is the right one on a well-shaped mesh: its spectrum is
that of the Killing energy, >= 0 up to discretization error. Badly shaped triangles and
cone-like vertices give it modes localized on a few edges far below zero (spurious: below
:data:`SPURIOUS_BELOW`, λ·area = -1, where the solver skips modes under a remedy), and those
meshes need the "smooth" remedy. "auto" asks exactly that of each mesh: is ``R - σ S1`` positive
definite at σ = :data:`SPURIOUS_BELOW`? (Sylvester's law of inertia: it is if and only if every
eigenvalue of ``R w = λ S1 w`` lies above σ.) The test is made on the CPU on every device, so a
mesh gets the same decision on any device and in any batch. No geometric statistic separated
the two kinds of mesh as well (docs/design.md).

What it costs (:func:`check_paper_operator`): with CHOLMOD called directly, the LDLᵀ of the
paper's operator stops at its first step of rows with a non-positive pivot, a few percent of a
factorization on a mesh with spurious modes; its symbolic analysis is shared with the solver's
factors of the remedied operator where the two patterns agree; a mesh that keeps the paper's
operator keeps the factor too, as its definite shift-invert factor (σ = -1 is the ladder's
first shift); and :func:`auto_operator` assembles the remedied operator from the paper's
assembly, adding only the terms a remedy changes.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from ..errors import SolverError
from ..mesh.batch import MeshBatch
from ..operators.killing import DEFAULT_REMEDY, KillingAssembly, KillingSystem, killing_operator
from . import cholmod
from .cholesky import CpuFactor, lower_pattern
from .factor import SHIFTS, ShiftedFactor

#: Under a mesh-quality remedy, eigenpairs below this (λ·area) are spurious: a Killing energy is
#: >= 0, and good meshes give at worst small negatives (-0.06 on a hemisphere); badly shaped
#: vertices give modes localized on a few edges far below zero.
SPURIOUS_BELOW = -1.0
#: The remedy "auto" applies where the paper's operator has a spurious mode.
AUTO_REMEDY = "smooth"


@dataclass
class PaperCheck:
    """What the decision learned of one mesh's paper operator.

    spurious : it has an eigenvalue below :data:`SPURIOUS_BELOW` (no Cholesky factor there)
    symbolic : CHOLMOD's analysis of its pattern (None without CHOLMOD called directly), for the
        solver's factors of whichever operator the mesh gets, where the pattern is the same
    factor : where it is not spurious, its factor at σ = :data:`SPURIOUS_BELOW` (the first shift
        of the definite ladder, :data:`~torchakvf.solvers.factor.SHIFTS`), else None
    """

    spurious: bool
    symbolic: object = None
    factor: ShiftedFactor | None = None


def check_paper_operator(system: KillingSystem, b: int) -> PaperCheck:
    """Whether mesh b of ``system`` (its paper operator) has an eigenvalue below
    :data:`SPURIOUS_BELOW`: its ``R_b - σ S1_b`` at σ = :data:`SPURIOUS_BELOW` has no Cholesky
    factor. On the CPU with CHOLMOD called directly the factorization stops at the first
    non-positive pivot (the same answer as a whole one); elsewhere cholespy factors it whole."""
    rows, cols, vals, size = system.block(b)
    lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
    cpu = torch.device("cpu")
    mass = system.mass[lo:hi].to(cpu, torch.float64)
    rows, cols, vals = rows.to(cpu), cols.to(cpu), vals.to(cpu, torch.float64)
    if cholmod.library() is None:
        try:
            ShiftedFactor(rows, cols, vals, mass, shifts=(SPURIOUS_BELOW,))
        except SolverError:
            return PaperCheck(True)
        return PaperCheck(False)
    engine = CpuFactor(lower_pattern(rows, cols, vals, size))
    if not engine.positive_definite_at(-SPURIOUS_BELOW * mass):
        return PaperCheck(True, engine.symbolic)
    # The ladder's first shift is this σ: the factor is the one the solver would make.
    kept = ShiftedFactor.made(engine, SPURIOUS_BELOW) if SHIFTS[0] == SPURIOUS_BELOW else None
    return PaperCheck(False, engine.symbolic, kept)


def has_spurious_modes(system: KillingSystem, b: int) -> bool:
    """Whether mesh b of ``system`` (a :class:`KillingSystem` of the paper's operator) has an
    eigenvalue below :data:`SPURIOUS_BELOW` (:func:`check_paper_operator`)."""
    return check_paper_operator(system, b).spurious


def choose_remedies(paper_system: KillingSystem) -> list[str]:
    """[B] the remedy "auto" gives each mesh, from the batch's paper operator ``paper_system``
    (a :class:`KillingSystem` built with remedy "none"): :data:`AUTO_REMEDY` where
    :func:`has_spurious_modes`, "none" elsewhere."""
    return [AUTO_REMEDY if has_spurious_modes(paper_system, b) else "none"
            for b in range(paper_system.n_meshes)]


def auto_operator(batch: MeshBatch, boundary_correction: bool = True,
                  dtype: torch.dtype = torch.float64) -> tuple[KillingSystem, list[PaperCheck]]:
    """The batch's operator under remedy "auto" and what the decision learned of each mesh
    ([B] :class:`PaperCheck`, for the solver's factors). One assembly: the remedied operator
    adds its own terms to the paper's shared parts (:class:`KillingAssembly`); the meshes that
    keep the paper's operator get it unchanged."""
    assembly = KillingAssembly(batch, boundary_correction, dtype)
    paper = assembly.system(["none"] * len(batch))
    checks = [check_paper_operator(paper, b) for b in range(len(batch))]
    remedies = [AUTO_REMEDY if c.spurious else "none" for c in checks]
    if all(r == "none" for r in remedies):
        return paper, checks
    return assembly.system(remedies), checks


def killing_system(batch: MeshBatch, boundary_correction: bool = True, remedy: str | list[str] = DEFAULT_REMEDY,
                   dtype: torch.dtype = torch.float64) -> KillingSystem:
    """The Killing operator of ``batch`` (:func:`~torchakvf.operators.killing.killing_operator`)
    under any remedy, "auto" (the default) included: decided per mesh here
    (:func:`auto_operator`), the others assembled as they are."""
    if isinstance(remedy, str) and remedy == "auto":
        return auto_operator(batch, boundary_correction, dtype)[0]
    return killing_operator(batch, boundary_correction=boundary_correction, remedy=remedy, dtype=dtype)


__all__ = ["AUTO_REMEDY", "SPURIOUS_BELOW", "PaperCheck", "auto_operator", "check_paper_operator",
           "choose_remedies", "has_spurious_modes", "killing_system"]
