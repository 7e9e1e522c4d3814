"""Sparse Cholesky factors of the shifted Killing operator, used as the exact shift-invert
preconditioner of the eigensolver.

Why a factorization: slivers put R's largest eigenvalue near 1e7 against ~1 for the smallest,
and no product-only preconditioner (Jacobi, ILU, AMG, Chebyshev) brought LOBPCG under thousands
of iterations; (R - σ S1)^{-1} brings it to a handful. CHOLMOD factors it: on the CPU called
directly (:mod:`.cholmod`: AMD ordering, one symbolic analysis for every trial shift), on CUDA
through ``cholespy`` (the sparse Cholesky that works on torch tensors on CPU and CUDA, whose
triangular solves run on the GPU); cholespy on the CPU too where :func:`.cholmod.library`
finds no usable CHOLMOD.
"""
from __future__ import annotations

import torch

from ..errors import ParameterError, SolverError
from . import cholesky as chol
from . import cholmod

#: Shifts tried in turn (λ·area units): R is only approximately PSD, so the shift must lie
#: below its smallest eigenvalue for R - σ S1 to be positive definite. -1 suffices on good
#: meshes; badly shaped real meshes go down to about -250 (docs/akvf_operator.md, Sec. 4).
SHIFTS = (-1.0, -8.0, -64.0, -512.0, -4096.0, -32768.0)


class ShiftedFactor:
    """Cholesky factor of ``R_b - σ diag(S1_b)`` for one mesh, with the first shift that works
    (σ below every eigenvalue: the factor is positive definite).

    rows, cols, vals : COO of R_b (local indices, symmetric); mass : [E] S1_b.
    ``solve(rhs)`` returns (R_b - σ S1_b)^{-1} rhs for rhs [E, k] on the factor's device.
    """

    @property
    def backend(self):
        """The factorization object that solves: a :class:`~torchakvf.solvers.cholmod.CholmodFactor`
        on the CPU where the CHOLMOD library loads, else cholespy's."""
        return self._solver

    def __init__(self, rows: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor,
                 mass: torch.Tensor, name: str = "mesh", shifts=None, like=None):
        shifts = SHIFTS if shifts is None else tuple(shifts)
        self.device = check_factor_device(mass.device)
        pattern = chol.lower_pattern(rows, cols, vals, len(mass))
        engine = chol.cpu_engine(pattern, self.device, like)
        last = None
        for sigma in shifts:
            diagonal = -sigma * mass.to(torch.float64)
            self._solver, last = chol.cholesky(pattern, diagonal, engine)
            if self._solver is not None:
                self.sigma = sigma
                chol.check_first_solve(self._solver, self.device, pattern, diagonal, name)
                return
        # No advice here: what to try next depends on what was tried (the caller adds it).
        raise SolverError(f"{name}: the Killing operator has eigenvalues below {shifts[-1]} "
                          f"(λ·area); no shift made R - σS1 positive definite ({last}); the mesh "
                          "is likely badly shaped")

    #: σ lies below the spectrum (see :class:`InteriorFactor`)
    below = 0

    @classmethod
    def made(cls, engine: "chol.CpuFactor", sigma: float) -> "ShiftedFactor":
        """The factor ``engine`` holds, positive definite at ``sigma``: where the ladder would
        stop at that shift (its first), the same factor without making it again."""
        if not engine.factor.positive_definite:
            raise SolverError("internal: a factor that is not positive definite kept as the definite one")
        out = cls.__new__(cls)
        out.device, out._solver, out.sigma = torch.device("cpu"), engine.factor, float(sigma)
        return out

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        """(R - σS1)^{-1} rhs for rhs [E, k] (float64, on the factor's device)."""
        return chol.solve(self._solver, self.device, rhs)

    def solve_rows(self, rows: torch.Tensor) -> torch.Tensor:
        """(R - σS1)^{-1} applied to each row of rows [k, E]: returns [k, E] (float64).
        On the CPU with CHOLMOD called directly this is its native layout (no transposes)."""
        return chol.solve_rows(self._solver, self.device, rows)


#: Interior shift of the block Krylov solver per wanted eigenpair (λ·area units): σ = this · n.
#: Unit-area PSB meshes have λ_n ≈ 8-9.5 n (n = 32: λ₃₂ 250-304), so σ = 5 n puts about 60% of
#: the n wanted eigenvalues below it: about 30% fewer right-hand sides than at σ = -1 for the
#: same pairs (see docs/design.md).
INTERIOR_SHIFT_PER_PAIR = 5.0


class InteriorFactor:
    """LDLᵀ factor of ``R_b - σ diag(S1_b)`` at a shift σ *inside* the wanted part of the
    spectrum, for the block Krylov solver (:func:`~torchakvf.solvers.krylov.block_krylov`).

    Why: shift-invert maps λ to θ = 1/(λ - σ). With σ below the spectrum the wanted pairs whose
    λ is near the n-th crowd together at small θ, next to the unwanted ones, and converge last;
    with σ among the wanted ones they sit at large |θ| on both sides and the unwanted ones stay
    near 0, so the Krylov space needs about 30% fewer solves (:data:`INTERIOR_SHIFT_PER_PAIR`).

    ``below`` (ν) is the number of eigenvalues below σ, read off the factor (Sylvester's law of
    inertia: the negative pivots of D). The solver checks its result against it: exactly ν of the
    converged pairs must lie below σ, so no eigenvalue below the shift can be missed unseen.
    ``skipped``: where not None, the number of eigenvalues below the spurious threshold
    ``skip_below`` (the inertia of a second factor there): the solver may then leave the
    spurious pairs out (unconverged, unreturned), and exactly ``below - skipped`` of its pairs
    must lie in [skip_below, σ).
    ``definite()`` is the mesh's positive definite :class:`ShiftedFactor` (made on first use),
    what the solver falls back to where that check or convergence fails, and where an eigenvalue
    lies at or below ``floor`` (the last definite shift tried, :data:`SHIFTS`): such a mesh
    raises there as it always has (a decimated one is then solved at full resolution).
    """

    floor = SHIFTS[-1]

    def __init__(self, engine: "chol.CpuFactor", sigma: float, below: int, definite,
                 skipped: int | None = None):
        self._solver, self.sigma, self.below = engine.factor, float(sigma), int(below)
        self.skipped = None if skipped is None else int(skipped)
        self.device = torch.device("cpu")
        self._definite, self._made = definite, None

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        return chol.solve(self._solver, self.device, rhs)

    def solve_rows(self, rows: torch.Tensor) -> torch.Tensor:
        return chol.solve_rows(self._solver, self.device, rows)

    def definite(self) -> ShiftedFactor:
        if self._made is None:
            self._made = self._definite()
        return self._made


#: Interior shifts tried after 5n and 5n/2, each moved down towards about 60% of the wanted
#: pairs below it (the eigenvalue count grows about linearly with λ), for meshes with many
#: spurious modes or a spectrum far below a unit-area surface's: PSB 351 decimated has 82
#: spurious modes and λ₃₂ = 17 against 250-304 on the typical PSB mesh.
INTERIOR_RETRIES = 4


def interior_factor(system, b: int, need: int, definite, like=None,
                    skip_below: float | None = None) -> InteriorFactor | ShiftedFactor:
    """Mesh b's :class:`InteriorFactor` on the CPU at a shift σ with at most ``need``
    eigenvalues below it: σ = INTERIOR_SHIFT_PER_PAIR · need, else half that (the two shifts
    that suit a unit-area surface), else up to :data:`INTERIOR_RETRIES` lower ones chosen from
    the counts. With ``skip_below`` (a remedy's spurious threshold), those retries count only
    the eigenvalues in [skip_below, σ) (the inertia at skip_below taken off) and the factor's
    ``skipped`` says so. Otherwise (another device, no direct CHOLMOD, a breakdown, no shift
    found) ``definite()``, the positive definite :class:`ShiftedFactor`. ``like``: a symbolic
    analysis to share where the pattern is the same (:class:`~torchakvf.solvers.cholesky.CpuFactor`)."""
    r, c, v, size = system.block(b)
    if system.mass.device.type != "cpu" or cholmod.library() is None or need < 1:
        return definite()
    lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
    mass = system.mass[lo:hi].to(torch.float64)
    engine = chol.CpuFactor(chol.lower_pattern(r, c, v, size), like=like)
    sigma = INTERIOR_SHIFT_PER_PAIR * need
    for _ in range(2):
        usable = engine.factorize(-sigma * mass, indefinite=True)
        count = engine.factor.negative_pivots
        if usable and count <= need:
            return InteriorFactor(engine, sigma, count, definite)
        sigma /= 2
    sigma *= 2                                            # the last shift tried
    skipped = None
    if skip_below is not None:
        # A mesh with an eigenvalue below the last definite shift must still raise where its
        # definite factor is made (a decimated one is then solved at full resolution): leaving
        # its spurious pairs out would hide that one.
        skipped = _inertia(engine, -skip_below * mass)
        if skipped is None or _inertia(engine, -SHIFTS[-1] * mass) != 0:
            return definite()
    lowest = -1.0 if skip_below is None else skip_below      # the retries' σ stay above it
    for _ in range(INTERIOR_RETRIES):
        wanted = count - (skipped or 0)
        if not (usable and wanted <= need):
            # Down towards 60% of the wanted pairs below σ, never by more than 16x in one step
            # (a breakdown, not a count, moves it by a quarter). Where the spurious ones alone
            # were too many, the last σ is factored again (the engine now holds skip_below's).
            step = 0.75 if wanted <= need else min(max(0.6 * need / max(wanted, 1), 1 / 16), 0.5)
            sigma = lowest + (sigma - lowest) * step
        usable = engine.factorize(-sigma * mass, indefinite=True)
        count = engine.factor.negative_pivots
        if usable and count - (skipped or 0) <= need:
            return InteriorFactor(engine, sigma, count, definite, skipped=skipped)
    return definite()


def _inertia(engine: "chol.CpuFactor", diagonal: torch.Tensor) -> int | None:
    """The number of negative pivots of R + diag(diagonal) (the eigenvalues below the shift),
    or None where its LDLᵀ breaks down (a zero, infinite or NaN pivot: no count)."""
    engine.factorize(diagonal, indefinite=True)
    f = engine.factor
    return f.negative_pivots if f.pivots_finite else None


class BlockDiagonalFactor:
    """One Cholesky factor of a whole batch's block-diagonal ``R - diag(σ_b S1_b)``, each mesh b
    at its own shift σ_b, so that one solve call serves every mesh of the batch.

    Why (the batched LOBPCG's preconditioner on CUDA): with one factor per mesh, every
    iteration makes one solve call per live mesh, each a pair of level-scheduled triangular
    sweeps whose levels run one after another. In a block-diagonal factor the meshes' rows are
    independent, so one level holds the rows of every mesh at that depth: a call costs about the
    levels of the deepest mesh, not the sum over the batch. The factor is computed by CHOLMOD
    on the CPU either way (cholespy uploads it to the GPU), at about the sum of the meshes' own
    costs.

    system : a :class:`~torchakvf.operators.killing.KillingSystem`; names : one per mesh
    shifts : [B] the σ_b to use; default: each mesh's own ladder first (:func:`mesh_shift`, on
        the CPU, which names a mesh that no shift makes definite), then the one block factor at
        the shifts found. Never a trial factor of the whole batch: one mesh needing a lower
        shift would make it fail, and the batch would be factored twice.

    ``sigma`` is [B] float64 on the system's device; ``solve(rhs)`` solves the block-diagonal
    system for packed rhs [ΣE, k] (a mesh's rows of the solution depend on its rows of rhs only).
    """

    def __init__(self, system, names: list[str] | None = None, shifts=None):
        nb = system.n_meshes
        names = names or [f"mesh {b}" for b in range(nb)]
        self.device = check_factor_device(system.mass.device)
        if shifts is None:
            shifts = [mesh_shift(system, b, names[b]) for b in range(nb)]
        shifts = [float(x) for x in shifts]
        if len(shifts) != nb:
            raise ParameterError(f"BlockDiagonalFactor: {len(shifts)} shifts for {nb} meshes")
        idx, vals = system.stiffness.indices(), system.stiffness.values()
        pattern = chol.lower_pattern(idx[0], idx[1], vals, len(system.mass))
        sizes = (system.edge_ptr[1:] - system.edge_ptr[:-1]).to(self.device)
        self.sigma = torch.tensor(shifts, dtype=torch.float64, device=self.device)
        diagonal = -torch.repeat_interleave(self.sigma, sizes, output_size=len(system.mass)) \
            * system.mass.to(torch.float64)
        self._solver, last = chol.cholesky(pattern, diagonal, chol.cpu_engine(pattern, self.device))
        if self._solver is None:
            raise SolverError(f"{', '.join(names)}: R - σS1 is not positive definite at the "
                              f"shifts {shifts} ({last})")
        chol.check_first_solve(self._solver, self.device, pattern, diagonal, ", ".join(names))

    def solve(self, rhs: torch.Tensor) -> torch.Tensor:
        """The block-diagonal system's solution for packed rhs [ΣE, k] (float64)."""
        return chol.solve(self._solver, self.device, rhs)


def mesh_factor(system, b: int, name: str, device=None, like=None) -> ShiftedFactor:
    """The :class:`ShiftedFactor` of mesh b of a :class:`~torchakvf.operators.killing.KillingSystem`
    (its block of R and its S1), on ``device`` (default: the system's); ``like``: a symbolic
    analysis to share where the pattern is the same (:class:`~torchakvf.solvers.cholesky.CpuFactor`)."""
    r, c, v, _ = system.block(b)
    lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
    mass = system.mass[lo:hi]
    if device is not None:
        r, c, v, mass = (t.to(device) for t in (r, c, v, mass))
    return ShiftedFactor(r, c, v, mass, name=name, like=like)


def mesh_shift(system, b: int, name: str) -> float:
    """The shift of mesh b's own ladder (:data:`SHIFTS`): the first that makes its block of
    R - σ S1 positive definite, found on the CPU (a :class:`SolverError` naming the mesh where
    none does)."""
    return mesh_factor(system, b, name, device="cpu").sigma


def check_factor_device(device) -> torch.device:
    """``device`` as a torch.device, or a :class:`ParameterError` for a CUDA device that
    cholespy cannot factor on: cholespy always solves on the first visible GPU (its CUDA
    context is device 0's), so any other index would solve with another device's factor."""
    device = torch.device(device)
    if device.type != "cuda":
        return device
    index = device.index
    if index is None and torch.cuda.is_available():
        index = torch.cuda.current_device()
    if index not in (None, 0):
        raise ParameterError(f"device {device}: the sparse factor (cholespy) runs on the first "
                             f"visible GPU only; run with CUDA_VISIBLE_DEVICES={index} and device "
                             "'cuda' (or 'cuda:0')")
    return device
