"""pytest-benchmark cases: operator assembly and eigensolve, torchakvf vs scipy ``eigsh``.

Cases: icosphere(4) (one mesh, 5,120 faces), a batch of the 4 built-in composite shapes
(:data:`torchakvf.shapes.BUILTIN_SHAPES`, 48 vertices around, ~14,000 faces in all), and the first
PSB mesh (skipped when the PSB is absent).
scipy solves the *same* operator torchakvf assembled (``system.stiffness`` / ``system.mass``, block
by block) with ``eigsh(R, k=n, M=diags(S1), sigma=σ, which='LM')`` (default SuperLU), σ being the
shift torchakvf's factor used. Every solve is checked (residual <= 1e-6, eigenvalues agree).

Not collected by CI (``pytest tests``). The project's pytest options pass ``--benchmark-disable``
(each case then runs once, as a smoke test); to time, enable it::

    pytest benchmarks/test_bench_eigensolver.py --benchmark-enable
    pytest benchmarks/test_bench_eigensolver.py --benchmark-enable --benchmark-group-by=group

Each case runs ``rounds=3`` (about 2-3 minutes in all on an idle 2-core machine; much longer when
other processes load the CPUs: with 2 OpenMP/OpenBLAS threads on oversubscribed cores, small dense
LAPACK/BLAS calls can spin-wait for ~100x their time, for torch (MKL) and scipy (OpenBLAS) alike;
``OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1`` gives stable comparisons there). The
full 19-mesh PSB comparison is ``python benchmarks/eigensolver_psb.py``.
"""
from __future__ import annotations

import importlib.util
import pathlib
import sys

import numpy as np
import pytest
import scipy.sparse as sp
import torch

from torchakvf.mesh import Mesh, MeshBatch
from torchakvf.operators.killing import killing_operator
from torchakvf.shapes import BUILTIN_SHAPES, icosphere
from torchakvf.solvers.lobpcg import segmented_lobpcg

_HERE = pathlib.Path(__file__).resolve().parent


def _load(name: str, path: pathlib.Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault(name, mod)   # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return sys.modules[name]


from torchakvf import scipy_reference as ref  # noqa: E402
from torchakvf.evaluate.psb import default_psb_root  # noqa: E402

bench = _load("eigensolver_psb", _HERE / "eigensolver_psb.py")

N = 32
TOL = 1e-6
ROUNDS = 3
PSB_ID = 1          # Human: the first mesh of the first category


def _batch(shapes) -> MeshBatch:
    return MeshBatch.from_meshes([Mesh(s.vertices, s.faces, name=s.name) for s in shapes])


def _psb_batch() -> MeshBatch:
    checkout_psb = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "psb"
    root = default_psb_root() or ((checkout_psb / "meshes").is_dir() and checkout_psb) or None
    if root is None:
        pytest.skip("Princeton Segmentation Benchmark not found: set TORCHAKVF_PSB or put it at "
                    "../shared/psb")
    return bench.load_clean(root, PSB_ID)


_BUILDERS = {
    "ico4": lambda: _batch([icosphere(4)]),
    # The 4 composite shapes at a coarser resolution than their defaults (~14,000 faces in all
    # instead of ~41,000) so that the file stays within a few minutes.
    "shapes4": lambda: _batch([make(**({"n_major": 48} if name == "torus_chain" else {"n_around": 48}))
                               for name, make in BUILTIN_SHAPES.items()]),
    f"psb{PSB_ID}": _psb_batch,
}
_CACHE: dict = {}


def _case(name: str) -> dict:
    """Batch, its operator and a reference torchakvf solve (untimed, built once per session)."""
    if name not in _CACHE:
        batch = _BUILDERS[name]()
        remedy = "smooth" if name.startswith("psb") else "none"
        system = killing_operator(batch, remedy=remedy)
        eig = segmented_lobpcg(system, N, tol=TOL, names=batch.names)
        assert bool(eig.converged.all()), eig.residuals.max()
        _CACHE[name] = dict(batch=batch, remedy=remedy, system=system, eig=eig)
    return _CACHE[name]


CASES = [
    "ico4",
    "shapes4",
    pytest.param(f"psb{PSB_ID}", marks=pytest.mark.psb),
]


def _scipy_blocks(system):
    """Per-mesh (CSC R_b, S1_b) of a torch KillingSystem (this conversion is timed with eigsh)."""
    out = []
    for b in range(system.n_meshes):
        r, c, v, e = system.block(b)
        lo, hi = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
        rb = sp.csc_matrix((v.numpy(), (r.numpy(), c.numpy())), shape=(e, e))
        out.append((rb, system.mass[lo:hi].numpy()))
    return out


def _scipy_solve(system, shifts):
    return [(rb, s1, *bench.scipy_eigsh(rb, s1, N, float(sigma)))
            for (rb, s1), sigma in zip(_scipy_blocks(system), shifts)]


# --------------------------------------------------------------------------------------------
# Assembly
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("case", CASES)
def test_assembly_torchakvf(benchmark, case):
    c = _case(case)
    benchmark.group = f"assembly-{case}"
    system = benchmark.pedantic(killing_operator, args=(c["batch"],), kwargs={"remedy": c["remedy"]},
                                rounds=ROUNDS, iterations=1)
    assert system.stiffness.shape[0] == len(c["batch"].edges)


@pytest.mark.parametrize("case", CASES)
def test_assembly_scipy_reference(benchmark, case):
    """The independent numpy/scipy assembly (what a user writes by hand), mesh by mesh."""
    c = _case(case)
    benchmark.group = f"assembly-{case}"
    meshes = [(m.vertices, m.faces) for m in c["batch"].meshes]
    out = benchmark.pedantic(lambda: [ref.killing_operator_scipy(v, f) for v, f in meshes],
                             rounds=ROUNDS, iterations=1)
    assert sum(r.shape[0] for r, *_ in out) == len(c["batch"].edges)


# --------------------------------------------------------------------------------------------
# Eigensolve on the same operator
# --------------------------------------------------------------------------------------------

@pytest.mark.parametrize("case", CASES)
def test_eigensolve_torchakvf(benchmark, case):
    c = _case(case)
    benchmark.group = f"eigensolve-{case}"
    eig = benchmark.pedantic(segmented_lobpcg, args=(c["system"], N), kwargs={"tol": TOL},
                             rounds=ROUNDS, iterations=1)
    assert bool(eig.converged.all())
    assert float(eig.residuals.max()) <= TOL
    benchmark.extra_info["iterations"] = eig.iterations.tolist()
    benchmark.extra_info["shifts"] = eig.shifts.tolist()
    benchmark.extra_info["torch_threads"] = torch.get_num_threads()


@pytest.mark.parametrize("case", CASES)
def test_eigensolve_torchakvf_lanczos(benchmark, case):
    """ARPACK shift-invert on torchakvf's CHOLMOD factor (what ``ta.akvf`` picks on CPU)."""
    if bench.shift_invert_lanczos is None:
        pytest.skip("this torchakvf has no solvers.lanczos")
    c = _case(case)
    benchmark.group = f"eigensolve-{case}"
    eig = benchmark.pedantic(bench.shift_invert_lanczos, args=(c["system"], N), kwargs={"tol": TOL},
                             rounds=ROUNDS, iterations=1)
    assert float(eig.residuals.max()) <= TOL
    np.testing.assert_allclose(eig.eigenvalues.numpy(), c["eig"].eigenvalues.numpy(), rtol=0,
                               atol=1e-6 * max(1.0, float(c["eig"].eigenvalues.abs().max())))
    benchmark.extra_info["solves"] = eig.iterations.tolist()


@pytest.mark.parametrize("case", CASES)
def test_eigensolve_scipy(benchmark, case):
    c = _case(case)
    benchmark.group = f"eigensolve-{case}"
    eig = c["eig"]
    out = benchmark.pedantic(_scipy_solve, args=(c["system"], eig.shifts.tolist()),
                             rounds=ROUNDS, iterations=1)
    for b, (rb, s1, lam, w) in enumerate(out):
        order = np.argsort(lam)
        lam, w = lam[order], w[:, order]
        assert bench.residuals_np(rb, s1, lam, w).max() <= TOL
        lam_ta = eig.eigenvalues[b].numpy()
        assert lam.min() > float(eig.shifts[b])
        np.testing.assert_allclose(lam_ta, lam, rtol=0, atol=1e-6 * max(1.0, np.abs(lam).max()))


@pytest.mark.parametrize("case", CASES)
def test_total_torchakvf(benchmark, case):
    """Assembly + eigensolve, the path ``ta.akvf`` takes (without the Whitney interpolation)."""
    c = _case(case)
    benchmark.group = f"total-{case}"

    def run():
        return segmented_lobpcg(killing_operator(c["batch"], remedy=c["remedy"]), N, tol=TOL)

    eig = benchmark.pedantic(run, rounds=ROUNDS, iterations=1)
    assert bool(eig.converged.all())


@pytest.mark.parametrize("case", CASES)
def test_total_scipy(benchmark, case):
    """torchakvf's assembly + conversion + eigsh (scipy solves the operator torchakvf built)."""
    c = _case(case)
    benchmark.group = f"total-{case}"
    shifts = c["eig"].shifts.tolist()

    def run():
        return _scipy_solve(killing_operator(c["batch"], remedy=c["remedy"]), shifts)

    out = benchmark.pedantic(run, rounds=ROUNDS, iterations=1)
    assert len(out) == len(c["batch"])

