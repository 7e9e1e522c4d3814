"""The AKVF solver object (torchakvf.solvers.akvf_solver, and the group solves of
torchakvf.solvers.group_solver it holds): factors kept across solves, the
solver chosen per mesh, a CPU batch solved one mesh at a time (the pieces add up to the
whole-batch computation), spurious modes re-solved per mesh, the Krylov -> Lanczos and
decimated -> full-resolution fallbacks, the advice in its errors."""
import warnings

import numpy as np
import pytest
import torch
from helpers.eigen_checks import METHODS, PAPER, clusters, mesh_of, s1_principal_cosines
from helpers.roundoff import residual_roundoff

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import ConvergenceWarning, FieldCountError
from torchakvf.fields.akvf import akvf_falling_back
from torchakvf.solvers import AKVFSolver, akvf_solver, group_solver, lobpcg
from torchakvf.solvers.akvf_solver import KRYLOV_MIN_EDGES, remedy_advice, solver_for
from torchakvf.solvers.remedy import killing_system

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)


@pytest.fixture(scope="module")
def meshes():
    return [ta.Mesh(s.vertices, s.faces, name=s.name)
            for s in (shapes.dumbbell(), shapes.hemisphere(), shapes.three_blobs(n_around=16))]


def test_concatenated_systems_are_the_batch_system(meshes):
    """R, S1 and the geometry of the meshes assembled one at a time, concatenated, against the
    whole batch assembled at once: the same sparsity, entries equal up to the round-off of
    summing a few terms in another order (relative 1e-12 of each mesh's largest entry)."""
    batch = ta.MeshBatch.from_meshes(meshes)
    whole = killing_system(batch)
    parts = ta.operators.KillingSystem.concatenate(
        [killing_system(batch.mesh(b)) for b in range(len(batch))], batch.edge_ptr)
    assert parts.stiffness.is_coalesced()
    assert torch.equal(parts.stiffness.indices(), whole.stiffness.indices())
    scale = whole.stiffness.values().abs().max()
    torch.testing.assert_close(parts.stiffness.values(), whole.stiffness.values(), rtol=0, atol=1e-12 * scale)
    torch.testing.assert_close(parts.mass, whole.mass, rtol=1e-13, atol=0)
    torch.testing.assert_close(parts.star1_raw, whole.star1_raw, rtol=1e-13, atol=1e-15)
    for name in ("points", "scale", "area", "face_area", "normal", "cot", "angle", "grad_bary"):
        torch.testing.assert_close(getattr(parts.geometry, name), getattr(whole.geometry, name),
                                   rtol=1e-12, atol=1e-12, msg=name)


def test_cpu_batch_is_each_mesh_alone_and_one_system(meshes):
    batch = ta.MeshBatch.from_meshes(meshes)
    res = ta.akvf(batch, n=12)
    assert res.batch is batch and res.system.n_meshes == len(meshes)
    assert torch.equal(res.system.edge_ptr, batch.edge_ptr)
    # Bitwise by construction: the CPU solves a batch one mesh at a time, each as a batch of
    # its own (ONE_MESH_AT_A_TIME_ON), so both sides make the same calls on the same shapes.
    for b, m in enumerate(meshes):
        one = ta.akvf(m, n=12)
        assert torch.equal(res.eigenvalues[b], one.eigenvalues[0])
        assert torch.equal(res.mesh_forms(b), one.forms)
        f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
        assert torch.equal(res.face_vectors[f0:f1], one.face_vectors)
        assert torch.equal(res.residuals[b], one.residuals[0])
    # The residuals stored are those of the concatenated system, recomputed here by another
    # product (the whole batch's): to residual_roundoff, the cancellation's round-off in
    # R w - λ S1 w (1.7e-10 seen on a residual of 8e-7 with AVX2 MKL, under 0.01 of the bound), far
    # below the solve's tol (1e-6).
    from torchakvf.solvers.lobpcg import relative_residuals
    again = relative_residuals(res.system, res.forms, res.eigenvalues)
    bound = residual_roundoff(res.system, res.forms, res.eigenvalues)
    assert ((again - res.residuals).abs() <= bound).all(), float(((again - res.residuals).abs() / bound).max())


def test_one_warning_names_every_unconverged_mesh(meshes):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = ta.akvf(ta.MeshBatch.from_meshes(meshes[:2]), n=8, tol=1e-30)
    conv = [w for w in caught if issubclass(w.category, ConvergenceWarning)]
    assert len(conv) == 1
    assert not bool(res.converged.any())
    for m in meshes[:2]:
        assert m.name in str(conv[0].message)
    assert conv[0].filename == __file__       # reported at the caller of akvf
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        AKVFSolver(meshes[:1]).solve(8, tol=1e-30)
    assert [w.filename for w in caught if issubclass(w.category, ConvergenceWarning)] == [__file__]


def test_untangled_fields_made_per_mesh_add_up_to_the_packed_arrays(meshes):
    fields = ta.akvf(ta.MeshBatch.from_meshes(meshes), n=12)
    ns = [8, 12, 10]
    unt = ta.untangle(fields, n=ns, seed=0, restarts=2)
    batch = fields.batch
    assert unt.features.shape == (int(batch.face_ptr[-1]), 12)
    assert unt.face_vectors.shape == (int(batch.face_ptr[-1]), 12, 3)
    assert unt.forms.shape == (int(batch.edge_ptr[-1]), 12)
    for b, n in enumerate(ns):
        f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
        e0, e1 = int(batch.edge_ptr[b]), int(batch.edge_ptr[b + 1])
        assert torch.equal(unt.features[f0:f1, :n], unt.mesh_features(b))
        assert not unt.features[f0:f1, n:].any() and not unt.face_vectors[f0:f1, n:].any()
        assert torch.equal(unt.face_vectors[f0:f1, :n], unt.mesh_face_vectors(b))
        assert torch.equal(unt.forms[e0:e1, :n], unt.mesh_forms(b))
        a = unt.rotation[b, :n, :n].double()
        # the definitions: raw fields rotated, features their norms, forms S1-orthonormal
        torch.testing.assert_close(unt.mesh_forms(b), fields.mesh_forms(b)[:, :n] @ a)
        torch.testing.assert_close(unt.mesh_features(b), unt.mesh_face_vectors(b).norm(dim=-1))
        gram = unt.mesh_forms(b).T @ (fields.system.mass[e0:e1, None] * unt.mesh_forms(b))
        torch.testing.assert_close(gram, torch.eye(n, dtype=gram.dtype), rtol=0, atol=1e-8)


@pytest.fixture(params=["one mesh at a time", "batched", "batched, block factor"])
def batch_path(request, monkeypatch):
    """The solver's ways through a batch on CPU: one mesh at a time (the CPU's), as one batch (the
    GPU's, run here on CPU), and as one batch whose LOBPCG is preconditioned by one
    block-diagonal factor (the GPU's default, run here on CPU)."""
    if request.param.startswith("batched"):
        monkeypatch.setattr(akvf_solver, "ONE_MESH_AT_A_TIME_ON", ())
    if request.param.endswith("block factor"):
        monkeypatch.setattr(lobpcg, "BLOCK_FACTOR_ON", ("cpu",))
    return request.param


@pytest.mark.parametrize("method", METHODS)
def test_batch_of_different_sizes_equals_each_alone(method, batch_path):
    meshes = [mesh_of(shapes.icosphere(3)), mesh_of(shapes.flat_disk()), mesh_of(shapes.open_tube(n_around=36)),
              mesh_of(shapes.dumbbell(n_around=36))]
    n = 10
    both = ta.akvf(meshes, n=n, solver=method, remedy=PAPER)
    assert both.eigenvalues.shape == (4, n) and bool(both.converged.all())
    assert both.forms.shape == (int(both.batch.edge_ptr[-1]), n)
    assert both.face_vectors.shape == (int(both.batch.face_ptr[-1]), n, 3)
    sizes = set()
    for b, m in enumerate(meshes):
        alone = ta.akvf(m, n=n, solver=method, remedy=PAPER)
        lam_b, lam_a = both.eigenvalues[b].numpy(), alone.eigenvalues[0].numpy()
        np.testing.assert_allclose(lam_b, lam_a, rtol=1e-9, atol=1e-11)
        fb, fa = both.mesh_forms(b).numpy(), alone.forms.numpy()
        s1 = alone.system.mass.numpy()
        for start, stop in clusters(lam_a):
            if stop == n:
                continue          # last cluster may be cut by n
            cos = s1_principal_cosines(fb[:, start:stop], fa[:, start:stop], s1)
            assert np.all(cos > 1 - 1e-6), (b, start, stop, cos)
        assert both.mesh_face_vectors(b).shape == (m.n_faces, n, 3)
        sizes.add(len(fa))
    assert len(sizes) == 4


def test_solver_error_never_suggests_what_was_tried():
    # A block whose every shift fails: R = -1e6 S1 (eigenvalues far below the last shift).
    from torchakvf.solvers.factor import ShiftedFactor
    n = 5
    idx = torch.arange(n)
    with pytest.raises(ta.SolverError) as exc:
        ShiftedFactor(idx, idx, torch.full((n,), -1e6, dtype=torch.float64), torch.ones(n, dtype=torch.float64))
    assert "remedy" not in str(exc.value)
    for remedy in ("none", "clamp", "smooth"):
        for decimated in (False, True):
            advice = remedy_advice(remedy, decimated)
            assert f"try remedy={remedy!r}" not in advice, (remedy, advice)
    assert "full resolution" in remedy_advice("smooth", True)
    assert "full resolution" not in remedy_advice("smooth", False)
    assert "try remedy='smooth'" in remedy_advice("none")


def test_spurious_mode_resolve_is_per_mesh(monkeypatch, batch_path):
    """A mesh needing room for more spurious modes is solved again alone: its mates keep the
    eigenpairs they get alone. Spurious modes are simulated by calling every eigenvalue below
    1 spurious, which makes the sphere's three rotations (λ ≈ 0.12) spurious, and one mode
    of the ellipsoid (λ ≈ -0.12), with room for one: only the sphere must be solved again."""
    monkeypatch.setattr(group_solver, "SPURIOUS_BELOW", 1.0)
    monkeypatch.setattr(group_solver, "SPURIOUS_MARGIN", 1)
    sphere, ell = mesh_of(shapes.icosphere(2), "sphere"), mesh_of(shapes.ellipsoid(level=3), "ellipsoid")
    for solver in ("lanczos", "lobpcg"):
        both = ta.akvf([ell, sphere], n=6, remedy="smooth", solver=solver)
        assert both.dropped.tolist() == [1, 3]
        assert both.solved.tolist() == [7, 6 + 1 + 2 + 1]               # the sphere: 2 short, +margin
        assert (both.eigenvalues[1] > 1.0).all()                   # the sphere's rotations skipped
        for b, m in enumerate((ell, sphere)):
            alone = ta.akvf(m, n=6, remedy="smooth", solver=solver)
            # Same count, same start: equal to round-off (the operator assembled in a batch
            # differs from the one assembled alone in the last bits).
            torch.testing.assert_close(both.eigenvalues[b], alone.eigenvalues[0], rtol=1e-9, atol=1e-9)
            assert both.eigenvalues.shape == (2, 6)
            assert int(both.dropped[b]) == int(alone.dropped[0])
            assert int(both.solved[b]) == int(alone.solved[0])
            # The ellipsoid's spectrum is simple: the same vectors up to sign.
            if b == 0:
                e = int(both.batch.edge_ptr[1])
                cos = (both.forms[:e] * alone.forms * alone.system.mass[:, None]).sum(0).abs()
                assert cos.min() > 1 - 1e-8, cos


def test_segmentation_does_not_depend_on_batch_mates_psb(psb):
    """PSB mesh 200 alone and beside mesh 353 (33 spurious modes under the default remedy, so it
    is solved again with more room): identical eigenvalues and labels (agreement threshold
    below 1 only for round-off ties on another BLAS)."""
    load = lambda i: ta.load_mesh(psb / "meshes" / f"{i}.off.gz")  # noqa: E731
    alone = ta.segment([load(200)], 4, coarse_faces=4000)[0]
    both = ta.segment([load(200), load(353)], 4, coarse_faces=4000)
    assert int(both.untangled.source.dropped[1]) > 8                 # the mate needs a re-solve
    np.testing.assert_allclose(both[0].eigenvalues, alone.eigenvalues, rtol=1e-9, atol=1e-9)
    assert both[0].params["n_fields"] == alone.params["n_fields"]
    agree = float((both[0].labels == alone.labels).mean())
    assert agree >= 0.999, agree


def test_psb_unsolvable_mesh_error_does_not_suggest_what_was_tried(psb, monkeypatch):
    """PSB mesh 351 decimated needs the shift -512 under "smooth" (the default); with the shifts
    cut to -1 and -8 it cannot be factored: the error names the mesh and what was tried, and
    suggests something else."""
    from torchakvf.solvers import factor
    monkeypatch.setattr(factor, "SHIFTS", (-1.0, -8.0))
    mesh = ta.load_mesh(psb / "meshes" / "351.off.gz")
    with pytest.raises(ta.SolverError) as exc:
        ta.akvf(ta.MeshBatch.from_meshes([mesh], coarse_faces=4000), n=20)
    text = str(exc.value)
    assert "351" in text and "remedy='smooth'" in text
    assert "try remedy='smooth'" not in text and "full resolution" in text


def test_auto_solver_is_block_krylov_on_large_cpu_meshes():
    assert solver_for("cpu") == "krylov"
    assert solver_for("cpu", KRYLOV_MIN_EDGES) == "krylov"
    assert solver_for("cpu", KRYLOV_MIN_EDGES - 1) == "lanczos"
    assert solver_for("cuda", 10 * KRYLOV_MIN_EDGES) == "lobpcg"
    r = ta.akvf(mesh_of(shapes.icosphere(2)), n=6, remedy=PAPER, solver="krylov")
    # Shift-invert right-hand sides, several per solve: far fewer than edges, at least one block.
    assert 6 <= int(r.iterations[0]) < len(r.batch.edges)


def test_auto_decides_per_mesh(monkeypatch):
    """With the threshold between two meshes' sizes, "auto" solves each with its own solver in
    one batch, and each gets what that solver gives it alone."""
    small, large = mesh_of(shapes.icosphere(2), "small"), mesh_of(shapes.icosphere(3), "large")
    e_small = ta.akvf(small, n=6, remedy=PAPER, solver="lanczos").batch.edges.shape[0]
    monkeypatch.setattr(akvf_solver, "KRYLOV_MIN_EDGES", e_small + 1)
    both = ta.akvf([small, large], n=6, remedy=PAPER)
    for b, (m, which) in enumerate(((small, "lanczos"), (large, "krylov"))):
        alone = ta.akvf(m, n=6, remedy=PAPER, solver=which)
        assert int(both.iterations[b]) == int(alone.iterations[0])
        np.testing.assert_allclose(both.eigenvalues[b].numpy(), alone.eigenvalues[0].numpy(),
                                   rtol=1e-9, atol=1e-11)


# ---------------------------------------------------------------------------------------------
# the solver object
# ---------------------------------------------------------------------------------------------

def equal_results(a, b) -> None:
    for name in ("eigenvalues", "forms", "face_vectors", "residuals", "iterations", "shifts", "converged",
                 "dropped", "solved"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name


@pytest.mark.parametrize("solver", ["auto", "lanczos", "krylov", "lobpcg"])
def test_solver_reuses_its_factors_and_gives_akvf_bits(solver, monkeypatch):
    """Two solves of one solver object (another n, another seed) give akvf's bits, and the
    second makes no new definite factor."""
    meshes = [mesh_of(shapes.table()), mesh_of(shapes.dumbbell(n_around=24))]
    made = []
    real = group_solver.mesh_factor
    monkeypatch.setattr(group_solver, "mesh_factor", lambda *a, **k: made.append(a[1]) or real(*a, **k))
    s = AKVFSolver(meshes, solver=solver)
    first = s.solve(12, seed=1)
    count = len(made)
    second = s.solve(8, seed=2)
    assert len(made) == count                       # the factors were kept
    equal_results(first, ta.akvf(meshes, n=12, seed=1, solver=solver))
    equal_results(second, ta.akvf(meshes, n=8, seed=2, solver=solver))
    assert first.batch is s.batch and second.n == 8


def test_solver_holds_the_batch_system_and_choice():
    small, large = mesh_of(shapes.icosphere(2), "small"), mesh_of(shapes.table(), "large")
    s = AKVFSolver([small, large])
    assert s.solvers == ["lanczos", "krylov"]
    assert s.system.n_meshes == 2 and torch.equal(s.system.edge_ptr, s.batch.edge_ptr)
    assert s.solve(6).system is s.system
    with pytest.raises(ta.ParameterError, match="solver"):
        AKVFSolver([small], solver="arpack")
    with pytest.raises(ta.ParameterError, match="remedy"):
        AKVFSolver([small], remedy="soft")
    with pytest.raises(ta.ParameterError):
        AKVFSolver([small]).solve(0)


def test_too_many_fields_is_a_field_count_error_without_advice():
    """A mesh with fewer edges than fields: a FieldCountError (a SolverError) saying so, with no
    remedy advice (no remedy helps), from every solver."""
    m = mesh_of(shapes.icosphere(1))                # 120 edges
    for solver in ("lanczos", "krylov", "lobpcg"):
        with pytest.raises(FieldCountError, match="fields asked for") as exc:
            ta.akvf(m, n=500, solver=solver)
        assert isinstance(exc.value, ta.SolverError) and "remedy" not in str(exc.value)


def test_krylov_not_converged_falls_back_to_lanczos(monkeypatch):
    """A mesh the block Krylov solver returns unconverged is solved by ARPACK on its definite
    factor: the result is Lanczos's, at the definite shift."""
    mesh = mesh_of(shapes.table())
    real = group_solver.block_krylov

    def stopped_early(*args, **kwargs):
        eig = real(*args, **kwargs)
        eig.converged[:] = False
        return eig

    monkeypatch.setattr(group_solver, "block_krylov", stopped_early)
    got = ta.akvf(mesh, n=8, solver="krylov")
    want = ta.akvf(mesh, n=8, solver="lanczos")
    assert bool(got.converged.all()) and float(got.shifts[0]) == -1.0
    torch.testing.assert_close(got.eigenvalues, want.eigenvalues, rtol=1e-9, atol=1e-9)


def test_decimated_mesh_that_fails_is_solved_at_full_resolution(monkeypatch):
    """A decimated mesh whose solve raises is found by solving each decimated mesh alone, and the
    batch is solved again with it at full resolution: the result is akvf's on that batch; its
    mates (one decimated, one never decimated) keep theirs; akvf itself raises, with advice."""
    sphere, disk = mesh_of(shapes.icosphere(4), "sphere"), mesh_of(shapes.flat_disk(), "disk")
    blob = mesh_of(shapes.three_blobs(n_around=24), "blobs")
    batch = ta.MeshBatch.from_meshes([sphere, disk, blob], coarse_faces=1000)
    assert batch.coarse_of(0) is not None and batch.coarse_of(1) is not None and batch.coarse_of(2) is None
    decimated_sphere_edges = int(batch.edge_ptr[1])
    real = group_solver.mesh_factor

    def refuse_the_decimated_sphere(system, b, name, **kw):
        if name == "sphere" and int(system.edge_ptr[b + 1] - system.edge_ptr[b]) == decimated_sphere_edges:
            raise ta.SolverError("sphere: no shift made R - σS1 positive definite")
        return real(system, b, name, **kw)

    monkeypatch.setattr(group_solver, "mesh_factor", refuse_the_decimated_sphere)
    with pytest.raises(ta.SolverError, match="full resolution"):
        ta.akvf(batch, n=6, solver="lanczos")
    s = AKVFSolver(batch, solver="lanczos")
    got = s.solve(6)
    assert [b for b, _ in s.fell_back] == [0] and "no shift" in s.fell_back[0][1]
    assert s.batch.coarse_of(0) is None and s.batch.coarse_of(1) is not None
    assert got.batch is s.batch and int(s.batch.edge_ptr[1]) == 7680     # icosphere(4)'s edges
    equal_results(got, ta.akvf(batch.at_full_resolution([0]), n=6, solver="lanczos"))
    again, fell_back = akvf_falling_back(batch, n=6, solver="lanczos")
    equal_results(again, got)
    assert fell_back == s.fell_back
    # a second solve of the solver object stays at full resolution, with nothing new to fall back
    assert s.solve(4).batch is s.batch and len(s.fell_back) == 1


def test_without_decimated_meshes_the_error_is_raised(monkeypatch):
    def refuse(system, b, name, **kw):
        raise ta.SolverError(f"{name}: no shift made R - σS1 positive definite")

    monkeypatch.setattr(group_solver, "mesh_factor", refuse)
    # (under remedy "auto" the sphere would keep the paper's operator, and with it the factor
    # its decision made: it has one by definition)
    with pytest.raises(ta.SolverError, match="no shift made"):
        akvf_falling_back(ta.MeshBatch.from_meshes([mesh_of(shapes.icosphere(2))]), n=6, solver="lanczos",
                          remedy="smooth")


# ---------------------------------------------------------------------------------------------
# a batch solved as one: each mesh's shift first, failures kept to their mesh
# ---------------------------------------------------------------------------------------------

def _edges(batch, b: int) -> int:
    return int(batch.edge_ptr[b + 1] - batch.edge_ptr[b])


def assert_mates_equal_alone(got, batch, mates, n, tol):
    """Each mate's eigenvalues as the per-mesh path gives them (each mesh alone, its own
    factor): both converge to residual <= tol = 1e-8, so eigenvalues agree to ~tol² over gaps
    of order 1; 1e-9 relative leaves room for clusters. Its shift is its own ladder's."""
    for b in mates:
        alone = ta.akvf(batch.mesh(b), n=n, tol=tol, solver="lobpcg", batched=False, remedy=got.remedies[b])
        torch.testing.assert_close(got.eigenvalues[b], alone.eigenvalues[0], rtol=1e-9, atol=1e-9)
        assert float(got.shifts[b]) == float(alone.shifts[0]), b


def test_batched_factor_takes_each_mesh_shift_first(monkeypatch):
    """A batch whose meshes need different shifts (the sliver sphere -64, its mates -1: a disk and a tube), solved
    as one: each mesh's own ladder runs once, then one factor of the whole batch at the shifts
    found, never a trial of the whole batch at -1 first; each mesh's eigenvalues and shift are
    the per-mesh path's."""
    from helpers.eigen_checks import SolveLog, sliver_sphere
    meshes = [mesh_of(shapes.flat_disk(), "disk"), sliver_sphere(), mesh_of(shapes.open_tube(n_around=24), "tube")]
    batch = ta.MeshBatch.from_meshes(meshes)
    log = SolveLog(monkeypatch)
    # remedy "smooth" on every mesh: the shifts of the remedied operator are the subject here,
    # and "auto" would add each mesh's decision factor to the log
    got = ta.akvf(batch, n=8, tol=1e-8, batched=True, remedy="smooth")
    total = int(batch.edge_ptr[-1])
    assert log.sizes.count(total) == 1                       # one block factor, no trial
    # each mesh's own ladder, once: -1 for the mates, -1, -8, -64 for the sliver
    assert [log.sizes.count(_edges(batch, b)) for b in range(3)] == [1, 3, 1]
    assert got.shifts.tolist() == [-1.0, -64.0, -1.0]
    assert bool(got.converged.all())
    assert_mates_equal_alone(got, batch, range(3), 8, 1e-8)


def test_unsolvable_mesh_leaves_its_batch(monkeypatch):
    """With the ladder cut at -8 the sliver sphere cannot be solved (and was not decimated):
    the batch raises its SolverError (naming it, ``failed_meshes`` [1]) after the meshes' own
    ladders only, before any batch work (no block factor, no LOBPCG call): a caller can solve
    the mates again without it."""
    from helpers.eigen_checks import SolveLog, sliver_sphere

    from torchakvf.solvers import factor
    monkeypatch.setattr(factor, "SHIFTS", (-1.0, -8.0))
    meshes = [mesh_of(shapes.icosphere(2), "ico"), sliver_sphere(), mesh_of(shapes.open_tube(n_around=24), "tube")]
    batch = ta.MeshBatch.from_meshes(meshes)
    log = SolveLog(monkeypatch)
    with pytest.raises(ta.SolverError, match="sliver") as exc:
        ta.akvf(batch, n=8, batched=True, remedy="smooth")
    assert exc.value.failed_meshes == [1]
    assert log.groups == []
    assert log.sizes == [_edges(batch, 0), _edges(batch, 1), _edges(batch, 1), _edges(batch, 2)]


def test_decimated_mesh_that_fails_is_solved_alone_at_full_resolution(monkeypatch):
    """A decimated mesh with no shift leaves the batch: its mates are solved once, together;
    it is solved alone at full resolution (its edges never pad theirs) and takes its place in
    batch order. A second solve keeps it alone."""
    from helpers.eigen_checks import SolveLog
    sphere, disk = mesh_of(shapes.icosphere(4), "sphere"), mesh_of(shapes.flat_disk(), "disk")
    blob = mesh_of(shapes.three_blobs(n_around=24), "blobs")
    batch = ta.MeshBatch.from_meshes([sphere, disk, blob], coarse_faces=1000)
    decimated_sphere_edges = _edges(batch, 0)
    real = group_solver.mesh_shift

    def refuse_the_decimated_sphere(system, b, name):
        if name == "sphere" and int(system.edge_ptr[b + 1] - system.edge_ptr[b]) == decimated_sphere_edges:
            raise ta.SolverError("sphere: no shift made R - σS1 positive definite")
        return real(system, b, name)

    monkeypatch.setattr(group_solver, "mesh_shift", refuse_the_decimated_sphere)
    log = SolveLog(monkeypatch)
    s = AKVFSolver(batch, batched=True)
    got = s.solve(8, tol=1e-8)
    assert [b for b, _ in s.fell_back] == [0] and "full resolution" in s.fell_back[0][1]
    assert log.groups == [["disk", "blobs"], ["sphere"]]
    assert _edges(s.batch, 0) == 7680 and got.batch is s.batch
    s.solve(6, tol=1e-8)
    assert log.groups[2:] == [["sphere"], ["disk", "blobs"]]
    assert_mates_equal_alone(got, s.batch, [0, 1, 2], 8, 1e-8)


def test_a_batch_failing_for_no_known_mesh_is_bisected(monkeypatch):
    """A group solve that fails without a mesh known beforehand (a device error, simulated on
    the LOBPCG call of any group holding "bad") is split in halves, not singletons: 5 calls
    for 4 meshes, and the error names the mesh and lists it in ``failed_meshes``."""
    names = ["a", "b", "bad", "c"]
    meshes = [mesh_of(shapes.icosphere(1), x) for x in names]
    calls = []
    real = group_solver.segmented_lobpcg

    def failing(system, n, **kw):
        calls.append(kw["names"])
        if "bad" in kw["names"]:
            raise ta.SolverError(f"{', '.join(kw['names'])}: the device's solve failed its check")
        return real(system, n, **kw)

    monkeypatch.setattr(group_solver, "segmented_lobpcg", failing)
    with pytest.raises(ta.SolverError, match="bad") as exc:
        ta.akvf(meshes, n=6, batched=True)
    assert exc.value.failed_meshes == [2]
    assert calls == [names, ["a", "b"], ["bad", "c"], ["bad"], ["c"]]


def test_psb_114_leaves_its_batch(psb, monkeypatch):
    """PSB meshes decimated to 2000 faces that need -1, -64, -512 and none (114: no shift makes
    it definite), solved as one batch: one block factor of the four mates at their own shifts,
    114 alone at full resolution; each mate's eigenvalues and shift are the per-mesh path's."""
    from helpers.eigen_checks import SolveLog
    ids = [1, 241, 181, 114, 21]
    meshes = [ta.load_mesh(psb / "meshes" / f"{i}.off.gz") for i in ids]
    batch = ta.MeshBatch.from_meshes(meshes, coarse_faces=2000)
    log = SolveLog(monkeypatch)
    s = AKVFSolver(batch, batched=True)
    got = s.solve(8, tol=1e-8)
    assert [b for b, _ in s.fell_back] == [3]
    mates = [0, 1, 2, 4]
    assert log.sizes.count(sum(_edges(batch, b) for b in mates)) == 1
    assert int(batch.edge_ptr[-1]) not in log.sizes
    name = s.batch.names[3]
    assert [name] in log.groups and all(g == [name] for g in log.groups if name in g)   # 114 alone
    assert got.shifts[[0, 1, 2, 4]].tolist() == [-1.0, -64.0, -512.0, -1.0]
    assert_mates_equal_alone(got, s.batch, mates, 8, 1e-8)
