"""Eval gallery: label matching so a part and its human counterpart share a colour, and one
PNG per category with a prediction/human pair per mesh."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf import shapes
from torchakvf.evaluate.gallery import (
    CELL_PIXELS,
    MESHES_PER_GALLERY_WORKER,
    gallery_canvas,
    gallery_workers,
    match_labels,
    write_gallery,
)
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


def _dumbbells():
    items = []
    for n_around in (16, 24, 20):
        s = shapes.dumbbell(n_around=n_around)
        pred = s.part_labels
        human = np.where(np.arange(len(pred)) % 5 == 0, 7, pred)
        items.append((f"d{n_around}", s.vertices, s.faces, pred, human, rand_index_error(pred, human)))
    return items


def test_gallery_canvas_holds_each_picture_unresampled_at_its_place(tmp_path):
    """Every painted picture (the prediction, then the matched human) sits in the canvas at its
    cell's position with its exact pixels (0-255, truncated), white around; the PNG written has
    the canvas's pixels wherever there is no text (captions stay above the pictures)."""
    from torchakvf.io.render import best_view, paint, raster_view, view_aspect

    items, pixels = _dumbbells(), 120
    canvas, texts = gallery_canvas(items, title="Dumbbell", columns=2, pixels=pixels)
    views = [best_view(v, f) for _, v, f, *_ in items]
    img_h = int(round(pixels * max(view_aspect(it[1], vw) for it, vw in zip(items, views))))
    cell_w = 2 * pixels + 16
    assert canvas.dtype == np.uint8 and canvas.shape == (50 + 2 * (img_h + 46), 2 * cell_w, 3)
    covered = np.zeros(canvas.shape[:2], bool)
    for i, ((_, v, f, pred, human, _), view) in enumerate(zip(items, views)):
        raster = raster_view(v, f, view, pixels, img_h)
        r, c = divmod(i, 2)
        y0 = 50 + r * (img_h + 46) + 46
        for j, lab in enumerate((pred, match_labels(pred, human))):
            x0 = c * cell_w + j * (pixels + 16)
            want = (paint(raster, lab).image * 255).astype(np.uint8)
            np.testing.assert_array_equal(canvas[y0:y0 + img_h, x0:x0 + pixels], want)
            covered[y0:y0 + img_h, x0:x0 + pixels] = True
    assert (canvas[~covered] == 255).all()
    caption = "d16   k=2 (human 3)   1-RI=%.3f" % items[0][5]
    assert [t[2] for t in texts[:4]] == ["Dumbbell", "prediction", "human", caption]
    # a text's centre lies above the pictures of its row
    assert all(not covered[int(y), int(x)] for x, y, *_ in texts)
    write_gallery(tmp_path / "g.png", items, title="Dumbbell", columns=2, pixels=pixels)
    png = _read_rgb(tmp_path / "g.png")
    assert png.shape == canvas.shape
    np.testing.assert_array_equal(png[covered], canvas[covered])
    assert (png[~covered] < 128).any()                              # the captions are written


def _read_rgb(path):
    import matplotlib.image

    return np.round(matplotlib.image.imread(str(path))[..., :3] * 255).astype(np.uint8)


def test_gallery_workers_start_a_pool_only_for_enough_meshes():
    m = MESHES_PER_GALLERY_WORKER
    assert gallery_workers(m - 1, 15, 8) == 1                      # a quick run: drawn here
    assert gallery_workers(2 * m - 1, 15, 2) == 1                  # one worker would not repay
    assert gallery_workers(2 * m, 15, 2) == 2
    assert gallery_workers(300, 15, 8) == min(8, 300 // m)
    assert gallery_workers(300, 1, 8) == 1                          # one category: one process
    assert gallery_workers(10 * m, 15, 1) == 1
