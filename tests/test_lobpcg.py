"""The segmented LOBPCG (torchakvf.solvers.lobpcg): a block-diagonal factor against per-mesh
factors, locking (each mesh stops on its own), warm starts."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from helpers.eigen_checks import PAPER, batch_with_a_low_mesh, clusters, mesh_of, s1_principal_cosines

import torchakvf as ta
from torchakvf import shapes

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)


def test_lobpcg_block_factor_equals_per_mesh_factors():
    """The batched LOBPCG preconditioned by one block-diagonal factor (the CUDA default) finds
    the same eigenpairs as with one factor per mesh, within an iteration of the same count (the
    two differ in the factors' round-off only): eigenvalues to 1e-9 relative (residuals < 1e-8,
    squared over gaps of order 1), the same invariant subspaces, the same shifts."""
    from torchakvf.solvers.lobpcg import segmented_lobpcg
    system = batch_with_a_low_mesh()
    per_mesh = segmented_lobpcg(system, 8, tol=1e-8, block_factor=False)
    block = segmented_lobpcg(system, 8, tol=1e-8, block_factor=True)
    assert bool(per_mesh.converged.all()) and bool(block.converged.all())
    assert block.shifts.tolist() == per_mesh.shifts.tolist() == [-1.0, -8.0, -1.0]
    # A residual that crosses tol within round-off of it may cross one iteration apart.
    assert (block.iterations - per_mesh.iterations).abs().max() <= 1
    torch.testing.assert_close(block.eigenvalues, per_mesh.eigenvalues, rtol=1e-9, atol=1e-9)
    assert float(block.eigenvalues[1, 0]) < -1.0             # the lowered mesh's own spectrum
    for b in range(system.n_meshes):
        e0, e1 = int(system.edge_ptr[b]), int(system.edge_ptr[b + 1])
        lam = per_mesh.eigenvalues[b].numpy()
        for start, stop in clusters(lam):
            if stop == 8:
                continue
            cos = s1_principal_cosines(block.vectors[e0:e1, start:stop].numpy(),
                                       per_mesh.vectors[e0:e1, start:stop].numpy(),
                                       system.mass[e0:e1].numpy())
            assert np.all(cos > 1 - 1e-6), (b, start, stop, cos)


def test_lobpcg_locking_each_mesh_stops_on_its_own():
    """Segmented LOBPCG on a batch whose meshes converge after different numbers of iterations:
    a converged mesh leaves the iteration (the live meshes' R is rebuilt), and every mesh ends
    with the eigenpairs it gets alone, within one iteration of its count alone. Alone and batched
    differ only in the round-off of the padded products: a residual that lands within round-off
    of tol can cross it one iteration earlier or later (which one depends on the CPU's and BLAS's
    summation order), eigenvalues agree to 1e-9 relative (their residuals are below 1e-8, squared
    over gaps of order 1), and the invariant subspaces are the same."""
    from torchakvf.operators import killing_operator
    from torchakvf.solvers.lobpcg import segmented_lobpcg
    meshes = [mesh_of(shapes.icosphere(2)), mesh_of(shapes.dumbbell(n_around=24)),
              mesh_of(shapes.open_tube(n_around=24)), mesh_of(shapes.ellipsoid(level=3))]
    batch = ta.MeshBatch.from_meshes(meshes)
    system = killing_operator(batch, remedy=PAPER)
    both = segmented_lobpcg(system, 8, tol=1e-8)
    assert bool(both.converged.all())
    assert len(set(both.iterations.tolist())) > 1           # they did stop at different times
    for b in range(len(meshes)):
        one = killing_operator(batch.mesh(b), remedy=PAPER)
        alone = segmented_lobpcg(one, 8, tol=1e-8)
        assert abs(int(both.iterations[b]) - int(alone.iterations[0])) <= 1
        torch.testing.assert_close(both.eigenvalues[b], alone.eigenvalues[0], rtol=1e-9, atol=1e-9)
        e0, e1 = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
        lam = alone.eigenvalues[0].numpy()
        for start, stop in clusters(lam):
            if stop == 8:
                continue
            cos = s1_principal_cosines(both.vectors[e0:e1, start:stop].numpy(),
                                       alone.vectors[:, start:stop].numpy(), one.mass.numpy())
            assert np.all(cos > 1 - 1e-6), (b, start, stop, cos)


def test_lobpcg_warm_start():
    """``segmented_lobpcg(start=...)``: a mesh started from its own converged eigenvectors (the
    n wanted and the guard ones) is done in at most one iteration with the same eigenvalues
    (to 1e-9 relative: both sides' residuals are below 1e-8, squared over gaps of order 1);
    a partial start (fewer columns, the rest random) gives the same eigenpairs too, and a mesh
    given None keeps its random start; a start of the wrong shape (or count) is a
    ParameterError naming the mesh."""
    from torchakvf.operators import killing_operator
    from torchakvf.solvers.lobpcg import segmented_lobpcg
    meshes = [mesh_of(shapes.icosphere(2), "ico"), mesh_of(shapes.ellipsoid(level=3), "ell")]
    system = killing_operator(ta.MeshBatch.from_meshes(meshes), remedy=PAPER)
    n, guard = 8, 8
    cold = segmented_lobpcg(system, n + guard, tol=1e-8, guard=guard)
    assert bool(cold.converged.all())
    e = system.edge_ptr.tolist()
    full = [cold.vectors[e[b]:e[b + 1]] for b in range(2)]
    ref = segmented_lobpcg(system, n, tol=1e-8, guard=guard)
    warm = segmented_lobpcg(system, n, tol=1e-8, guard=guard, start=full)
    assert bool(warm.converged.all()) and warm.iterations.max() <= 1 < ref.iterations.min()
    torch.testing.assert_close(warm.eigenvalues, ref.eigenvalues, rtol=1e-9, atol=1e-9)
    part = segmented_lobpcg(system, n, tol=1e-8, guard=guard, start=[full[0][:, :4], None])
    assert bool(part.converged.all())
    torch.testing.assert_close(part.eigenvalues, ref.eigenvalues, rtol=1e-9, atol=1e-9)
    # Mesh 1 kept its random start: its iterations are ref's (within one: when mesh 0 leaves
    # the iteration earlier, mesh 1's products run in a batch of one, other round-off).
    assert abs(int(part.iterations[1]) - int(ref.iterations[1])) <= 1
    with pytest.raises(ta.ParameterError, match="ell"):
        segmented_lobpcg(system, n, guard=guard, start=[None, full[1][:-1]], names=["ico", "ell"])
    with pytest.raises(ta.ParameterError, match="at most 16"):
        segmented_lobpcg(system, n, guard=guard, start=[torch.cat([full[0], full[0][:, :1]], 1), None])
    with pytest.raises(ta.ParameterError):
        segmented_lobpcg(system, n, guard=guard, start=[None])


def test_host_synchronizations_per_iteration_have_a_ceiling():
    """Calls that would make the host wait for a GPU (tests/helpers/syncs.py), per iteration of
    the batched LOBPCG with one block factor (the device's path), counted on the CPU as the
    difference between 10 and 4 iterations (no mesh converges at tol 1e-30, so the start and
    end cancel): the two dense eigh of the Rayleigh-Ritz step (torch reads their error code)
    and one read of which meshes converged every CHECK_EVERY iterations; no mask indexing, no
    nonzero, no list to the device. The factor's solve is the factor library's and is not
    counted."""
    from helpers.syncs import SyncCounter

    from torchakvf.solvers import lobpcg
    from torchakvf.solvers.factor import BlockDiagonalFactor
    system = batch_with_a_low_mesh()
    block = BlockDiagonalFactor(system)

    def counted(iterations: int) -> SyncCounter:
        counter = SyncCounter()
        real = block.solve

        def solve(rhs):
            with counter.paused():
                return real(rhs)

        block.solve = solve
        with counter:
            lobpcg.segmented_lobpcg(system, 8, tol=1e-30, max_iter=iterations, factors=block)
        del block.solve
        return counter

    short, long = counted(4), counted(10)
    per_iteration = (long.counts - short.counts)
    assert per_iteration["linalg.eigh"] == 2 * 6
    others = sum(per_iteration.values()) - per_iteration["linalg.eigh"]
    assert others <= 6 / lobpcg.CHECK_EVERY, per_iteration


def test_working_bytes_bound_the_arrays_allocated():
    """lobpcg.working_bytes (a batch's memory budget) against a tensor-size audit of the
    solve (tests/helpers/allocations.py: the peak bytes of the storages alive at once): never
    below it, and within 15% above it (the formula counts the Rayleigh-Ritz step's arrays; the
    audit saw 1-5% less), for several n, with every mesh live (tol 1e-30) past the second
    iteration (the first has no P block)."""
    from helpers.allocations import PeakBytes

    from torchakvf.solvers import lobpcg
    from torchakvf.solvers.factor import BlockDiagonalFactor
    system = batch_with_a_low_mesh()
    block = BlockDiagonalFactor(system)
    edges = (system.edge_ptr[1:] - system.edge_ptr[:-1]).tolist()
    for n in (4, 16):
        with PeakBytes(min_bytes=1024) as audit:
            lobpcg.segmented_lobpcg(system, n, tol=1e-30, max_iter=3, factors=block)
        budget = lobpcg.working_bytes(edges, n)
        assert audit.peak <= budget <= 1.15 * audit.peak, (n, audit.peak, budget)
