"""Checks shared by the eigensolver tests: meshes from shapes, subspace angles, clusters of
equal eigenvalues, a system's blocks as scipy matrices, a batch with a low mesh."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch

import torchakvf as ta
from torchakvf import shapes

#: The paper's operator (no mesh-quality remedy): the tables and the scipy reference are its.
PAPER = "none"
#: The eigensolvers a user can pick.
METHODS = ["lobpcg", "lanczos", "krylov"]


def mesh_of(shape, name=None) -> ta.Mesh:
    return ta.Mesh(shape.vertices, shape.faces, name or shape.name)


def s1_principal_cosines(a: np.ndarray, b: np.ndarray, s1: np.ndarray) -> np.ndarray:
    """Cosines of the S1-principal angles between span(a) and span(b) ([E, k] each)."""
    def orth(x):
        g = x.T @ (s1[:, None] * x)
        return x @ np.linalg.inv(np.linalg.cholesky(g)).T
    return np.linalg.svd(orth(a).T @ (s1[:, None] * orth(b)), compute_uv=False)


def clusters(lam: np.ndarray, rel: float = 1e-6) -> list[tuple[int, int]]:
    """[start, stop) runs of (numerically) equal eigenvalues."""
    out, start = [], 0
    for i in range(1, len(lam) + 1):
        if i == len(lam) or abs(lam[i] - lam[i - 1]) > rel * max(abs(lam[i]), 1.0):
            out.append((start, i))
            start = i
    return out


def scipy_matrices(system, b: int = 0):
    r, c, v, size = system.block(b)
    R = sp.csc_matrix((v.cpu().numpy(), (r.cpu().numpy(), c.cpu().numpy())), shape=(size, size))
    lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
    return R, system.mass[lo:hi].cpu().numpy()


def batch_with_a_low_mesh():
    """A 3-mesh system whose middle mesh has R lowered by 5 S1 (eigenvalues near -5: it needs
    the shift -8, its mates -1), to exercise the block factor's per-mesh shift ladder."""
    from torchakvf.operators import killing_operator
    from torchakvf.operators.killing import KillingSystem
    meshes = [mesh_of(shapes.icosphere(2)), mesh_of(shapes.dumbbell(n_around=24)),
              mesh_of(shapes.open_tube(n_around=24))]
    system = killing_operator(ta.MeshBatch.from_meshes(meshes), remedy=PAPER)
    idx, vals = system.stiffness.indices(), system.stiffness.values().clone()
    lo, hi = int(system.edge_ptr[1]), int(system.edge_ptr[2])
    on_diag = (idx[0] == idx[1]) & (idx[0] >= lo) & (idx[0] < hi)
    vals[on_diag] -= 5.0 * system.mass[idx[0][on_diag]]
    stiff = torch.sparse_coo_tensor(idx, vals, system.stiffness.shape, is_coalesced=True,
                                    check_invariants=False)
    return KillingSystem(stiffness=stiff, mass=system.mass, edge_ptr=system.edge_ptr,
                         star1_raw=system.star1_raw, geometry=system.geometry)


def sliver_sphere(name: str = "sliver") -> ta.Mesh:
    """icosphere(2) with one vertex moved to 1e-4 of its edge's length from a neighbour: two
    slivers whose Killing operator (remedy "smooth") needs the shift -64 where its mates take
    -1 (and that no shift of a ladder cut at -8 makes definite)."""
    s = shapes.icosphere(2)
    v = s.vertices.copy()
    a, b = s.faces[0][0], s.faces[0][1]
    v[a] = v[a] + 0.9999 * (v[b] - v[a])
    return ta.Mesh(v, s.faces, name)


class SolveLog:
    """Counts, through monkeypatching, the numeric factorizations a solve makes (every trial
    shift: ``sizes``, the matrix order of each) and the LOBPCG calls (``groups``: the mesh names
    of each)."""

    def __init__(self, monkeypatch):
        from torchakvf.solvers import cholesky as chol
        from torchakvf.solvers import group_solver
        self.sizes, self.groups = [], []
        real_cholesky, real_lobpcg = chol.cholesky, group_solver.segmented_lobpcg

        def cholesky(pattern, diagonal, engine=None):
            self.sizes.append(int(pattern[0]))
            return real_cholesky(pattern, diagonal, engine)

        def lobpcg(system, n, **kw):
            self.groups.append(list(kw.get("names") or []))
            return real_lobpcg(system, n, **kw)

        monkeypatch.setattr(chol, "cholesky", cholesky)
        monkeypatch.setattr(group_solver, "segmented_lobpcg", lobpcg)


class FactorLog:
    """Counts, through monkeypatching, what CHOLMOD called directly does: symbolic analyses
    (``analyses``; a factor that copies another's analysis counts in ``shared``), whole numeric
    factorizations (``numeric``, every trial shift) and definiteness tests stopped at the first
    non-positive pivot (``stopped``: those that stopped early; ``complete``: those that did not)."""

    def __init__(self, monkeypatch):
        from torchakvf.solvers import cholmod
        self.analyses = self.shared = self.numeric = self.stopped = self.complete = 0
        cls = cholmod.CholmodFactor
        init, factorize, definite = cls.__init__, cls.factorize, cls.positive_definite_at
        log = self

        def counted_init(self, *args, symbolic=None, **kw):
            init(self, *args, symbolic=symbolic, **kw)
            if symbolic is None:
                log.analyses += 1
            else:
                log.shared += 1

        def counted_factorize(self, *args, **kw):
            log.numeric += 1
            return factorize(self, *args, **kw)

        def counted_definite(self, *args, **kw):
            out = definite(self, *args, **kw)
            if out:
                log.complete += 1
            else:
                log.stopped += 1
            return out

        monkeypatch.setattr(cls, "__init__", counted_init)
        monkeypatch.setattr(cls, "factorize", counted_factorize)
        monkeypatch.setattr(cls, "positive_definite_at", counted_definite)
