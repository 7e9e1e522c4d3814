"""The eigenpairs of the meshes of one batch's Killing operator, solved in groups (meshes that
need the same count from the same eigensolver together), with every factor made once and kept
for the next solve. Under a remedy each mesh gets room for its spurious modes, and again more
room where it had more than that; a group that fails is bisected so that only the meshes that
fail are left out; a mesh the Krylov solver does not converge is solved by ARPACK.
:class:`~torchakvf.solvers.akvf_solver.AKVFSolver` holds one per batch solved as one (or per
mesh), beside the solver choice and the fallbacks (its module docstring: the whole policy)."""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable, NamedTuple

import torch

from ..errors import FieldCountError, SolverError
from ..mesh.batch import MeshBatch
from ..operators.killing import KillingSystem
from ..operators.whitney import whitney_face_vectors
from .akvf_result import AKVFResult
from .factor import BlockDiagonalFactor, ShiftedFactor, interior_factor, mesh_factor, mesh_shift
from .krylov import KrylovBasis, block_krylov
from .lanczos import shift_invert_lanczos
from .lobpcg import EigenResult, segmented_lobpcg
from .remedy import SPURIOUS_BELOW, PaperCheck

#: Extra eigenpairs computed to make room for spurious ones.
SPURIOUS_MARGIN = 8
#: Solves of a mesh at most under a remedy: the first, then again with more room while it has
#: more spurious modes than room (each time what it was short of plus SPURIOUS_MARGIN).
SPURIOUS_SOLVES = 4


def remedy_advice(remedy: str, decimated: bool = False) -> str:
    """What to try after a failed solve under ``remedy`` (never what was just tried)."""
    if remedy != "smooth":
        return f"it was solved with remedy={remedy!r}; try remedy='smooth'"
    if decimated:
        return ("it was solved decimated with remedy='smooth', the strongest remedy; solve it at "
                "full resolution (akvf_falling_back does) or repair the input mesh")
    return ("it was solved with remedy='smooth', the strongest remedy; repair the mesh (remesh "
            "it, close its holes)")


@dataclass(frozen=True)
class SolveSettings:
    """What a solve asks for (the rest is the solver's)."""
    n: int
    tol: float
    seed: int
    max_iter: int


class _Pairs(NamedTuple):
    """One mesh's eigenpairs as solved (room for spurious modes included)."""
    values: torch.Tensor        # [k]
    vectors: torch.Tensor       # [E, k]
    residuals: torch.Tensor     # [k]
    iterations: torch.Tensor    # []
    shift: torch.Tensor         # []
    left_out: int = 0           # spurious pairs counted by inertia, not among the values


class GroupSolver:
    """The eigenpairs of the meshes of one batch, solved in groups on kept factors.

    system, batch : the batch's :class:`KillingSystem` and :class:`MeshBatch`
    solvers : [B] the eigensolver of each mesh ("lobpcg", "lanczos" or "krylov")
    batched : the batch is solved as one (LOBPCG with one block-diagonal factor of a group at
        its meshes' own shifts, found first by each mesh's ladder)
    checks : [B] what remedy "auto" learned of each mesh's paper operator (None: not decided so)
    shifts : {mesh: shift} found before for meshes that did not change; filled in place
    full_resolution : the meshes that fell back to full resolution (each solved alone)
    fixable : whether failures {mesh: exception} will be solved again at full resolution (a
        failure that will not stops the work: the solve raises)
    """

    def __init__(self, system: KillingSystem, batch: MeshBatch, solvers: list[str], *, batched: bool,
                 checks: list[PaperCheck] | None, shifts: dict[int, float], full_resolution: set[int],
                 fixable: Callable[[dict], bool]):
        self.system, self.batch, self.solvers, self.batched = system, batch, solvers, batched
        self.edges: list[int] = (batch.edge_ptr[1:] - batch.edge_ptr[:-1]).tolist()
        self.shifts, self.full_resolution = shifts, full_resolution
        self._checks, self._fixable = checks, fixable
        self._factors: dict[int, ShiftedFactor] = {}
        self._interior: dict[tuple[int, int], object] = {}
        self._blocks: dict[tuple[int, ...], BlockDiagonalFactor] = {}

    def _drops(self, b: int) -> bool:
        """Whether mesh b's spurious modes are skipped: under any remedy of its operator."""
        return self.system.remedies[b] != "none"

    def solve(self, settings: SolveSettings, meshes: list[int]) -> tuple[dict, dict, dict]:
        """Each mesh's eigenpairs {b: _Pairs}, how many were solved {b: count} (n plus room for
        spurious modes, capped below the mesh's edge count, solved again with more room where
        they outnumber it) and the meshes that failed {b: exception}."""
        n = settings.n
        counts = {b: n + (min(SPURIOUS_MARGIN, max(self.edges[b] - n - 1, 0)) if self._drops(b) else 0)
                  for b in meshes}
        pairs: dict = {}
        failed = self._without_shift(meshes)
        if failed and not self._fixable(failed):
            return pairs, counts, failed        # the solve raises: no work for the mates
        todo = [b for b in meshes if b not in failed]
        for _ in range(SPURIOUS_SOLVES):
            for group in self._groups(todo, counts):
                self._solve_group(group, counts[group[0]], settings, pairs, counts, failed)
            todo = [b for b in todo if b not in failed]
            todo = self._short_of_room([b for b in todo if self._drops(b)], pairs, counts, n)
            if not todo:
                break
        return pairs, counts, failed

    def _solve_group(self, group: list[int], count: int, settings: SolveSettings, pairs: dict, counts: dict,
                     failed: dict) -> None:
        """``group`` solved as one into ``pairs`` and ``counts``; where that fails, its halves
        are (and theirs, down to single meshes, whose failures go to ``failed``)."""
        try:
            eig = self._eigensolve(group, count, self.solvers[group[0]], settings)
        except (SolverError, torch.cuda.OutOfMemoryError) as exc:
            if len(group) == 1:
                failed[group[0]] = exc
                return
            half = len(group) // 2
            for part in (group[:half], group[half:]):
                self._solve_group(part, count, settings, pairs, counts, failed)
            return
        vecs = self.batch.split(eig.vectors, self._group_ptr(group))
        for j, b in enumerate(group):
            left_out = 0 if eig.left_out is None else int(eig.left_out[j])
            pairs[b] = _Pairs(eig.eigenvalues[j], vecs[j], eig.residuals[j], eig.iterations[j], eig.shifts[j],
                              left_out)
            counts[b] = max(counts[b], eig.eigenvalues.shape[1])

    def _without_shift(self, meshes: list[int]) -> dict:
        """{mesh: SolverError} of the meshes that no shift makes definite, found by each mesh's
        own ladder where the batch is solved as one by LOBPCG (one block factor at the shifts
        found): such a mesh leaves its group before any batch work."""
        failed = {}
        if not self.batched:
            return failed
        for b in meshes:
            if self.solvers[b] == "lobpcg" and b not in self.shifts:
                try:
                    self.shifts[b] = mesh_shift(self.system, b, self.batch.names[b])
                except SolverError as exc:
                    advice = remedy_advice(self.system.remedies[b], self.batch.coarse_of(b) is not None)
                    failed[b] = SolverError(f"{exc}; {advice}")
        return failed

    def _groups(self, todo: list[int], counts: list[int]) -> list[list[int]]:
        """Meshes needing the same count from the same solver are solved together. The Krylov
        solver works one mesh at a time and makes room for spurious modes itself (it returns
        more pairs where they need it): each of its meshes is a group of one, and so is a mesh
        that fell back to full resolution (its edge count must not pad its mates' arrays)."""
        alone = {b for b in todo if self.solvers[b] == "krylov" or b in self.full_resolution}
        others = [b for b in todo if b not in alone]
        return [[b] for b in todo if b in alone] + [
            [b for b in others if (counts[b], self.solvers[b]) == key]
            for key in sorted({(counts[b], self.solvers[b]) for b in others})]

    def _short_of_room(self, todo: list[int], pairs: list[_Pairs], counts: list[int], n: int) -> list[int]:
        """The meshes of ``todo`` with more spurious modes than room, their counts raised (in
        place) to what they were short of plus SPURIOUS_MARGIN; their mates keep theirs."""
        again = []
        for b in todo:
            spurious = int((pairs[b].values < SPURIOUS_BELOW).sum())
            short = spurious - (counts[b] - n)
            if short > 0 and counts[b] < self.edges[b] - 1:
                counts[b] = min(counts[b] + short + SPURIOUS_MARGIN, self.edges[b] - 1)
                again.append(b)
        return again

    def _group_ptr(self, group: list[int]) -> torch.Tensor:
        """[len(group)+1] offsets of the group's meshes in a group's packed vectors."""
        return torch.tensor([0] + list(itertools.accumulate(self.edges[b] for b in group)))

    def _eigensolve(self, group: list[int], count: int, solver: str, settings: SolveSettings) -> EigenResult:
        """``count`` eigenpairs of each mesh of ``group`` by ``solver``; a failure other than
        too many fields gets advice on what to try next."""
        try:
            if solver == "lanczos":
                return self._lanczos(group, count, settings)
            if solver == "krylov":
                return self._krylov(group, count, settings)
            return self._lobpcg(group, count, settings)
        except FieldCountError:
            raise
        except SolverError as exc:
            decimated = any(self.batch.coarse_of(b) is not None for b in group)
            raise SolverError(f"{exc}; {remedy_advice(self.system.remedies[group[0]], decimated)}") from None

    def _lanczos(self, group: list[int], count: int, settings: SolveSettings) -> EigenResult:
        # ARPACK needs CPU factors; on CPU they are kept for a re-solve with more room.
        cpu = self.system.mass.device.type == "cpu"
        return shift_invert_lanczos(self._subsystem(group), count, tol=settings.tol, seed=settings.seed,
                                    names=self._names(group),
                                    factors=[self.factor(b) for b in group] if cpu else None)

    def _lobpcg(self, group: list[int], count: int, settings: SolveSettings) -> EigenResult:
        # Where LOBPCG takes one factor per mesh, the solver's own are passed (and kept); a batch
        # solved as one takes one block-diagonal factor of the group at the meshes' own shifts.
        factors = self._block(group) if self.batched else [self.factor(b) for b in group]
        return segmented_lobpcg(self._subsystem(group), count, tol=settings.tol, seed=settings.seed,
                                names=self._names(group), max_iter=settings.max_iter, factors=factors)

    def _block(self, group: list[int]) -> BlockDiagonalFactor:
        """The group's block-diagonal factor at its meshes' own shifts (made once, then kept)."""
        key = tuple(group)
        if key not in self._blocks:
            missing = self._without_shift(group)    # shifts not found yet (a caller's own group)
            if missing:
                raise missing[min(missing)]
            self._blocks[key] = BlockDiagonalFactor(self._subsystem(group), self._names(group),
                                                    shifts=[self.shifts[b] for b in group])
        return self._blocks[key]

    def _krylov(self, group: list[int], count: int, settings: SolveSettings) -> EigenResult:
        """Only the n kept pairs (and the spurious ones below them) must converge; the room for
        spurious modes is returned as it is. A mesh it does not converge (rare: seen on a mesh
        with 33 spurious modes at shift -512, where the wanted pairs' 1/(λ - σ) all crowd
        together) is solved by ARPACK on the definite factor."""
        n = settings.n
        skip_below = SPURIOUS_BELOW if self._drops(group[0]) else None
        eig = block_krylov(self.system, count, tol=settings.tol, seed=settings.seed, names=self._names(group),
                           need=n, skip_below=skip_below,
                           factors=[self._interior_factor(b, n, skip_below) for b in group],
                           basis=KrylovBasis(grow=len(group) == 1), meshes=group)
        if len(group) == 1 and not bool(eig.converged[0]) and self.system.mass.device.type == "cpu":
            k = min(eig.eigenvalues.shape[1], self.edges[group[0]] - 1)
            eig = shift_invert_lanczos(self._subsystem(group), k, tol=settings.tol, seed=settings.seed,
                                       names=self._names(group), factors=[self.factor(b) for b in group])
        return eig

    def factor(self, b: int) -> ShiftedFactor:
        """Mesh b's positive definite shift-invert factor (made on first use, then kept): where
        remedy "auto" kept the paper's operator, the factor its decision made."""
        if b not in self._factors:
            check = self._check(b)
            kept = check.factor if check is not None and self.system.remedies[b] == "none" else None
            self._factors[b] = kept or mesh_factor(self.system, b, self.batch.names[b], like=self._symbolic(b))
        return self._factors[b]

    def _interior_factor(self, b: int, need: int, skip_below: float | None = None):
        """Mesh b's factor for the Krylov solver at ``need`` wanted pairs (kept per need)."""
        if (b, need) not in self._interior:
            self._interior[b, need] = interior_factor(self.system, b, need, lambda: self.factor(b),
                                                      like=self._symbolic(b), skip_below=skip_below)
        return self._interior[b, need]

    def _check(self, b: int) -> PaperCheck | None:
        """What remedy "auto" learned of mesh b, where its factors can use it (on the CPU)."""
        if self._checks is None or self.system.mass.device.type != "cpu":
            return None
        return self._checks[b]

    def _symbolic(self, b: int):
        """The analysis of mesh b's paper operator, which its factors share where the pattern is
        the same (None: each factor analyses its own)."""
        check = self._check(b)
        return None if check is None else check.symbolic

    def _subsystem(self, group: list[int]) -> KillingSystem:
        return self.system if len(group) == len(self.batch) else self.system.select(group)

    def _names(self, group: list[int]) -> list[str]:
        return [self.batch.names[b] for b in group]

    def result(self, pairs: list[_Pairs], counts: list[int], settings: SolveSettings) -> AKVFResult:
        """Per mesh, the first n eigenpairs that are not spurious (ascending order kept), their
        Whitney vectors, in the batch's dtype."""
        n = settings.n
        lam, forms, res, dropped = [], [], [], []
        for b, p in enumerate(pairs):
            spurious = (p.values < SPURIOUS_BELOW if self._drops(b)
                        else torch.zeros_like(p.values, dtype=torch.bool))
            keep = torch.argsort(spurious.to(torch.int8), stable=True)[:n]
            # Column slices where the kept pairs lead (no spurious ones): a view, not a gather.
            cols = slice(0, n) if bool((keep == torch.arange(len(keep), device=keep.device)).all()) else keep
            lam.append(p.values[cols]), forms.append(p.vectors[:, cols]), res.append(p.residuals[cols])
            dropped.append(int(spurious.sum()) + p.left_out)
        dev = self.batch.device
        eigenvalues, residuals, forms = torch.stack(lam), torch.stack(res), torch.cat(forms)
        fv = whitney_face_vectors(self.batch, self.system.geometry, forms)
        out_dt = self.batch.dtype
        return AKVFResult(eigenvalues=eigenvalues.to(out_dt), forms=forms.to(out_dt),
                          face_vectors=fv.to(out_dt), residuals=residuals,
                          iterations=torch.stack([p.iterations for p in pairs]).to(dev),
                          shifts=torch.stack([p.shift for p in pairs]).to(dev),
                          converged=(residuals <= settings.tol).all(dim=1),
                          dropped=torch.tensor(dropped, dtype=torch.long, device=dev), batch=self.batch,
                          system=self.system, solved=torch.tensor(counts, dtype=torch.long, device=dev))
