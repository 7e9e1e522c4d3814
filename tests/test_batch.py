"""The packed batch (torchakvf.mesh.batch): dtype moves keep index tensors, owner maps, a mesh of
a batch is the batch of that mesh."""
import pytest
import torch

import torchakvf as ta
from torchakvf import shapes


def test_meshbatch_to_dtype_keeps_index_tensors():
    b = ta.MeshBatch.from_meshes([ta.Mesh(shapes.icosphere(1).vertices, shapes.icosphere(1).faces)])
    for moved in (b.to(torch.float32), b.to("cpu", torch.float32), b.to(dtype=torch.float32)):
        assert moved.verts.dtype == torch.float32 and moved.face_edge_sign.dtype == torch.float32
        for name in ("faces", "edges", "face_edges", "vert_ptr", "face_ptr", "edge_ptr"):
            assert getattr(moved, name).dtype == torch.int64, name
            assert torch.equal(getattr(moved, name), getattr(b, name)), name
    assert b.to("cpu").dtype == torch.float64
    with pytest.raises(ta.ParameterError):
        b.to(torch.int32)


def test_owner_index_matches_batch_maps():
    from torchakvf.mesh import owner_index
    ptr = torch.tensor([0, 3, 3, 5])
    assert owner_index(ptr).tolist() == [0, 0, 0, 2, 2]
    s = [shapes.icosphere(1), shapes.icosphere(2)]
    b = ta.MeshBatch.from_meshes([ta.Mesh(x.vertices, x.faces) for x in s])
    assert torch.equal(b.face_to_mesh, owner_index(b.face_ptr))
    assert b.edge_to_mesh.tolist() == [0] * 120 + [1] * 480


def test_mesh_of_a_batch_is_the_batch_of_that_mesh():
    meshes = [ta.Mesh(s.vertices, s.faces, name=s.name)
              for s in (shapes.dumbbell(), shapes.hemisphere(), shapes.three_blobs(n_around=16))]
    batch = ta.MeshBatch.from_meshes(meshes)
    for b, m in enumerate(meshes):
        one, ref = batch.mesh(b), ta.MeshBatch.from_meshes([m])
        for name in ("verts", "faces", "edges", "face_edges", "face_edge_sign", "vert_ptr", "face_ptr", "edge_ptr"):
            assert torch.equal(getattr(one, name), getattr(ref, name)), name
        assert one.meshes[0] is batch.meshes[b]


def test_to_input_faces_puts_packed_values_on_the_file_faces():
    import numpy as np

    s = shapes.icosphere(level=3)                                      # 1280 faces
    mesh = ta.Mesh(s.vertices, s.faces)
    batch = ta.MeshBatch.from_meshes([mesh, mesh], coarse_faces=300)
    full = ta.MeshBatch.from_meshes([mesh])
    # full resolution: the packed faces are the file's, in its order
    np.testing.assert_array_equal(full.to_input_faces(0, np.arange(1280)), np.arange(1280))
    # decimated: each file face takes the value of the coarse face under its barycenter
    coarse = batch.coarse_of(1)
    n_coarse = len(batch.meshes[1].faces)
    assert n_coarse < 400
    out = batch.to_input_faces(1, np.arange(n_coarse))
    assert out.shape == (1280,)
    np.testing.assert_array_equal(out, coarse.faces_on_coarse.face)
