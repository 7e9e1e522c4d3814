"""Segmented LOBPCG for the smallest eigenpairs of ``R w = λ S1 w`` of every mesh of a batch.

One sparse multiply serves the whole batch; the Gram matrices and the small Rayleigh-Ritz
problems are per mesh (padded, batched dense ``eigh``); each mesh converges, and stops, on its
own: a converged mesh leaves the iteration (locking: the live meshes' arrays shrink). The
preconditioner is the exact shift-invert ``(R_b - σ_b S1_b)^{-1}`` (one sparse Cholesky factor
per mesh, see :mod:`.factor`; on CUDA one block-diagonal factor of the whole batch, so that
an iteration makes one solve call, not one per mesh), and the block carries ``guard`` extra
vectors beyond the ``n`` wanted: convergence then goes like (λ_n - σ)/(λ_{n+guard+1} - σ)
instead of depending on the tiny gap after λ_n, and block methods keep every copy of a repeated eigenvalue (Lanczos with
a loose tolerance was seen to drop some).

Residuals are recomputed at the end from R and S1, not taken from the iteration.

On a GPU the host waits for the device wherever a value comes back to Python: the loop reads
which meshes converged once every :data:`CHECK_EVERY` iterations and indexes the padded arrays
with index tensors, not boolean masks, so an iteration's only other synchronizations are the
two dense ``eigh`` of the Rayleigh-Ritz step (torch reads their error codes).
:func:`working_bytes` gives the padded arrays' peak size, for sizing batches.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import torch

from ..errors import FieldCountError, ParameterError, SolverError
from ..mesh.batch import owner_index
from ..operators.killing import KillingSystem
from ..threads import single_threaded
from .factor import BlockDiagonalFactor, mesh_factor

log = logging.getLogger(__name__)

#: Relative directions kept when orthonormalizing a basis: smaller ones are numerically
#: dependent (converged columns make W nearly parallel to X).
_DROP = 1e-9
#: Squared fraction of a new direction's norm that must lie outside span(X) for it to be kept.
_INSIDE = 1e-16
_BIG = 1e30
#: Device types on which the batched LOBPCG is preconditioned by one block-diagonal factor of
#: the batch by default (see :class:`~torchakvf.solvers.factor.BlockDiagonalFactor`): where a
#: solve call costs its levels, not its rows. On the CPU the two take the same time.
BLOCK_FACTOR_ON = ("cuda",)
#: Iterations between host reads of which meshes converged (a read is a host synchronization on
#: a GPU). A mesh's pairs are recorded when it converges whatever this is: only when it leaves
#: the iteration (its padded rows stop costing work) waits for the next read.
CHECK_EVERY = 3


@dataclass
class EigenResult:
    """Smallest eigenpairs of a batch.

    eigenvalues : [B, n] ascending, λ·area (the operator is built on unit-area meshes)
    vectors : packed [ΣE, n], S1-orthonormal per mesh
    residuals : [B, n] ||S1^{-1/2}(R w - λ S1 w)|| / max(|λ|, 1) for S1-normalized w
    iterations : [B] LOBPCG iterations per mesh (Lanczos: shift-invert solves; block Krylov:
        shift-invert right-hand sides)
    shifts : [B] the shift σ of each mesh's factor, λ·area: below every eigenvalue (-1, -8, ...)
        for a definite factor; the block Krylov solver's interior shift (5n, 5n/2 or lower, inside
        the wanted eigenvalues) where it took one (:class:`~torchakvf.solvers.factor.InteriorFactor`)
    converged : [B] bool, every residual <= tol
    left_out : [B] spurious eigenpairs (below the remedy's threshold) that the solver counted by
        inertia and did not return (the block Krylov solver at an interior shift that counted
        them); None: every spurious pair found is among the returned ones
    """

    eigenvalues: torch.Tensor
    vectors: torch.Tensor
    residuals: torch.Tensor
    iterations: torch.Tensor
    shifts: torch.Tensor
    converged: torch.Tensor
    left_out: torch.Tensor | None = None


def relative_residuals(system: KillingSystem, vectors: torch.Tensor, values: torch.Tensor
                       ) -> torch.Tensor:
    """[B, n] residuals of packed S1-normalized ``vectors`` [ΣE, n] for ``values`` [B, n]."""
    owner = owner_index(system.edge_ptr.to(vectors.device))
    res = torch.sparse.mm(system.stiffness, vectors) - system.mass[:, None] * vectors * values[owner]
    sq = (res ** 2 / system.mass[:, None])
    out = vectors.new_zeros(values.shape).index_add_(0, owner, sq)
    return out.sqrt() / values.abs().clamp(min=1.0)


def segmented_lobpcg(system: KillingSystem, n: int, tol: float = 1e-6, max_iter: int = 60,
                     guard: int | None = None, seed: int = 0, names: list[str] | None = None,
                     factors: list | None = None, block_factor: bool | None = None,
                     start: list | None = None) -> EigenResult:
    """The ``n`` smallest eigenpairs of every mesh of ``system`` (see module docstring).

    tol : residual (as in :class:`EigenResult`) at which a mesh's first n pairs count as converged
    guard : extra block vectors, default max(8, n // 2)
    seed : the random start of each mesh is drawn from ``torch.Generator().manual_seed(seed)``
        alone, so a mesh gets the same start (and result) in any batch
    factors : optional precomputed :class:`ShiftedFactor` per mesh, or one
        :class:`BlockDiagonalFactor` of ``system`` (then used whatever ``block_factor`` says)
    block_factor : precondition with one :class:`BlockDiagonalFactor` of the whole batch (one
        solve call per iteration for every live mesh, the converged meshes' rows solved too)
        instead of one factor per mesh (one call per live mesh, on its unconverged columns);
        default: on the device types of :data:`BLOCK_FACTOR_ON` (CUDA), where a call's cost is
        its levels, not its rows (ignored when ``factors`` are given). The two give the same
        eigenpairs up to round-off.
    start : optional warm start, one [E_b, m_b] block per mesh (e.g. a coarse mesh's fields
        prolonged to this one's edges, S1-orthonormality not needed): it replaces the first m_b
        columns of that mesh's random start block (m_b <= n + guard; the rest stay random);
        like the random block it is pushed once through the preconditioner before the first
        Rayleigh-Ritz. ``factors`` may be any preconditioners with ``solve(rhs [E, k])`` and a
        ``sigma`` attribute.
    """
    nb = system.n_meshes
    names = names or [f"mesh {b}" for b in range(nb)]
    dev = system.mass.device
    sizes = (system.edge_ptr[1:] - system.edge_ptr[:-1]).tolist()
    for b, e in enumerate(sizes):
        if n > e:
            raise FieldCountError(f"{names[b]}: {n} fields asked for but the mesh has only {e} edges; "
                              "ask for fewer fields")
    guard = max(8, n // 2) if guard is None else guard
    m = n + guard
    start = _start_blocks(start, sizes, m, names)
    e_max = max(sizes)
    dt = torch.float64

    if block_factor is None:
        block_factor = dev.type in BLOCK_FACTOR_ON
    block = factors if isinstance(factors, BlockDiagonalFactor) else None
    if block is not None:
        factors = None
    elif factors is None and block_factor:
        block = BlockDiagonalFactor(system, names)
    elif factors is None:
        factors = [mesh_factor(system, b, names[b]) for b in range(nb)]
    ptr = system.edge_ptr.tolist()

    mask = torch.zeros(nb, e_max, dtype=torch.bool, device=dev)
    for b, e in enumerate(sizes):
        mask[b, :e] = True
    s = system.mass.new_zeros(nb, e_max, dtype=dt)
    s[mask] = system.mass.to(dt)
    inv_sqrt_s = torch.where(mask, s.clamp(min=1e-300).rsqrt(), torch.zeros_like(s))
    # Locking: a mesh whose n pairs have converged leaves the iteration. The working arrays hold
    # the live meshes only (``live``: their indices in the batch), and R is the live meshes'
    # block-diagonal part, rebuilt when one leaves (at most B times): the finished ones cost
    # nothing more (without locking a batch costs about 1.5x its meshes solved one by one).
    # Which meshes converged is read on the host every CHECK_EVERY iterations only (a read is a
    # host synchronization on a GPU); in between, a mesh that converges has its pairs recorded
    # on the device, as they are when it converges, and iterates on uncounted until it leaves.
    live = list(range(nb))
    stiff = system.stiffness.to(dt)
    s_l, inv_l = s, inv_sqrt_s
    # Index tensors in place of boolean masks (a mask index is a host synchronization): the
    # padded slots [L·Emax] of the live meshes' packed rows, and those rows in the packing.
    slots_l, rows_l = _live_slots(live, sizes, ptr, e_max, dev)
    live_t = torch.arange(nb, device=dev)

    def r_mul(x: torch.Tensor) -> torch.Tensor:          # [L, Emax, k] -> [L, Emax, k]
        flat = x.reshape(-1, x.shape[2])
        out = torch.zeros_like(flat)
        out.index_copy_(0, slots_l, torch.sparse.mm(stiff, flat.index_select(0, slots_l)))
        return out.view(x.shape)

    def precondition(res: torch.Tensor, todo: torch.Tensor) -> torch.Tensor:
        out = torch.zeros_like(res)
        if block is not None:
            flat, k = out.view(-1, res.shape[2]), res.shape[2]
            rhs = res.new_zeros(len(system.mass), k)
            rhs.index_copy_(0, rows_l, res.reshape(-1, k).index_select(0, slots_l))
            flat.index_copy_(0, slots_l, block.solve(rhs).index_select(0, rows_l).to(dt))
            return out * todo[:, None, :]
        todo_host = todo.tolist()             # one read for every mesh's columns
        for j, cols_host in enumerate(todo_host):
            if not any(cols_host):
                continue
            b = live[j]
            cols = torch.tensor([c for c, t in enumerate(cols_host) if t], device=dev)
            out[j, :sizes[b], cols] = factors[b].solve(res[j, :sizes[b]][:, cols]).to(dt)
        return out

    # Start: the same seeded random block per mesh, pushed once through the shift-invert.
    x = torch.zeros(nb, e_max, m, dtype=dt, device=dev)
    starts = [torch.randn(e, m, generator=torch.Generator().manual_seed(seed), dtype=dt).to(dev)
              for e in sizes]
    for b, block0 in enumerate(start):
        if block0 is not None:
            starts[b][:, :block0.shape[1]] = block0.to(dev, dt)
    if block is not None:
        x[mask] = block.solve(system.mass.to(dt)[:, None] * torch.cat(starts)).to(dt)
    else:
        for b, e in enumerate(sizes):
            x[b, :e] = factors[b].solve(s[b, :e, None] * starts[b]).to(dt)
    x, rx, lam, _ = _rayleigh_ritz(x, r_mul(x), s, m)
    final_x = torch.zeros(nb, e_max, n, dtype=dt, device=dev)
    final_lam = torch.zeros(nb, n, dtype=dt, device=dev)
    done_l = torch.zeros(nb, dtype=torch.bool, device=dev)   # converged, not yet locked
    p = None
    iters = torch.zeros(nb, dtype=torch.long, device=dev)
    for it in range(max_iter):
        res = rx - s_l[..., None] * x * lam[:, None, :]
        rel = torch.linalg.norm(res * inv_l[..., None], dim=1) / lam.abs().clamp(min=1.0)
        new = (rel[:, :n] <= tol).all(dim=1) & ~done_l
        # Pairs recorded on the device as they are when their mesh converges.
        final_x[live_t] = torch.where(new[:, None, None], x[:, :, :n], final_x[live_t])
        final_lam[live_t] = torch.where(new[:, None], lam[:, :n], final_lam[live_t])
        done_l = done_l | new
        if it % CHECK_EVERY == 0 and bool(done_l.any()):
            stay = torch.nonzero(~done_l).reshape(-1)
            if len(stay) == 0:
                live = []
                break
            live = [live[j] for j in stay.tolist()]
            live_t, done_l = live_t[stay], done_l[stay]
            x, rx, lam, res, rel = x[stay], rx[stay], lam[stay], res[stay], rel[stay]
            p = None if p is None else p[stay]
            s_l, inv_l = s[live_t], inv_sqrt_s[live_t]
            stiff = system.select(live).stiffness.to(dt)
            slots_l, rows_l = _live_slots(live, sizes, ptr, e_max, dev)
        iters.index_add_(0, live_t, (~done_l).long())
        w = precondition(res, (rel > tol) & ~done_l[:, None])
        # Orthogonalize the new directions against X (S-inner product) for a well-conditioned basis.
        w = _orthogonalize(w, x, s_l)
        rw = r_mul(w)
        if p is None:
            z, rz = torch.cat([x, w], 2), torch.cat([rx, rw], 2)
        else:
            # R P is recomputed, not updated by recurrence: the recurrence drifts from R·P and
            # the drift shows up as spurious Ritz values far below the spectrum.
            p = _orthogonalize(p, x, s_l)
            rp = r_mul(p)
            z, rz = torch.cat([x, w, p], 2), torch.cat([rx, rw, rp], 2)
        x, rx, lam, c = _rayleigh_ritz(z, rz, s_l, m)
        p = z[:, :, m:] @ c[:, m:, :]
        # The basis and its products go now, not when the next iteration rebinds them: they
        # would be alive beside the next basis (about 19 P·m arrays at once instead of 16).
        del z, rz, w, rw, res
    if live:    # out of iterations: the meshes still live keep where they got, unless converged
        final_x[live_t] = torch.where(done_l[:, None, None], final_x[live_t], x[:, :, :n])
        final_lam[live_t] = torch.where(done_l[:, None], final_lam[live_t], lam[:, :n])

    vectors = final_x[mask]
    values = final_lam
    residuals = relative_residuals(system, vectors, values)
    converged = (residuals <= tol).all(dim=1)
    if not bool(torch.isfinite(values).all()):
        bad = torch.nonzero(~torch.isfinite(values).all(dim=1)).reshape(-1).tolist()
        raise SolverError(f"{', '.join(names[b] for b in bad)}: the eigensolver's results are not "
                          "finite (a failed solve on the device?)")
    for b in torch.nonzero(~converged).reshape(-1).tolist():
        log.warning("%s: eigensolver stopped after %d iterations with residual %.2e > tol %.1e",
                    names[b], int(iters[b]), float(residuals[b].max()), tol)
    shifts = (block.sigma if block is not None
              else torch.tensor([f.sigma for f in factors], dtype=dt, device=dev))
    return EigenResult(eigenvalues=values, vectors=vectors, residuals=residuals, iterations=iters,
                       shifts=shifts, converged=converged)


def _live_slots(live: list[int], sizes: list[int], ptr: list[int], e_max: int, dev):
    """([ΣE_live] slots of the live meshes' rows in their padded [L·Emax] arrays, [ΣE_live]
    those rows in the batch's packing), in the same order, built on the host."""
    slots = torch.cat([torch.arange(j * e_max, j * e_max + sizes[b]) for j, b in enumerate(live)])
    rows = torch.cat([torch.arange(ptr[b], ptr[b + 1]) for b in live])
    return slots.to(dev), rows.to(dev)


def working_bytes(edges: list[int], n: int, guard: int | None = None) -> int:
    """Bytes of the arrays :func:`segmented_lobpcg` holds at once, at its peak (an iteration
    with every mesh live and a P block), for meshes of ``edges`` edges and ``n`` pairs: a
    budget for sizing batches against a device's free memory. The factor's own memory (its
    sparse Cholesky factor) and the operator are not included.

    Counted from the arrays the code allocates, float64, padded to P = B·Emax rows (B meshes,
    Emax the largest edge count), m = n + guard columns: during the Rayleigh-Ritz step 16 P·m
    (X, R X, the residuals, W, R W, P, R P: 7; the basis Z and R Z: 6; S Z: 3), the converged
    pairs P·n, the mass and its inverse square root 2 P, the mask P bytes, the start blocks kept
    ΣE·m, and the B Gram-sized [3m, 3m] matrices of the step (6 of them)."""
    guard = max(8, n // 2) if guard is None else guard
    m, b, e_max, total = n + guard, len(edges), max(edges), sum(edges)
    rows = b * e_max
    floats = 16 * rows * m + rows * n + 2 * rows + total * m + 6 * b * (3 * m) ** 2
    return 8 * floats + rows


def _start_blocks(start, sizes: list[int], m: int, names: list[str]) -> list:
    """The warm start blocks as tensors ([E_b, <= m] or None per mesh), checked before any
    factorization: a wrong count or shape is a ParameterError naming the mesh."""
    if start is None:
        return [None] * len(sizes)
    if len(start) != len(sizes):
        raise ParameterError(f"segmented_lobpcg: {len(start)} start blocks for {len(sizes)} meshes")
    out = []
    for b, block0 in enumerate(start):
        if block0 is not None:
            block0 = torch.as_tensor(block0)
            if block0.ndim != 2 or block0.shape[0] != sizes[b] or block0.shape[1] > m:
                raise ParameterError(f"{names[b]}: start block of shape {tuple(block0.shape)}; "
                                     f"expected [{sizes[b]}, at most {m}] (edges, n + guard)")
        out.append(block0)
    return out


def _orthogonalize(v: torch.Tensor, x: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Remove from v [B, Emax, k] its components along the S-orthonormal x (twice: one pass
    leaves O(eps·cond) components), and zero the columns that were (numerically) inside span(x):
    rescaled to unit length they would be pure round-off, and round-off directions of this
    indefinite R carry huge spurious Ritz values at tight tolerances."""
    before = (v * v * s[..., None]).sum(1)
    for _ in range(2):
        v = v - x @ (x.transpose(1, 2) @ (s[..., None] * v))
    after = (v * v * s[..., None]).sum(1)
    keep = after > _INSIDE * before
    return v * keep[:, None, :]


def _rayleigh_ritz(z: torch.Tensor, rz: torch.Tensor, s: torch.Tensor, m: int):
    """Rayleigh-Ritz per mesh on the basis z [B, Emax, k] with rz = R z.

    Returns the m lowest Ritz vectors [B, Emax, m], R times them, Ritz values [B, m] and the
    coefficients c [B, k, m] (Ritz vectors = z @ c). Numerically dependent directions of z
    (zero columns included) are dropped per mesh.
    """
    gram = z.transpose(1, 2) @ (s[..., None] * z)
    gram = 0.5 * (gram + gram.transpose(1, 2))
    d = gram.diagonal(dim1=1, dim2=2)
    live = d > 1e-24 * d.amax(dim=1, keepdim=True)
    scale = torch.where(live, d.clamp(min=1e-300).rsqrt(), torch.zeros_like(d))
    gram = gram * scale[:, :, None] * scale[:, None, :]
    with single_threaded():
        g, u = torch.linalg.eigh(gram)
    ok = g > _DROP * g[:, -1:].clamp(min=1e-300)
    cmat = u * torch.where(ok, g.clamp(min=1e-300).rsqrt(), torch.zeros_like(g))[:, None, :]
    cmat = scale[:, :, None] * cmat
    h = cmat.transpose(1, 2) @ (z.transpose(1, 2) @ rz) @ cmat
    h = 0.5 * (h + h.transpose(1, 2))
    h = h + torch.diag_embed(torch.where(ok, torch.zeros_like(g), torch.full_like(g, _BIG)))
    with single_threaded():
        theta, v = torch.linalg.eigh(h)
    c = cmat @ v[:, :, :m]
    return z @ c, rz @ c, theta[:, :m], c
