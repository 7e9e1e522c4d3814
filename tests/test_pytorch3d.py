"""torchakvf.interop.pytorch3d: the pytorch3d Meshes bridge (a duck-typed stand-in here, the
real class when pytorch3d is installed)."""
from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import torch

from torchakvf import shapes


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
    a = shapes.icosphere(level=1)
    b = (shapes.torus(n_major=12, n_minor=8) if "n_minor" in shapes.torus.__code__.co_varnames
         else shapes.torus(n_major=12))
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
