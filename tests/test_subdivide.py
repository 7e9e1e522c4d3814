"""Midpoint subdivision keeps the surface, its orientation and one value per input face."""
from __future__ import annotations

import numpy as np
import trimesh

import torchakvf as ta
from torchakvf.mesh.clean import face_areas, undirected_edges
from torchakvf.mesh.subdivide import levels_to_fit, subdivide


def test_subdivided_cube_keeps_area_orientation_and_input_faces():
    box = trimesh.creation.box()
    clean = ta.clean_mesh(ta.Mesh(box.vertices, box.faces, "cube"))
    fine = subdivide(clean, 2)
    assert len(fine.faces) == 16 * 12 and fine.report["subdivided"] == 2
    assert np.isclose(face_areas(fine.vertices, fine.faces).sum(), 6.0)
    # closed and consistently oriented: each edge once each way
    half = np.stack([fine.faces, np.roll(fine.faces, -1, axis=1)], axis=2).reshape(-1, 2)
    assert len({tuple(h) for h in half.tolist()}) == len(half)
    assert len(undirected_edges(fine.faces).unique) * 2 == len(half)
    np.testing.assert_array_equal(fine.face_index, np.repeat(np.arange(12), 16))
    labels = np.arange(len(fine.faces)) % 16 == 15             # the last child of each face
    out = fine.labels_to_input_faces(labels.astype(np.int64))
    assert out.shape == (12,) and (out == 1).all()


def test_levels_to_fit_and_a_segmentation_of_a_subdivided_cube():
    box = trimesh.creation.box()
    clean = ta.clean_mesh(ta.Mesh(box.vertices, box.faces, "cube"))
    assert levels_to_fit(clean, 18) == 0 and levels_to_fit(clean, 19) == 1
    level = levels_to_fit(clean, 28)
    fine = subdivide(clean, level)
    assert len(undirected_edges(fine.faces).unique) >= 28
    seg = ta.segment([fine], k=5, seed=0)[0]
    assert seg.labels.shape == (12,)                          # one label per face of the file
