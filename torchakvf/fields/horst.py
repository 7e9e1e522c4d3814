"""Horst's iteration of the untangling (the paper's Algorithm 1), accelerated by SQUAREM.

Each step maps rotations A to the polar factor of G = Yᵀ (Y A)^3 (:func:`horst_step`), G by two
GEMMs (:class:`Products`) or from Y's fourth moments
(:class:`~torchakvf.fields.fourth_moments.FourthMoments`); every third step is taken from an
extrapolated point (:func:`extrapolated`) where that raises the objective
(:func:`horst_batched`). :func:`horst_one_mesh` is the same arithmetic for one mesh on CPU.
"""
from __future__ import annotations

import torch

from ..errors import ParameterError
from ..threads import single_threaded
from .fourth_moments import FourthMoments, side_by_side

#: Largest SQUAREM extrapolation (|α|) of the accelerated Horst iteration (:func:`horst_batched`):
#: longer steps leave the plain iteration's basin more often, shorter ones save fewer steps
#: (see docs/design.md).
SQUAREM_MAX_STEP = 4.0


def horst(ypad: torch.Tensor, a: torch.Tensor, tol: float, max_iter: int,
          iteration_dtype: torch.dtype, moments: bool = False):
    """Horst's iteration, accelerated (:func:`horst_batched`), from rotations a [b, R, n, n]
    (float64) for scaled forms [b, Emax, n]; the products Y A and Yᵀ (Y A)^3 in
    ``iteration_dtype``, or with ``moments`` (float64 only) Yᵀ (Y A)^3 from Y's fourth moments
    (:class:`FourthMoments`). Returns (rotations [b, R, n, n], iterations [b, R]: Horst steps, i.e.
    evaluations of Yᵀ (Y A)^3); a restart stops when a plain step changes trace(D) by less
    than tol (relative), and returns that step's rotation.

    One mesh on CPU (every call of :func:`orthomax_rotations` there) takes
    :func:`horst_one_mesh`, the same arithmetic without the batch's bookkeeping; any other
    call :func:`horst_batched`."""
    if len(ypad) == 1 and ypad.device.type == "cpu":
        return horst_one_mesh(ypad, a, tol, max_iter, iteration_dtype, moments)
    return horst_batched(ypad, a, tol, max_iter, iteration_dtype, moments)


def horst_step(gradient, al: torch.Tensor):
    """One Horst step of rotations al [m, q, n, n] (float64): G = Yᵀ (Y A)^3 per rotation
    [m, q, n, n] (float64, from ``gradient``: :class:`Products` or :class:`FourthMoments`),
    its polar factor U Vᵀ (the step's rotation) and trace(D) = Σ σ(G) [m, q]."""
    g = gradient(al)
    with single_threaded():
        u, sv, vh = torch.linalg.svd(g)
    return u @ vh, sv.sum(-1), g


class Products:
    """G(A) = Yᵀ (Y A)^3 by two GEMMs per mesh, for y [m, E, n] in iteration_dtype (G in
    float64). Y A is [m, E, q·n], the largest array here: one buffer, cubed in place, because
    fresh allocations of that size cost more than the GEMMs (measured 2.2x per step at 30k
    edges)."""

    def __init__(self, y: torch.Tensor, restarts: int, iteration_dtype: torch.dtype):
        self.y = y.to(iteration_dtype)
        self.dtype = iteration_dtype
        nb, e, n = y.shape
        self.buf = self.y.new_empty(nb * e * restarts * n)

    def select(self, meshes: torch.Tensor) -> "Products":
        """The same for a subset of the meshes (indices into this one's), sharing the buffer."""
        out = object.__new__(Products)
        out.y, out.dtype, out.buf = self.y[meshes], self.dtype, self.buf
        return out

    def __call__(self, al: torch.Tensor) -> torch.Tensor:
        """G [m, q, n, n] (float64) of rotations al [m, q, n, n]."""
        m, e, n = self.y.shape
        q = al.shape[1]
        out = self.buf[:m * e * q * n].view(m, e, q * n)
        ya = torch.matmul(self.y, side_by_side(al).to(self.dtype), out=out).pow_(3)
        return (self.y.transpose(1, 2) @ ya).reshape(m, n, q, n).permute(0, 2, 1, 3).double()


def horst_gradient(ypad: torch.Tensor, restarts: int, iteration_dtype: torch.dtype, moments: bool):
    """G(A) = Yᵀ (Y A)^3 for Horst's steps on ypad [m, Emax, n] with up to ``restarts``
    rotations per mesh: from the fourth moments (float64 steps only) or by the products."""
    if moments:
        if iteration_dtype != torch.float64:
            raise ParameterError("the fourth-moment steps are float64 steps")
        return FourthMoments(ypad.to(torch.float64))
    return Products(ypad, restarts, iteration_dtype)


def extrapolated(a0: torch.Tensor, a1: torch.Tensor, a2: torch.Tensor) -> torch.Tensor:
    """SQUAREM's point (Varadhan and Roland 2008, scheme S3) from a rotation a0 and its two
    Horst steps a1, a2 ([..., n, n]): with r = a1 - a0, v = a2 - 2 a1 + a0 and
    α = -|r| / |v| clamped to [-:data:`SQUAREM_MAX_STEP`, -1], the polar factor of
    a0 - 2α r + α² v (α = -1 gives a2 itself)."""
    r = a1 - a0
    v = a2 - a1 - r
    rn = r.square().sum(dim=(-2, -1)).sqrt()
    vn = v.square().sum(dim=(-2, -1)).sqrt()
    alpha = (-(rn / vn.clamp_min(1e-300))).clamp(-SQUAREM_MAX_STEP, -1.0)[..., None, None]
    m = a0 - 2 * alpha * r + alpha.square() * v
    with single_threaded():
        u, _, vh = torch.linalg.svd(m)
    return u @ vh


def squarem_state(a: torch.Tensor) -> dict:
    """The accelerated iteration's state for rotations a [b, R, n, n]: per restart the answer so
    far ("a"), the cycle's base point and its two Horst steps, trace(D) of the last plain step
    before the cycle, of the cycle's first and second steps, and the objective at step 1."""
    zeros = lambda: torch.zeros(a.shape[:2], dtype=torch.float64, device=a.device)   # noqa: E731
    return {"a": a.clone(), "base": a.clone(), "a1": torch.empty_like(a), "a2": torch.empty_like(a),
            "d_last": torch.full(a.shape[:2], -1.0, dtype=torch.float64, device=a.device),
            "d1": zeros(), "d2": zeros(), "obj1": zeros()}


def squarem_step(phase: int, state: dict, pick, put, gradient, tol: float) -> torch.Tensor:
    """Step ``phase`` (0, 1, 2) of a SQUAREM cycle (:func:`horst_batched`) for the restarts
    ``pick`` gathers from the state's [b, R, ...] arrays ([m, q, ...]; ``put`` scatters [m, q, ...]
    values back): 0 and 1 are plain Horst steps, 2 the step from the extrapolated point, kept
    where the objective there is no lower than at step 1. Returns done [m, q]: the plain step
    changed trace(D) by less than tol (relative; never after step 2)."""
    if phase == 0:
        rot, d, _ = horst_step(gradient, pick(state["base"]))
        done = (d - pick(state["d_last"])).abs() < tol * d.abs()
        put(state["a1"], rot)
        put(state["d1"], d)
    elif phase == 1:
        src = pick(state["a1"])
        rot, d, g = horst_step(gradient, src)
        done = (d - pick(state["d1"])).abs() < tol * d.abs()
        put(state["a2"], rot)
        put(state["d2"], d)
        put(state["obj1"], (src * g).sum(dim=(-2, -1)))
    else:
        x = extrapolated(pick(state["base"]), pick(state["a1"]), pick(state["a2"]))
        rot, d, g = horst_step(gradient, x)
        ok = (x * g).sum(dim=(-2, -1)) >= pick(state["obj1"])
        rot = torch.where(ok[..., None, None], rot, pick(state["a2"]))
        put(state["base"], rot)
        put(state["d_last"], torch.where(ok, d, pick(state["d2"])))
        done = torch.zeros(d.shape, dtype=torch.bool, device=d.device)
    put(state["a"], rot)
    return done


def horst_one_mesh(ypad: torch.Tensor, a: torch.Tensor, tol: float, max_iter: int,
                   iteration_dtype: torch.dtype, moments: bool = False):
    """:func:`horst_batched` for one mesh (ypad [1, E, n], a [1, R, n, n]) on CPU, bitwise.

    The same products of the same shapes and layouts on the same operands: each step's active
    restarts, in index order, side by side (the batched path's slots for one mesh, which has
    no padding restarts). What goes is the per-step bookkeeping on small tensors (argsort of
    the slots, gathers, scatters, boolean-mask writes, 1.5 ms per step on 4000-face meshes,
    more than the step's GEMMs at n = 16): which restarts are active is a Python list, read
    back once per step.
    """
    _, e_max, n = ypad.shape
    r = a.shape[1]
    gradient = horst_gradient(ypad, r, iteration_dtype, moments)
    state = squarem_state(a)
    iters = [0] * r
    act = list(range(r))                                              # active restarts, in order
    for step in range(max_iter):
        if not act:
            break
        q = len(act)
        every = q == r
        pick = (lambda t: t) if every else (lambda t: t[:, act])

        def put(t, v):
            if every:
                t.copy_(v)
            else:
                t[:, act] = v

        done = squarem_step(step % 3, state, pick, put, gradient, tol)[0].tolist()
        for j in act:
            iters[j] += 1
        act = [j for j, stop in zip(act, done) if not stop]
    return state["a"], torch.tensor([iters], dtype=torch.long)


def horst_batched(ypad: torch.Tensor, a: torch.Tensor, tol: float, max_iter: int,
                  iteration_dtype: torch.dtype, moments: bool = False):
    """Horst's iteration for any batch on any device (see :func:`horst`), accelerated by
    SQUAREM: each cycle makes two plain steps A1 = F(A0), A2 = F(A1) (F(A) = polar factor of
    Yᵀ (Y A)^3), then a third from the extrapolated point X = :func:`extrapolated` (A0, A1,
    A2); F(X) is the next cycle's base point where the objective at X is at least that at A1
    (else A2 is: the iteration never loses ground against plain Horst). Horst's iteration
    converges linearly, slowly on the plateaus of near-equal optima; the extrapolation takes
    well under half its steps to the same or a better objective (see docs/design.md).

    All restarts of all meshes step in lockstep (every cycle has three steps; a restart stops
    only after a plain step). The live meshes' active restarts are gathered into slots, the
    results scattered back where the restart is still active. Which restarts are active is read
    on the host once per cycle (:data:`SLOTS_EVERY` steps; a read is a host synchronization on a
    GPU): a restart that stops within a cycle keeps its slot, computed but never written back,
    until the next read."""
    nb, e_max, n = ypad.shape
    dev = ypad.device
    r = a.shape[1]
    state = squarem_state(a)
    active = torch.ones(nb, r, dtype=torch.bool, device=dev)
    iters = torch.zeros(nb, r, dtype=torch.long, device=dev)

    whole = horst_gradient(ypad, r, iteration_dtype, moments)
    live_host = list(range(nb))
    live = torch.arange(nb, device=dev)
    gradient = whole
    for step in range(max_iter):
        if step % SLOTS_EVERY == 0:
            # Only restarts still moving iterate: converged ones (and meshes whose restarts have
            # all converged) drop out, so neither a slow mesh nor a slow restart makes the others
            # pay. Each live mesh's q active restarts go first; shorter lists are padded with
            # converged restarts, computed but not written back. One read: the counts.
            counts = active.sum(dim=1).tolist()
            still = [b for b, c in enumerate(counts) if c > 0]
            if not still:
                break
            if still != live_host:
                live_host, live = still, torch.tensor(still, device=dev)
                gradient = whole.select(live)
            m, q = len(live_host), max(counts)
            act = active[live]                                        # [m, R]
            slot = torch.argsort((~act).to(torch.int8), dim=1, stable=True)[:, :q]
            rows = torch.arange(m, device=dev)[:, None]
        valid = torch.gather(active[live], 1, slot)                   # [m, q], on the device
        pick = lambda t: t[live][rows, slot]                          # noqa: E731  [m, q, ...]

        def put(t, v):
            tl = t[live]
            keep = valid.reshape(valid.shape + (1,) * (v.dim() - 2))
            tl[rows, slot] = torch.where(keep, v, tl[rows, slot])
            t[live] = tl

        done = squarem_step(step % 3, state, pick, put, gradient, tol)
        iters[live] += active[live].long()
        active[live] = active[live].scatter(1, slot, valid & ~done)
    return state["a"], iters


#: Steps between host reads of which restarts are still active in :func:`horst_batched`: one
#: SQUAREM cycle.
SLOTS_EVERY = 3


__all__ = ["horst", "horst_step", "horst_one_mesh", "horst_batched", "horst_gradient", "Products", "extrapolated",
           "squarem_state", "squarem_step", "SQUAREM_MAX_STEP", "SLOTS_EVERY"]
