"""Untangling AKVFs (the paper's Algorithm 1): an orthomax (quartimax) rotation per mesh.

Each mesh's n fields Φ_b [E_b, n] are rotated by an orthogonal A_b [n, n] maximizing the sum of
fourth powers of the per-edge norms sqrt(S1) Φ A, which concentrates every rotated field on as
few edges (one part) as possible. Horst's iteration: G = Yᵀ (Y A)^3, A <- U Vᵀ from svd(G),
accelerated by SQUAREM extrapolation (every third step, kept only where it raises the objective;
:func:`horst_batched`). All restarts of a mesh step side by side ([E, n] x [n, R·n] products).
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass, field

import torch

from ..errors import ParameterError
from ..mesh.batch import pad_packed
from ..restarts import best_restart
from ..threads import single_threaded
from .akvf import AKVFResult
from .canonical import SIGN_MOMENT_FLOOR, odd_moments, sign_statistics
from .fourth_moments import STEPS_PER_RESTART, fourth_moments_pay, side_by_side
from .horst import horst

#: float32 iterations stop at tol * FLOAT32_PHASE_TOL; float64 iterations then run to tol.
FLOAT32_PHASE_TOL = 10.0
#: Random orthogonal starts besides the identity of :func:`untangle` called by itself (a
#: segmentation uses :data:`~torchakvf.options.SEGMENT_UNTANGLE_RESTARTS`): enough that an exactly
#: symmetric shape's best rotation is found among them.
DEFAULT_RESTARTS = 8
#: Frames the starts of Algorithm 1 are given in: "eigen", the fields as the eigensolver returned
#: them (the identity start is the raw eigenbasis); "moments", the fields' own moment frame
#: (:func:`moment_frame`), which turns with the fields, so the untangling does not depend on the
#: basis the eigensolver chose inside an eigenspace nor on the fields' signs.
START_FRAMES = ("eigen", "moments")


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
    each is made once and kept. A segmentation reads one mesh at a time: on CPU, whole-batch
    arrays of every round cost more in fresh memory than their products.

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


def untangle(fields: AKVFResult, n: int | list[int] | None = None, *, restarts: int = DEFAULT_RESTARTS,
             seed: int = 0, tol: float = 1e-6, max_iter: int = 500,
             iteration_dtype: torch.dtype = torch.float32, frame: str = "eigen") -> UntangledFields:
    """Algorithm 1 on the first ``n`` fields of every mesh (default: all of them).

    n : one count for all meshes, or one per mesh; arrays are padded to the largest n
        (zero columns beyond a mesh's own n).
    restarts : random orthogonal starts besides the identity; the best by the orthomax
        objective is kept. Started at the identity alone, the iteration cannot leave the
        raw eigenbasis of an exactly symmetric shape (a symmetric dumbbell stays 50/50).
    seed : each mesh's starts come from ``torch.Generator().manual_seed(seed)``, so a mesh
        gets the same result in any batch.
    tol : stop when the relative change of trace(D) is below tol (per restart); at most max_iter
        iterations per phase (a looser tol stops on slow plateaus, where float32 round-off
        then picks the end point).
    iteration_dtype : float type of the two large products of each iteration (Y A and
        Yᵀ (Y A)^3); the rotations, SVDs and the final choice of restart stay float64.
        torch.float32 iterations stop at ``tol * FLOAT32_PHASE_TOL`` and float64 iterations
        then run from there to ``tol``, so every restart ends on a float64 stopping test and
        the best restart is chosen by float64 objectives: float32 iterations are faster and
        reach the float64 end points (see docs/design.md; tests/test_precision.py checks it).
    frame : one of :data:`START_FRAMES`: the starts (the identity and the random rotations) are
        applied to the raw fields ("eigen") or to the fields in their moment frame ("moments",
        :func:`moment_frame`): then any orthogonal mix of the same n fields (another
        eigensolver start on an exactly or nearly symmetric shape, flipped signs) untangles to
        the same fields, up to round-off, wherever that frame is decided (its moment's
        eigenvalues distinct, its columns' signs set by the surface).
    """
    nb = len(fields.batch)
    ns = [fields.n] * nb if n is None else ([int(n)] * nb if isinstance(n, numbers.Integral) else [int(v) for v in n])
    if len(ns) != nb or min(ns) < 1 or max(ns) > fields.n:
        raise ParameterError(f"n must be 1..{fields.n} per mesh (one int or {nb} ints), got {n!r}")
    rots = orthomax_rotations(fields, dict(enumerate(ns)), restarts=restarts, seed=seed, tol=tol,
                              max_iter=max_iter, iteration_dtype=iteration_dtype, frame=frame)
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


def orthomax_rotations(fields: AKVFResult, ns: dict, *, restarts: int = DEFAULT_RESTARTS, seed: int = 0,
                       tol: float = 1e-6, max_iter: int = 500, iteration_dtype: torch.dtype = torch.float32,
                       frame: str = "eigen") -> dict:
    """Algorithm 1 for some meshes of the batch: ns {mesh index b: n_b} -> {b: :class:`MeshRotation`}
    (frame: :func:`untangle`'s).

    A mesh's rotation depends on its own fields, n_b and the seed alone, so a caller can keep
    them per (mesh, n) and untangle only the meshes whose n is new (a segmentation's rounds do:
    :mod:`torchakvf.parts.rounds`).
    On CPU each mesh iterates alone on its own edges: batched, every live mesh computes as many
    restarts as the slowest one still has, and
    without the batch's padding rows the bits are those of the mesh untangled by itself. On other
    devices the meshes sharing n_b run as one batch, padded to the batch's largest edge count.
    """
    batch = fields.batch
    if frame not in START_FRAMES:
        raise ParameterError(f"frame must be one of {START_FRAMES}, got {frame!r}")
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
        frames = None
        if frame == "moments":
            frames = torch.stack([moment_frame(y[j, :int(batch.edge_ptr[b + 1] - batch.edge_ptr[b])],
                                               _first_columns(sign_statistics(fields, b), ns[b]))
                                  for j, b in enumerate(members)])
        ag, sg, ig, scores = orthomax(y, restarts, seed, tol, max_iter, iteration_dtype, frames=frames)
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


def _first_columns(statistics: tuple, n: int) -> tuple:
    """:func:`~torchakvf.fields.canonical.sign_statistics` of the first n fields."""
    area, omega, radial = statistics
    return area, omega[:, :n], radial[:, :n]


def moment_frame(y: torch.Tensor, statistics: tuple | None = None) -> torch.Tensor:
    """[n, n] orthogonal Q: the eigenvectors (by descending eigenvalue) of the fields' weighted
    second moment M = Yᵀ diag(|y_e|²) Y for scaled forms y [E, n] (zero padding rows add
    nothing), each column signed by the surface.

    M turns with the fields: for Y B (B orthogonal: another basis of the same span, signs
    flipped) it is Bᵀ M B, so Y B Q' = Y Q wherever M's eigenvalues are distinct and the signs
    are decided. statistics : (area, omega, radial) of the mesh
    (:func:`~torchakvf.fields.canonical.sign_statistics`, columns: the n fields): each column q
    is signed as :func:`~torchakvf.fields.canonical.canonical_signs` signs a field, by the
    odd moments of the combined field Φ q, which a mirror symmetry of the surface does not
    make vanish both at once; where they do (or without statistics), by Σ_e (y_e · q)³."""
    y = y.to(torch.float64)
    w = (y * y).sum(dim=1)
    m = y.T @ (w[:, None] * y)
    m = 0.5 * (m + m.T)
    with single_threaded():
        _, q = torch.linalg.eigh(m)
    q = q.flip(1)
    odd = ((y @ q) ** 3).sum(dim=0)
    if statistics is not None:
        area, omega, radial = (t.to(torch.float64) for t in statistics)
        surface = odd_moments(area, omega @ q, radial @ q)
        odd = torch.where(surface.abs() > SIGN_MOMENT_FLOOR, surface, odd)
    return q * torch.where(odd < 0, -1.0, 1.0).to(q.dtype)[None, :]


def orthomax(ypad: torch.Tensor, restarts: int, seed: int, tol: float, max_iter: int,
             iteration_dtype: torch.dtype = torch.float64, frames: torch.Tensor | None = None):
    """Horst's iteration for [b, Emax, n] scaled forms, all restarts at once (frames: optional
    [b, n, n] orthogonal frames the starts are given in, e.g. :func:`moment_frame`; None: the
    raw fields').

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
    if frames is not None:
        a = frames.to(dev, torch.float64)[:, None] @ a
    # The float64 steps come from Y's fourth moments where that is faster (:func:`fourth_moments_pay`);
    # the float32 ones always from the products.
    if iteration_dtype == torch.float64:
        steps = STEPS_PER_RESTART * a.shape[1]
        a, iters = horst(ypad, a, tol, max_iter, torch.float64, fourth_moments_pay(e_max, n, steps))
    else:
        a, iters = horst(ypad, a, tol * FLOAT32_PHASE_TOL, max_iter, iteration_dtype)
        # float64 polish from the float32 end points: the optimum each restart settles on, and
        # so the restart kept, is decided by float64 iterations (float32 round-off, which
        # depends on the BLAS kernel, thread count and padding, only chooses the start). It
        # takes about as many steps as the float32 phase did: the moments' size rule reads that.
        steps = int(iters.sum(dim=1).max())
        a, polish = horst(ypad, a, tol, max_iter, torch.float64, fourth_moments_pay(e_max, n, steps))
        iters = iters + polish
    score = orthomax_objective(ypad, a)                              # [b, R]
    # On a symmetric shape restarts reach the same rotation up to column order and signs, with
    # objectives equal to round-off: the first of those wins on any machine.
    best = best_restart(score, largest=True)
    ar = torch.arange(nb, device=dev)
    return a[ar, best], score[ar, best], iters[ar, best], score


def orthomax_objective(ypad: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
    """[b, R] float64 objective Σ (Y A_r)^4 of rotations a [b, R, n, n] for Y [b, Emax, n]."""
    nb, e_max, n = ypad.shape
    y = ypad.to(torch.float64)
    return ((y @ side_by_side(a)) ** 4).reshape(nb, e_max, a.shape[1], n).sum(dim=(1, 3))


__all__ = ["UntangledFields", "untangle", "MeshRotation", "orthomax_rotations", "untangled_from_rotations",
           "random_rotations", "moment_frame", "orthomax", "orthomax_objective", "DEFAULT_RESTARTS",
           "FLOAT32_PHASE_TOL", "START_FRAMES"]
