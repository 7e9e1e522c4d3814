"""Writing results: the .seg writer checks its labels and writes atomically."""
from __future__ import annotations

import gzip

import numpy as np
import pytest

import torchakvf as ta
from torchakvf import shapes


def test_write_seg_is_checked(tmp_path):
    for bad, problem in [(np.array([0.5, 1.0]), "must be integers"), (np.array([True]), "must be integers"),
                         (np.zeros((2, 2), int), "1-D"), (np.array([], int), "non-empty")]:
        with pytest.raises(ta.errors.ParameterError, match=problem) as info:
            ta.io.write_seg(tmp_path / "x.seg", bad)
        assert "x.seg" in str(info.value)
    assert not (tmp_path / "x.seg").exists()
    a = ta.io.write_seg(tmp_path / "a.seg.gz", np.array([3, 1, 2]))
    b = ta.io.write_seg(tmp_path / "b.seg.gz", np.array([3, 1, 2], dtype=np.int32))
    assert a.read_bytes() == b.read_bytes() and gzip.decompress(a.read_bytes()) == b"3\n1\n2\n"


def test_write_seg_is_atomic(tmp_path, monkeypatch):
    path = ta.io.write_seg(tmp_path / "x.seg", np.array([0, 1, 1]))

    def fail(src, dst):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(ta.io.outputs.os, "replace", fail)
    with pytest.raises(ta.errors.TorchAKVFError, match="x.seg: cannot write output"):
        ta.io.write_seg(path, np.array([2, 2, 2]))
    assert path.read_text() == "0\n1\n1\n"                       # the old file, whole
    assert not list(tmp_path.glob(f".*{ta.io.TEMP_SUFFIX}"))     # no temp file left




def test_write_off_reads_back_the_same_arrays(tmp_path):
    s = shapes.fish()
    v = s.vertices * np.pi          # coordinates with full float64 mantissas
    for name in ("fish.off", "fish.off.gz"):
        mesh = ta.load_mesh(ta.io.write_off(tmp_path / name, v, s.faces))
        assert np.array_equal(mesh.vertices, v) and np.array_equal(mesh.faces, s.faces)
    for bad_v, bad_f, problem in [(v[:, :2], s.faces, "shape"), (v, s.faces + len(v), "in 0.."),
                                  (v, s.faces.astype(float), "integers")]:
        with pytest.raises(ta.errors.ParameterError, match=problem):
            ta.io.write_off(tmp_path / "bad.off", bad_v, bad_f)
    assert not (tmp_path / "bad.off").exists()


def test_write_npz_round_trips_plain_arrays_compressed(tmp_path):
    """write_npz: every array comes back equal in value and dtype through np.load without
    pickles, the file is a deflated zip (a repetitive array takes a fraction of its bytes), and
    an object array is refused naming the file and the field."""
    rng = np.random.default_rng(0)
    arrays = dict(features=rng.random((500, 8)).astype(np.float32), values=rng.standard_normal(7),
                  faces=np.arange(30, dtype=np.int32).reshape(10, 3), converged=np.bool_(True),
                  names=np.array(["a", "bc"]), params_json=np.array('{"k": 3}'),
                  zeros=np.zeros(100_000))
    path = tmp_path / "x.npz"
    ta.io.write_npz(path, **arrays)
    with np.load(path, allow_pickle=False) as back:
        assert sorted(back.files) == sorted(arrays)
        for key, want in arrays.items():
            assert back[key].dtype == np.asarray(want).dtype
            np.testing.assert_array_equal(back[key], want)
    assert path.stat().st_size < arrays["zeros"].nbytes / 20
    with pytest.raises(ta.errors.TorchAKVFError, match=r"y\.npz.*'bad'"):
        ta.io.write_npz(tmp_path / "y.npz", bad=np.array([{}, 1], dtype=object))
    assert not (tmp_path / "y.npz").exists()
