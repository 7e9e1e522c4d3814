"""At most k parts: the smallest parts merge into the part they touch, or the nearest piece."""
from __future__ import annotations

import numpy as np
import pytest

import torchakvf as ta
from torchakvf import shapes
from torchakvf.parts.pieces import limit_parts


def test_k_or_fewer_parts_are_returned_as_they_are():
    s = shapes.three_blobs(n_around=12)
    labels = s.part_labels
    assert limit_parts(labels, s.vertices, s.faces, 3) is labels
    assert limit_parts(labels, s.vertices, s.faces, 5) is labels


def test_smallest_part_merges_into_the_part_it_touches_most():
    s = shapes.flat_disk()
    x = s.vertices[s.faces].mean(axis=1)[:, 0]
    labels = np.digitize(x, [-0.5, 0.0, 0.05]).astype(np.int64)     # 4 bands, band 2 the thinnest
    assert len(np.unique(labels)) == 4
    out = limit_parts(labels, s.vertices, s.faces, 3)
    assert len(np.unique(out)) == 3
    thin = labels == 2
    assert len(np.unique(out[thin])) == 1
    # it joined a neighbouring band, the others kept their faces together
    assert out[thin][0] in (out[labels == 1][0], out[labels == 3][0])
    for band in (0, 1, 3):
        assert len(np.unique(out[labels == band])) == 1
    np.testing.assert_array_equal(np.unique(out), [0, 1, 2])


def test_disconnected_pieces_merge_into_the_nearest_and_region_is_kept():
    t = shapes.torus()
    rng = np.random.default_rng(0)
    faces = t.faces[np.sort(rng.choice(len(t.faces), 19, replace=False))]
    labels = np.arange(19)
    labels[0] = -1
    out = limit_parts(labels, t.vertices, faces, 3)
    assert out[0] == -1
    assert sorted(np.unique(out[1:])) == [0, 1, 2]


def test_segmenting_many_pieces_then_limiting_gives_k_labels_per_input_face():
    """19 faces of a torus (19 pieces) asked for 3 parts: one label per face, 3 labels."""
    t = shapes.torus()
    faces = t.faces[np.sort(np.random.default_rng(0).choice(len(t.faces), 19, replace=False))]
    seg = ta.segment([ta.Mesh(t.vertices, faces, "pieces")], k=3, seed=0)[0]
    out = limit_parts(seg.labels, t.vertices, faces, 3)
    assert out.shape == (19,) and len(np.unique(out)) == 3


def test_k_below_one_is_refused():
    with pytest.raises(ta.errors.ParameterError, match="k must be at least 1"):
        limit_parts(np.zeros(3, int), np.eye(3), np.array([[0, 1, 2]] * 3), 0)
