"""Approximate Killing vector fields of a batch: operator, eigensolve, Whitney interpolation."""
from __future__ import annotations

import itertools
import numbers
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import ConvergenceWarning, ParameterError, SolverError
from ..mesh.batch import MeshBatch
from ..mesh.clean import CleanMesh
from ..mesh.mesh import Mesh
from ..operators.killing import DEFAULT_REMEDY, REMEDIES, KillingSystem, killing_operator
from ..solvers.factor import ShiftedFactor, interior_factor, mesh_factor
from ..solvers.krylov import block_krylov
from ..solvers.lanczos import shift_invert_lanczos
from ..solvers.lobpcg import segmented_lobpcg
from .whitney import whitney_face_vectors


@dataclass
class AKVFResult:
    """The n smallest AKVFs of every mesh of a batch (unit-area frame).

    Index spaces: "packed" rows are the batch's meshes one after another (``batch.edge_ptr``,
    ``batch.face_ptr``), each mesh as packed, i.e. cleaned and, in a batch built with
    ``coarse_faces``, decimated; :meth:`mesh_face_vectors` maps back to the input faces.

    eigenvalues : [B, n] ascending, λ·area (a unit sphere's rotations: 0, then 8π, ...)
    forms : packed [ΣE, n] 1-forms (edge values), S1-orthonormal per mesh
    face_vectors : packed [ΣF, n, 3] Whitney vectors at face barycenters
    residuals : [B, n] relative residual of each eigenpair (see :class:`EigenResult`)
    converged : [B] bool, every one of the mesh's n residuals <= tol; a mesh where it is False
        was returned with a :class:`~torchakvf.errors.ConvergenceWarning` and must not be used
        as if solved
    iterations, shifts : [B] eigensolver diagnostics: LOBPCG iterations or shift-invert solves
        (Lanczos, Krylov: right-hand sides); the shift σ of the factor, λ·area (negative: below
        the spectrum; positive: the Krylov solver's interior shift; see :class:`EigenResult`)
    dropped : [B] spurious negative modes (λ·area < SPURIOUS_BELOW) skipped under a remedy
    solved : [B] eigenpairs computed per mesh (n + room for spurious modes; decided per mesh)
    batch : the :class:`MeshBatch`; ``system``: its :class:`KillingSystem`
    """

    eigenvalues: torch.Tensor
    forms: torch.Tensor
    face_vectors: torch.Tensor
    residuals: torch.Tensor
    iterations: torch.Tensor
    shifts: torch.Tensor
    converged: torch.Tensor
    dropped: torch.Tensor
    batch: MeshBatch
    system: KillingSystem
    solved: torch.Tensor | None = None

    @property
    def n(self) -> int:
        return self.eigenvalues.shape[1]

    def mesh_forms(self, b: int) -> torch.Tensor:
        """[E_b, n] forms of mesh b on the edges of the packed mesh (``batch.meshes[b]``)."""
        return self.forms[int(self.batch.edge_ptr[b]):int(self.batch.edge_ptr[b + 1])]

    def mesh_face_vectors(self, b: int) -> np.ndarray:
        """[F_input, n, 3] face vectors of mesh b on the faces of the mesh that was packed, in
        its input order (0 on faces cleaning dropped). For a decimated mesh that is the
        decimated mesh; :meth:`Segmentation.face_vectors` reports on the original's faces."""
        fv = self.face_vectors[int(self.batch.face_ptr[b]):int(self.batch.face_ptr[b + 1])]
        return self.batch.meshes[b].to_input_faces(fv.detach().cpu().numpy())


def as_batch(meshes, device=None, coarse_faces: int | None = None) -> MeshBatch:
    """A :class:`MeshBatch` from a batch, a mesh or a list of meshes (``coarse_faces``: as in
    :meth:`MeshBatch.from_meshes`; a batch given keeps its own)."""
    if isinstance(meshes, MeshBatch):
        return meshes if device is None else meshes.to(device)
    if isinstance(meshes, (Mesh, CleanMesh)):
        meshes = [meshes]
    return MeshBatch.from_meshes(list(meshes), device=device or "cpu", coarse_faces=coarse_faces)


SOLVERS = ("auto", "lobpcg", "lanczos", "krylov")

#: Device types on which :func:`akvf` solves a batch one mesh at a time (each mesh as a batch
#: of its own, results concatenated: the bits of each mesh alone); see the comment in akvf.
#: On the others the batch is solved as one (LOBPCG on the packed batch, with locking).
ONE_MESH_AT_A_TIME_ON = ("cpu",)

#: Under a mesh-quality remedy, eigenpairs below this (λ·area) are spurious: a Killing energy is
#: >= 0, and good meshes give at worst small negatives (-0.06 on a hemisphere, akvf-math.md);
#: badly shaped vertices give modes localized on a few edges far below zero.
SPURIOUS_BELOW = -1.0
#: Extra eigenpairs computed to make room for spurious ones.
SPURIOUS_MARGIN = 8


#: On CPU, "auto" solves meshes with at least this many edges with the block Krylov solver and
#: smaller ones with ARPACK Lanczos (same factor). Measured (wall time, n = 36, best of 2-3
#: interleaved rounds, PSB meshes decimated as eval does; benchmarks/results/eigensolver_threads.md),
#: Lanczos / Krylov: 0.91 at ~1,500 edges (8 meshes at 1000 faces), 1.06 at ~3,000 (2000 faces),
#: 1.46 at ~6,000 (19 meshes at 4000 faces, one thread; 1.36 on two), 1.3-1.4 at full
#: resolution (14,112-45,594 edges). It was 10000, measured when the Krylov products went
#: through numpy's BLAS. With the Krylov solver at its interior shift (2026-12-04, CPU time, one
#: thread, 7 PSB meshes decimated to 800/1500/2500 faces): 1.44, 1.72 and 2.01 at ~1,200, ~2,250
#: and ~3,750 edges, but 0.76-0.79 on icospheres of 480 and 1,920 edges (exactly repeated
#: eigenvalues, where the Krylov solver widens its block and solves again) and 0.85-1.2 on the
#: other small built-in shapes: a few ms either way, so the threshold stays.
KRYLOV_MIN_EDGES = 4000


def solver_for(device: torch.device, edges: int | None = None) -> str:
    """The eigensolver "auto" picks for a mesh of ``edges`` edges on ``device``: on CPU the block
    Krylov solver from :data:`KRYLOV_MIN_EDGES` edges on (and when ``edges`` is not given),
    Lanczos below; the batched LOBPCG elsewhere.

    All use the same CHOLMOD shift-invert factor (one per mesh). On CPU the block
    shift-invert Krylov solver (:func:`~torchakvf.solvers.krylov.block_krylov`) keeps every
    solve it makes, like ARPACK, but solves 4 right-hand sides per sweep through the factor and
    converges only the n pairs asked for; on small meshes its per-step dense work costs more
    than ARPACK's single-vector steps (see :data:`KRYLOV_MIN_EDGES`). LOBPCG's dense
    Rayleigh-Ritz work (bases of 3·(n + guard) columns, every column solved each iteration) is
    the slowest of the three on CPU (4x Lanczos on PSB 21 and 301). On a GPU the block method's
    batched dense work is what the device is good at, and ARPACK does not run there (the Krylov
    solver would, but has not been measured on one).
    """
    if torch.device(device).type != "cpu":
        return "lobpcg"
    return "krylov" if edges is None or edges >= KRYLOV_MIN_EDGES else "lanczos"


def _remedy_advice(remedy: str, decimated: bool = False) -> str:
    """What to try after a failed solve under ``remedy`` (never what was just tried)."""
    if remedy != "smooth":
        return f"it was solved with remedy={remedy!r}; try remedy='smooth' (the default)"
    if decimated:
        return ("it was solved decimated with remedy='smooth', the strongest remedy; solve it at "
                "full resolution (akvf_falling_back does) or repair the input mesh")
    return ("it was solved with remedy='smooth', the strongest remedy; repair the mesh (remesh "
            "it, close its holes)")


def _field_count(n) -> int:
    if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
        raise ParameterError(f"n must be a positive integer, got {n!r}")
    return int(n)


def akvf(meshes, n: int = 32, *, tol: float = 1e-6, seed: int = 0, remedy: str = DEFAULT_REMEDY,
         boundary_correction: bool = True, max_iter: int = 60, solver: str = "auto",
         device=None, method: str | None = None) -> AKVFResult:
    """The n smallest approximate Killing vector fields of each mesh.

    Parameters
    ----------
    meshes : MeshBatch, Mesh, or list of Mesh (a mesh is a batch of one)
    n : number of fields per mesh (a Python or numpy integer; each mesh needs more than n edges)
    tol : eigenpair residual at which a mesh counts as converged (``AKVFResult.converged``;
        a mesh that does not converge is flagged there and warned about, not raised)
    seed : seed of the solver's random start (the same start for every mesh)
    remedy : mesh-quality remedy of the operator (:data:`torchakvf.operators.REMEDIES`, default
        :data:`~torchakvf.operators.killing.DEFAULT_REMEDY`; "none" is the paper's operator);
        any remedy but "none" also skips spurious eigenpairs below :data:`SPURIOUS_BELOW` (the
        n returned are the n smallest of the rest; ``dropped`` counts the skipped ones)
    boundary_correction : use the open-mesh boundary terms (akvf-math.md)
    solver : "lobpcg" (segmented block solver over the batch, any device; a mesh that has
        converged leaves its iteration; on CUDA one block-diagonal factor of the batch serves
        every mesh's solves), "lanczos" (ARPACK
        shift-invert on the same factor, CPU, one mesh at a time), "krylov" (block shift-invert
        Krylov on the same factor, one mesh at a time) or "auto" (:func:`solver_for`, decided
        per mesh: on CPU Krylov for meshes from :data:`KRYLOV_MIN_EDGES` edges, Lanczos below)
    device : device of the batch built from Mesh inputs (a MeshBatch given is moved there);
        default: the batch's own, "cpu" for meshes
    method : deprecated alias of ``solver``

    Work runs on the batch's device; the operator and solve are float64 whatever the
    coordinates' dtype, and results are returned in the batch's dtype.

    Each mesh's result depends on that mesh alone: the number of eigenpairs solved (n plus
    room for spurious modes) is decided per mesh, never by its batch mates. On CPU
    (:data:`ONE_MESH_AT_A_TIME_ON`) a batch is solved one mesh at a time, with every solver:
    each mesh gets the bits it gets alone (benchmarks/results/batched_vs_alone_cpu.md for the
    speed of either way).
    """
    if method is not None:
        warnings.warn("akvf(method=...) is deprecated; use solver=...", DeprecationWarning, stacklevel=2)
        solver = method
    n = _field_count(n)
    if solver not in SOLVERS:
        raise ParameterError(f"solver must be one of {SOLVERS}, got {solver!r}")
    if remedy not in REMEDIES:
        raise ParameterError(f"remedy must be one of {REMEDIES}, got {remedy!r}")
    batch = as_batch(meshes, device=device)
    edges = (batch.edge_ptr[1:] - batch.edge_ptr[:-1]).tolist()
    # The solver of each mesh ("auto" decides per mesh, by its size).
    solvers = [solver_for(batch.device, e) if solver == "auto" else solver for e in edges]
    names = batch.names
    if len(batch) > 1 and batch.device.type in ONE_MESH_AT_A_TIME_ON:
        # On CPU a batch is solved one mesh at a time (operator, factor, eigensolve, residuals,
        # Whitney vectors). The batch's arrays are only larger, not fewer operations, and fresh
        # memory is what they cost: on 16 PSB meshes at 4000 faces the batched stage took 1.35x
        # the time of the same meshes one by one (Lanczos/Krylov, which solve mesh by mesh
        # anyway), and the batched LOBPCG (with locking) 1.34x on 8 of them (15.2 against
        # 11.3 s CPU; its [B, E, 3m] bases and their concatenations are fresh arrays every
        # iteration). The batched paths are the GPU's, whose caching allocator reuses memory.
        return _one_mesh_at_a_time(batch, n, tol=tol, seed=seed, remedy=remedy,
                                   boundary_correction=boundary_correction, max_iter=max_iter,
                                   solver=solver)
    system = killing_operator(batch, boundary_correction=boundary_correction, remedy=remedy)

    drop = remedy != "none"
    factors: dict[int, ShiftedFactor] = {}     # a re-solve with more room reuses them

    def factor_of(b: int) -> ShiftedFactor:
        if b not in factors:
            factors[b] = mesh_factor(system, b, names[b])
        return factors[b]

    def solve(meshes_: list[int], count: int, solver: str):
        whole = len(meshes_) == len(batch)
        sub = system if whole or solver == "krylov" else system.select(meshes_)
        sub_names = [names[b] for b in meshes_]
        try:
            if solver == "lanczos":
                # On CPU the factors are kept for a re-solve with more room (ARPACK needs CPU ones).
                cpu = system.mass.device.type == "cpu"
                return shift_invert_lanczos(sub, count, tol=tol, seed=seed, names=sub_names,
                                            factors=[factor_of(b) for b in meshes_] if cpu else None)
            if solver == "krylov":
                # Only the n kept pairs (and the spurious ones below them) must converge; the
                # room for spurious modes is returned as it is. The factor is at an interior
                # shift where the mesh allows one (interior_factor), else the definite one.
                fac = [interior_factor(system, b, n, lambda b=b: factor_of(b)) for b in meshes_]
                eig = block_krylov(sub, count, tol=tol, seed=seed, names=sub_names, need=n,
                                   skip_below=SPURIOUS_BELOW if drop else None, factors=fac,
                                   grow=len(meshes_) == 1, meshes=meshes_)
                if len(meshes_) == 1 and not bool(eig.converged[0]) and sub.mass.device.type == "cpu":
                    # Rare (seen on a mesh with 33 spurious modes and shift -512, where the
                    # wanted pairs' 1/(λ - σ) all crowd together): ARPACK on the definite factor.
                    one = sub if whole else system.select(meshes_)
                    k = min(eig.eigenvalues.shape[1], len(one.mass) - 1)
                    eig = shift_invert_lanczos(one, k, tol=tol, seed=seed, names=sub_names,
                                               factors=[factor_of(b) for b in meshes_])
                return eig
            return segmented_lobpcg(sub, count, tol=tol, seed=seed, names=sub_names, max_iter=max_iter)
        except SolverError as exc:
            if "fields asked for" in str(exc):
                raise
            decimated = any(batch.coarse_of(b) is not None for b in meshes_)
            raise SolverError(f"{exc}; {_remedy_advice(remedy, decimated)}") from None

    # Per mesh: n eigenpairs plus room for spurious ones (capped below the mesh's edge count).
    counts = [n + (min(SPURIOUS_MARGIN, max(e - n - 1, 0)) if drop else 0) for e in edges]
    per_mesh: list = [None] * len(batch)
    todo = list(range(len(batch)))
    for _ in range(4):
        # Meshes needing the same count are solved together; a mesh with more spurious modes
        # than its room is solved again alone with more (its mates keep theirs).
        # The Krylov solver works one mesh at a time anyway and makes room for spurious modes
        # itself (it returns more pairs where they need it), so it needs no second round.
        others = [b for b in todo if solvers[b] != "krylov"]
        groups = [[b] for b in todo if solvers[b] == "krylov"] + [
            [b for b in others if (counts[b], solvers[b]) == key]
            for key in sorted({(counts[b], solvers[b]) for b in others})]
        for group in groups:
            eig = solve(group, counts[group[0]], solvers[group[0]])
            vecs = batch.split(eig.vectors, _group_ptr(eig, group, edges))
            for j, b in enumerate(group):
                per_mesh[b] = (eig.eigenvalues[j], vecs[j], eig.residuals[j], eig.iterations[j], eig.shifts[j])
                counts[b] = max(counts[b], eig.eigenvalues.shape[1])
        if not drop:
            break
        again = []
        for b in todo:
            spurious = int((per_mesh[b][0] < SPURIOUS_BELOW).sum())
            short = spurious - (counts[b] - n)
            if short > 0 and counts[b] < edges[b] - 1:
                counts[b] = min(counts[b] + short + SPURIOUS_MARGIN, edges[b] - 1)
                again.append(b)
        if not again:
            break
        todo = again
    # Per mesh, the first n eigenpairs that are not spurious (ascending order kept).
    lam, forms, res, dropped = [], [], [], []
    for values, vectors, residuals, _, _ in per_mesh:
        spurious = values < SPURIOUS_BELOW if drop else torch.zeros_like(values, dtype=torch.bool)
        keep = torch.argsort(spurious.to(torch.int8), stable=True)[:n]
        # Column slices where the kept pairs lead (no spurious ones): a view, not a gather.
        cols = slice(0, n) if bool((keep == torch.arange(len(keep), device=keep.device)).all()) else keep
        lam.append(values[cols]), forms.append(vectors[:, cols]), res.append(residuals[cols])
        dropped.append(int(spurious.sum()))
    dev = batch.device
    eigenvalues, residuals, forms = torch.stack(lam), torch.stack(res), torch.cat(forms)
    converged = (residuals <= tol).all(dim=1)
    _warn_unconverged(names, residuals, converged, tol)
    fv = whitney_face_vectors(batch, system.geometry, forms)
    out_dt = batch.dtype
    return AKVFResult(eigenvalues=eigenvalues.to(out_dt), forms=forms.to(out_dt),
                      face_vectors=fv.to(out_dt), residuals=residuals,
                      iterations=torch.stack([p[3] for p in per_mesh]).to(dev),
                      shifts=torch.stack([p[4] for p in per_mesh]).to(dev), converged=converged,
                      dropped=torch.tensor(dropped, dtype=torch.long, device=dev), batch=batch, system=system,
                      solved=torch.tensor(counts, dtype=torch.long, device=dev))


def _warn_unconverged(names: list, residuals: torch.Tensor, converged: torch.Tensor, tol: float,
                      stacklevel: int = 3) -> None:
    """One :class:`ConvergenceWarning` naming every mesh of the batch that did not reach
    ``tol`` (``stacklevel``: of the caller of :func:`akvf`, counted from here)."""
    if not bool(converged.all()):
        bad = [f"{names[b]} (residual {float(residuals[b].max()):.1e})"
               for b in torch.nonzero(~converged).reshape(-1).tolist()]
        warnings.warn(f"AKVF eigensolve did not reach tol {tol:.0e} for {', '.join(bad)}; these "
                      "meshes are flagged in AKVFResult.converged", ConvergenceWarning, stacklevel=stacklevel)


def _one_mesh_at_a_time(batch: MeshBatch, n: int, **kwargs) -> AKVFResult:
    """:func:`akvf` of each mesh of ``batch`` alone (:meth:`MeshBatch.mesh`), as one result on
    ``batch``: the same bits as each mesh solved by itself, by construction."""
    parts = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)    # one warning for the batch, below
        for b in range(len(batch)):
            parts.append(akvf(batch.mesh(b), n, **kwargs))
    cat = lambda name: torch.cat([getattr(p, name) for p in parts])  # noqa: E731
    out = AKVFResult(eigenvalues=cat("eigenvalues"), forms=cat("forms"), face_vectors=cat("face_vectors"),
                     residuals=cat("residuals"), iterations=cat("iterations"), shifts=cat("shifts"),
                     converged=cat("converged"), dropped=cat("dropped"), batch=batch,
                     system=KillingSystem.concatenate([p.system for p in parts], batch.edge_ptr),
                     solved=cat("solved"))
    _warn_unconverged(batch.names, out.residuals, out.converged, kwargs["tol"], stacklevel=4)
    return out


def _group_ptr(eig, group: list[int], edges: list[int]) -> torch.Tensor:
    """[len(group)+1] offsets of the group's meshes in ``eig.vectors``."""
    return torch.tensor([0] + list(itertools.accumulate(edges[b] for b in group)))


def akvf_falling_back(batch: MeshBatch, n: int = 32, **kwargs) -> tuple[AKVFResult, list]:
    """:func:`akvf` on a batch of decimated meshes (``MeshBatch.from_meshes(coarse_faces=)``),
    solving at full resolution the meshes whose decimated version cannot be solved.

    A decimated surface can be worse than its original (holes that could not be closed, whose
    boundary terms make R - σS1 indefinite at every shift): on a :class:`SolverError` each
    decimated mesh is solved alone to find the ones that fail, and the batch is solved again
    with those at full resolution. Returns (the result, [(mesh index, error text)] of the
    meshes that fell back). A batch without decimated meshes raises as :func:`akvf` does.
    """
    try:
        return akvf(batch, n=n, **kwargs), []
    except SolverError as exc:
        decimated = [b for b in range(len(batch)) if batch.coarse_of(b) is not None]
        if not decimated:
            raise
        first = exc
    failed = []
    for b in decimated:
        try:
            akvf(MeshBatch.from_meshes([batch.meshes[b]], device=batch.device, dtype=batch.dtype), n=n, **kwargs)
        except SolverError as exc:
            failed.append((b, str(exc)))
    if not failed:   # no decimated mesh is to blame
        raise first
    return akvf(batch.at_full_resolution([b for b, _ in failed]), n=n, **kwargs), failed
