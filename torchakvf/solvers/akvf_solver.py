"""The AKVF solver of a batch: its Killing operator, its factors, the solver choice per mesh and
every fallback, kept together so that a second solve (another n, another seed) reuses them.

Policy, in the order it applies:

* **Which eigensolver** (:func:`solver_for`): on CPU block Krylov from
  :data:`KRYLOV_MIN_EDGES` edges, ARPACK Lanczos below; the batched LOBPCG elsewhere.
* **One mesh at a time on CPU** (:data:`ONE_MESH_AT_A_TIME_ON`): each mesh gets the bits it
  gets alone; batched arrays are only larger there, not fewer operations.
* **Spurious modes**: under a remedy, eigenpairs below :data:`SPURIOUS_BELOW` are skipped;
  each mesh is solved with :data:`SPURIOUS_MARGIN` pairs of room, and again with more room
  (at most :data:`SPURIOUS_SOLVES` solves in all) where it has more spurious modes than room.
* **Krylov to Lanczos**: a mesh the block Krylov solver does not converge is solved by ARPACK
  on its definite factor.
* **A batch solved as one** (``batched``): each mesh's shift is found first, by its own ladder
  (:func:`~torchakvf.solvers.factor.mesh_shift`); a mesh that no shift makes definite leaves
  the batch before any batch work, and the others get one block-diagonal factor at their shifts.
* **Failures stay with their mesh**: a group whose solve fails for a reason no mesh was named
  for beforehand is bisected (halves, then their halves), so the meshes that fail are found
  and their mates are solved once.
* **Decimated to full resolution** (``full_resolution_fallback``): a decimated mesh that cannot
  be solved is solved at full resolution instead, alone (its edge count never pads its mates'
  arrays), and its result takes its place in batch order (:attr:`AKVFSolver.fell_back`).
"""
from __future__ import annotations

import numbers
import sys
import warnings

import torch

from ..errors import ConvergenceWarning, ParameterError, SolverError
from ..mesh.batch import MeshBatch
from ..mesh.clean import CleanMesh
from ..mesh.mesh import Mesh
from ..operators.killing import DEFAULT_REMEDY, REMEDIES, KillingSystem, killing_operator
from .akvf_result import AKVFResult
from .factor import ShiftedFactor, check_factor_device
from .group_solver import SPURIOUS_MARGIN, SPURIOUS_SOLVES, GroupSolver, SolveSettings, remedy_advice
from .remedy import SPURIOUS_BELOW, PaperCheck, auto_operator

__all__ = ["AKVFSolver", "SOLVERS", "ONE_MESH_AT_A_TIME_ON", "KRYLOV_MIN_EDGES", "SPURIOUS_BELOW", "SPURIOUS_MARGIN",
           "SPURIOUS_SOLVES", "as_batch", "batched_by_default", "field_count", "remedy_advice", "solver_for"]

#: The eigensolvers a caller may ask for ("auto": :func:`solver_for` decides per mesh).
SOLVERS = ("auto", "lobpcg", "lanczos", "krylov")

#: Device types on which a batch is solved one mesh at a time (each mesh as a batch of its own,
#: results concatenated: the bits of each mesh alone). The batch's arrays are only larger there,
#: not fewer operations, and fresh memory is what they cost: on 16 PSB meshes at 4000 faces the
#: batched stage took 1.35x the time of the same meshes one by one (see docs/design.md). The
#: batched paths are the GPU's, whose caching allocator reuses memory.
ONE_MESH_AT_A_TIME_ON = ("cpu",)

#: On CPU, "auto" solves meshes with at least this many edges with the block Krylov solver and
#: smaller ones with ARPACK Lanczos (same factor): below it the Krylov solver's per-step dense
#: work costs more than ARPACK's single-vector steps (wall time of the two on PSB meshes
#: decimated as eval does, and on the built-in shapes: see docs/design.md).
KRYLOV_MIN_EDGES = 4000


def batched_by_default(device) -> bool:
    """Whether a batch on ``device`` is solved as one batch when the caller does not say:
    everywhere but on the device types of :data:`ONE_MESH_AT_A_TIME_ON`."""
    return torch.device(device).type not in ONE_MESH_AT_A_TIME_ON


def solver_for(device: torch.device, edges: int | None = None, batched: bool | None = None) -> str:
    """The eigensolver "auto" picks for a mesh of ``edges`` edges on ``device``: on CPU the block
    Krylov solver from :data:`KRYLOV_MIN_EDGES` edges on (and when ``edges`` is not given),
    Lanczos below; the batched LOBPCG elsewhere.

    All use the same CHOLMOD shift-invert factor (one per mesh). On CPU the block
    shift-invert Krylov solver (:func:`~torchakvf.solvers.krylov.block_krylov`) keeps every
    solve it makes, like ARPACK, but solves 4 right-hand sides per sweep through the factor and
    converges only the n pairs asked for; on small meshes its per-step dense work costs more
    than ARPACK's single-vector steps (see :data:`KRYLOV_MIN_EDGES`). LOBPCG's dense
    Rayleigh-Ritz work (bases of 3·(n + guard) columns, every column solved each iteration) is
    the slowest of the three on CPU. On a GPU the block method's batched dense work is what the
    device is good at, and ARPACK does not run there. A batch solved as one (``batched``) takes
    the batched LOBPCG on any device: the accelerator's path.
    """
    if torch.device(device).type != "cpu" or batched:
        return "lobpcg"
    return "krylov" if edges is None or edges >= KRYLOV_MIN_EDGES else "lanczos"


def as_batch(meshes, device=None, coarse_faces: int | None = None) -> MeshBatch:
    """A :class:`MeshBatch` from a batch, a mesh or a list of meshes (``coarse_faces``: as in
    :meth:`MeshBatch.from_meshes`; a batch given keeps its own)."""
    if isinstance(meshes, MeshBatch):
        return meshes if device is None else meshes.to(device)
    if isinstance(meshes, (Mesh, CleanMesh)):
        meshes = [meshes]
    return MeshBatch.from_meshes(list(meshes), device=device or "cpu", coarse_faces=coarse_faces)


def field_count(n) -> int:
    """``n`` as an int, or a :class:`ParameterError` unless it is a positive integer (Python or
    numpy)."""
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
        raise ParameterError(f"n must be a positive integer, got {n!r}")
    return int(n)


class AKVFSolver:
    """The approximate Killing vector fields of a batch, with everything a solve builds kept for
    the next one: the batch's :class:`KillingSystem`, each mesh's shift-invert factors, the
    eigensolver of each mesh and the fallbacks (module docstring).

    meshes : MeshBatch, Mesh, or list of Mesh (a mesh is a batch of one)
    remedy : mesh-quality remedy of the operator (:data:`torchakvf.operators.REMEDIES`, default
        :data:`~torchakvf.operators.killing.DEFAULT_REMEDY`; "none" is the paper's operator);
        any remedy but "none" also skips spurious eigenpairs below :data:`SPURIOUS_BELOW`
    boundary_correction : use the open-mesh boundary terms
    solver : "lobpcg" (segmented block solver over the batch, any device), "lanczos" (ARPACK
        shift-invert, CPU, one mesh at a time), "krylov" (block shift-invert Krylov, one mesh at
        a time) or "auto" (:func:`solver_for`, decided per mesh)
    device : device of the batch built from Mesh inputs (a MeshBatch given is moved there)
    batched : solve the batch as one (one operator; for "auto" the batched LOBPCG with one
        block-diagonal factor at each mesh's own shift), as on an accelerator, or one mesh at a
        time (each mesh as a batch of its own); default
        (None): :func:`batched_by_default` for the batch's device (one at a time on the CPU).
        ``batched=True`` on the CPU runs the accelerator's path there.
    full_resolution_fallback : a decimated mesh (``MeshBatch.from_meshes(coarse_faces=)``) that
        cannot be solved is solved alone at full resolution (:attr:`fell_back` lists them;
        ``batch`` is then the re-packed batch); its mates keep what they got. Without it, or for
        a mesh that was not decimated or fails at full resolution too, the
        :class:`SolverError` of the first failing mesh is raised, with ``failed_meshes`` (the
        batch indices of every mesh that failed) set on it.

    ``solve(n, tol=, seed=, max_iter=)`` returns an :class:`AKVFResult`; a second call reuses
    the operator and the factors (the Krylov solver's interior factor per n). The factors are
    kept until the solver is dropped: one per mesh of the batch.
    """

    def __init__(self, meshes, *, remedy: str = DEFAULT_REMEDY, boundary_correction: bool = True,
                 solver: str = "auto", device=None, batched: bool | None = None,
                 full_resolution_fallback: bool = True):
        if solver not in SOLVERS:
            raise ParameterError(f"solver must be one of {SOLVERS}, got {solver!r}")
        if remedy not in REMEDIES:
            raise ParameterError(f"remedy must be one of {REMEDIES}, got {remedy!r}")
        self.remedy, self.boundary_correction, self.solver = remedy, boundary_correction, solver
        self.full_resolution_fallback = full_resolution_fallback
        self._batched = batched
        #: [(mesh index, error text)] of the meshes solved at full resolution because their
        #: decimated version could not be solved
        self.fell_back: list[tuple[int, str]] = []
        self._shifts: dict[int, float] = {}
        self._alone: list[AKVFSolver] | None = None
        self._use(as_batch(meshes, device=device))

    def _use(self, batch: MeshBatch, changed=None) -> None:
        """Solve ``batch`` from now on. ``changed``: the meshes re-packed (indices); the others'
        shifts and one-mesh solvers are kept (None: nothing built for another batch is kept)."""
        kept = {} if changed is None else {b: v for b, v in self._shifts.items() if b not in changed}
        kept_alone = None if changed is None else self._alone
        check_factor_device(batch.device)
        self.batch = batch
        #: whether the batch is solved as one (else one mesh at a time)
        self.batched = batched_by_default(batch.device) if self._batched is None else bool(self._batched)
        self.edges: list[int] = (batch.edge_ptr[1:] - batch.edge_ptr[:-1]).tolist()
        #: the eigensolver of each mesh ("auto" decides per mesh, by its size)
        self.solvers: list[str] = [solver_for(batch.device, e, self.batched) if self.solver == "auto" else self.solver
                                   for e in self.edges]
        self._shifts: dict[int, float] = kept
        self._grouped: GroupSolver | None = None
        self._system: KillingSystem | None = None
        #: what remedy "auto" learned of each mesh's paper operator (its analysis, its factor)
        self._checks: list[PaperCheck] | None = None
        self._alone: list[AKVFSolver] | None = None
        if len(batch) > 1 and not self.batched:
            self._alone = [kept_alone[b] if kept_alone is not None and b not in changed else
                           AKVFSolver(batch.mesh(b), remedy=self.remedy, solver=self.solver,
                                      boundary_correction=self.boundary_correction, batched=False,
                                      full_resolution_fallback=False) for b in range(len(batch))]
        elif self.remedy == "auto":
            self._system, self._checks = auto_operator(batch, boundary_correction=self.boundary_correction)
        else:
            self._system = killing_operator(batch, boundary_correction=self.boundary_correction,
                                            remedy=self.remedy)

    @property
    def system(self) -> KillingSystem:
        """The batch's :class:`KillingSystem` (solved one mesh at a time: its meshes' systems
        concatenated)."""
        if self._system is None:
            self._system = KillingSystem.concatenate([s.system for s in self._alone], self.batch.edge_ptr)
        return self._system

    @property
    def _group_solver(self) -> GroupSolver:
        """The eigensolves of the batch's meshes and their kept factors (made on first use)."""
        if self._grouped is None:
            self._grouped = GroupSolver(self.system, self.batch, self.solvers, batched=self.batched,
                                       checks=self._checks, shifts=self._shifts,
                                       full_resolution={b for b, _ in self.fell_back}, fixable=self._fixable)
        return self._grouped

    def factor(self, b: int) -> ShiftedFactor:
        """Mesh b's positive definite shift-invert factor (made on first use, then kept): where
        remedy "auto" kept the paper's operator, the factor its decision made."""
        return self._group_solver.factor(b)

    def drops_spurious(self, b: int) -> bool:
        """Whether mesh b's spurious modes (below :data:`SPURIOUS_BELOW`) are skipped: under any
        remedy its operator was built with (``KillingSystem.remedies``, decided per mesh)."""
        return self.system.remedies[b] != "none"

    def solve(self, n: int = 32, *, tol: float = 1e-6, seed: int = 0, max_iter: int = 60) -> AKVFResult:
        """The ``n`` smallest AKVFs of each mesh (see :func:`~torchakvf.fields.akvf.akvf` for
        the parameters). A mesh that does not reach ``tol`` is flagged in
        ``AKVFResult.converged`` and named in one :class:`ConvergenceWarning`."""
        settings = SolveSettings(field_count(n), tol, seed, max_iter)
        out = self._solve_falling_back(settings)
        _warn_unconverged(self.batch.names, out.residuals, out.converged, tol)
        return out

    # -- failures kept to their meshes, the decimated -> full-resolution fallback ------------

    def _solve_falling_back(self, settings: SolveSettings) -> AKVFResult:
        """Every mesh solved; the meshes that fail (and only they) at full resolution, alone."""
        pieces, failed = self._solve_meshes(settings, list(range(len(self.batch))))
        if failed:
            self._raise_unless_decimated(failed)
            self.fell_back += [(b, str(failed[b])) for b in sorted(failed)]
            self._use(self.batch.at_full_resolution(sorted(failed)), changed=set(failed))
            for b in sorted(failed):
                more, still = self._solve_meshes(settings, [b])
                if still:
                    self._raise_unless_decimated(still, decimated=False)
                pieces.update(more)
        return self._assemble(pieces, settings)

    def _fixable(self, failed: dict) -> bool:
        """Whether every failure of ``failed`` {mesh: exception} is a :class:`SolverError` of a
        decimated mesh that the fallback may solve at full resolution."""
        return self.full_resolution_fallback and all(
            isinstance(e, SolverError) and self.batch.coarse_of(b) is not None for b, e in failed.items())

    def _raise_unless_decimated(self, failed: dict, decimated: bool = True) -> None:
        """Raise the first failure of ``failed`` {mesh: exception} unless the fallback may solve
        every one at full resolution (never where ``decimated`` is False); the exception
        carries ``failed_meshes``, the batch indices of all of them."""
        if not (decimated and self._fixable(failed)):
            exc = failed[min(failed)]
            exc.failed_meshes = sorted(failed)
            raise exc

    def _solve_meshes(self, settings: SolveSettings, meshes: list[int]) -> tuple[dict, dict]:
        """({mesh: its piece of the result}, {mesh: the exception it failed with}) for
        ``meshes``: pieces are one-mesh :class:`AKVFResult` s (one mesh at a time) or
        (eigenpairs, pairs solved) (a batch solved as one: :meth:`GroupSolver.solve`). A failure
        the fallback cannot fix stops the work there: the solve will raise, and its mates'
        results would be lost."""
        if self._alone is None:
            pairs, counts, failed = self._group_solver.solve(settings, meshes)
            return {b: (pairs[b], counts[b]) for b in pairs}, failed
        pieces, failed = {}, {}
        for b in meshes:
            try:
                pieces[b] = self._alone[b]._solve(settings)
            except SolverError as exc:
                failed[b] = exc
                if not self._fixable(failed):
                    break
        return pieces, failed

    def _assemble(self, pieces: dict, settings: SolveSettings) -> AKVFResult:
        order = range(len(self.batch))
        if self._alone is not None:
            return AKVFResult.concatenate([pieces[b] for b in order], self.batch, self.system)
        pairs, counts = zip(*(pieces[b] for b in order))
        return self._group_solver.result(list(pairs), list(counts), settings)

    # -- one solve of the current batch ------------------------------------------------------

    def _solve(self, settings: SolveSettings) -> AKVFResult:
        """Every mesh solved (raising the first failure)."""
        pieces, failed = self._solve_meshes(settings, list(range(len(self.batch))))
        if failed:
            self._raise_unless_decimated(failed, decimated=False)
        return self._assemble(pieces, settings)


def _warn_unconverged(names: list, residuals: torch.Tensor, converged: torch.Tensor, tol: float) -> None:
    """One :class:`ConvergenceWarning` naming every mesh of the batch that did not reach
    ``tol``, attributed to the caller of :meth:`AKVFSolver.solve` or of its wrappers."""
    if not bool(converged.all()):
        bad = [f"{names[b]} (residual {float(residuals[b].max()):.1e})"
               for b in torch.nonzero(~converged).reshape(-1).tolist()]
        warnings.warn(f"AKVF eigensolve did not reach tol {tol:.0e} for {', '.join(bad)}; these "
                      "meshes are flagged in AKVFResult.converged", ConvergenceWarning,
                      stacklevel=_caller_level())


#: Modules whose frames a warning skips to reach the caller: this one and its wrappers'.
_WRAPPERS = (__name__, "torchakvf.fields.akvf")


def _caller_level() -> int:
    """``stacklevel`` for a warning issued in the caller of this function: the first frame
    outside :data:`_WRAPPERS`."""
    frame, level = sys._getframe(1), 1
    while frame is not None and frame.f_globals.get("__name__") in _WRAPPERS:
        frame, level = frame.f_back, level + 1
    return level
