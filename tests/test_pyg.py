"""torchakvf.interop.pyg: the torch_geometric transform (runs when torch_geometric is installed)."""
from __future__ import annotations

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


# ---- torch_geometric ----------------------------------------------------------------------
def test_pyg_transform_round_trip():
    pyg = pytest.importorskip("torch_geometric")
    from torch_geometric.data import Batch, Data

    from torchakvf.interop.pyg import AKVFFeatures

    s = _sphere()
    pos = torch.tensor(s.vertices, dtype=torch.float32)
    face = torch.tensor(s.faces.T.copy(), dtype=torch.long)
    data = Data(pos=pos.clone(), face=face.clone(), y=torch.tensor([3]))
    # remedy "smooth": the paper operator (what "auto" gives this clean sphere) has an exactly
    # degenerate rotation triple here, whose per-field norms no face order pins down
    out = AKVFFeatures(n=N, raw_norms=True, remedy="smooth")(data)
    # untouched inputs (the caller's Data gets no new attributes), new attributes with PyG shapes
    assert out is not data and not hasattr(data, "akvf_face_features")
    assert torch.equal(out.pos, pos) and torch.equal(out.face, face) and int(out.y) == 3
    assert out.akvf_face_features.shape == (len(s.faces), N)
    assert out.akvf_face_features.dtype == torch.float32
    assert out.akvf_eigenvalues.shape == (1, N) and out.akvf_norms.shape == (len(s.faces), N)
    # 11 field columns (one count), then the 8 part columns
    assert out.akvf_descriptors.shape == (len(s.faces), 19) and out.akvf_descriptors.dtype == torch.float32
    # a sphere: three rotations (λ·area ~ 0; 0.12 at this resolution), then a gap
    lam = out.akvf_eigenvalues[0].double()
    assert torch.all(lam[:3].abs() < 0.3) and lam[3] > 10.0
    # the same numbers as the library-free core on the same mesh
    ref = face_features(MeshBatch.from_meshes([Mesh(s.vertices.astype(np.float32).astype(np.float64), s.faces)]), N,
                        remedy="smooth")[0]
    np.testing.assert_allclose(out.akvf_face_features.numpy(), ref.features, rtol=1e-5, atol=1e-6)
    fields_only = AKVFFeatures(n=N, remedy="smooth", part_descriptors=False)(data)
    assert fields_only.akvf_descriptors.shape == (len(s.faces), 11)
    # the face order of the Data is the order of the features
    perm = np.random.default_rng(0).permutation(len(s.faces))
    shuffled = AKVFFeatures(n=N, raw_norms=True, remedy="smooth")(
        Data(pos=pos.clone(), face=face[:, perm].clone(), y=torch.tensor([1])))
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


