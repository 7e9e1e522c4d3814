"""Shared fixtures: where the PSB lives, and skips with a reason when it or CUDA is absent; one
torch thread for a module; the solved fields several modules segment; the ``numerics`` marker
on the numerical kernels' test files (:data:`NUMERICAL_TEST_FILES`).

``device`` runs a test on "cpu" always and on "cuda" where there is a GPU (that parameter is
marked ``cuda`` and skipped elsewhere), so the comparison logic of a device test runs in CI too
(CPU against CPU). A test using the ``cuda`` fixture is marked ``cuda`` as well, so
``pytest -m cuda`` (benchmarks/device_check.sh) selects every test that needs a GPU.

Helpers that are not fixtures live in the ``helpers`` package beside this file
(``from helpers.meshfiles import write_off``).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
import torch

from torchakvf.evaluate.psb import PSB_ENV, default_psb_root

#: The benchmark beside this checkout, where the tests look when $TORCHAKVF_PSB is not set (the
#: package itself looks only where --psb or the variable say).
CHECKOUT_PSB = Path(__file__).resolve().parents[1].parent / "shared" / "psb"
if not os.environ.get(PSB_ENV) and (CHECKOUT_PSB / "meshes").is_dir():
    os.environ[PSB_ENV] = str(CHECKOUT_PSB)


@pytest.fixture(scope="session")
def psb() -> Path:
    root = default_psb_root()   # $TORCHAKVF_PSB, set above to ../shared/psb beside the checkout
    if root is None:
        pytest.skip("Princeton Segmentation Benchmark not found: set TORCHAKVF_PSB or put it at "
                    "../shared/psb (meshes/N.off.gz, gt/N/N_k.seg.gz)")
    return root


@pytest.fixture(scope="session")
def cuda() -> torch.device:
    if not torch.cuda.is_available():
        pytest.skip(_NO_CUDA)
    return torch.device("cuda")


_NO_CUDA = "no CUDA device on this machine"
#: The devices a ``device`` test runs on: cpu everywhere, cuda where torch sees a GPU.
DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.cuda,
                                               pytest.mark.skipif(not torch.cuda.is_available(),
                                                                  reason=_NO_CUDA)])]


@pytest.fixture(params=DEVICES)
def device(request) -> torch.device:
    """The device under test (compare its result with the CPU's)."""
    return torch.device(request.param)


#: The test files of the numerical kernels (operators, eigensolvers, untangling, k-means, the
#: parts' cut and merge, the numpy oracles), marked ``numerics``: CI runs them a second time as
#: other CPUs would (.ci/run), since their assertions are where rounding decides. Chosen by
#: measured time (pytest --durations, one thread): 414 s of the suite's 1204 s, measured on a
#: loaded 2-core machine (about 2.5 min of the 6.5 on a quiet one). Left out: the PSB, command,
#: runner, rendering and surface-map files (I/O and exact geometry, minutes between them).
NUMERICAL_TEST_FILES = frozenset({
    "test_akvf.py", "test_akvf_solver.py", "test_alpha_expansion.py", "test_boundaries.py", "test_boundary_cues.py",
    "test_boundary_probability.py", "test_canonical.py", "test_cholmod.py", "test_concavity.py", "test_creases.py",
    "test_dec.py", "test_descriptors.py", "test_discovery.py", "test_factor.py",
    "test_field_counts.py", "test_fourth_moments.py", "test_generators.py", "test_graphcut.py",
    "test_grouping.py", "test_horst.py", "test_k_auto.py", "test_killing.py", "test_kmeanspp.py", "test_krylov.py",
    "test_lobpcg.py", "test_merge.py", "test_merge_terms.py", "test_metrics.py", "test_part_descriptors.py",
    "test_remedy_choice.py", "test_restarts.py", "test_rounds.py", "test_scipy_reference.py",
    "test_segment.py", "test_segmenter.py", "test_spherical_kmeans.py", "test_untangle.py", "test_whitney.py",
})


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "cuda" in getattr(item, "fixturenames", ()) and item.get_closest_marker("cuda") is None:
            item.add_marker(pytest.mark.cuda)
        if item.path.name in NUMERICAL_TEST_FILES:
            item.add_marker(pytest.mark.numerics)


@pytest.fixture(scope="module")
def one_torch_thread():
    """One torch intra-op thread for a whole test module, which opts in with
    ``pytestmark = pytest.mark.usefixtures("one_torch_thread")``.

    Small meshes run many tiny kernels and sparse solves: on a busy 2-core machine intra-op
    threads spin-waiting on each other made such tests 10-100x slower (measured: 0.4 s vs 40 s
    for the runner's corpus), while one thread is as fast on an idle machine.
    """
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="module")
def fields():
    """24 AKVFs (remedy "smooth") of a batch of two meshes: three_blobs (20 around) and the
    built-in dumbbell; one solve per module that segments, clusters or untangles them."""
    import torchakvf as ta
    from torchakvf import shapes
    meshes = [ta.Mesh(s.vertices, s.faces, name=n) for n, s in
              (("blobs", shapes.three_blobs(n_around=20)), ("dumbbell", shapes.BUILTIN_SHAPES["dumbbell"]()))]
    return ta.akvf(ta.MeshBatch.from_meshes(meshes), n=24, remedy="smooth")


@pytest.fixture(scope="module")
def blobs_and_bent():
    """20 AKVFs (remedy "smooth") of three_blobs and of the dumbbell bent by 0.6, for the checks
    of float32 iterations: three distinct blobs (a well-separated optimum), and a shape whose
    optima compete."""
    import torchakvf as ta
    from torchakvf import shapes
    meshes = [ta.Mesh(s.vertices, s.faces, name=n) for n, s in
              (("three_blobs", shapes.three_blobs()), ("bent", shapes.bend(shapes.dumbbell(), 0.6)))]
    return ta.akvf(ta.MeshBatch.from_meshes(meshes), n=20, remedy="smooth")


@pytest.fixture(scope="module")
def blobs_and_bent_float64(blobs_and_bent):
    """``blobs_and_bent`` untangled to 16 fields with float64 iterations throughout."""
    import torchakvf as ta
    return ta.untangle(blobs_and_bent, n=16, seed=0, iteration_dtype=torch.float64)


@pytest.fixture(scope="module")
def ico2_shuffled():
    """icosphere(2) (vertices, faces) with its faces in a random order (so "order kept" is a
    real check)."""
    from torchakvf import shapes
    s = shapes.icosphere(2)
    perm = np.random.default_rng(7).permutation(len(s.faces))
    return s.vertices, s.faces[perm]
