"""Interop: the torch_geometric transform (runs when torch_geometric is installed) and the
pytorch3d Meshes bridge (a duck-typed stand-in here, the real class when pytorch3d is)."""
from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch

from torchakvf import shapes
from torchakvf.errors import MeshError
from torchakvf.interop import face_features
from torchakvf.mesh import Mesh, MeshBatch

N = 8


def _sphere():
    return shapes.icosphere(level=2)


def test_face_features_on_input_faces_of_a_decimated_mesh():
    s = shapes.icosphere(level=4)                                    # 5120 faces
    full = face_features(MeshBatch.from_meshes([Mesh(s.vertices, s.faces)]), N)[0]
    batch = MeshBatch.from_meshes([Mesh(s.vertices, s.faces)], coarse_faces=1000)
    n_coarse = len(batch.meshes[0].faces)
    coarse = face_features(batch, N)[0]
    assert n_coarse < 1300
    assert full.features.shape == coarse.features.shape == (len(s.faces), N)
    # every input face carries the values of the coarse face under it: at most n_coarse rows
    assert len(np.unique(coarse.features, axis=0)) <= n_coarse
    assert np.all(coarse.features.sum(axis=1) > 0)
    # both resolutions find the sphere's three rotations (λ·area near 0, a gap after them)
    for ff in (full, coarse):
        assert np.all(np.abs(ff.eigenvalues[:3]) < 1.0) and ff.eigenvalues[3] > 10.0


# ---- torch_geometric ----------------------------------------------------------------------
def test_pyg_transform_round_trip():
    pyg = pytest.importorskip("torch_geometric")
    from torch_geometric.data import Batch, Data

    from torchakvf.interop.pyg import AKVFFeatures

    s = _sphere()
    pos = torch.tensor(s.vertices, dtype=torch.float32)
    face = torch.tensor(s.faces.T.copy(), dtype=torch.long)
    data = Data(pos=pos.clone(), face=face.clone(), y=torch.tensor([3]))
    out = AKVFFeatures(n=N, raw_norms=True)(data)
    # untouched inputs (the caller's Data gets no new attributes), new attributes with PyG shapes
    assert out is not data and not hasattr(data, "akvf_face_features")
    assert torch.equal(out.pos, pos) and torch.equal(out.face, face) and int(out.y) == 3
    assert out.akvf_face_features.shape == (len(s.faces), N)
    assert out.akvf_face_features.dtype == torch.float32
    assert out.akvf_eigenvalues.shape == (1, N) and out.akvf_norms.shape == (len(s.faces), N)
    # a sphere: three rotations (λ·area ~ 0; 0.12 at this resolution), then a gap
    lam = out.akvf_eigenvalues[0].double()
    assert torch.all(lam[:3].abs() < 0.3) and lam[3] > 10.0
    # the same numbers as the library-free core on the same mesh
    ref = face_features(MeshBatch.from_meshes([Mesh(s.vertices.astype(np.float32).astype(np.float64), s.faces)]), N)[0]
    np.testing.assert_allclose(out.akvf_face_features.numpy(), ref.features, rtol=1e-5, atol=1e-6)
    # the face order of the Data is the order of the features
    perm = np.random.default_rng(0).permutation(len(s.faces))
    shuffled = AKVFFeatures(n=N, raw_norms=True)(Data(pos=pos.clone(), face=face[:, perm].clone(), y=torch.tensor([1])))
    np.testing.assert_allclose(shuffled.akvf_face_features.numpy(),
                               out.akvf_face_features.numpy()[perm], rtol=1e-4, atol=1e-5)
    # batching: per-face rows concatenate, graph-level eigenvalues stack
    b = Batch.from_data_list([out, shuffled])
    assert b.akvf_face_features.shape == (2 * len(s.faces), N)
    assert b.akvf_eigenvalues.shape == (2, N)
    assert "AKVFFeatures(n=8" in repr(AKVFFeatures(n=N))
    assert pyg.__version__


def test_pyg_transform_needs_a_mesh():
    pytest.importorskip("torch_geometric")
    from torch_geometric.data import Data

    from torchakvf.interop.pyg import AKVFFeatures

    with pytest.raises(MeshError, match="data.face"):
        AKVFFeatures(n=N)(Data(pos=torch.zeros(4, 3)))
    with pytest.raises(MeshError, match=r"\[3, F\]"):
        AKVFFeatures(n=N)(Data(pos=torch.zeros(4, 3), face=torch.zeros(4, 3, dtype=torch.long)))


# ---- pytorch3d -----------------------------------------------------------------------------
class _FakeMeshes:
    """pytorch3d's documented constructor and list accessors, nothing else."""

    def __init__(self, verts, faces):
        self._v, self._f = list(verts), list(faces)

    def verts_list(self):
        return self._v

    def faces_list(self):
        return self._f


@pytest.fixture
def fake_pytorch3d(monkeypatch):
    mod = types.ModuleType("pytorch3d")
    sub = types.ModuleType("pytorch3d.structures")
    sub.Meshes = _FakeMeshes
    mod.structures = sub
    monkeypatch.setitem(sys.modules, "pytorch3d", mod)
    monkeypatch.setitem(sys.modules, "pytorch3d.structures", sub)
    return sub


def _two_meshes():
    a, b = shapes.icosphere(level=1), shapes.torus(n_major=12, n_minor=8) if "n_minor" in shapes.torus.__code__.co_varnames else shapes.torus(n_major=12)
    return [a, b]


def test_pytorch3d_round_trip_with_the_documented_api(fake_pytorch3d):
    from torchakvf.interop.pytorch3d import from_pytorch3d, to_pytorch3d

    ms = _two_meshes()
    meshes = _FakeMeshes([torch.tensor(m.vertices, dtype=torch.float32) for m in ms],
                         [torch.tensor(m.faces) for m in ms])
    batch = from_pytorch3d(meshes)
    assert len(batch) == 2 and batch.dtype == torch.float64
    assert [int(x) for x in batch.face_ptr] == [0, len(ms[0].faces), len(ms[0].faces) + len(ms[1].faces)]
    back = to_pytorch3d(batch, dtype=torch.float32)
    for m, v, f in zip(ms, back.verts_list(), back.faces_list()):
        assert v.dtype == torch.float32 and f.min() == 0 and f.max() == len(m.vertices) - 1
        # same triangles (a clean mesh keeps these meshes' vertices and faces; orientation kept)
        np.testing.assert_allclose(v[f].numpy(), m.vertices[m.faces].astype(np.float32), atol=1e-6)


def test_from_pytorch3d_refuses_empty():
    from torchakvf.errors import ParameterError
    from torchakvf.interop.pytorch3d import from_pytorch3d

    with pytest.raises(ParameterError):
        from_pytorch3d(_FakeMeshes([], []))


def test_real_pytorch3d_round_trip():
    p3d = pytest.importorskip("pytorch3d.structures")
    from torchakvf.interop.pytorch3d import from_pytorch3d, to_pytorch3d

    ms = _two_meshes()
    meshes = p3d.Meshes(verts=[torch.tensor(m.vertices, dtype=torch.float32) for m in ms],
                        faces=[torch.tensor(m.faces) for m in ms])
    back = to_pytorch3d(from_pytorch3d(meshes), dtype=torch.float32)
    assert isinstance(back, p3d.Meshes) and len(back) == 2
    for a, b in zip(meshes.verts_list(), back.verts_list()):
        assert torch.allclose(a, b)
