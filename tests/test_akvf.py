"""torchakvf.fields.akvf: the eigenvalue tables of the AKVF operator (see docs/design.md),
agreement with the independent scipy reference (eigenvalues, cluster spans, residuals, Whitney
vectors), reproducibility, float32, parameters, CUDA and two real PSB meshes."""
from __future__ import annotations

import gzip
import logging

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
import trimesh
from helpers.eigen_checks import METHODS, PAPER, clusters, mesh_of, s1_principal_cosines, scipy_matrices

import torchakvf as ta
from torchakvf import scipy_reference as ref
from torchakvf import shapes
from torchakvf.solvers.factor import mesh_factor

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

#: "near zero" as in the tables: below this, with the next eigenvalue above GAP.
ZERO, GAP = 0.1, 5.0


def near_zero_count(lam: np.ndarray, gap: float = GAP) -> int:
    k = int(np.sum(np.abs(lam) < ZERO))
    assert np.all(np.abs(lam[:k]) < ZERO), lam            # the small ones come first
    assert k < len(lam) and lam[k] > gap, lam               # and then a clear gap
    return k


def eigs(mesh, n, **kw) -> np.ndarray:
    kw.setdefault("remedy", PAPER)        # the tables are the paper's operator's
    r = ta.akvf(mesh, n=n, **kw)
    assert bool(r.converged.all()), r.residuals
    return r.eigenvalues[0].numpy()


# ---------------------------------------------------------------------------------------------
# the eigenvalue tables
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("method", METHODS)
def test_icosphere3_table(method):
    lam = eigs(mesh_of(shapes.icosphere(3)), 12, solver=method)
    expected = np.array([0.015] * 3 + [24.885] * 3 + [50.172] * 5 + [124.08])
    assert near_zero_count(lam) == 3
    np.testing.assert_allclose(lam[:3], expected[:3], atol=2e-3)
    np.testing.assert_allclose(lam[3:], expected[3:], rtol=1e-3)


def test_icosphere4_table():
    lam = eigs(mesh_of(shapes.icosphere(4)), 11)
    expected = np.array([0.004] * 3 + [25.071] * 3 + [50.242] * 5)
    assert near_zero_count(lam) == 3
    np.testing.assert_allclose(lam[:3], expected[:3], atol=2e-3)
    np.testing.assert_allclose(lam[3:], expected[3:], rtol=1e-3)
    # converging to the smooth values 0, 8 pi, 16 pi from below
    assert np.all(lam[3:6] < 8 * np.pi) and np.all(lam[6:] < 16 * np.pi)


def test_ellipsoid_of_revolution_one_zero():
    # revolved 1:1:1.6 spheroid (a coarser mesh than the table's: loose values)
    lam = eigs(mesh_of(shapes.ellipsoid_of_revolution()), 8)
    assert near_zero_count(lam, gap=1.0) == 1   # the axial rotation only; then ~2.37
    np.testing.assert_allclose(lam[1:3], 2.374, rtol=0.05)
    assert abs(lam[1] - lam[2]) < 1e-6 * lam[1]   # 6-fold symmetric mesh: an exact pair
    np.testing.assert_allclose(lam[3:6], [18.83, 25.08, 25.08], rtol=0.02)


@pytest.fixture(scope="module")
def generic_ellipsoid():
    """The table's mesh: trimesh's icosphere(4) scaled 1:1.3:1.7 (28 negative cotan weights)."""
    m = trimesh.creation.icosphere(subdivisions=4)
    return ta.Mesh(np.asarray(m.vertices) * [1.0, 1.3, 1.7], np.asarray(m.faces), "ellipsoid")


def test_generic_ellipsoid_no_killing_field(generic_ellipsoid):
    lam = eigs(generic_ellipsoid, 8)
    assert np.all(lam > ZERO), lam            # no near-zero eigenvalue at all
    np.testing.assert_allclose(lam[0], 0.295, atol=2e-3)
    # 75x the sphere's near-zeros, yet far below the sphere's first nonzero cluster
    assert lam[0] > 50 * 0.004 and lam[2] < 5


def test_generic_ellipsoid_full_table(generic_ellipsoid):
    lam = eigs(generic_ellipsoid, 8)
    np.testing.assert_allclose(lam, [0.295, 0.899, 2.301, 19.70, 23.40, 28.02, 35.99, 42.93],
                               rtol=2e-3)


def test_torus_table():
    lam = eigs(mesh_of(shapes.torus()), 8)
    assert near_zero_count(lam) == 1
    np.testing.assert_allclose(lam[1:7], [16.04, 20.80, 20.80, 23.08, 23.08, 43.18], rtol=0.02)


@pytest.mark.parametrize("bc", [True, False], ids=["bc", "naive"])
@pytest.mark.parametrize("method", METHODS)
def test_open_tube_table(bc, method):
    lam = eigs(mesh_of(shapes.open_tube()), 8, solver=method, boundary_correction=bc)
    if bc:   # rotation + translation along the axis
        assert near_zero_count(lam) == 2
        np.testing.assert_allclose(lam[2:], [9.145, 9.145, 20.66, 37.85, 37.85, 40.83], rtol=5e-3)
    else:    # the translation is lost without the boundary terms
        assert near_zero_count(lam) == 1
        np.testing.assert_allclose(lam[1:], [20.66, 37.70, 37.70, 39.50, 39.50, 41.30, 78.95],
                                   rtol=5e-3)


@pytest.mark.parametrize("bc", [True, False], ids=["bc", "naive"])
@pytest.mark.parametrize("method", METHODS)
def test_flat_disk_table(bc, method):
    lam = eigs(mesh_of(shapes.flat_disk()), 8, solver=method, boundary_correction=bc)
    if bc:   # two translations and a rotation
        assert near_zero_count(lam) == 3
        np.testing.assert_allclose(lam[3:7], [17.18, 17.18, 19.31, 19.31], rtol=1e-2)
    else:    # the closed formula has no Killing kernel on a disk
        assert np.all(lam > GAP), lam
        np.testing.assert_allclose(lam[:5], [18.17, 21.28, 21.28, 46.09, 46.09], rtol=1e-2)


def test_sphere_first_fields_are_rotations():
    r = ta.akvf(mesh_of(shapes.icosphere(3)), n=3)
    p = r.system.geometry.points.numpy()
    e = r.batch.edges.numpy()
    mid = 0.5 * (p[e[:, 0]] + p[e[:, 1]])
    vec = p[e[:, 1]] - p[e[:, 0]]
    w = np.stack([np.einsum("ec,ec->e", np.cross(a, mid), vec) for a in np.eye(3)], axis=1)
    cos = s1_principal_cosines(r.forms.numpy(), w, r.system.mass.numpy())
    assert np.all(cos > 0.9999), cos
    # and a non-rotation (a gradient) is far from that span
    g = vec @ np.array([0.3, -1.0, 0.5])
    assert s1_principal_cosines(r.forms.numpy(), g[:, None], r.system.mass.numpy())[0] < 0.1


# ---------------------------------------------------------------------------------------------
# agreement with the scipy reference
# ---------------------------------------------------------------------------------------------

REF_CASES = {
    "icosphere3": (lambda: shapes.icosphere(3), 12),
    "open_tube": (lambda: shapes.open_tube(n_around=36), 10),
    "hemisphere3": (lambda: shapes.hemisphere(3), 10),
}


@pytest.fixture(scope="module", params=[(c, m) for c in sorted(REF_CASES) for m in METHODS],
                ids=lambda p: f"{p[0]}-{p[1]}")
def ref_case(request):
    case, method = request.param
    make, n = REF_CASES[case]
    s = make()
    res = ta.akvf(mesh_of(s, case), n=n, solver=method, remedy=PAPER)
    cm = res.batch.meshes[0]                     # the cleaned mesh: same vertex and edge order
    R, S1, edges, meta = ref.killing_operator_scipy(cm.vertices, cm.faces)
    assert meta["n_nonpositive_S1"] == 0
    lam_ref, forms_ref = ref.akvf_scipy(cm.vertices, cm.faces, n=n + 6)
    return dict(res=res, n=n, R=R, S1=S1, edges=edges, meta=meta, lam_ref=lam_ref,
                forms_ref=forms_ref, cm=cm)


def test_eigenvalues_match_scipy(ref_case):
    n, lam = ref_case["n"], ref_case["res"].eigenvalues[0].numpy()
    lam_ref = ref_case["lam_ref"][:n]
    np.testing.assert_array_equal(ref_case["res"].batch.edges.numpy(), ref_case["edges"])
    tol = np.maximum(1e-6 * np.abs(lam_ref), 1e-8)
    assert np.all(np.abs(lam - lam_ref) <= tol), np.abs(lam - lam_ref) / np.abs(lam_ref)
    assert np.all(np.diff(lam) >= 0)


def test_cluster_spans_match_scipy(ref_case):
    n = ref_case["n"]
    forms = ref_case["res"].forms.numpy()
    checked = 0
    for start, stop in clusters(ref_case["lam_ref"]):
        if stop > n:          # a cluster cut by n is not determined
            break
        cos = s1_principal_cosines(forms[:, start:stop], ref_case["forms_ref"][:, start:stop],
                                   ref_case["S1"])
        assert np.all(cos > 1 - 1e-6), (start, stop, cos)
        checked += stop - start
    assert checked >= n // 2


def test_residuals_recomputed_with_scipy(ref_case):
    res, R, S1 = ref_case["res"], ref_case["R"], ref_case["S1"]
    w = res.forms.numpy()
    lam = res.eigenvalues[0].numpy()
    np.testing.assert_allclose(w.T @ (S1[:, None] * w), np.eye(ref_case["n"]), atol=1e-10)
    r = R @ w - S1[:, None] * w * lam
    mine = np.linalg.norm(r / np.sqrt(S1)[:, None], axis=0) / np.maximum(np.abs(lam), 1.0)
    reported = res.residuals[0].numpy()
    # Residuals at round-off level (~1e-12) differ with the summation order of R @ w, so
    # agreement is asked for relative to the tolerance they are judged against (1e-6).
    np.testing.assert_allclose(reported, mine, rtol=1e-4, atol=1e-10)
    assert np.all(mine <= 1e-6) and bool(res.converged.all())
    assert res.iterations.shape == (1,) and int(res.iterations[0]) >= 1


def test_face_vectors_match_scipy_whitney(ref_case):
    res = ref_case["res"]
    w = res.forms.numpy()
    fv_ref = ref.whitney_face_vectors_scipy(ref_case["meta"]["V"], ref_case["cm"].faces,
                                            ref_case["edges"], w)
    np.testing.assert_allclose(res.face_vectors.numpy(), fv_ref, rtol=0,
                               atol=1e-10 * np.abs(fv_ref).max())
    out = res.mesh_face_vectors(0)
    assert out.shape == (ref_case["cm"].n_input_faces, ref_case["n"], 3)
    # each vector is tangent to its face
    normal = ref_case["meta"]["face_normal"]
    assert np.abs(np.einsum("fnc,fc->fn", res.face_vectors.numpy(), normal)).max() < 1e-10


# ---------------------------------------------------------------------------------------------
# reproducibility, precision, parameters
# ---------------------------------------------------------------------------------------------

def test_same_seed_is_bitwise_reproducible():
    m = mesh_of(shapes.open_tube(n_around=36))
    a, b = ta.akvf(m, n=8, seed=3, remedy=PAPER), ta.akvf(m, n=8, seed=3, remedy=PAPER)
    assert torch.equal(a.eigenvalues, b.eigenvalues)
    assert torch.equal(a.forms, b.forms)
    c = ta.akvf(m, n=8, seed=4, remedy=PAPER)
    np.testing.assert_allclose(c.eigenvalues.numpy(), a.eigenvalues.numpy(), rtol=1e-9, atol=1e-11)


def test_float32_coordinates():
    meshes = [mesh_of(shapes.icosphere(3)), mesh_of(shapes.open_tube(n_around=36))]
    r64 = ta.akvf(ta.MeshBatch.from_meshes(meshes, dtype=torch.float64), n=8, remedy=PAPER)
    r32 = ta.akvf(ta.MeshBatch.from_meshes(meshes, dtype=torch.float32), n=8, remedy=PAPER)
    assert r32.eigenvalues.dtype == torch.float32
    assert r32.forms.dtype == torch.float32 and r32.face_vectors.dtype == torch.float32
    assert r64.eigenvalues.dtype == torch.float64 and r64.forms.dtype == torch.float64
    l32, l64 = r32.eigenvalues.double().numpy(), r64.eigenvalues.numpy()
    np.testing.assert_allclose(l32, l64, rtol=1e-4, atol=1e-4)
    assert bool(r32.converged.all())


def test_parameter_errors():
    m = mesh_of(shapes.icosphere(1))
    with pytest.raises(ta.ParameterError):
        ta.akvf(m, n=0, remedy=PAPER)
    with pytest.raises(ta.SolverError, match="edges"):
        ta.akvf(m, n=500, remedy=PAPER)            # icosphere(1) has 120 edges
    with pytest.raises(ta.ParameterError):
        ta.MeshBatch.from_meshes([m], dtype=torch.int64)


def test_tight_tolerance_does_not_break_down(caplog, recwarn):
    with caplog.at_level(logging.WARNING, logger="torchakvf"):
        r = ta.akvf(mesh_of(shapes.icosphere(2)), n=12, tol=1e-10, solver="lobpcg", remedy=PAPER)
    lam = r.eigenvalues[0].numpy()
    assert lam.min() > -1.0, lam
    assert bool(r.converged.all()), r.residuals
    # Converged at 1e-10: no "stopped ... with residual" record, no ConvergenceWarning.
    assert not [rec for rec in caplog.records if "residual" in rec.getMessage()], caplog.text
    assert not [w for w in recwarn if issubclass(w.category, ta.ConvergenceWarning)]


def test_not_converged_is_flagged_and_warned(caplog):
    # Two LOBPCG iterations cannot reach 1e-12: the result comes back, flagged, with a warning.
    with caplog.at_level(logging.WARNING, logger="torchakvf"):
        with pytest.warns(ta.ConvergenceWarning, match="icosphere"):
            r = ta.akvf(mesh_of(shapes.icosphere(2), "icosphere2"), n=12, tol=1e-12, max_iter=2,
                        solver="lobpcg", remedy=PAPER)
    assert r.converged.shape == (1,) and not bool(r.converged[0])
    assert float(r.residuals.max()) > 1e-12
    assert any("icosphere2" in rec.getMessage() for rec in caplog.records), caplog.text


def test_api_removed_method_numpy_n_and_device():
    m = mesh_of(shapes.icosphere(2))
    a = ta.akvf(m, n=np.int64(6), solver="lanczos", remedy=PAPER)
    assert a.n == 6
    assert ta.untangle(a, n=np.int32(4)).n == 4
    with pytest.raises(ta.ParameterError, match="solver=") as exc:
        ta.akvf(m, n=6, method="lanczos", remedy=PAPER)
    assert "\n" not in str(exc.value)
    with pytest.raises(TypeError, match="metod"):
        ta.akvf(m, n=6, metod="lanczos")
    c = ta.akvf(m, n=6, device="cpu", remedy=PAPER)
    assert c.batch.device.type == "cpu"
    with pytest.raises(ta.ParameterError, match="solver"):
        ta.akvf(m, n=6, solver="arpack")
    for bad in (True, 2.0, "6"):
        with pytest.raises(ta.ParameterError):
            ta.akvf(m, n=bad)


def test_default_remedy_is_the_one_everywhere():
    import inspect

    from torchakvf.operators import killing_operator
    from torchakvf.operators.killing import DEFAULT_REMEDY
    from torchakvf.parts import DEFAULT_REMEDY as parts_default
    assert DEFAULT_REMEDY == "auto" and parts_default is DEFAULT_REMEDY
    for fn in (ta.akvf, killing_operator):
        assert inspect.signature(fn).parameters["remedy"].default == DEFAULT_REMEDY, fn
    assert ta.SegmentOptions().remedy == DEFAULT_REMEDY     # segment's, through its options


# ---------------------------------------------------------------------------------------------
# CUDA and the PSB
# ---------------------------------------------------------------------------------------------

def test_cuda_matches_cpu(cuda):
    meshes = [mesh_of(shapes.icosphere(3)), mesh_of(shapes.flat_disk()), mesh_of(shapes.open_tube(n_around=36))]
    cpu = ta.akvf(ta.MeshBatch.from_meshes(meshes), n=10, remedy=PAPER)
    gpu = ta.akvf(ta.MeshBatch.from_meshes(meshes, device=cuda), n=10, remedy=PAPER)
    assert gpu.eigenvalues.device.type == "cuda" and gpu.forms.device.type == "cuda"
    assert gpu.face_vectors.device.type == "cuda"
    np.testing.assert_allclose(gpu.eigenvalues.cpu().numpy(), cpu.eigenvalues.numpy(),
                               rtol=1e-8, atol=1e-10)
    assert bool(gpu.converged.all())
    assert gpu.residuals.max().item() <= 1e-6
    for b in range(len(meshes)):
        assert gpu.mesh_face_vectors(b).shape == (meshes[b].n_faces, 10, 3)


#: Two of the smallest PSB meshes (about 3,100 and 3,700 faces) that converge quickly.
PSB_MESHES = ["52", "58"]


@pytest.mark.parametrize("mesh_id", PSB_MESHES)
def test_psb_smooth_remedy_matches_eigsh(psb, mesh_id):
    path = psb / "meshes" / f"{mesh_id}.off.gz"
    mesh = ta.load_mesh(path)
    with gzip.open(path, "rt") as fh:                 # face count as the file announces it
        header = [ln for ln in fh.read(200).split("\n") if ln.strip() and not ln.startswith("#")]
    assert mesh.n_faces == int(header[1].split()[1])
    n = 16
    res = ta.akvf(mesh, n=n, remedy="smooth")
    assert bool(res.converged.all()) and res.residuals.max().item() <= 1e-6
    R, s1 = scipy_matrices(res.system)
    assert abs(R - R.T).max() <= 1e-12 * abs(R).max()
    # eigsh's shift: below the spectrum (the definite factor's; ta.akvf's own may be interior)
    sigma = mesh_factor(res.system, 0, "mesh").sigma
    assert sigma <= float(res.shifts[0])
    v0 = np.random.default_rng(0).standard_normal(R.shape[0])
    n_dropped = int(res.dropped[0])
    lam_all = np.sort(spla.eigsh(R, k=n + n_dropped, M=sp.diags(s1).tocsc(), sigma=sigma, which="LM",
                                 v0=v0, tol=1e-12)[0])
    # The remedy skips exactly the spurious pairs below the threshold, and keeps the rest.
    from torchakvf.fields.akvf import SPURIOUS_BELOW
    assert int((lam_all < SPURIOUS_BELOW).sum()) == n_dropped
    lam_ref = lam_all[lam_all >= SPURIOUS_BELOW][:n]
    lam = res.eigenvalues[0].numpy()
    assert np.all(np.abs(lam - lam_ref) <= np.maximum(1e-6 * np.abs(lam_ref), 1e-8)), \
        np.c_[lam, lam_ref]
    # the shift is below the whole spectrum found
    assert sigma < lam_all[0]
