"""torchakvf.pipeline.features: the ``features`` task (sizes refused up front, decimation, the
content cache)."""
from __future__ import annotations

import numpy as np
import pytest
from helpers.meshfiles import write_off
from helpers.runs import by_stem, cli_run, small_meshes

import torchakvf as ta
from torchakvf import shapes
from torchakvf.pipeline.features import FeaturesTask
from torchakvf.pipeline.runner import run_corpus

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

N = 8


def test_features_refuses_a_big_mesh_up_front(tmp_path, capsys):
    big = small_meshes(tmp_path / "in", names=("big",), level=2)[0]     # 320 faces
    out = tmp_path / "out"
    rc, stdout, err = cli_run(["features", big, "--out", out, "--n", "4", "--max-faces", "100"], capsys)
    assert rc == 1
    rec = by_stem(out)["big"]
    assert rec["status"] == "failed" and "seconds" in rec
    for part in (str(big), "320 faces", "--max-faces 100", "GB", "--coarse-faces"):
        assert part in rec["error"], rec["error"]
    assert "failed: " in stdout and "--coarse-faces" in stdout
    # Memory: the estimate against what the machine has (here a pretend 1 MB).
    task = FeaturesTask(4, memory_bytes=2**20)
    summary = run_corpus([big], tmp_path / "o2", task, progress=False)
    assert summary.failed == 1 and "more than the 0.0 GB of memory" in summary.failures[0][1]


def test_features_coarse_to_fine(tmp_path):
    s = shapes.ellipsoid(level=3)                                 # 1280 faces
    src = write_off(tmp_path / "in" / "e.off", s.vertices, s.faces)
    out = tmp_path / "out"
    summary = run_corpus([src], out, FeaturesTask(4, coarse_faces=300, max_faces=400), progress=False)
    assert summary.ok == 1, summary.failures                     # 300 solved faces: admitted
    z = ta.data.load_feature_file(out / "e.npz")
    assert z["features"].shape == (len(s.faces), 4) and np.all(z["features"].sum(1) > 0)
    assert z["descriptors"].shape == (len(s.faces), 19) and z["descriptor_names"][0] == "share1@4"
    rec = by_stem(out)["e"]
    assert rec["params"]["coarse_faces"] == 300 and isinstance(rec["converged"], bool)
    assert rec["converged"] == bool(np.all(z["residuals"] <= 1e-6)) == bool(z["converged"])
    assert rec["max_residual"] == pytest.approx(float(z["residuals"].max()))


def test_truncated_cache_entry_is_recomputed_not_copied(tmp_path):
    paths = small_meshes(tmp_path / "in", names=("a",))
    cache = tmp_path / "cache"
    first = run_corpus(paths, tmp_path / "o1", FeaturesTask(4, cache_dir=cache), progress=False)
    assert first.ok == 1
    (entry,) = cache.glob("*.npz")
    whole = entry.read_bytes()
    entry.write_bytes(whole[:300])
    second = run_corpus(paths, tmp_path / "o2", FeaturesTask(4, cache_dir=cache), progress=False)
    assert (second.ok, second.cached) == (1, 0)                  # not "ok (from cache)"
    assert (tmp_path / "o2" / "a.npz").read_bytes() == whole
    assert entry.read_bytes() == whole                           # the entry is whole again
    third = run_corpus(paths, tmp_path / "o3", FeaturesTask(4, cache_dir=cache), progress=False)
    assert third.cached == 1


def test_cache_makes_reruns_free(tmp_path):
    s = shapes.icosphere(1)
    src = write_off(tmp_path / "in" / "a.off", s.vertices, s.faces)
    cache = tmp_path / "cache"
    first = run_corpus([src], tmp_path / "o1", FeaturesTask(N, cache_dir=cache, face_vectors=True))
    assert first.ok == 1 and first.cached == 0 and len(list(cache.glob("*.npz"))) == 1
    with np.load(tmp_path / "o1" / "a.npz", allow_pickle=False) as z:   # --face-vectors
        assert z["face_vectors"].shape == (len(s.faces), N, 3) and z["face_vectors"].dtype == np.float32
        np.testing.assert_allclose(np.linalg.norm(z["face_vectors"], axis=-1), z["features"], rtol=1e-4, atol=1e-5)
    assert ta.data.FeatureDataset(tmp_path / "o1")[0]["face_vectors"].shape == (len(s.faces), N, 3)
    # Other parameters are another cache entry: not a hit.
    other = run_corpus([src], tmp_path / "o3", FeaturesTask(N, cache_dir=cache))
    assert other.cached == 0 and len(list(cache.glob("*.npz"))) == 2
    second = run_corpus([src], tmp_path / "o2", FeaturesTask(N, cache_dir=cache, face_vectors=True))
    assert second.ok == 1 and second.cached == 1
    assert (tmp_path / "o1" / "a.npz").read_bytes() == (tmp_path / "o2" / "a.npz").read_bytes()
    rec = by_stem(tmp_path / "o2")["a"]
    assert rec["cached"] is True and rec["status"] == "ok"


def test_features_checks_gpu_memory_on_a_gpu(tmp_path, monkeypatch):
    """On a GPU the estimate is the batched solve's arrays against the GPU's free memory (here a
    simulated 1 MiB), not host RAM; the error names the GPU."""
    import torch

    from torchakvf.pipeline.features import estimate_device_bytes

    monkeypatch.setattr(torch.cuda, "mem_get_info", lambda device=None: (2**20, 80 * 2**30))
    task = FeaturesTask(4, device="cuda")
    assert task.memory_bytes == 2**20
    with pytest.raises(ta.errors.TorchAKVFError, match="free on the GPU"):
        task.check_size("m.off", 320)
    assert estimate_device_bytes(320, 4) > 2**20 > estimate_device_bytes(10, 4) / 100
    FeaturesTask(4, device="cuda", memory_bytes=2**34).check_size("m.off", 320)    # fits


def test_features_file_holds_what_face_features_computes(tmp_path):
    """The ``features`` command and ``interop.face_features`` are one computation: on a mesh
    solved as it is, the file's untangled norms and descriptors are face_features' (float32).
    The ellipsoid's equal eigenvalues make the frame of the untangling's starts matter, so
    a path that started in another frame would give other columns here."""
    from torchakvf.interop import face_features
    from torchakvf.mesh import MeshBatch

    s = shapes.ellipsoid(level=2)                                 # 320 faces, solved as it is
    src = write_off(tmp_path / "in" / "e.off", s.vertices, s.faces)
    out = tmp_path / "out"
    summary = run_corpus([src], out, FeaturesTask(N, part_descriptors=False), progress=False)
    assert summary.ok == 1, summary.failures
    z = ta.data.load_feature_file(out / "e.npz")
    ref = face_features(MeshBatch.from_meshes([ta.load_mesh(src)]), N, part_descriptors=False)[0]
    assert list(z["descriptor_names"]) == ref.descriptor_names
    np.testing.assert_allclose(z["features"], ref.features, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(z["descriptors"], ref.descriptors, rtol=1e-4, atol=1e-5)
