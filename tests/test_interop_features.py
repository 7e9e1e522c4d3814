"""torchakvf.interop.features: per-face AKVF features of a batch."""
from __future__ import annotations

import numpy as np

from torchakvf import shapes
from torchakvf.interop import face_features
from torchakvf.mesh import Mesh, MeshBatch

N = 8


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
    # the order-free descriptors, on the same input faces (N = 8 fields: one count, 11 field
    # columns, then the 8 part columns)
    assert coarse.descriptors.shape == (len(s.faces), len(coarse.descriptor_names)) == (len(s.faces), 19)
    assert coarse.descriptor_names[0] == "share1@8" and coarse.descriptor_names[11] == "cut_distance@2"
    assert np.isfinite(coarse.descriptors).all()
    # field columns are the coarse face's; part columns come from cuts on the input mesh
    assert len(np.unique(coarse.descriptors[:, :11], axis=0)) <= n_coarse
    fields_only = face_features(batch, N, part_descriptors=False)[0]
    assert fields_only.descriptor_names == coarse.descriptor_names[:11]
    np.testing.assert_array_equal(fields_only.descriptors, coarse.descriptors[:, :11])
    bare = face_features(batch, N, descriptors=False)[0]
    assert bare.descriptors is None and bare.descriptor_names == []
    np.testing.assert_array_equal(bare.features, coarse.features)
    # both resolutions find the sphere's three rotations (λ·area near 0, a gap after them)
    for ff in (full, coarse):
        assert np.all(np.abs(ff.eigenvalues[:3]) < 1.0) and ff.eigenvalues[3] > 10.0
