"""The scipy reference's segmentation: the paper's Algorithm 1 (untangling) and spherical k-means
in plain numpy, and the whole pipeline on one mesh (see :mod:`torchakvf.scipy_reference`)."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .operator import clamp_mass, killing_operator_scipy, solve_akvf, whitney_face_vectors_scipy

__all__ = ["untangle_numpy", "spherical_kmeans_numpy", "features_scipy", "segment_scipy"]


# ----------------------------------------------------------------------------------------------------------------
# Algorithm 1 (untangling) and spherical k-means
# ----------------------------------------------------------------------------------------------------------------

def _random_orthogonal(n: int, rng: np.random.Generator) -> np.ndarray:
    """Haar-distributed orthogonal matrix (QR of a Gaussian matrix with the sign of R's diagonal fixed)."""
    Q, Rr = np.linalg.qr(rng.standard_normal((n, n)))
    return Q * np.sign(np.diag(Rr))


def untangle_numpy(Phi, s1, tol: float = 1e-5, max_iter: int = 500, restarts: int = 5, seed: int = 0):
    """Algorithm 1 of the paper: quartimax rotation of the AKVFs (Horst's SVD iteration).

    Maximizes ``sum((H Phi A)^4)`` over orthogonal A, H = sqrt(S1), which is equivalent to minimizing the
    tangling energy (row norms of H Phi A are rotation invariant).  Columns of Phi are first normalized to
    ``w^T S1 w = 1``.  Started from A = I the iteration cannot leave the raw eigenbasis of an exactly symmetric
    shape (docs/akvf_operator.md, Sec. 4), so it is run from the identity plus ``restarts`` Haar-random orthogonal
    starts and the result with the largest sum of 4th powers is kept.

    Returns ``(U, A)``: untangled forms ``U = Phi_normalized @ A`` [E, N] and the orthogonal A [N, N].
    """
    Phi = np.asarray(Phi, dtype=np.float64)
    s1 = np.asarray(s1, dtype=np.float64)
    H = np.sqrt(np.maximum(s1, 0.0))  # clamped weights are ~0 anyway; never take sqrt of a negative
    norms = np.sqrt(np.einsum("en,e,en->n", Phi, s1, Phi))
    Phi = Phi / norms
    HPhi = H[:, None] * Phi
    N = Phi.shape[1]
    rng = np.random.default_rng(seed)
    starts = [np.eye(N)] + [_random_orthogonal(N, rng) for _ in range(restarts)]

    best_A, best_score = None, -np.inf
    for A in starts:
        out = HPhi @ A
        d = 0.0
        for _ in range(max_iter):
            d_old = d
            # out*out*out, not out**3: numpy's float power is ~100x slower than two multiplies here.
            Lm, Dv, Mt = np.linalg.svd(HPhi.T @ (out * out * out))  # max tr(A^T Q), Q fixed: A = L M^T
            A = Lm @ Mt
            d = Dv.sum()
            out = HPhi @ A
            if abs(d - d_old) / d < tol:
                break
        out2 = out * out
        score = np.sum(out2 * out2)
        if score > best_score:
            best_A, best_score = A, score
    return Phi @ best_A, best_A


def spherical_kmeans_numpy(X, k: int, restarts: int = 20, iters: int = 100, seed: int = 0):
    """k-means with cosine distance 1 - cos (rows of X projected to the unit sphere).

    k-means++ seeding (probability proportional to 1 - max cos, i.e. half the squared chord distance),
    assignment by largest cosine, centers = renormalized cluster means.  The restart with the lowest
    ``sum(1 - cos(x, center))`` wins.  Returns ``(labels [n] int, cost)``.
    """
    X = np.asarray(X, dtype=np.float64)
    nrm = np.linalg.norm(X, axis=1, keepdims=True)
    Xn = X / np.maximum(nrm, 1e-300)  # zero rows stay zero: cos = 0 to every center
    n = Xn.shape[0]
    if not 0 < k <= n:
        raise ValueError("need 0 < k <= number of points")
    rng = np.random.default_rng(seed)

    best_labels, best_cost = None, np.inf
    for _ in range(restarts):
        C = np.empty((k, Xn.shape[1]))
        C[0] = Xn[rng.integers(n)]
        dist = 1.0 - Xn @ C[0]
        for j in range(1, k):
            p = np.maximum(dist, 0.0)
            tot = p.sum()
            idx = rng.choice(n, p=p / tot) if tot > 0 else rng.integers(n)
            C[j] = Xn[idx]
            dist = np.minimum(dist, 1.0 - Xn @ C[j])

        labels = None
        for _ in range(iters):
            cos = Xn @ C.T
            new = np.argmax(cos, axis=1)
            if labels is not None and np.array_equal(new, labels):
                break
            labels = new
            # Cluster sums as a sparse indicator product (np.add.at is an order of magnitude slower).
            S = sp.csr_matrix((np.ones(n), (labels, np.arange(n))), shape=(k, n)) @ Xn
            sn = np.linalg.norm(S, axis=1)
            empty = sn == 0
            if np.any(empty):
                # Re-seed empty clusters with the worst-fitted points instead of leaving them dead.
                worst = np.argsort(cos[np.arange(n), labels])[: int(empty.sum())]
                S[empty] = Xn[worst]
                sn[empty] = 1.0
            C = S / sn[:, None]
        cos = Xn @ C.T
        labels = np.argmax(cos, axis=1)
        cost = float(np.sum(1.0 - cos[np.arange(n), labels]))
        if cost < best_cost:
            best_labels, best_cost = labels, cost
    return best_labels, best_cost


# ----------------------------------------------------------------------------------------------------------------
# Whole pipeline
# ----------------------------------------------------------------------------------------------------------------

def _features_info(V, F, n: int, seed: int, sigma: float, remedy: str, boundary_correction: bool,
                   **untangle_kwargs) -> dict:
    """The plain pipeline up to the face features: operator, eigsh, Algorithm 1, Whitney norms
    (``untangle_kwargs``: :func:`untangle_numpy`'s). Returns a dict of eigenvalues, forms,
    untangled forms, rotation, features [F, n], edges and S1."""
    R, S1, edges, meta = killing_operator_scipy(V, F, boundary_correction=boundary_correction, remedy=remedy)
    S1 = clamp_mass(S1)
    lam, forms = solve_akvf(R, S1, n, sigma)
    U, A = untangle_numpy(forms, S1, seed=seed, **untangle_kwargs)
    X = whitney_face_vectors_scipy(meta["V"], F, edges, U)
    return dict(eigenvalues=lam, forms=forms, untangled=U, rotation=A,
                features=np.linalg.norm(X, axis=2), edges=edges, S1=S1)


def features_scipy(V, F, n: int = 32, seed: int = 0, sigma: float = -1.0, remedy: str = "smooth",
                   restarts: int = 8, tol: float = 1e-6, boundary_correction: bool = True):
    """Per-face AKVF descriptors, plain pipeline: AKVFs (eigsh, SuperLU) -> Algorithm 1 (numpy)
    -> norms of the untangled fields' Whitney vectors at the barycenters.

    Returns ``(features [F, n], eigenvalues [n])``: the baseline of ``torchakvf``'s ``features``
    (:func:`torchakvf.interop.face_features`) with the same remedy, field count and restarts.
    """
    info = _features_info(V, F, n, seed, sigma, remedy, boundary_correction, tol=tol, restarts=restarts)
    return info["features"], info["eigenvalues"]


def segment_scipy(V, F, k: int, n: int | None = None, seed: int = 0, sigma: float = -1.0,
                  boundary_correction: bool = True, return_info: bool = False):
    """Intrinsic-primitive segmentation, plain pipeline: AKVFs -> Algorithm 1 -> face features -> k-means.

    ``n`` (number of AKVFs) defaults to ``clamp(2k, 16, 32)``.  Face feature phi(f)_i = |X_f(u_i)|, the norm of
    the Whitney vector of the i-th untangled field at the barycenter.  Returns face labels [F] (and, with
    ``return_info``, a dict with eigenvalues, untangled forms, features and the k-means cost).
    """
    if n is None:
        n = int(np.clip(2 * k, 16, 32))
    info = _features_info(V, F, n, seed, sigma, "none", boundary_correction)
    feats = info["features"]
    labels, cost = spherical_kmeans_numpy(feats, k, seed=seed)
    if return_info:
        return labels, dict(info, kmeans_cost=cost)
    return labels
