"""torchakvf.data: the Dataset over a ``torchakvf features`` folder and its packed collate."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.meshfiles import write_small_corpus
from helpers.runs import small_meshes

import torchakvf as ta
from torchakvf.errors import TorchAKVFError
from torchakvf.pipeline.features import FeaturesTask
from torchakvf.pipeline.inputs import discover_inputs
from torchakvf.pipeline.runner import run_corpus

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

N = 8


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    """A ``features`` run over a small corpus (its broken file fails)."""
    corpus = write_small_corpus(tmp_path_factory.mktemp("corpus"), degenerate_face=True)
    out = tmp_path_factory.mktemp("features")
    summary = run_corpus(discover_inputs([str(corpus)]), out, FeaturesTask(N), progress=False)
    assert (summary.ok, summary.failed) == (3, 1)
    return out


def test_feature_dataset_round_trip(reference):
    ds = ta.data.FeatureDataset(reference)
    assert len(ds) == 3 and [f.stem for f in ds.files] == ["dumb", "ell", "ico"]
    items = [ds[i] for i in range(len(ds))]
    for it in items:
        with np.load(reference / f"{it['name']}.npz", allow_pickle=False) as z:
            for key in ("vertices", "features", "akvf_norms", "descriptors", "eigenvalues", "residuals"):
                np.testing.assert_array_equal(it[key].numpy(), z[key])
            np.testing.assert_array_equal(it["faces"].numpy(), z["faces"])
        assert it["faces"].dtype == torch.int64 and it["params"]["n"] == N
    batch = ta.data.collate_packed(items)
    nv = [len(it["vertices"]) for it in items]
    nf = [len(it["faces"]) for it in items]
    assert batch["vert_ptr"].tolist() == np.concatenate([[0], np.cumsum(nv)]).tolist()
    assert batch["face_ptr"].tolist() == np.concatenate([[0], np.cumsum(nf)]).tolist()
    assert batch["vertices"].shape == (sum(nv), 3) and batch["features"].shape == (sum(nf), N)
    assert batch["eigenvalues"].shape == (3, N) and batch["names"] == ["dumb", "ell", "ico"]
    assert batch["descriptors"].shape == (sum(nf), 19) and items[0]["descriptor_names"][0] == "share1@8"
    for b, it in enumerate(items):
        f0, f1 = batch["face_ptr"][b], batch["face_ptr"][b + 1]
        v0 = batch["vert_ptr"][b]
        assert torch.equal(batch["faces"][f0:f1] - v0, it["faces"])
        assert torch.equal(batch["features"][f0:f1], it["features"])
        assert torch.equal(batch["vertices"][batch["faces"][f0:f1]], it["vertices"][it["faces"]])
        assert (batch["face_to_mesh"][f0:f1] == b).all()
    loader = torch.utils.data.DataLoader(ds, batch_size=2, collate_fn=ta.data.collate_packed)
    assert [len(b["names"]) for b in loader] == [2, 1]


def test_feature_dataset_without_manifest(reference, tmp_path):
    for stem in ("ico", "ell"):
        (tmp_path / f"{stem}.npz").write_bytes((reference / f"{stem}.npz").read_bytes())
    ds = ta.data.FeatureDataset(tmp_path)
    assert [it["name"] for it in ds] == ["ell", "ico"]


def _good_features(tmp_path) -> Path:
    paths = small_meshes(tmp_path / "in", names=("a",), level=2)
    out = tmp_path / "feats"
    run_corpus(paths, out, FeaturesTask(4), progress=False)
    return out


def test_feature_dataset_names_the_bad_file(tmp_path):
    out = _good_features(tmp_path)
    good = dict(ta.data.load_feature_file(out / "a.npz"))
    assert good["faces"].shape == (320, 3)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "t.npz").write_bytes((out / "a.npz").read_bytes()[:500])            # truncated
    mis = dict(good, features=np.zeros((10, 4), np.float32))                   # [10, n] beside [320, 3]
    np.savez(bad / "m.npz", **mis)
    few = {k: v for k, v in good.items() if k != "residuals"}
    np.savez(bad / "r.npz", **few)
    ds = ta.data.FeatureDataset(bad)
    for i, (name, problem) in enumerate([("m.npz", "features has shape [10, 4] beside faces [320, 3]"),
                                         ("r.npz", "missing array(s) residuals"),
                                         ("t.npz", "not a readable feature file")]):
        assert ds.files[i].name == name
        with pytest.raises(TorchAKVFError) as info:
            ds[i]
        assert str(bad / name) in str(info.value) and problem in str(info.value)
