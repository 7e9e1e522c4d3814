"""The scipy reference's AKVF operator and eigensolve: mesh combinatorics, the Killing operator
R and mass S1 (docs/akvf_operator.md, Sec. 2, literally), Whitney vectors, ARPACK shift-invert
(see :mod:`torchakvf.scipy_reference` for its role and conventions)."""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["mesh_edges", "killing_operator_scipy", "whitney_face_vectors_scipy", "clamp_mass", "solve_akvf",
           "akvf_scipy"]


# ----------------------------------------------------------------------------------------------------------------
# Mesh combinatorics
# ----------------------------------------------------------------------------------------------------------------

def mesh_edges(F: np.ndarray, n_vertices: int):
    """Unique undirected edges of a triangle mesh in the canonical order.

    Returns ``edges`` [E, 2] (``i < j``, lexicographic by ``(i, j)``), ``face_edges`` [F, 3] (the edge opposite
    corner k of each face, i.e. face-edge k runs ``F[:, k+1] -> F[:, k+2]``) and ``face_signs`` [F, 3]
    (+1 if that ccw face-edge agrees with the global ``i -> j`` orientation, -1 otherwise).
    """
    F = np.asarray(F, dtype=np.int64)
    tail = F[:, [1, 2, 0]]  # face-edge k is opposite corner k: (v1 -> v2), (v2 -> v0), (v0 -> v1)
    head = F[:, [2, 0, 1]]
    lo = np.minimum(tail, head)
    hi = np.maximum(tail, head)
    # A single int64 key i*nV + j sorts exactly like the pair (i, j), and np.unique is much faster on it
    # than on rows (axis=0).
    keys = lo.ravel() * np.int64(n_vertices) + hi.ravel()
    ukeys, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    if np.any(counts > 2):
        raise ValueError(f"non-manifold mesh: {int(np.sum(counts > 2))} edges have more than two faces")
    edges = np.stack([ukeys // n_vertices, ukeys % n_vertices], axis=1)
    face_edges = inverse.reshape(-1, 3)
    face_signs = np.where(tail < head, 1.0, -1.0)
    return edges, face_edges, face_signs


def _edge_lookup(edges: np.ndarray, F: np.ndarray, n_vertices: int):
    """Map the ccw face-edges of F onto rows of a user-given ``edges`` array (any order); returns (idx, sign)."""
    F = np.asarray(F, dtype=np.int64)
    edges = np.asarray(edges, dtype=np.int64)
    tail = F[:, [1, 2, 0]]
    head = F[:, [2, 0, 1]]
    ekeys = np.minimum(edges[:, 0], edges[:, 1]) * np.int64(n_vertices) + np.maximum(edges[:, 0], edges[:, 1])
    order = np.argsort(ekeys, kind="stable")
    fkeys = np.minimum(tail, head) * np.int64(n_vertices) + np.maximum(tail, head)
    pos = np.clip(np.searchsorted(ekeys[order], fkeys), 0, len(order) - 1)
    idx = order[pos]
    if not np.array_equal(ekeys[idx], fkeys):
        raise ValueError("some face edges are missing from `edges`")
    # The global orientation of an edge is edges[e, 0] -> edges[e, 1] (normally i < j).
    sign = np.where(edges[idx, 0] == tail, 1.0, -1.0)
    return idx, sign


def _face_geometry(V: np.ndarray, F: np.ndarray):
    """Per-face area, unit normal, barycentric-coordinate gradients (ccw) and corner angles/cotangents."""
    P = V[F]  # [F, 3 corners, 3 xyz]
    # e_k = p_{k+2} - p_{k+1}: the edge opposite corner k, traversed ccw.
    e = P[:, [2, 0, 1]] - P[:, [1, 2, 0]]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    dbl_area = np.linalg.norm(n, axis=1)
    if np.any(~(dbl_area > 0)):
        raise ValueError(f"{int(np.sum(~(dbl_area > 0)))} zero-area (degenerate) faces; remove them first")
    area = 0.5 * dbl_area
    N = n / dbl_area[:, None]
    # grad l_k = N_f x (p_{k+2} - p_{k+1}) / (2 A_f): points from the opposite edge towards corner k, |.| = 1/h_k.
    grad = np.cross(N[:, None, :], e) / dbl_area[:, None, None]
    # Corner k is spanned by a = p_{k+1} - p_k and b = p_{k+2} - p_k.  atan2(|a x b|, a.b) is accurate for all
    # angles (arccos of a normalized dot is not near 0 and pi); cot = a.b / |a x b| with |a x b| = 2A_f.
    a = P[:, [1, 2, 0]] - P
    b = P[:, [2, 0, 1]] - P
    dots = np.einsum("fkc,fkc->fk", a, b)
    angles = np.arctan2(dbl_area[:, None], dots)
    cots = dots / dbl_area[:, None]
    return area, N, grad, angles, cots


# ----------------------------------------------------------------------------------------------------------------
# The Killing operator
# ----------------------------------------------------------------------------------------------------------------

#: Mesh-quality remedies, restated here from the docstring of torchakvf.operators.killing (the
#: oracle must not import it): star1 floored at this fraction of its mean |star1| ...
REMEDY_FLOOR = 0.1
#: ... and, for "smooth", Gaussian curvature averaged over this many vertex rings.
SMOOTH_RINGS = 2


def killing_operator_scipy(V, F, boundary_correction: bool = True, remedy: str = "none"):
    """Discrete Killing operator of docs/akvf_operator.md section 2 on the unit-area-scaled mesh.

    Parameters
    ----------
    V : [nV, 3] float vertex positions.   F : [nF, 3] int faces (consistently oriented).
    boundary_correction : if True (default), meshes with boundary get the divergence correction (a) and the
        boundary term of docs/akvf_operator.md, Sec. 2.3; if False, the closed-surface formula
        ``d1^T S2 d1 + 2 S1 d0 S0^{-1} d0^T S1 - 2 S1 diag(K_e)`` is used as is (wrong on open meshes, kept for
        comparison).  On closed meshes both are identical.
    remedy : "none" (the paper's operator), "clamp" (star1 replaced by max(star1, 0.1 mean|star1|)
        everywhere it appears: mass matrix, divergence, curvature term) or "smooth" (clamp, and
        K_v = (sum of angle defects) / (sum of vertex areas) over the closed 4-ring of each vertex,
        i.e. ``(I + Adj)^4 theta / (I + Adj)^4 A_v`` with Adj the vertex adjacency).

    Returns
    -------
    R : scipy.sparse.csr_matrix [E, E], symmetric;  w^T R w ~ (1/2) int |L_X g|^2.
    S1 : [E] diagonal of star1 (cotan weights), the mass matrix:  w^T diag(S1) w ~ int |X|^2.
    edges : [E, 2] int64, i < j, lexicographically sorted; edge e is oriented edges[e,0] -> edges[e,1].
    meta : dict with the scale factor, scaled vertices, d0, d1, star0/star2 diagonals, angle defect (0 on the
        boundary), boundary turning angles (pi - angle sum on boundary vertices, so that
        sum(angle_defect) + sum(boundary_turning) = 2 pi chi), K_v, K_e, Euler characteristic, the number of
        non-positive S1 entries, ...
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    nV, nF = V.shape[0], F.shape[0]

    # --- unit total area (eigenvalues become lambda * area; sigma = -1 then has a fixed meaning) -------------
    area0, *_ = _face_geometry(V, F)
    scale = 1.0 / np.sqrt(area0.sum())
    V = V * scale
    area, N, grad, angles, cots = _face_geometry(V, F)

    edges, fe, fs = mesh_edges(F, nV)
    nE = edges.shape[0]
    rows_f = np.repeat(np.arange(nF), 3)

    # --- DEC operators ----------------------------------------------------------------------------------------
    d0 = sp.csr_matrix(
        (np.tile([-1.0, 1.0], nE), (np.repeat(np.arange(nE), 2), edges.ravel())), shape=(nE, nV))
    d1 = sp.csr_matrix((fs.ravel(), (rows_f, fe.ravel())), shape=(nF, nE))
    # star1: (cot a + cot b)/2; a boundary edge has a single incident face and so automatically a single cot.
    S1 = np.bincount(fe.ravel(), weights=0.5 * cots.ravel(), minlength=nE)
    # star0: barycentric vertex area; star2 = 1/A_f.
    A_v = np.bincount(F.ravel(), weights=np.repeat(area / 3.0, 3), minlength=nV)
    S0_inv = np.divide(1.0, A_v, out=np.zeros(nV), where=A_v > 0)  # unreferenced vertices: no edges, 0
    S2 = 1.0 / area
    if remedy not in ("none", "clamp", "smooth"):
        raise ValueError(f"unknown remedy {remedy!r}")
    if remedy != "none":
        S1 = np.maximum(S1, REMEDY_FLOOR * np.mean(np.abs(S1)))

    # --- boundary edges: used once by a face -----------------------------------------------------------------
    edge_nfaces = np.bincount(fe.ravel(), minlength=nE)
    is_bface_edge = edge_nfaces[fe] == 1  # [F, 3]
    bf, bk = np.nonzero(is_bface_edge)  # face and local index k (the edge opposite corner k)
    n_b = bf.size
    boundary_vertex = np.zeros(nV, dtype=bool)
    boundary_vertex[edges[edge_nfaces == 1].ravel()] = True

    # --- curvature: angle defect, 0 on boundary vertices (their defect is the geodesic turning, used in R_b) ---
    angle_sum = np.bincount(F.ravel(), weights=angles.ravel(), minlength=nV)
    referenced = np.bincount(F.ravel(), minlength=nV) > 0
    theta = np.where(referenced & ~boundary_vertex, 2.0 * np.pi - angle_sum, 0.0)
    turning = np.where(boundary_vertex, np.pi - angle_sum, 0.0)  # geodesic turning (Gauss-Bonnet partner)
    K_v = theta * S0_inv
    if remedy == "smooth":
        ring = sp.csr_matrix((np.ones(2 * nE), (edges.ravel(), edges[:, ::-1].ravel())), shape=(nV, nV))
        ring = ring + sp.identity(nV, format="csr")
        num, den = theta.copy(), A_v.copy()
        for _ in range(SMOOTH_RINGS):
            num, den = ring @ num, ring @ den
        K_v = np.divide(num, den, out=np.zeros(nV), where=den > 0)
    K_e = 0.5 * (K_v[edges[:, 0]] + K_v[edges[:, 1]])
    euler = nV - int(np.sum(~referenced)) - nE + nF

    S1m = sp.diags(S1)
    D = -(d0.T @ S1m)  # integrated divergence (outward flux of the dual cell) of the Whitney field
    R_b = None
    if boundary_correction and n_b > 0:
        # Boundary edge e_b = t -> h, oriented along the ccw boundary of its face (interior on the left).
        t = F[bf, (bk + 1) % 3]
        h = F[bf, (bk + 2) % 3]
        tau = V[h] - V[t]
        L = np.linalg.norm(tau, axis=1)
        tau /= L[:, None]
        nu = np.cross(N[bf], tau)  # inward normal
        # X_mid = Whitney field of the face at the edge midpoint (barycentric l_t = l_h = 1/2, l_o = 0):
        # X = sum_{face edges a->b} w_ab (l_a grad l_b - l_b grad l_a); with the ccw face-edge m running
        # corner m+1 -> corner m+2 and w_ab = sign * w_e, the coefficient vector of w_e is
        # sign * (l_{m+1} grad l_{m+2} - l_{m+2} grad l_{m+1}).
        lam = np.full((n_b, 3), 0.5)  # barycentric coordinates of the midpoint
        lam[np.arange(n_b), bk] = 0.0  # the corner opposite the boundary edge
        G = grad[bf]  # [nb, 3 corners, 3]
        m = np.arange(3)
        coef = (lam[:, (m + 1) % 3, None] * G[:, (m + 2) % 3] - lam[:, (m + 2) % 3, None] * G[:, (m + 1) % 3])
        coef *= fs[bf][:, :, None]  # [nb, 3 face-edges, 3 xyz]
        cols = fe[bf].ravel()
        rows = np.repeat(np.arange(n_b), 3)
        Ufun = sp.csr_matrix((np.einsum("bmc,bc->bm", coef, tau).ravel(), (rows, cols)), shape=(n_b, nE))
        Vfun = sp.csr_matrix((np.einsum("bmc,bc->bm", coef, nu).ravel(), (rows, cols)), shape=(n_b, nE))

        # (a) Divergence: -d0^T S1 misses the flux through the boundary half-edges of each boundary vertex's dual
        # cell.  Outward normal is -nu, so both endpoints t and h get -(L/2) nu . X_mid.
        T = sp.csr_matrix((np.ones(2 * n_b), (np.concatenate([t, h]), np.tile(np.arange(n_b), 2))),
                          shape=(nV, n_b))
        D = D + T @ sp.diags(-0.5 * L) @ Vfun

        # (b) Boundary term  w^T R_b w = sum_q Im( conj(z_q) z_{q+1} e^{i phi_q} ),  z = u + i v.
        # The successor of boundary edge q is the boundary edge whose tail is q's head (loops are cyclic).
        if np.bincount(t, minlength=nV).max() > 1:
            raise ValueError("non-manifold boundary vertex (two boundary loops touch); cannot chain the boundary")
        edge_from = np.full(nV, -1, dtype=np.int64)
        edge_from[t] = np.arange(n_b)
        nxt = edge_from[h]
        if np.any(nxt < 0):
            raise ValueError("boundary edges do not form closed loops (inconsistent face orientation?)")
        phi = turning[h]  # geodesic turning angle at the vertex shared by e_q and e_q+1
        c, s = sp.diags(np.cos(phi)), sp.diags(np.sin(phi))
        Un, Vn = Ufun[nxt], Vfun[nxt]
        Rb = Ufun.T @ (s @ Un + c @ Vn) - Vfun.T @ (c @ Un - s @ Vn)
        R_b = 0.5 * (Rb + Rb.T)

    R = d1.T @ sp.diags(S2) @ d1 + 2.0 * (D.T @ sp.diags(S0_inv) @ D) - 2.0 * sp.diags(S1 * K_e)
    if R_b is not None:
        R = R - 2.0 * R_b
    R = (0.5 * (R + R.T)).tocsr()  # exact symmetry for eigsh (float round-off in the products)
    R.sum_duplicates()

    meta = dict(
        scale=scale, V=V, area_input=float(area0.sum()), face_area=area, face_normal=N,
        d0=d0, d1=d1, star0=A_v, star2=S2, angle_defect=theta, K_v=K_v, K_e=K_e,
        boundary_vertex=boundary_vertex, boundary_turning=turning, n_boundary_edges=int(n_b),
        euler_characteristic=euler,
        n_nonpositive_S1=int(np.sum(S1 <= 0)), face_edges=fe, face_signs=fs,
        boundary_correction=bool(boundary_correction and n_b > 0),
    )
    return R, S1, edges, meta


# ----------------------------------------------------------------------------------------------------------------
# Whitney interpolation
# ----------------------------------------------------------------------------------------------------------------

def whitney_face_vectors_scipy(V, F, edges, forms):
    """Whitney-interpolated tangent vectors at face barycenters.

    ``X_f = (1/3) sum_{e=(i->j) in f} w_e (grad l_j - grad l_i)``, ``grad l_k = N_f x (p_{k+2}-p_{k+1}) / (2A_f)``.

    ``forms`` is [E] or [E, n] (edge values in the orientation ``edges[e,0] -> edges[e,1]``); returns [F, 3] or
    [F, n, 3] respectively.  Use the same vertex scaling the forms were computed with (``meta["V"]`` of
    :func:`killing_operator_scipy`); another uniform scale only rescales the vectors.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    forms = np.asarray(forms, dtype=np.float64)
    single = forms.ndim == 1
    W = forms[:, None] if single else forms
    _, _, grad, _, _ = _face_geometry(V, F)
    idx, sign = _edge_lookup(edges, F, V.shape[0])
    # Face-edge k runs corner k+1 -> corner k+2, so its contribution is w (grad l_{k+2} - grad l_{k+1}).
    dgrad = grad[:, [2, 0, 1]] - grad[:, [1, 2, 0]]  # [F, 3 face-edges, 3 xyz]
    wf = W[idx] * sign[:, :, None]  # [F, 3, n]: face-edge values in ccw face orientation
    X = np.einsum("fkn,fkc->fnc", wf, dgrad) / 3.0
    return X[:, 0] if single else X


# ----------------------------------------------------------------------------------------------------------------
# Eigenproblem
# ----------------------------------------------------------------------------------------------------------------

def clamp_mass(S1: np.ndarray) -> np.ndarray:
    """eigsh needs an SPD mass matrix: clamp S1 <= 0 (obtuse pairs, right-angle diagonals) to 1e-8 * mean|S1|."""
    bad = S1 <= 0
    if np.any(bad):
        warnings.warn(f"{int(bad.sum())} non-positive cotan weights in star1 clamped to 1e-8*mean|S1| "
                      "(mesh quality; consider an intrinsic Delaunay retriangulation)", RuntimeWarning, stacklevel=3)
        S1 = np.where(bad, 1e-8 * np.mean(np.abs(S1)), S1)
    return S1


def solve_akvf(R, S1, n: int, sigma: float):
    """Smallest-n generalized eigenpairs of R w = lambda diag(S1) w by ARPACK shift-invert around sigma."""
    M = sp.diags(S1).tocsc()
    nE = R.shape[0]
    if not 0 < n < nE:
        raise ValueError(f"need 0 < n < |E| = {nE}")
    v0 = np.random.default_rng(0).standard_normal(nE)  # deterministic ARPACK start
    lam, Phi = spla.eigsh(R.tocsc(), k=n, M=M, sigma=sigma, which="LM", v0=v0)
    # Rayleigh-Ritz in the computed subspace: sorts, and makes the basis S1-orthonormal to machine precision
    # even inside (near-)degenerate clusters, where ARPACK's vectors are only approximately M-orthogonal.
    B = Phi.T @ (S1[:, None] * Phi)
    A = Phi.T @ (R @ Phi)
    lam, C = scipy.linalg.eigh(0.5 * (A + A.T), 0.5 * (B + B.T))
    return lam, Phi @ C


def akvf_scipy(V, F, n: int = 32, sigma: float = -1.0, boundary_correction: bool = True):
    """Approximate Killing vector fields: the n smallest eigenpairs of R w = lambda S1 w.

    The mesh is scaled to unit area, so eigenvalues are ``lambda * area``.  Uses
    ``scipy.sparse.linalg.eigsh(R, k=n, M=diag(S1), sigma=sigma, which='LM')`` (shift-invert with the default
    SuperLU factorization of ``R - sigma M``); ``sigma`` must be negative because R is only approximately PSD.
    Non-positive S1 entries are clamped to ``1e-8 * mean(|S1|)`` (with a warning) since M must be SPD.

    Returns ``(eigenvalues [n] ascending, forms [E, n])`` with ``forms.T @ diag(S1) @ forms = I`` (S1 after
    clamping) and edges in the order of :func:`killing_operator_scipy`.
    """
    R, S1, _, _ = killing_operator_scipy(V, F, boundary_correction=boundary_correction)
    return solve_akvf(R, clamp_mass(S1), n, sigma)
