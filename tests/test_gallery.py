"""Eval gallery: label matching so a part and its human counterpart share a colour, and one
PNG per category with a prediction/human pair per mesh."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf import shapes
from torchakvf.evaluate.gallery import CELL_PIXELS, match_labels, write_gallery
from torchakvf.evaluate.metrics import rand_index_error


def test_match_labels_renumbers_to_the_reference():
    ref = np.array([0, 0, 0, 1, 1, 2, 2, 2, -1])
    hum = np.array([5, 5, 7, 3, 3, 9, 9, 9, 9])                 # 5 -> 0, 3 -> 1, 9 -> 2, 7 fresh
    out = match_labels(ref, hum)
    np.testing.assert_array_equal(out, [0, 0, 3, 1, 1, 2, 2, 2, 2])
    # a relabelling changes no segment: the Rand index error to the original is 0
    assert rand_index_error(out, hum) == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_array_equal(match_labels(ref, np.array([-1] * 9)), [-1] * 9)


def test_write_gallery_one_png_with_pairs(tmp_path):
    import matplotlib.image

    items = []
    for n_around in (16, 20, 24):
        s = shapes.dumbbell(n_around=n_around)
        pred = s.part_labels
        human = 1 - s.part_labels                                   # same parts, other numbers
        items.append((f"d{n_around}", s.vertices, s.faces, pred, human, rand_index_error(pred, human)))
    items.append(("nan", s.vertices, s.faces, pred, np.zeros_like(pred), float("nan")))
    write_gallery(tmp_path / "gallery" / "Dumbbell.png", items, title="Dumbbell", columns=2)
    img = matplotlib.image.imread(str(tmp_path / "gallery" / "Dumbbell.png"))
    assert img.shape[1] == 2 * (2 * CELL_PIXELS + 16)
    assert img.shape[0] > 2 * 0.3 * CELL_PIXELS
    # the human picture of the first mesh is drawn in the prediction's colours (matched labels):
    # the two pictures of the pair are the same image
    top = 50 + 46                                                  # heading, mesh title + labels
    height = (img.shape[0] - 50) // 2 - 46                         # two rows of pictures
    left = img[top:top + height, 0:CELL_PIXELS, :3]
    right = img[top:top + height, CELL_PIXELS + 16:2 * CELL_PIXELS + 16, :3]
    assert (left.sum(axis=2) < 2.9).mean() > 0.1                   # something is drawn
    np.testing.assert_allclose(left, right, atol=0.02)
    with pytest.raises(ValueError):
        write_gallery(tmp_path / "empty.png", [])
