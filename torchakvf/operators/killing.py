"""The discrete Killing operator R on 1-forms, block-diagonal over a batch.

``w^T R w = (1/2) ∫ |L_X g|^2`` and ``w^T S1 w = ∫ |X|^2``; the AKVFs are the smallest
eigenpairs of ``R w = λ S1 w``. Formulas of docs/akvf_operator.md, Sec. 2:

    R = d1^T S2 d1 + 2 D^T S0^{-1} D - 2 S1 diag(K_e) - 2 sym(R_b)

with D = -d0^T S1 plus the boundary-flux correction, and R_b the boundary term (both vanish on
closed meshes). Everything is computed on unit-area meshes, so eigenvalues are λ·area.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch

from ..errors import ParameterError
from ..mesh.batch import MeshBatch, owner_index
from . import dec
from .geometry import BatchGeometry, batch_geometry

#: The remedies a mesh's operator can be built with (see :func:`killing_operator`).
MESH_REMEDIES = ("none", "clamp", "smooth")
#: Mesh-quality remedies a caller may ask for: one for every mesh, or "auto", decided per mesh
#: by a factorization (:func:`torchakvf.solvers.remedy.choose_remedies`).
REMEDIES = MESH_REMEDIES + ("auto",)
#: The remedy every entry point uses by default (akvf, segment, features, the CLI): "auto", the
#: paper's operator ("none") on well-shaped meshes and "smooth" on the badly shaped ones, which
#: "none" leaves without a positive definite shift or with eigenvalues far below zero
#: (see docs/design.md).
DEFAULT_REMEDY = "auto"
#: Rings of curvature averaging per remedy. "smooth" averages over 2 rings: enough to tame the
#: badly shaped triangles it is chosen for, few enough to keep a thin part's curvature (fins,
#: discs); chosen leave-one-group-out over the PSB and the procedural corpus (docs/design.md).
CURVATURE_RINGS = {"none": 0, "clamp": 0, "smooth": 2}

#: Floor of the "none" formulation: the mass matrix must be positive definite, so star1 is
#: floored at this fraction of the mesh's mean |star1| (docs/akvf_operator.md, Sec. 4).
MASS_FLOOR = 1e-8


@dataclass
class KillingSystem:
    """The generalized eigenproblem ``R w = λ S1 w`` of a batch.

    stiffness : sparse COO [ΣE, ΣE], R (block-diagonal, symmetric, coalesced)
    mass : [ΣE] positive diagonal S1 of the mass matrix (floored star1, see :func:`mass_star1`)
    edge_ptr : [B+1] offsets of each mesh's edges
    star1_raw : [ΣE] cotangent weights before any floor or remedy
    geometry : the unit-area :class:`BatchGeometry` the operator was built from
    remedies : [B] the remedy each mesh's operator was built with (one of :data:`MESH_REMEDIES`;
        None for a system assembled by hand)
    """

    stiffness: torch.Tensor
    mass: torch.Tensor
    edge_ptr: torch.Tensor
    star1_raw: torch.Tensor
    geometry: BatchGeometry
    remedies: list[str] | None = None

    @property
    def n_meshes(self) -> int:
        return len(self.edge_ptr) - 1

    def select(self, meshes) -> "KillingSystem":
        """The system of meshes ``meshes`` (indices, in that order) alone, for solving a subset
        of the batch; ``geometry`` is None in it (Whitney vectors need the whole batch's)."""
        rows, cols, vals, ptr, mass, raw = [], [], [], [0], [], []
        for b in meshes:
            r, c, v, size = self.block(int(b))
            rows.append(r + ptr[-1]), cols.append(c + ptr[-1]), vals.append(v)
            lo, hi = int(self.edge_ptr[b]), int(self.edge_ptr[b + 1])
            mass.append(self.mass[lo:hi]), raw.append(self.star1_raw[lo:hi])
            ptr.append(ptr[-1] + size)
        dev = self.mass.device
        stiff = torch.sparse_coo_tensor(torch.stack([torch.cat(rows), torch.cat(cols)]), torch.cat(vals),
                                        (ptr[-1], ptr[-1]), check_invariants=False).coalesce()
        remedies = None if self.remedies is None else [self.remedies[int(b)] for b in meshes]
        return KillingSystem(stiffness=stiff, mass=torch.cat(mass), star1_raw=torch.cat(raw),
                             edge_ptr=torch.tensor(ptr, dtype=torch.long, device=dev), geometry=None,
                             remedies=remedies)

    @classmethod
    def concatenate(cls, systems: list, edge_ptr: torch.Tensor) -> "KillingSystem":
        """One batch's system from the systems of its meshes solved one at a time (in batch
        order; ``edge_ptr`` [B+1] the batch's): R block-diagonal, the rest stacked."""
        offsets = edge_ptr[:-1].tolist()
        idx = torch.cat([s.stiffness.indices() + off for s, off in zip(systems, offsets)], dim=1)
        n = int(edge_ptr[-1])
        # each block coalesced and the blocks in row order: the whole is coalesced too
        stiff = torch.sparse_coo_tensor(idx, torch.cat([s.stiffness.values() for s in systems]), (n, n),
                                        is_coalesced=True, check_invariants=False)
        geos = [s.geometry for s in systems]
        geometry = None if any(g is None for g in geos) else BatchGeometry(
            **{name: torch.cat([getattr(g, name) for g in geos]) for name in BatchGeometry.__dataclass_fields__})
        remedies = None if any(s.remedies is None for s in systems) else [r for s in systems for r in s.remedies]
        return cls(stiffness=stiff, mass=torch.cat([s.mass for s in systems]), edge_ptr=edge_ptr,
                   star1_raw=torch.cat([s.star1_raw for s in systems]), geometry=geometry, remedies=remedies)

    def block(self, b: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
        """COO entries (rows, cols, vals) of mesh b's block with local indices, and its size."""
        idx, vals = self.stiffness.indices(), self.stiffness.values()
        lo, hi = int(self.edge_ptr[b]), int(self.edge_ptr[b + 1])
        start, stop = torch.searchsorted(idx[0], torch.tensor([lo, hi], device=idx.device)).tolist()
        return idx[0, start:stop] - lo, idx[1, start:stop] - lo, vals[start:stop], hi - lo

    def negative_star1_counts(self) -> torch.Tensor:
        """[B] number of edges with star1 <= 0 (obtuse pairs) per mesh."""
        counts = self.edge_ptr.new_zeros(self.n_meshes)
        counts.index_add_(0, owner_index(self.edge_ptr), (self.star1_raw <= 0).long())
        return counts


def _per_mesh_mean(x: torch.Tensor, ptr: torch.Tensor) -> torch.Tensor:
    owner = owner_index(ptr)
    total = x.new_zeros(len(ptr) - 1).index_add_(0, owner, x)
    return (total / (ptr[1:] - ptr[:-1]).to(x.dtype))[owner]


def _check_remedy(remedy: str | list[str], n_meshes: int) -> None:
    if isinstance(remedy, str):
        if remedy not in REMEDIES:
            raise ParameterError(f"remedy must be one of {REMEDIES}, got {remedy!r}")
    elif len(remedy) != n_meshes or any(r not in MESH_REMEDIES for r in remedy):
        raise ParameterError(f"a list of remedies needs one of {MESH_REMEDIES} per mesh "
                             f"({n_meshes}), got {list(remedy)!r}")


def mass_star1(star1: torch.Tensor, edge_ptr: torch.Tensor, remedy: str | list[str] = "smooth") -> torch.Tensor:
    """The positive star1 used as S1 under ``remedy`` ([ΣE] -> [ΣE]; ``remedy`` one of
    :data:`MESH_REMEDIES`, or a list of one per mesh).

    "none": the paper's cotan weights, floored at MASS_FLOOR * mean |star1| only so that the
    mass matrix stays positive definite. "clamp" and "smooth": floored at 0.1 * mean |star1|,
    which also removes the large negative curvature terms that obtuse pairs put into R.
    """
    remedies = [remedy] * (len(edge_ptr) - 1) if isinstance(remedy, str) else list(remedy)
    for r in remedies:
        if r not in MESH_REMEDIES:
            raise ParameterError(f"remedy must be one of {MESH_REMEDIES}, got {r!r}")
    fraction = torch.tensor([MASS_FLOOR if r == "none" else 0.1 for r in remedies],
                            dtype=star1.dtype, device=star1.device)
    floor = fraction[owner_index(edge_ptr)] * _per_mesh_mean(star1.abs(), edge_ptr)
    return torch.maximum(star1, floor)


def _ring_average_curvature(batch: MeshBatch, theta: torch.Tensor, a_v: torch.Tensor,
                            rings: int) -> torch.Tensor:
    """[ΣV] Gaussian curvature K_v = Σ θ / Σ A over ``rings`` rings around each vertex.

    rings = 0 is the plain θ_v / A_v. Averaging over a neighbourhood is still consistent
    (it converges to K under refinement) but spreads curvature concentrated at cone-like
    vertices (finger tips, horns of coarse real meshes) over the area around them.
    """
    if rings == 0:
        return theta / a_v
    e = batch.edges
    n = len(theta)
    idx = torch.cat([e, e.flip(1), torch.arange(n, device=e.device)[:, None].expand(-1, 2)]).t()
    ones = torch.ones(idx.shape[1], dtype=theta.dtype, device=e.device)
    if e.device.type == "cpu":
        # scipy's CSR product: torch's COO product with a dense vector is several times slower.
        ring = sp.csr_matrix((ones.numpy(), (idx[0].numpy(), idx[1].numpy())), shape=(n, n))
        nd = np.stack([theta.numpy(), a_v.numpy()], 1)
        for _ in range(rings):
            nd = ring @ nd
        nd = torch.from_numpy(nd).to(theta.dtype)
        return nd[:, 0] / nd[:, 1]
    adj = torch.sparse_coo_tensor(idx, ones, (n, n), check_invariants=False).coalesce().to_sparse_csr()
    num, den = theta[:, None], a_v[:, None]
    for _ in range(rings):
        num, den = torch.sparse.mm(adj, num), torch.sparse.mm(adj, den)
    return (num / den)[:, 0]


def _mesh_curvature(batch: MeshBatch, theta: torch.Tensor, a_v: torch.Tensor, rings: list[int]) -> torch.Tensor:
    """[ΣV] :func:`_ring_average_curvature` with ``rings[b]`` rings on mesh b (rings stay within
    a mesh: each count is averaged over the whole batch and kept on its meshes' vertices)."""
    counts = sorted(set(rings))
    if len(counts) == 1:
        return _ring_average_curvature(batch, theta, a_v, counts[0])
    per_vertex = torch.tensor(rings, device=theta.device)[batch.vert_to_mesh]
    k_v = torch.empty_like(theta)
    for count in counts:
        mine = per_vertex == count
        k_v[mine] = _ring_average_curvature(batch, theta, a_v, count)[mine]
    return k_v


def killing_operator(batch: MeshBatch, boundary_correction: bool = True, remedy: str | list[str] = DEFAULT_REMEDY,
                     dtype: torch.dtype = torch.float64,
                     curvature_rings: int | None = None) -> KillingSystem:
    """Assemble R and S1 for every mesh of ``batch`` (on the batch's device).

    Parameters
    ----------
    boundary_correction : add the boundary-flux and boundary terms on open meshes (without
        them the operator's kernel is the Neumann-harmonic fields, not the Killing fields).
    remedy : mesh-quality remedy, one of :data:`MESH_REMEDIES` ("none" is the paper's operator,
        see :func:`mass_star1`), or a list of one per mesh; ``KillingSystem.remedies`` says which
        each mesh got. "auto" (the default of the solvers) is decided per mesh by a
        factorization, in the solvers: :func:`torchakvf.solvers.remedy.killing_system`.
    curvature_rings : rings of curvature averaging on every mesh (default: the remedy's,
        :data:`CURVATURE_RINGS`).
    dtype : float type of the assembly; float64 unless a float32 check says otherwise.
    """
    _check_remedy(remedy, len(batch))
    if remedy == "auto":
        raise ParameterError("killing_operator: remedy='auto' is decided per mesh by a factorization: use "
                             "torchakvf.solvers.killing_system(batch), or pass remedy='none', 'clamp' or 'smooth'")
    remedies = [remedy] * len(batch) if isinstance(remedy, str) else list(remedy)
    return KillingAssembly(batch, boundary_correction, dtype).system(remedies, curvature_rings)


class KillingAssembly:
    """What the Killing operator of a batch has in common under every remedy, computed once:
    the unit-area geometry, the raw cotan weights, vertex areas and angle defects, the
    d1ᵀ S2 d1 blocks and the boundary terms. :meth:`system` adds the terms a remedy changes (S1,
    the curvature, DᵀS0⁻¹D) and sums them, so that a second remedy of the same batch (the "auto"
    decision's) does not assemble it all again. The result is the same, bit for bit, as one
    assembly under those remedies.
    """

    def __init__(self, batch: MeshBatch, boundary_correction: bool = True, dtype: torch.dtype = torch.float64):
        self.batch = batch
        geo = self.geometry = batch_geometry(batch, dtype)
        fe = batch.face_edges
        sign = batch.face_edge_sign.to(dtype)
        self.star1_raw = dec.star1(batch, geo)
        self.vertex_area = dec.star0(batch, geo)
        self.angle_defect = dec.angle_defect(batch, geo)
        # d1^T S2 d1: a 3x3 block per face.
        vals = (sign[:, :, None] * sign[:, None, :]) / geo.face_area[:, None, None]
        self._faces = (fe[:, :, None].expand(-1, 3, 3), fe[:, None, :].expand(-1, 3, 3), vals)
        self._bnd = _boundary_functionals(batch, geo, sign) if boundary_correction else None
        self._rb = None if self._bnd is None else _boundary_term(self._bnd)

    def system(self, remedies: list[str], curvature_rings: int | None = None) -> KillingSystem:
        """R and S1 of the batch with ``remedies[b]`` on mesh b."""
        batch, geo, bnd = self.batch, self.geometry, self._bnd
        n_e, n_v = len(batch.edges), len(batch.verts)
        dev = batch.verts.device
        s1_raw = self.star1_raw
        s1 = mass_star1(s1_raw, batch.edge_ptr, remedies)
        # The paper's operator keeps the raw cotan weights inside R and floors only the mass
        # matrix; the remedies use their floored weights throughout (that is what they change).
        paper = torch.tensor([r == "none" for r in remedies], device=dev)
        s1_op = torch.where(paper[owner_index(batch.edge_ptr)], s1_raw, s1)
        a_v = self.vertex_area
        rings = [CURVATURE_RINGS[r] if curvature_rings is None else curvature_rings for r in remedies]
        k_v = _mesh_curvature(batch, self.angle_defect, a_v, rings)
        k_e = 0.5 * (k_v[batch.edges[:, 0]] + k_v[batch.edges[:, 1]])

        parts = [self._faces]
        # -2 S1 diag(K_e).
        ar = torch.arange(n_e, device=dev)
        parts.append((ar, ar, -2.0 * s1_op * k_e))

        # D = -d0^T S1 (+ boundary flux); D[i, e] = +S1_e, D[j, e] = -S1_e for e = (i -> j).
        d_rows = [batch.edges[:, 0], batch.edges[:, 1]]
        d_cols = [ar, ar]
        d_vals = [s1_op, -s1_op]
        if bnd is not None:
            flux = -(bnd.length / 2)[:, None] * bnd.nu_coef                   # [Q, 3]
            for end in (bnd.tail, bnd.head):
                d_rows.append(end[:, None].expand(-1, 3))
                d_cols.append(bnd.edges)
                d_vals.append(flux)
        dmat = dec.sparse_coo(torch.cat([r.reshape(-1) for r in d_rows]),
                              torch.cat([c.reshape(-1) for c in d_cols]),
                              torch.cat([v.reshape(-1) for v in d_vals]), (n_v, n_e))
        ddd = dec.weighted_gram(dmat, 1.0 / a_v)
        parts.append((ddd.indices()[0], ddd.indices()[1], 2.0 * ddd.values()))
        if self._rb is not None:
            parts += self._rb

        rows = torch.cat([p[0].reshape(-1) for p in parts])
        cols = torch.cat([p[1].reshape(-1) for p in parts])
        vals = torch.cat([p[2].reshape(-1) for p in parts])
        r = dec.sparse_coo(rows, cols, vals, (n_e, n_e))
        return KillingSystem(stiffness=r, mass=s1, edge_ptr=batch.edge_ptr, star1_raw=s1_raw, geometry=geo,
                             remedies=list(remedies))


def _boundary_term(bnd: "_BoundaryFunctionals") -> list[tuple]:
    """The COO parts (rows, cols, values) of -2 sym(R_b): w^T R_b w = sum_q Im(conj(z_q) z_{q+1}
    e^{i phi_q}), z = u + i v."""
    nxt = bnd.successor
    c, s = torch.cos(bnd.phi)[:, None, None], torch.sin(bnd.phi)[:, None, None]
    u, v = bnd.tau_coef, bnd.nu_coef
    un, vn = u[nxt], v[nxt]
    block = (u[:, :, None] * (s * un[:, None, :] + c * vn[:, None, :])
             - v[:, :, None] * (c * un[:, None, :] - s * vn[:, None, :]))      # [Q, 3, 3]
    rows = bnd.edges[:, :, None].expand(-1, 3, 3)
    cols = bnd.edges[nxt][:, None, :].expand(-1, 3, 3)
    return [(rows, cols, -block), (cols, rows, -block)]          # -2 * (B + B^T) / 2


@dataclass
class _BoundaryFunctionals:
    """Linear functionals of the Whitney field at the midpoint of each boundary edge q.

    edges : [Q, 3] global edges of q's face (slot order: t->h, h->o, o->t)
    tau_coef, nu_coef : [Q, 3] coefficients of u_q = tau . X_mid and v_q = nu . X_mid on those edges
    tail, head : [Q] vertices of q oriented with its face (interior on the left)
    length : [Q]; phi : [Q] geodesic turning at head; successor : [Q] index of the next boundary edge
    """

    edges: torch.Tensor
    tau_coef: torch.Tensor
    nu_coef: torch.Tensor
    tail: torch.Tensor
    head: torch.Tensor
    length: torch.Tensor
    phi: torch.Tensor
    successor: torch.Tensor


def _boundary_functionals(batch: MeshBatch, geo: BatchGeometry, sign: torch.Tensor):
    count = dec.edge_face_count(batch)
    half = torch.nonzero(count[batch.face_edges.reshape(-1)] == 1).reshape(-1)
    if len(half) == 0:
        return None
    face, k = half // 3, half % 3
    slots = torch.stack([k, (k + 1) % 3, (k + 2) % 3], dim=1)                # t->h, h->o, o->t
    fverts = batch.faces[face]
    tail, head = fverts.gather(1, slots[:, :1])[:, 0], fverts.gather(1, slots[:, 1:2])[:, 0]
    grads = geo.grad_bary[face]                                              # [Q, 3(l), 3(xyz)]
    g = lambda idx: grads[torch.arange(len(face), device=face.device), idx]  # noqa: E731
    g_t, g_h, g_o = g(slots[:, 0]), g(slots[:, 1]), g(slots[:, 2])
    sg = sign[face].gather(1, slots)                                         # half-edge signs
    # X_mid = 1/2 [w_th (grad l_h - grad l_t) + w_ho grad l_o - w_ot grad l_o], l_t = l_h = 1/2.
    coef = 0.5 * torch.stack([sg[:, 0:1] * (g_h - g_t), sg[:, 1:2] * g_o, -sg[:, 2:3] * g_o], dim=1)
    p = geo.points
    edge_vec = p[head] - p[tail]
    length = torch.linalg.norm(edge_vec, dim=1)
    tau = edge_vec / length[:, None]
    nu = torch.cross(geo.normal[face], tau, dim=1)
    phi = math.pi - dec.angle_sum(batch, geo)[head]
    # The next boundary edge starts where this one ends.
    by_tail = torch.full((len(batch.verts),), -1, dtype=torch.long, device=face.device)
    by_tail[tail] = torch.arange(len(face), device=face.device)
    successor = by_tail[head]
    return _BoundaryFunctionals(edges=batch.face_edges[face].gather(1, slots),
                                tau_coef=(coef * tau[:, None, :]).sum(-1),
                                nu_coef=(coef * nu[:, None, :]).sum(-1),
                                tail=tail, head=head, length=length, phi=phi, successor=successor)
