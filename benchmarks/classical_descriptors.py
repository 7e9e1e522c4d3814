"""Classical per-face descriptors for the learning benchmarks, on one mesh in its unit-area frame.

Groups (each a [F, k] float array; per-vertex quantities are averaged over a face's corners):

* ``curvature`` [F, 6]: principal curvatures k1 >= k2 (libigl's quadric fit,
  ``igl.principal_curvature``) at neighbourhood radii of 2, 5 and 10 mean edge lengths, as
  asinh(k) (k in 1/length at unit area; asinh keeps the sign and compresses the tails).
* ``hks`` [F, 8]: heat kernel signature (Sun et al. 2009) at 8 log-spaced times from
  4 ln 10 / λ_max to 4 ln 10 / λ_1, each divided by the heat trace Σ exp(-λ t) (scale
  normalized), log.
* ``wks`` [F, 8]: wave kernel signature (Aubry et al. 2011) at 8 log-energies evenly spaced over
  [log λ_1, log λ_max], σ = 2 steps, normalized per energy.
* ``sdf`` [F, 2]: shape diameter function (Shapiro et al. 2008, libigl + Embree, 32 rays in
  the inward cone per face): log(sdf) at unit area and log(sdf / its area-weighted median).
  libigl draws the ray directions from the C library's unseeded generator, so this group alone
  is not bit-reproducible (a rerun moved a few faces of PSB 121 by up to 0.7 in log sdf); the
  other groups are. (trimesh's ray casting would need rtree or embreex, not installed here.)

HKS and WKS use the first :data:`SPECTRUM` eigenpairs of the cotan Laplace-Beltrami operator
with a lumped mass matrix (scipy ``eigsh``, shift-invert); the first 32 non-zero eigenvalues
(λ·area) are also returned as ShapeDNA (Reuter et al. 2006).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

SPECTRUM = 64
SHAPEDNA = 32
CURVATURE_RADII = (2, 5, 10)
TIMES = 8
ENERGIES = 8
SDF_RAYS = 32
SEED = 0

GROUPS = {"curvature": [f"k{i}_r{r}" for r in CURVATURE_RADII for i in (1, 2)],
          "hks": [f"hks_{i}" for i in range(TIMES)],
          "wks": [f"wks_{i}" for i in range(ENERGIES)],
          "sdf": ["log_sdf", "log_sdf_rel"]}


def unit_area(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices scaled to unit total area [V, 3], face areas [F] summing to 1)."""
    a = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    s = 1.0 / np.sqrt(a.sum())
    return v * s, a * s * s


def laplace_spectrum(v: np.ndarray, f: np.ndarray, count: int = SPECTRUM):
    """(λ [k] ascending with the zero modes, φ [V, k] M-orthonormal, number of components) of
    the cotan Laplacian with lumped mass; v at unit area."""
    nv = len(v)
    rows, cols, vals = [], [], []
    for k in range(3):
        i, j, o = f[:, (k + 1) % 3], f[:, (k + 2) % 3], f[:, k]
        a, b = v[i] - v[o], v[j] - v[o]
        cot = np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(np.cross(a, b), axis=1), 1e-300)
        rows += [i, j]
        cols += [j, i]
        vals += [0.5 * cot, 0.5 * cot]
    w = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(nv, nv)).tocsr()
    lap = sp.diags(np.asarray(w.sum(axis=1)).ravel()) - w
    _, area = unit_area(v, f)
    mass = np.zeros(nv)
    np.add.at(mass, f.ravel(), np.repeat(area / 3.0, 3))
    mass = sp.diags(np.maximum(mass, 1e-12 * mass.mean()))
    n_comp = sp.csgraph.connected_components(w, directed=False)[0]
    k = min(count + n_comp, nv - 2)
    lam, phi = sla.eigsh(lap.tocsc(), k=k, M=mass.tocsc(), sigma=-1e-3, which="LM",
                         v0=np.random.default_rng(SEED).standard_normal(nv))
    order = np.argsort(lam)
    return np.maximum(lam[order], 0.0), phi[:, order], n_comp


def to_faces(values: np.ndarray, f: np.ndarray) -> np.ndarray:
    """[F, ...] per-vertex values averaged over each face's three corners."""
    return values[f].mean(axis=1)


def hks_wks(lam: np.ndarray, phi: np.ndarray, n_comp: int) -> tuple[np.ndarray, np.ndarray]:
    """([V, TIMES] log scale-normalized HKS, [V, ENERGIES] log normalized WKS)."""
    sq = phi ** 2
    nz = lam[n_comp:]
    t = np.geomspace(4 * np.log(10) / nz[-1], 4 * np.log(10) / max(nz[0], 1e-12), TIMES)
    heat = np.exp(-np.outer(lam, t))                                  # [k, T]
    hks = (sq @ heat) / heat.sum(axis=0)
    loglam = np.log(np.maximum(nz, 1e-12))
    e = np.linspace(loglam[0], loglam[-1], ENERGIES)
    sigma = 2.0 * (e[1] - e[0]) if ENERGIES > 1 else 1.0
    g = np.exp(-((e[None, :] - loglam[:, None]) ** 2) / (2 * sigma ** 2))   # [k', E]
    wks = (sq[:, n_comp:] @ g) / g.sum(axis=0)
    return np.log(np.maximum(hks, 1e-300)), np.log(np.maximum(wks, 1e-300))


def curvature(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """[F, 6] asinh of (k1, k2) per radius of :data:`CURVATURE_RADII` (0 where libigl fails)."""
    import igl

    out = []
    for r in CURVATURE_RADII:
        try:
            _, _, k1, k2, _ = igl.principal_curvature(v, f, radius=r)
            k = np.stack([k1, k2], axis=1)
            k = np.where(np.isfinite(k), k, 0.0)
        except (RuntimeError, ValueError):
            k = np.zeros((len(v), 2))
        out.append(np.arcsinh(to_faces(k, f)))
    return np.concatenate(out, axis=1)


def shape_diameter(v: np.ndarray, f: np.ndarray, area: np.ndarray) -> np.ndarray:
    """[F, 2] log SDF at unit area and log SDF relative to its area-weighted median."""
    import igl.embree

    c = v[f].mean(axis=1)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    # libigl shoots its cone against the normal given: outward normals measure inward
    sdf = igl.embree.shape_diameter_function(np.ascontiguousarray(v), np.ascontiguousarray(f),
                                             np.ascontiguousarray(c), np.ascontiguousarray(n),
                                             SDF_RAYS)
    sdf = np.where(np.isfinite(sdf) & (sdf > 0), sdf, np.nan)
    fill = np.nanmax(sdf) if np.isfinite(sdf).any() else 1.0
    sdf = np.where(np.isnan(sdf), fill, sdf)              # rays that hit nothing: open side
    order = np.argsort(sdf)
    median = sdf[order][np.searchsorted(np.cumsum(area[order]), 0.5 * area.sum())]
    return np.stack([np.log(sdf), np.log(sdf / median)], axis=1)


def classical_descriptors(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Every group of the module docstring on one mesh, plus ``shapedna`` [32] (λ·area)."""
    v, area = unit_area(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    f = np.asarray(faces, dtype=np.int64)
    lam, phi, n_comp = laplace_spectrum(v, f)
    hks, wks = hks_wks(lam, phi, n_comp)
    dna = lam[n_comp:n_comp + SHAPEDNA]
    dna = np.concatenate([dna, np.full(SHAPEDNA - len(dna), dna[-1] if len(dna) else 0.0)])
    return {"curvature": curvature(v, f), "hks": to_faces(hks, f), "wks": to_faces(wks, f),
            "sdf": shape_diameter(v, f, area), "shapedna": dna}
