"""Device tests, named for the device: they cover every stage, so no one module's file fits them.

Each stage on a device against the CPU result: operators, AKVFs, untangling, k-means, parts,
the corpus runner (segment and features) and the bench.

Every test takes the ``device`` fixture (tests/conftest.py): it runs on "cpu" everywhere, so the
comparison logic below is exercised in CI (CPU against CPU), and on "cuda" where torch sees a
GPU (that parameter is marked ``cuda``; benchmarks/device_check.sh runs ``pytest -m cuda``).

Each stage is given the CPU's inputs (moved to the device), so a difference is that stage's own.
Tolerances come from the problems' conditioning, not from what one run happened to give:
- operators: float64 assembly of the same float64 (or float32-rounded) coordinates; only the
  summation order may differ, so entries agree to 1e-12 of the largest.
- AKVFs: on CUDA the default solver is LOBPCG, on CPU Lanczos; both stop at residual <= tol.
  For a symmetric-definite pencil each computed λ lies within its residual of an eigenvalue, so
  the two λ_i differ by at most r_i(cpu) + r_i(dev) (residuals relative to max(|λ|, 1)); the
  subspaces of the first m fields, cut at an eigenvalue gap δ, differ by an angle of at most
  (‖r_cpu‖ + ‖r_dev‖) / δ (Davis-Kahan). Single eigenvectors are not compared: the shapes are
  rotationally symmetric, and a basis of a repeated eigenvalue is arbitrary.
- untangling (float32 iterations, float64 polish) and k-means: tests/test_precision.py showed
  that round-off moves neither the optimum nor the labels on three_blobs (a well-separated
  optimum); the same tolerances are used here (objective 1e-4, features 1e-4 of the largest,
  labels 99 %).
- segmentation end to end: the device's solver can return another basis of a degenerate
  eigenspace, and untangling starts from it, so labels are compared up to a renaming of the
  parts (>= 98 % of the faces, on shapes whose parts are clear); basis-free quantities
  (eigenvalues; Σ_j feature_j², which an orthogonal rotation of a field subspace cut at a gap
  keeps) are compared tightly.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
from helpers.meshfiles import write_off, write_seg

import torchakvf as ta
from torchakvf import shapes
from torchakvf.cli import main
from torchakvf.cluster import spherical_kmeans
from torchakvf.evaluate.metrics import matched_agreement
from torchakvf.fields.akvf import solver_for
from torchakvf.mesh.batch import pad_packed
from torchakvf.solvers.remedy import killing_system

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

TOL = 1e-6                  # akvf's residual tolerance
N = 16                      # fields untangled (as test_precision.py)


def _shapes():
    """Two small built-in shapes with clear parts: three_blobs (3 parts), dumbbell (2)."""
    return [("three_blobs", shapes.three_blobs(n_around=24)), ("dumbbell", shapes.dumbbell(n_around=24))]


def _meshes():
    return [ta.Mesh(s.vertices, s.faces, name=n) for n, s in _shapes()]


def on_device(obj, device):
    """A result dataclass (AKVFResult, KillingSystem, ...) with every tensor moved to ``device``."""
    if isinstance(obj, torch.Tensor):
        return obj.to(device)
    if isinstance(obj, ta.MeshBatch):
        return obj.to(device)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return type(obj)(**{f.name: on_device(getattr(obj, f.name), device)
                            for f in dataclasses.fields(obj)})
    return obj


def _on(t: torch.Tensor, device: torch.device) -> None:
    assert t.device.type == device.type, (t.device, device)


@pytest.fixture(scope="module")
def cpu_fields():
    """The CPU's AKVFs (default solver, float64) of the two shapes: the reference."""
    return ta.akvf(ta.MeshBatch.from_meshes(_meshes()), n=20)


# ---- operators ---------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_killing_operator_entries(device, dtype):
    ref = killing_system(ta.MeshBatch.from_meshes(_meshes(), dtype=dtype))
    got = killing_system(ta.MeshBatch.from_meshes(_meshes(), device=device, dtype=dtype))
    _on(got.stiffness, device), _on(got.mass, device)
    rs, gs = ref.stiffness.coalesce(), got.stiffness.coalesce().cpu()
    assert rs.dtype == gs.dtype == torch.float64        # assembled in float64 from any coordinates
    assert rs.shape == gs.shape
    # The difference as a sparse matrix: a sparse product on the device may keep or drop
    # entries that cancel to zero, so the patterns are compared through the values.
    scale = rs.values().abs().max()
    assert (rs - gs).coalesce().values().abs().max() <= 1e-12 * scale
    assert gs.values().numel() <= 1.1 * rs.values().numel() and rs.values().numel() <= 1.1 * gs.values().numel()
    for name in ("mass", "star1_raw", "edge_ptr"):
        a, b = getattr(ref, name), getattr(got, name).cpu()
        assert torch.allclose(a, b, rtol=1e-12, atol=0), name
    assert torch.allclose(ref.geometry.face_area, got.geometry.face_area.cpu(), rtol=1e-12, atol=0)


# ---- AKVFs -------------------------------------------------------------------------------

def _gap_cut(lam: np.ndarray, lo: int, hi: int) -> tuple[int, float]:
    """(m, δ): the m in [lo, hi) with the largest gap δ = λ_m - λ_{m-1} (1-based count m)."""
    gaps = lam[lo:hi] - lam[lo - 1:hi - 1]
    j = int(np.argmax(gaps))
    return lo + j, float(gaps[j])


def assert_same_akvfs(ref, got, n_cmp: int | None = None) -> None:
    """Eigenvalues within the residual bound and field subspaces (cut at a gap) within the
    Davis-Kahan bound, per mesh; ``ref`` and ``got`` solve the same meshes."""
    assert bool(got.converged.all()) and float(got.residuals.max()) <= TOL
    n = n_cmp or min(ref.n, got.n)
    lam_r, lam_g = ref.eigenvalues[:, :n].double().cpu(), got.eigenvalues[:, :n].double().cpu()
    res_r, res_g = ref.residuals[:, :n].cpu(), got.residuals[:, :n].cpu()
    bound = (res_r + res_g) * lam_r.abs().clamp(min=1.0) + 1e-10
    assert ((lam_r - lam_g).abs() <= bound).all(), (lam_r - lam_g).abs().max()
    mass = ref.system.mass.double().cpu()
    for b in range(len(ref.batch)):
        m, gap = _gap_cut(lam_r[b].numpy(), 2, n)
        lo, hi = int(ref.batch.edge_ptr[b]), int(ref.batch.edge_ptr[b + 1])
        wr = ref.forms[lo:hi, :m].double().cpu()
        wg = got.forms[lo:hi, :m].double().cpu()
        s = mass[lo:hi, None]
        # sin of the largest principal angle (S1 inner product; both bases S1-orthonormal):
        # the part of wg outside span(wr), without the cancellation of sqrt(1 - cos²).
        outside = wg - wr @ (wr.T @ (s * wg))
        sin = float(torch.linalg.matrix_norm(s.sqrt() * outside, ord=2))
        scale = float(lam_r[b, :m].abs().clamp(min=1.0).max())
        dk = float((res_r[b, :m].norm() + res_g[b, :m].norm()) * scale / gap)
        rounding = 10 * m * torch.finfo(got.forms.dtype).eps    # forms stored in the batch's dtype
        assert sin <= 10 * dk + rounding, (b, m, sin, dk)


def test_akvf_default_solver(device, cpu_fields):
    got = ta.akvf(_meshes(), n=20, device=device)
    _on(got.eigenvalues, device), _on(got.forms, device), _on(got.face_vectors, device)
    assert got.eigenvalues.dtype == torch.float64
    assert_same_akvfs(cpu_fields, got)


def test_akvf_lobpcg_and_float32_coordinates(device):
    """LOBPCG on both (the solver "auto" picks on a GPU), from float32 coordinates: the
    operator and solve are float64, results come back in float32."""
    ref = ta.akvf(ta.MeshBatch.from_meshes(_meshes(), dtype=torch.float32), n=12, solver="lobpcg")
    got = ta.akvf(ta.MeshBatch.from_meshes(_meshes(), device=device, dtype=torch.float32), n=12,
                  solver="lobpcg")
    assert got.eigenvalues.dtype == got.forms.dtype == torch.float32
    _on(got.forms, device)
    assert_same_akvfs(ref, got)


def test_lobpcg_block_factor_against_per_mesh_factors(device):
    """The batched LOBPCG's preconditioner on the device: one block-diagonal factor of the
    batch (the CUDA default: one solve call per iteration) against one factor per mesh on the
    CPU. Both are exact shift-inverts, so the eigenpairs agree within the residual bounds above."""
    from torchakvf.solvers.lobpcg import segmented_lobpcg
    batch = ta.MeshBatch.from_meshes(_meshes())
    ref = segmented_lobpcg(killing_system(batch), 12, block_factor=False)
    got = segmented_lobpcg(killing_system(batch.to(device)), 12, block_factor=True)
    assert bool(ref.converged.all()) and bool(got.converged.all())
    _on(got.vectors, device)
    assert got.shifts.tolist() == ref.shifts.tolist()
    bound = ref.residuals + got.residuals.cpu()
    lam_ref, lam = ref.eigenvalues, got.eigenvalues.cpu()
    assert bool(((lam - lam_ref).abs() <= bound * lam_ref.abs().clamp(min=1.0) + 1e-12).all())


def test_device_solver_on_cpu_within_the_same_bounds(cpu_fields):
    """The solver a GPU picks (LOBPCG), run on the CPU, against the CPU's default (Lanczos):
    a real difference of bases, checked here with the bounds the device tests use, and the
    basis-free Σ_j feature_j² of the untangled fields (n cut at a gap) equal on both."""
    assert solver_for(torch.device("cuda")) == "lobpcg"
    got = ta.akvf(_meshes(), n=20, solver="lobpcg")
    assert_same_akvfs(cpu_fields, got)
    for b in range(len(cpu_fields.batch)):
        n, _ = _gap_cut(cpu_fields.eigenvalues[b].numpy(), 4, 17)
        sub = [on_mesh(cpu_fields, b), on_mesh(got, b)]
        sa, sb = ((ta.untangle(f, n=n, seed=0).mesh_features(0).double() ** 2).sum(1) for f in sub)
        assert torch.allclose(sa, sb, rtol=1e-6, atol=1e-9 * float(sa.max())), (b, n)


def on_mesh(fields, b: int):
    """The AKVFs of mesh b alone (a batch of one), from a batch's result."""
    batch = ta.MeshBatch.from_meshes([fields.batch.meshes[b]], device=fields.batch.device,
                                     dtype=fields.batch.dtype)
    e0, e1 = int(fields.batch.edge_ptr[b]), int(fields.batch.edge_ptr[b + 1])
    f0, f1 = int(fields.batch.face_ptr[b]), int(fields.batch.face_ptr[b + 1])
    system = killing_system(batch)
    return dataclasses.replace(
        fields, eigenvalues=fields.eigenvalues[b:b + 1], forms=fields.forms[e0:e1],
        face_vectors=fields.face_vectors[f0:f1], residuals=fields.residuals[b:b + 1],
        iterations=fields.iterations[b:b + 1], shifts=fields.shifts[b:b + 1],
        converged=fields.converged[b:b + 1], dropped=fields.dropped[b:b + 1], batch=batch,
        system=system, solved=None if fields.solved is None else fields.solved[b:b + 1])


# ---- untangling --------------------------------------------------------------------------

@pytest.mark.parametrize("iteration_dtype", [torch.float32, torch.float64])
def test_untangle_features(device, cpu_fields, iteration_dtype):
    ref = ta.untangle(cpu_fields, n=N, seed=0, iteration_dtype=iteration_dtype)
    got = ta.untangle(on_device(cpu_fields, device), n=N, seed=0, iteration_dtype=iteration_dtype)
    _on(got.features, device), _on(got.rotation, device)
    rel = (got.score.cpu() / ref.score - 1).abs()
    assert (rel < 1e-4).all(), rel
    # three_blobs (mesh 0): a well-separated optimum, the same fields up to order and sign.
    cos = (ref.rotation[0].T @ got.rotation[0].cpu()).abs().max(dim=1).values
    assert cos.min() > 1 - 1e-6, cos.min()
    fa, fb = ref.mesh_features(0), got.mesh_features(0).cpu()
    assert (fa - fb).abs().max() < 1e-4 * fa.abs().max()
    # Basis-free on every mesh: Σ_j |X_j(f)|² is the same for any rotation of the fields.
    for b in range(len(cpu_fields.batch)):
        sa = (ref.mesh_features(b).double() ** 2).sum(1)
        sb = (got.mesh_features(b).double().cpu() ** 2).sum(1)
        assert torch.allclose(sa, sb, rtol=1e-9, atol=1e-12 * float(sa.max())), b


# ---- spherical k-means -------------------------------------------------------------------

def _lloyd_fixed_point(x, mask, res, ks) -> bool:
    """Centers are the normalized means of their clusters and rows sit at their nearest center
    (float64, on the CPU)."""
    xn = torch.nn.functional.normalize(x.double(), dim=-1)
    for b, k in enumerate(ks):
        rows, lab, c = xn[b][mask[b]], res.labels[b][mask[b]].cpu(), res.centers[b, :k].double().cpu()
        means = torch.nn.functional.normalize(torch.zeros_like(c).index_add_(0, lab, rows), dim=-1)
        if not torch.allclose(means, c, atol=1e-10) or not bool(((rows @ c.T).argmax(1) == lab).all()):
            return False
    return True


@pytest.mark.parametrize("ks", [[3, 2], [5, 4]])
def test_spherical_kmeans_labels_and_cost(device, cpu_fields, ks):
    unt = ta.untangle(cpu_fields, n=N, seed=0)
    x, mask = pad_packed(unt.features.double(), cpu_fields.batch.face_ptr)
    ref = spherical_kmeans(x, mask, ks, seed=0, restarts=10)
    got = spherical_kmeans(x.to(device), mask.to(device), ks, seed=0, restarts=10)
    _on(got.labels, device), _on(got.cost, device)
    assert _lloyd_fixed_point(x, mask, got, ks)
    assert torch.allclose(ref.cost, got.cost.cpu(), rtol=1e-4)
    for b in range(len(ks)):
        agree = matched_agreement(got.labels[b][mask[b].to(device)].cpu().numpy(),
                                  ref.labels[b][mask[b]].numpy())
        assert agree >= 0.99, (b, agree)


# ---- parts (segmentation end to end) -----------------------------------------------------

@pytest.fixture(scope="module")
def cpu_segments():
    ks = [s.n_parts for _, s in _shapes()]
    return ks, ta.segment(_meshes(), k=ks, seed=0)


def _assert_same_parts(ref, got, min_agree=0.98, eig_tol=2e-6):
    for a, b in zip(ref.meshes, got.meshes):
        assert b.converged and b.labels.shape == a.labels.shape
        assert len(set(b.labels.tolist()) - {-1}) == len(set(a.labels.tolist()) - {-1}), a.name
        agree = matched_agreement(b.labels, a.labels)
        assert agree >= min_agree, (a.name, agree)
        np.testing.assert_allclose(b.eigenvalues, a.eigenvalues, rtol=eig_tol, atol=eig_tol)


def test_segment_labels(device, cpu_segments):
    ks, ref = cpu_segments
    got = ta.segment(_meshes(), k=ks, seed=0, device=device)
    _on(got.untangled.features, device)
    _assert_same_parts(ref, got)


def test_segment_float32_batch(device, cpu_segments):
    """A float32 batch on the device (coordinates rounded to float32; the solve is float64)."""
    ks, ref = cpu_segments
    batch = ta.MeshBatch.from_meshes(_meshes(), device=device, dtype=torch.float32)
    got = ta.segment(batch, k=ks, seed=0)
    assert got.untangled.features.dtype == torch.float32
    # float32 coordinates move the paper operator's eigenvalues (these clean shapes get it) by
    # up to 6e-6 here: the float32 bound of docs/design.md#precision is 1e-4
    _assert_same_parts(ref, got, eig_tol=1e-4)


# ---- the corpus runner -------------------------------------------------------------------

@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    root = tmp_path_factory.mktemp("corpus")
    for name, s in _shapes():
        write_off(root / f"{name}.off", s.vertices, s.faces)
    return root


def _cli_segment(corpus, out, device) -> None:
    assert main(["segment", str(corpus), "-k", "3", "--out", str(out), "--device", str(device),
                 "--formats", "seg,npz", "--seed", "0"]) == 0


@pytest.fixture(scope="module")
def cpu_segment_run(corpus, tmp_path_factory):
    out = tmp_path_factory.mktemp("seg_cpu")
    _cli_segment(corpus, out, "cpu")
    return out


def test_corpus_segment_on_device(device, corpus, cpu_segment_run, tmp_path):
    out = tmp_path / "seg"
    _cli_segment(corpus, out, device)
    recs = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines()]
    assert sorted(r["status"] for r in recs) == ["ok", "ok"]
    for name, _ in _shapes():
        a = np.loadtxt(cpu_segment_run / f"{name}.seg", dtype=np.int64)
        b = np.loadtxt(out / f"{name}.seg", dtype=np.int64)
        assert len(a) == len(b) and matched_agreement(b, a) >= 0.98, name
        za, zb = np.load(cpu_segment_run / f"{name}.npz"), np.load(out / f"{name}.npz")
        np.testing.assert_allclose(zb["eigenvalues"], za["eigenvalues"], rtol=2e-6, atol=2e-6)


def test_corpus_features_on_device(device, corpus, cpu_fields, tmp_path):
    """``torchakvf features --device``: eigenvalues, and the basis-free Σ_j feature_j² per face
    (n cut at a gap of three_blobs' spectrum), equal to the CPU run's."""
    lam = cpu_fields.eigenvalues[0].numpy()
    n, _ = _gap_cut(lam, 4, 16)
    src = corpus / "three_blobs.off"
    outs = {}
    for dev in ("cpu", str(device)):
        outs[dev] = tmp_path / f"feat_{dev.replace(':', '_')}"
        assert main(["features", str(src), "--out", str(outs[dev]), "--n", str(n),
                     "--device", dev, "--seed", "0"]) == 0
    za = np.load(outs["cpu"] / "three_blobs.npz")
    zb = np.load(outs[str(device)] / "three_blobs.npz")
    assert bool(zb["converged"])
    bound = (za["residuals"] + zb["residuals"]) * np.maximum(np.abs(za["eigenvalues"]), 1) + 1e-10
    assert (np.abs(za["eigenvalues"] - zb["eigenvalues"]) <= bound).all()
    for key in ("features", "akvf_norms"):
        sa = (za[key].astype(np.float64) ** 2).sum(1)
        sb = (zb[key].astype(np.float64) ** 2).sum(1)
        # features are stored as float32: 1e-6 relative, and the subspace angle (<= 1e-5 here)
        np.testing.assert_allclose(sb, sa, rtol=1e-4, atol=1e-6 * sa.max(), err_msg=key)


# ---- the bench ---------------------------------------------------------------------------

def test_bench_on_device(device, tmp_path):
    """``torchakvf bench --device``: the runs happen there (CUDA: peak memory reported)."""
    d = shapes.dumbbell(n_around=12)
    root = tmp_path / "psb"
    write_off(root / "meshes" / "1.off", d.vertices, d.faces)
    write_seg(root / "gt" / "1" / "1_0.seg", d.part_labels)
    out = tmp_path / "bench"
    assert main(["bench", "--psb", str(root), "--out", str(out), "--device", str(device),
                 "--baseline-every", "1", "--workers", "1"]) == 0
    r = json.loads((out / "report.json").read_text())
    assert r["settings"]["device"] == str(device)
    for name in ("batched", "one_at_a_time", "batched_subset"):
        run = r["runs"][name]
        assert run["device"] == str(device) and run["meshes_ok"] == 1 and not run["failed"]
        peak = run["cuda_max_memory_allocated_mib"]
        assert (peak is None) if device.type == "cpu" else (peak > 0), (name, peak)
    if device.type == "cuda":
        assert r["environment"]["cuda_device"]


# ---- a device this machine cannot use: one package error, before any work ------------------

def _unusable_devices():
    """(device, words the error must contain): an unknown name, a type the package does not
    support, and CUDA where there is none (or an index beyond the GPUs present)."""
    out = [("tpu9", "is not a torch device"), ("mps", "only cpu and cuda"), ("meta", "only cpu and cuda")]
    if torch.cuda.is_available():
        out.append((f"cuda:{torch.cuda.device_count()}", "CUDA device(s)"))
    else:
        out += [("cuda", "CUDA is not available"), ("cuda:1", "CUDA is not available")]
    return out


@pytest.mark.parametrize("bad,words", _unusable_devices())
def test_unusable_device_is_a_parameter_error(bad, words, tmp_path):
    from torchakvf.evaluate.harness import evaluate_psb
    from torchakvf.pipeline.runner import run_corpus
    from torchakvf.pipeline.segment_task import SegmentTask

    mesh = _meshes()[1]
    calls = {"akvf": lambda: ta.akvf(mesh, n=8, device=bad),
             "segment": lambda: ta.segment(mesh, k=2, device=bad),
             "MeshBatch.to": lambda: ta.MeshBatch.from_meshes([mesh]).to(bad),
             "run_corpus": lambda: run_corpus([], tmp_path / "o", SegmentTask(2), device=bad),
             "evaluate_psb": lambda: evaluate_psb(tmp_path / "psb", tmp_path / "e", device=bad)}
    for name, call in calls.items():
        with pytest.raises(ta.ParameterError) as info:
            call()
        assert words in str(info.value) and bad in str(info.value), (name, str(info.value))
    assert not (tmp_path / "o").exists() and not (tmp_path / "e").exists()   # nothing started


@pytest.mark.parametrize("command", ["segment", "features", "eval", "bench"])
def test_unusable_device_on_the_cli_is_one_line(command, corpus, tmp_path, capsys):
    from helpers.faketask import assert_one_line_error

    bad, words = _unusable_devices()[-1]
    psb = tmp_path / "psb"
    (psb / "meshes").mkdir(parents=True)
    args = {"segment": ["segment", str(corpus), "-k", "2"], "features": ["features", str(corpus)],
            "eval": ["eval", "--psb", str(psb)], "bench": ["bench", "--psb", str(psb)]}[command]
    assert main(args + ["--out", str(tmp_path / "o"), "--device", bad]) == 2
    assert_one_line_error(capsys.readouterr().err, "--device", bad, words)
    assert not (tmp_path / "o").exists()


def test_device_spellings():
    from torchakvf.devices import resolve_device

    assert resolve_device(None) == resolve_device("cpu") == resolve_device(" cpu ") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    assert resolve_device("cuda:1", check_available=False) == torch.device("cuda", 1)
    assert resolve_device(2, check_available=False) == torch.device("cuda", 2)   # torch's int
    with pytest.raises(ta.ParameterError, match="must be a str or torch.device"):
        resolve_device(1.5)


@pytest.mark.parametrize("script", ["device_check.sh", "device_prepare.sh"])
def test_device_scripts_parse(script):
    """The GPU check runs once on a lent machine: a syntax error there costs the whole loan."""
    import shutil
    import subprocess
    from pathlib import Path

    if shutil.which("bash") is None:
        pytest.skip("no bash")
    path = Path(__file__).resolve().parents[1] / "benchmarks" / script
    run = subprocess.run(["bash", "-n", str(path)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
