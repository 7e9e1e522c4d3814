"""Alternative eigensolver: implicitly restarted Lanczos (ARPACK, via scipy ``eigsh``) in
shift-invert mode on the same CHOLMOD factor the LOBPCG path uses. CPU only, one mesh at a time.

The CPU solver of small meshes (``solver="auto"``), the block Krylov solver's fallback, and
offered by name (``torchakvf.akvf(..., solver="lanczos")``): it needs few solves per eigenpair,
but each is a single right-hand side, and with a loose tolerance Lanczos can drop copies of
repeated eigenvalues, which a block method does not (see docs/design.md).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
import torch

from ..errors import FieldCountError
from ..operators.killing import KillingSystem
from .factor import mesh_factor
from .lobpcg import EigenResult, relative_residuals


def shift_invert_lanczos(system: KillingSystem, n: int, tol: float = 1e-6, seed: int = 0,
                         names: list[str] | None = None, factors: list | None = None) -> EigenResult:
    """The ``n`` smallest eigenpairs of each mesh by ARPACK shift-invert on a CHOLMOD factor.

    ``tol`` is the residual reported as converged (ARPACK itself runs to machine precision,
    since a loose ARPACK tolerance is what loses repeated eigenvalues). factors : optional
    precomputed :class:`ShiftedFactor` per mesh.
    """
    nb = system.n_meshes
    names = names or [f"mesh {b}" for b in range(nb)]
    sizes = (system.edge_ptr[1:] - system.edge_ptr[:-1]).tolist()
    for b, e in enumerate(sizes):
        if n >= e:
            raise FieldCountError(f"{names[b]}: {n} fields asked for but the mesh has only {e} edges "
                              "(Lanczos needs fewer fields than edges); ask for fewer fields")
    values, vectors, shifts, solves = [], [], [], []
    for b in range(nb):
        r, c, v, size = system.block(b)
        lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
        mass = system.mass[lo:hi].cpu()
        factor = factors[b] if factors is not None else mesh_factor(system, b, names[b], device="cpu")
        stiff = sp.csr_matrix((v.cpu().numpy(), (r.cpu().numpy(), c.cpu().numpy())), shape=(size, size))
        count = [0]

        def apply(x, f=factor, count=count):
            count[0] += 1
            return f.solve(torch.from_numpy(x)).numpy()

        op_inv = sla.LinearOperator((size, size), dtype=np.float64, matvec=apply)
        v0 = np.random.default_rng(seed).standard_normal(size)
        lam, vec = sla.eigsh(stiff, k=n, M=sp.diags(mass.numpy()), sigma=factor.sigma, which="LM",
                             OPinv=op_inv, v0=v0)
        order = np.argsort(lam)
        values.append(torch.from_numpy(lam[order]))
        vectors.append(torch.from_numpy(vec[:, order]))
        shifts.append(factor.sigma)
        solves.append(count[0])
    dev = system.mass.device
    vals = torch.stack(values).to(dev)
    vecs = torch.cat(vectors).to(dev)
    res = relative_residuals(system, vecs, vals)
    return EigenResult(eigenvalues=vals, vectors=vecs, residuals=res,
                       iterations=torch.tensor(solves, dtype=torch.long, device=dev),
                       shifts=torch.tensor(shifts, dtype=torch.float64, device=dev),
                       converged=(res <= tol).all(dim=1))
