"""Untangling AKVFs (the paper's Algorithm 1): an orthomax (quartimax) rotation per mesh.

Each mesh's n fields Φ_b [E_b, n] are rotated by an orthogonal A_b [n, n] maximizing the sum of
fourth powers of the per-edge norms sqrt(S1) Φ A, which concentrates every rotated field on as
few edges (one part) as possible. Horst's iteration: G = Yᵀ (Y A)^3, A <- U Vᵀ from svd(G),
accelerated by SQUAREM extrapolation (every third step, kept only where it raises the objective;
:func:`_horst_batched`). All restarts of a mesh step side by side ([E, n] x [n, R·n] products).
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import torch

from .._restarts import best_restart
from .._threads import single_threaded
from ..errors import ParameterError
from ..mesh.batch import pad_packed
from .akvf import AKVFResult

#: float32 iterations stop at tol * FLOAT32_PHASE_TOL; float64 iterations then run to tol.
FLOAT32_PHASE_TOL = 10.0
#: Largest SQUAREM extrapolation (|α|) of the accelerated Horst iteration (:func:`_horst_batched`).
#: 4: on 19 PSB meshes (coarse 4000, n = 16, 24, 32) 4833 steps against 11569 plain, the kept
#: restart's rotation within 0.1 (feature max) of plain Horst's on 38 of 57; unbounded: 5192
#: steps, 27 of 57 (long steps leave the plain iteration's basin more often); 2: 7312 steps.
SQUAREM_MAX_STEP = 4.0
#: Float64 Horst steps per restart assumed by :func:`_moments_pay` where nothing better is known
#: (the float64 phase after the float32 one took 20-29 per restart on PSB 1 and 21 at full
#: resolution, n = 32; after a float32 phase its own step count is the estimate).
_STEPS_PER_RESTART = 20


@dataclass
class UntangledFields:
    """Untangled AKVFs of a batch (first n of each mesh's AKVFs, rotated).

    Packed rows are in the index space of the batch (``batch.edge_ptr`` / ``batch.face_ptr``):
    each mesh as packed, i.e. cleaned and, in a batch built with ``coarse_faces``, decimated.
    :meth:`torchakvf.parts.Segmentation.face_vectors` maps to the input faces.

    rotation : [B, n, n] orthogonal A_b (untangled = raw @ A_b; 0 beyond a mesh's own n)
    energies : [B, n] Killing energy (Rayleigh quotient, λ·area) of each untangled field
    score : [B] the orthomax objective Σ (sqrt(S1) Φ A)^4 reached
    iterations : [B] iterations of the restart kept
    n_fields : list of B ints, the number of fields untangled per mesh (arrays padded to the max)
    source : the :class:`AKVFResult` they came from

    The rotated fields themselves are made on demand, per mesh (:meth:`mesh_forms`,
    :meth:`mesh_face_vectors`, :meth:`mesh_features`, each one GEMM on the mesh's own rows),
    or packed for the whole batch (:attr:`forms`, :attr:`face_vectors`, :attr:`features`);
    each is made once and kept. The engine reads one mesh at a time: on CPU, whole-batch
    arrays of every round cost more in fresh memory than their products (measured on 16 PSB
    meshes at 4000 faces: 1.8 s of 11 s for the segment stage, against 0.13 s one mesh at a
    time).

    forms : packed [ΣE, n] untangled 1-forms (S1-orthonormal per mesh)
    face_vectors : packed [ΣF, n, 3] untangled Whitney vectors at barycenters
    features : packed [ΣF, n] per-face norms |X_f| of the untangled fields (the paper's φ(f))
    """

    rotation: torch.Tensor
    energies: torch.Tensor
    score: torch.Tensor
    iterations: torch.Tensor
    n_fields: list
    source: AKVFResult
    _made: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @property
    def n(self) -> int:
        return self.rotation.shape[-1]

    @property
    def batch(self):
        return self.source.batch

    def _mesh(self, what: str, b: int) -> torch.Tensor:
        key = (what, b)
        if key not in self._made:
            n = int(self.n_fields[b])
            # the float64 rotation where it was kept (a float32 batch stores its rotation in
            # float32, but its fields are rotated in float64 either way)
            a = self._made.get("rotation64", self.rotation)[b, :n, :n].to(torch.float64)
            if what == "forms":
                lo, hi = int(self.batch.edge_ptr[b]), int(self.batch.edge_ptr[b + 1])
                out = self.source.forms[lo:hi, :n].to(torch.float64) @ a
            elif what == "face_vectors":
                lo, hi = int(self.batch.face_ptr[b]), int(self.batch.face_ptr[b + 1])
                fv = self.source.face_vectors[lo:hi, :n].to(torch.float64)
                # contiguous: einsum returns a permuted view, across which the norm is slow
                out = torch.einsum("fnc,nm->fmc", fv, a).contiguous()
            else:
                out = torch.linalg.norm(self._mesh("face_vectors", b), dim=-1)
            self._made[key] = out
        return self._made[key].to(self.source.forms.dtype)

    def mesh_forms(self, b: int) -> torch.Tensor:
        """[E_b, n_b] untangled forms of mesh b on the edges of the packed mesh."""
        return self._mesh("forms", b)

    def mesh_face_vectors(self, b: int) -> torch.Tensor:
        """[F_b, n_b, 3] untangled Whitney vectors of mesh b on the faces of the packed mesh."""
        return self._mesh("face_vectors", b)

    def mesh_features(self, b: int) -> torch.Tensor:
        """[F_b, n_b] features of mesh b on the faces of the packed mesh ``batch.meshes[b]``
        (cleaned; decimated in a coarse_faces batch)."""
        return self._mesh("features", b)

    def _packed(self, what: str) -> torch.Tensor:
        if what not in self._made:
            ptr = self.batch.edge_ptr if what == "forms" else self.batch.face_ptr
            tail = (3,) if what == "face_vectors" else ()
            out = self.source.forms.new_zeros((int(ptr[-1]), self.n) + tail, dtype=torch.float64)
            for b, n in enumerate(self.n_fields):
                out[int(ptr[b]):int(ptr[b + 1]), :int(n)] = self._mesh(what, b)
            self._made[what] = out.to(self.source.forms.dtype)
        return self._made[what]

    @property
    def forms(self) -> torch.Tensor:
        return self._packed("forms")

    @property
    def face_vectors(self) -> torch.Tensor:
        return self._packed("face_vectors")

    @property
    def features(self) -> torch.Tensor:
        return self._packed("features")


def random_rotations(count: int, n: int, generator: torch.Generator, dtype=torch.float64) -> torch.Tensor:
    """[count, n, n] Haar-random orthogonal matrices (QR of Gaussians, sign-fixed)."""
    g = torch.randn(count, n, n, generator=generator, dtype=dtype)
    with single_threaded():
        q, r = torch.linalg.qr(g)
    return q * torch.sign(torch.diagonal(r, dim1=1, dim2=2))[:, None, :]


def untangle(fields: AKVFResult, n: int | list[int] | None = None, *, restarts: int = 8,
             seed: int = 0, tol: float = 1e-6, max_iter: int = 500,
             iteration_dtype: torch.dtype = torch.float32) -> UntangledFields:
    """Algorithm 1 on the first ``n`` fields of every mesh (default: all of them).

    n : one count for all meshes, or one per mesh; arrays are padded to the largest n
        (zero columns beyond a mesh's own n).
    restarts : random orthogonal starts besides the identity; the best by the orthomax
        objective is kept. Started at the identity alone, the iteration cannot leave the
        raw eigenbasis of an exactly symmetric shape (a symmetric dumbbell stays 50/50).
    seed : each mesh's starts come from ``torch.Generator().manual_seed(seed)``, so a mesh
        gets the same result in any batch.
    tol : stop when the relative change of trace(D) is below tol (per restart); at most max_iter
        iterations per phase. (1e-5 stopped on slow plateaus: the bent dumbbell's objective
        still rose by 1e-4 after it, enough for float32 round-off to pick another end point.)
    iteration_dtype : float type of the two large products of each iteration (Y A and
        Yᵀ (Y A)^3); the rotations, SVDs and the final choice of restart stay float64.
        torch.float32 iterations stop at ``tol * FLOAT32_PHASE_TOL`` and float64 iterations
        then run from there to ``tol``, so every restart ends on a float64 stopping test and
        the best restart is chosen by float64 objectives. Measured on 4 built-in shapes and
        PSB meshes 1, 21, 121, 181 (coarse_faces=4000), one thread: float32 1.3-2.5x faster
        than float64 iterations, the same end point (features within 2e-7 of their max) on 7
        of 8; on sphere_with_two_ellipsoids another optimum 5e-6 better in objective.
        tests/test_precision.py checks it against float64.
    """
    nb = len(fields.batch)
    ns = [fields.n] * nb if n is None else ([int(n)] * nb if isinstance(n, numbers.Integral) else [int(v) for v in n])
    if len(ns) != nb or min(ns) < 1 or max(ns) > fields.n:
        raise ParameterError(f"n must be 1..{fields.n} per mesh (one int or {nb} ints), got {n!r}")
    rots = orthomax_rotations(fields, dict(enumerate(ns)), restarts=restarts, seed=seed, tol=tol,
                              max_iter=max_iter, iteration_dtype=iteration_dtype)
    return untangled_from_rotations(fields, [rots[b] for b in range(nb)])


@dataclass
class MeshRotation:
    """Algorithm 1's answer for one mesh at one field count: rotation [n, n] (float64), the
    orthomax objective reached, the iterations of the restart kept, and restart_scores [R + 1]
    (the float64 objective every start ended at; index 0 is the identity start)."""

    rotation: torch.Tensor
    score: float
    iterations: int
    restart_scores: torch.Tensor


def orthomax_rotations(fields: AKVFResult, ns: dict, *, restarts: int = 8, seed: int = 0, tol: float = 1e-6,
                       max_iter: int = 500, iteration_dtype: torch.dtype = torch.float32) -> dict:
    """Algorithm 1 for some meshes of the batch: ns {mesh index b: n_b} -> {b: :class:`MeshRotation`}.

    A mesh's rotation depends on its own fields, n_b and the seed alone, so a caller can keep
    them per (mesh, n) and untangle only the meshes whose n is new (the engine's rounds do).
    On CPU each mesh iterates alone on its own edges: batched, every live mesh computes as many
    restarts as the slowest one still has (measured 1.4x slower for 5 PSB meshes at n = 16), and
    without the batch's padding rows the bits are those of the mesh untangled by itself. On other
    devices the meshes sharing n_b run as one batch, padded to the batch's largest edge count.
    """
    batch = fields.batch
    if not ns:
        return {}
    n_max = max(ns.values())
    dev = fields.forms.device
    sqrt_mass = fields.system.mass.to(torch.float64).sqrt()[:, None]
    out = {}
    if dev.type == "cpu":
        # Each mesh on its own rows, sliced from the packed forms (no padded copy of the whole
        # batch, whose fresh memory cost more than the slices' products on a 16-mesh batch).
        eptr = batch.edge_ptr.tolist()
        groups = []
        for b in sorted(ns):
            lo, hi = eptr[b], eptr[b + 1]
            y = fields.forms[lo:hi, :n_max].to(torch.float64) * sqrt_mass[lo:hi]
            groups.append(([b], y[None, :, :ns[b]]))
    else:
        phi = fields.forms[:, :n_max].to(torch.float64)
        ypad, _ = pad_packed(phi * sqrt_mass, batch.edge_ptr)          # [B, Emax, n_max]
        groups = []
        for g in sorted(set(ns.values())):
            members = [b for b in sorted(ns) if ns[b] == g]
            groups.append((members, ypad[torch.tensor(members, device=dev)][:, :, :g]))
    for members, y in groups:
        # Meshes sharing n run together; fields beyond a mesh's n are not part of its problem.
        ag, sg, ig, scores = _orthomax(y, restarts, seed, tol, max_iter, iteration_dtype)
        for j, b in enumerate(members):
            out[b] = MeshRotation(rotation=ag[j], score=float(sg[j]), iterations=int(ig[j]),
                                  restart_scores=scores[j])
    return out


def untangled_from_rotations(fields: AKVFResult, rotations: list) -> UntangledFields:
    """The untangled fields of every mesh from its :class:`MeshRotation` (B of them, in batch
    order; each mesh at its own n, arrays padded to the largest). Each mesh's fields are made
    on its own n columns by their own products: the bits of the mesh untangled alone,
    whatever the batch's largest n."""
    nb = len(fields.batch)
    ns = [int(r.rotation.shape[-1]) for r in rotations]
    n_max = max(ns)
    dev = fields.forms.device
    a = torch.zeros(nb, n_max, n_max, dtype=torch.float64, device=dev)
    energies = torch.zeros(nb, n_max, dtype=torch.float64, device=dev)
    lam = fields.eigenvalues[:, :n_max].to(torch.float64)
    for b, r in enumerate(rotations):
        n = ns[b]
        a[b, :n, :n] = r.rotation
        ab = a[b, :n, :n]
        energies[b, :n] = torch.einsum("bnm,bn->bm", (ab * ab)[None], lam[b:b + 1, :n])[0]
    score = torch.tensor([r.score for r in rotations], dtype=torch.float64, device=dev)
    iters = torch.tensor([r.iterations for r in rotations], dtype=torch.long, device=dev)
    dt = fields.forms.dtype
    out = UntangledFields(rotation=a.to(dt), energies=energies.to(dt), score=score, iterations=iters,
                          n_fields=ns, source=fields)
    out._made["rotation64"] = a
    return out


def _orthomax(ypad: torch.Tensor, restarts: int, seed: int, tol: float, max_iter: int,
              iteration_dtype: torch.dtype = torch.float64):
    """Horst's iteration for [b, Emax, n] scaled forms, all restarts at once.

    The R rotations of a mesh sit side by side, A = [A_1 | ... | A_R] [n, R·n], so each step is
    two GEMMs per mesh (Y A and Yᵀ (Y A)^3) rather than R small products over copies of Y.
    Returns the best rotation [b, n, n], its objective [b], its iteration count [b] and the
    objective of every restart [b, R + 1].
    """
    nb, e_max, n = ypad.shape
    dev = ypad.device
    starts = []
    for _ in range(nb):
        gen = torch.Generator().manual_seed(seed)
        rots = random_rotations(restarts, n, gen)
        starts.append(torch.cat([torch.eye(n, dtype=torch.float64)[None], rots]))
    a = torch.stack(starts).to(dev)                                   # [b, R, n, n]
    # The float64 steps come from Y's fourth moments where that is faster (:func:`_moments_pay`);
    # the float32 ones always from the products.
    if iteration_dtype == torch.float64:
        steps = _STEPS_PER_RESTART * a.shape[1]
        a, iters = _horst(ypad, a, tol, max_iter, torch.float64, _moments_pay(e_max, n, steps))
    else:
        a, iters = _horst(ypad, a, tol * FLOAT32_PHASE_TOL, max_iter, iteration_dtype)
        # float64 polish from the float32 end points: the optimum each restart settles on, and
        # so the restart kept, is decided by float64 iterations (float32 round-off, which
        # depends on the BLAS kernel, thread count and padding, only chooses the start). It
        # takes about as many steps as the float32 phase did (PSB 1 and 21 at full resolution,
        # n = 32: 0.96x and 1.08x of them, summed over the restarts).
        steps = int(iters.sum(dim=1).max())
        a, polish = _horst(ypad, a, tol, max_iter, torch.float64, _moments_pay(e_max, n, steps))
        iters = iters + polish
    score = _orthomax_objective(ypad, a)                              # [b, R]
    # On a symmetric shape restarts reach the same rotation up to column order and signs, with
    # objectives equal to round-off: the first of those wins on any machine.
    best = best_restart(score, largest=True)
    ar = torch.arange(nb, device=dev)
    return a[ar, best], score[ar, best], iters[ar, best], score


def _side(m: torch.Tensor) -> torch.Tensor:
    """[b, q, n, n] rotations -> [b, n, q·n], side by side."""
    n = m.shape[-1]
    return m.permute(0, 2, 1, 3).reshape(len(m), n, m.shape[1] * n)


def _orthomax_objective(ypad: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
    """[b, R] float64 objective Σ (Y A_r)^4 of rotations a [b, R, n, n] for Y [b, Emax, n]."""
    nb, e_max, n = ypad.shape
    y = ypad.to(torch.float64)
    return ((y @ _side(a)) ** 4).reshape(nb, e_max, a.shape[1], n).sum(dim=(1, 3))


def _horst(ypad: torch.Tensor, a: torch.Tensor, tol: float, max_iter: int,
           iteration_dtype: torch.dtype, moments: bool = False):
    """Horst's iteration, accelerated (:func:`_horst_batched`), from rotations a [b, R, n, n]
    (float64) for scaled forms [b, Emax, n]; the products Y A and Yᵀ (Y A)^3 in
    ``iteration_dtype``, or with ``moments`` (float64 only) Yᵀ (Y A)^3 from Y's fourth moments
    (:class:`_FourthMoments`). Returns (rotations [b, R, n, n], iterations [b, R]: Horst steps, i.e.
    evaluations of Yᵀ (Y A)^3); a restart stops when a plain step changes trace(D) by less
    than tol (relative), and returns that step's rotation.

    One mesh on CPU (every call of :func:`orthomax_rotations` there) takes
    :func:`_horst_one_mesh`, the same arithmetic without the batch's bookkeeping; any other
    call :func:`_horst_batched`."""
    if len(ypad) == 1 and ypad.device.type == "cpu":
        return _horst_one_mesh(ypad, a, tol, max_iter, iteration_dtype, moments)
    return _horst_batched(ypad, a, tol, max_iter, iteration_dtype, moments)


def _horst_step(gradient, al: torch.Tensor):
    """One Horst step of rotations al [m, q, n, n] (float64): G = Yᵀ (Y A)^3 per rotation
    [m, q, n, n] (float64, from ``gradient``: :class:`_Products` or :class:`_FourthMoments`),
    its polar factor U Vᵀ (the step's rotation) and trace(D) = Σ σ(G) [m, q]."""
    g = gradient(al)
    with single_threaded():
        u, sv, vh = torch.linalg.svd(g)
    return u @ vh, sv.sum(-1), g


class _Products:
    """G(A) = Yᵀ (Y A)^3 by two GEMMs per mesh, for y [m, E, n] in iteration_dtype (G in
    float64). Y A is [m, E, q·n], the largest array here: one buffer, cubed in place, because
    fresh allocations of that size cost more than the GEMMs (measured 2.2x per step at 30k
    edges)."""

    def __init__(self, y: torch.Tensor, restarts: int, iteration_dtype: torch.dtype):
        self.y = y.to(iteration_dtype)
        self.dtype = iteration_dtype
        nb, e, n = y.shape
        self.buf = self.y.new_empty(nb * e * restarts * n)

    def select(self, meshes: torch.Tensor) -> "_Products":
        """The same for a subset of the meshes (indices into this one's), sharing the buffer."""
        out = object.__new__(_Products)
        out.y, out.dtype, out.buf = self.y[meshes], self.dtype, self.buf
        return out

    def __call__(self, al: torch.Tensor) -> torch.Tensor:
        """G [m, q, n, n] (float64) of rotations al [m, q, n, n]."""
        m, e, n = self.y.shape
        q = al.shape[1]
        out = self.buf[:m * e * q * n].view(m, e, q * n)
        ya = torch.matmul(self.y, _side(al).to(self.dtype), out=out).pow_(3)
        return (self.y.transpose(1, 2) @ ya).reshape(m, n, q, n).permute(0, 2, 1, 3).double()


def _gradient(ypad: torch.Tensor, restarts: int, iteration_dtype: torch.dtype, moments: bool):
    """G(A) = Yᵀ (Y A)^3 for Horst's steps on ypad [m, Emax, n] with up to ``restarts``
    rotations per mesh: from the fourth moments (float64 steps only) or by the products."""
    if moments:
        if iteration_dtype != torch.float64:
            raise ParameterError("the fourth-moment steps are float64 steps")
        return _FourthMoments(ypad.to(torch.float64))
    return _Products(ypad, restarts, iteration_dtype)


class _FourthMoments:
    """G(A) = Yᵀ (Y A)^3 of each mesh (y [m, E, n] float64) from Y's fourth moments, in float64.

    Expanding the cube, G_ij = Σ_{k,l,m} M_iklm A_kj A_lj A_mj with M_iklm = Σ_e y_ei y_ek y_el
    y_em, which does not depend on A: computed once (the entries of ``Qᵀ Q`` at sorted
    quadruples, for Q [E, P] the products of column pairs, P = n(n+1)/2), each step then costs
    a product of n x C by C x q·n per mesh (C = n(n+1)(n+2)/6 sorted triples k <= l <= m),
    whatever E is. Where E is large against n (:func:`_moments_pay`) that is far cheaper than
    two float64 GEMMs over E per step: on PSB 21 (45,594 edges, n = 32) the float64 steps took
    3.1 of the untangling's 4.5 s. Both ways sum the same products in another order: they agree
    to round-off. Zero rows (padding) add nothing.
    """

    def __init__(self, y: torch.Tensor, gather: bool | None = None):
        """gather: form the pair products by two index gathers per pass (default: on devices
        other than the CPU) rather than by 2n broadcast products; the same values either way."""
        nb, e, n = y.shape
        dev = y.device
        self.n = n
        p = n * (n + 1) // 2
        # Every moment is one entry of Qᵀ Q: M_abcd for sorted a <= b <= c <= d is the product
        # of pair (a, b)'s column with pair (c, d)'s, and only those entries, b <= c, are
        # needed: n^4/24 of the P^2 (0.34 of them at n = 32). Rows of the product are the pairs
        # ordered by their second index b, columns the pairs in triu order (by first index c),
        # so the rows of one b need a suffix of the columns (c >= b). Rows are taken in 4 groups
        # of b, each times its suffix: one GEMM per group, 0.46 of Qᵀ Q's entries at n = 32,
        # and large enough blocks to run near the full GEMM's rate (PSB-21-sized forms,
        # E = 45594, n = 32: 0.6x the time of Qᵀ Q's upper block triangle).
        row_start = [b * (b + 1) // 2 for b in range(n + 1)]            # pairs (a <= b) by b
        col_start = [c * n - c * (c - 1) // 2 for c in range(n + 1)]    # pairs (c <= d) by c
        groups = sorted({round(n * g / 4) for g in range(5)})
        # Rows per pass: 2048 for one mesh (its [2048, P] pair products, 8.6 MB at n = 32, stay
        # in cache), fewer for a large batch so that [m, rows, P] stays near 16 MB.
        chunk = max(1, min(2048, max(16, 2 ** 21 // (nb * p)), e))
        gram = y.new_zeros(nb, p, p)
        cols = y.new_empty(nb, chunk, p)
        rows_t = y.new_empty(nb, p, chunk)
        gather = dev.type != "cpu" if gather is None else gather
        if gather:
            # One gather per pass on other devices, where 2n small products would be 2n kernel
            # launches per pass (and a large batch makes many short passes).
            first, second = torch.triu_indices(n, n)           # the pairs by first index: columns
            by_second = torch.argsort(second * n + first)       # the same by second index: rows
            c_first, c_second = first.to(dev), second.to(dev)
            r_first, r_second = first[by_second].to(dev), second[by_second].to(dev)
        for s in range(0, e, chunk):
            yc = y[:, s:s + chunk]
            h = yc.shape[1]
            yt = yc.transpose(1, 2).contiguous()                            # [m, n, h]
            qc, qr = cols[:, :h], rows_t[:, :, :h]
            if not gather:
                # Each pair block is one broadcast product (6.7x faster than gathering the P
                # columns twice by index: n = 32, 2048 rows, 0.9 against 5.9 ms).
                for i in range(n):
                    torch.mul(yc[:, :, i:i + 1], yc[:, :, i:], out=qc[:, :, col_start[i]:col_start[i + 1]])
                    torch.mul(yt[:, :i + 1], yt[:, i:i + 1], out=qr[:, row_start[i]:row_start[i + 1]])
            else:
                torch.mul(yc[:, :, c_first], yc[:, :, c_second], out=qc)
                torch.mul(yt[:, r_first], yt[:, r_second], out=qr)
            for b0, b1 in zip(groups[:-1], groups[1:]):
                r0, r1, c0 = row_start[b0], row_start[b1], col_start[b0]
                gram[:, r0:r1, c0:].baddbmm_(qr[:, r0:r1], qc[:, :, c0:])
        k, l, m = torch.combinations(torch.arange(n, device=dev), 3, with_replacement=True).T
        self._k, self._l, self._m = k.contiguous(), l.contiguous(), m.contiguous()
        # A sorted triple stands for its distinct orderings: 1, 3 or 6 of the n³ terms.
        mult = torch.where((k == l) & (l == m), 1.0,
                           torch.where((k == l) | (l == m), 3.0, 6.0)).to(y.dtype)
        # M_iklm for every i and sorted triple k <= l <= m, read at its sorted quadruple.
        i = torch.arange(n, device=dev)[:, None].expand(-1, len(k))
        quad = torch.stack([i, k.expand_as(i), l.expand_as(i), m.expand_as(i)], -1).sort(-1).values
        a, b, c, d = quad.unbind(-1)
        row = torch.tensor(row_start, device=dev)[b] + a
        col = torch.tensor(col_start, device=dev)[c] + (d - c)
        self.moments = gram[:, row, col] * mult                              # [m, n, C]

    def select(self, meshes: torch.Tensor) -> "_FourthMoments":
        """The same for a subset of the meshes (indices into this one's)."""
        out = object.__new__(_FourthMoments)
        out.n, out._k, out._l, out._m = self.n, self._k, self._l, self._m
        out.moments = self.moments[meshes]
        return out

    def __call__(self, al: torch.Tensor) -> torch.Tensor:
        """G [m, q, n, n] (float64) of rotations al [m, q, n, n]."""
        nb, q, n = al.shape[0], al.shape[1], self.n
        a = _side(al)                                                       # [m, n, q·n]
        cubes = a[:, self._k] * a[:, self._l]
        cubes.mul_(a[:, self._m])                                           # [m, C, q·n]
        return torch.bmm(self.moments, cubes).reshape(nb, n, q, n).permute(0, 2, 1, 3)


def _moments_pay(e: int, n: int, steps: int) -> bool:
    """Whether ``steps`` float64 Horst steps of single rotations (summed over the restarts) of a
    mesh with e edges (rows) and n fields are faster from :class:`_FourthMoments` than by the
    products.

    A time model in flops weighted by the rates measured here (one thread,
    benchmarks/results/untangle_moments.md): the moments' one-time Qᵀ Q (2 P² E flops) runs at
    about twice the products' rate per flop, their steps (a gather and an n x C by C x n
    product per rotation) at about half; the products cost 4 E n² flops per rotation and step."""
    pairs, triples = n * (n + 1) // 2, n * (n + 1) * (n + 2) // 6
    moments = 0.5 * (2.0 * pairs * pairs * e) + 2.0 * steps * (2.0 * n * n * triples + 4.0 * n * triples)
    return moments < steps * 4.0 * e * n * n


def _extrapolated(a0: torch.Tensor, a1: torch.Tensor, a2: torch.Tensor) -> torch.Tensor:
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


def _squarem_state(a: torch.Tensor) -> dict:
    """The accelerated iteration's state for rotations a [b, R, n, n]: per restart the answer so
    far ("a"), the cycle's base point and its two Horst steps, trace(D) of the last plain step
    before the cycle, of the cycle's first and second steps, and the objective at step 1."""
    zeros = lambda: torch.zeros(a.shape[:2], dtype=torch.float64, device=a.device)   # noqa: E731
    return {"a": a.clone(), "base": a.clone(), "a1": torch.empty_like(a), "a2": torch.empty_like(a),
            "d_last": torch.full(a.shape[:2], -1.0, dtype=torch.float64, device=a.device),
            "d1": zeros(), "d2": zeros(), "obj1": zeros()}


def _squarem_step(phase: int, state: dict, pick, put, gradient, tol: float) -> torch.Tensor:
    """Step ``phase`` (0, 1, 2) of a SQUAREM cycle (:func:`_horst_batched`) for the restarts
    ``pick`` gathers from the state's [b, R, ...] arrays ([m, q, ...]; ``put`` scatters [m, q, ...]
    values back): 0 and 1 are plain Horst steps, 2 the step from the extrapolated point, kept
    where the objective there is no lower than at step 1. Returns done [m, q]: the plain step
    changed trace(D) by less than tol (relative; never after step 2)."""
    if phase == 0:
        rot, d, _ = _horst_step(gradient, pick(state["base"]))
        done = (d - pick(state["d_last"])).abs() < tol * d.abs()
        put(state["a1"], rot)
        put(state["d1"], d)
    elif phase == 1:
        src = pick(state["a1"])
        rot, d, g = _horst_step(gradient, src)
        done = (d - pick(state["d1"])).abs() < tol * d.abs()
        put(state["a2"], rot)
        put(state["d2"], d)
        put(state["obj1"], (src * g).sum(dim=(-2, -1)))
    else:
        x = _extrapolated(pick(state["base"]), pick(state["a1"]), pick(state["a2"]))
        rot, d, g = _horst_step(gradient, x)
        ok = (x * g).sum(dim=(-2, -1)) >= pick(state["obj1"])
        rot = torch.where(ok[..., None, None], rot, pick(state["a2"]))
        put(state["base"], rot)
        put(state["d_last"], torch.where(ok, d, pick(state["d2"])))
        done = torch.zeros(d.shape, dtype=torch.bool, device=d.device)
    put(state["a"], rot)
    return done


def _horst_one_mesh(ypad: torch.Tensor, a: torch.Tensor, tol: float, max_iter: int,
                    iteration_dtype: torch.dtype, moments: bool = False):
    """:func:`_horst_batched` for one mesh (ypad [1, E, n], a [1, R, n, n]) on CPU, bitwise.

    The same products of the same shapes and layouts on the same operands: each step's active
    restarts, in index order, side by side (the batched path's slots for one mesh, which has
    no padding restarts). What goes is the per-step bookkeeping on small tensors (argsort of
    the slots, gathers, scatters, boolean-mask writes, 1.5 ms per step on 4000-face meshes,
    more than the step's GEMMs at n = 16): which restarts are active is a Python list, read
    back once per step.
    """
    _, e_max, n = ypad.shape
    r = a.shape[1]
    gradient = _gradient(ypad, r, iteration_dtype, moments)
    state = _squarem_state(a)
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

        done = _squarem_step(step % 3, state, pick, put, gradient, tol)[0].tolist()
        for j in act:
            iters[j] += 1
        act = [j for j, stop in zip(act, done) if not stop]
    return state["a"], torch.tensor([iters], dtype=torch.long)


def _horst_batched(ypad: torch.Tensor, a: torch.Tensor, tol: float, max_iter: int,
                   iteration_dtype: torch.dtype, moments: bool = False):
    """Horst's iteration for any batch on any device (see :func:`_horst`), accelerated by
    SQUAREM: each cycle makes two plain steps A1 = F(A0), A2 = F(A1) (F(A) = polar factor of
    Yᵀ (Y A)^3), then a third from the extrapolated point X = :func:`_extrapolated` (A0, A1,
    A2); F(X) is the next cycle's base point where the objective at X is at least that at A1
    (else A2 is: the iteration never loses ground against plain Horst). Horst's iteration
    converges linearly, slowly on the plateaus of near-equal optima; measured on 19 PSB meshes
    (coarse 4000, n = 16, 24, 32, two starts): 0.42x the steps of plain Horst, the kept
    restart's objective never lower by more than 1e-6 (relative), higher by up to 2e-3.

    All restarts of all meshes step in lockstep (every cycle has three steps; a restart stops
    only after a plain step). Each step the live meshes' active restarts are gathered into
    slots, the results scattered back."""
    nb, e_max, n = ypad.shape
    dev = ypad.device
    r = a.shape[1]
    state = _squarem_state(a)
    active = torch.ones(nb, r, dtype=torch.bool, device=dev)
    iters = torch.zeros(nb, r, dtype=torch.long, device=dev)

    whole = _gradient(ypad, r, iteration_dtype, moments)
    live = torch.arange(nb, device=dev)
    gradient = whole
    for step in range(max_iter):
        # Only restarts still moving iterate: converged ones (and meshes whose restarts have all
        # converged) drop out, so neither a slow mesh nor a slow restart makes the others pay.
        # Each live mesh's q active restarts go first; shorter lists are padded with converged
        # restarts, computed but not written back.
        still = torch.nonzero(active.any(dim=1)).reshape(-1)
        if len(still) == 0:
            break
        if len(still) != len(live):
            live, gradient = still, whole.select(still)
        m = len(live)
        act = active[live]                                            # [m, R]
        q = int(act.sum(dim=1).max())
        slot = torch.argsort((~act).to(torch.int8), dim=1, stable=True)[:, :q]
        valid = torch.gather(act, 1, slot)                            # [m, q]
        rows = torch.arange(m, device=dev)[:, None]
        sel = (rows.expand(m, q)[valid], slot[valid])
        pick = lambda t: t[live][rows, slot]                          # noqa: E731  [m, q, ...]

        def put(t, v):
            tl = t[live]
            tl[sel] = v[valid]
            t[live] = tl

        done = _squarem_step(step % 3, state, pick, put, gradient, tol)
        iters[live] += act.long()
        active[live] = act.scatter(1, slot, valid & ~done)
    return state["a"], iters
