"""Eval gallery: one PNG per category, each mesh's predicted parts next to a human
segmentation of the same k, with the Rand index error (1 - RI) of the pair.

The human segmentation's labels are renumbered to match the prediction's (maximum face
overlap, Hungarian assignment), so a part and its human counterpart share a colour.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

#: Meshes per row (each is two pictures: prediction, human).
MESHES_PER_ROW = 4
#: Pixels per picture (square).
CELL_PIXELS = 300


def match_labels(reference: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """``labels`` [F] renumbered so each of its segments takes the label of the ``reference``
    segment it overlaps most (one-to-one, Hungarian on face counts); segments left without a
    partner get fresh labels after the reference's. -1 (connecting region) stays -1."""
    from scipy.optimize import linear_sum_assignment

    reference, labels = np.asarray(reference), np.asarray(labels)
    ok = (labels >= 0) & (reference >= 0)
    ours = np.unique(labels[labels >= 0])
    theirs = np.unique(reference[reference >= 0])
    out = np.full(labels.shape, -1, dtype=np.int64)
    if len(ours) == 0:
        return out
    overlap = np.zeros((len(ours), max(len(theirs), 1)))
    if len(theirs):
        li = np.searchsorted(ours, labels[ok])
        ri = np.searchsorted(theirs, reference[ok])
        np.add.at(overlap, (li, ri), 1.0)
    rows, cols = linear_sum_assignment(-overlap)
    new = {}
    for r, c in zip(rows, cols):
        if len(theirs) and overlap[r, c] > 0:
            new[int(ours[r])] = int(theirs[c])
    fresh = int(max(theirs.max() if len(theirs) else -1, -1)) + 1
    for lab in ours:
        if int(lab) not in new:
            new[int(lab)] = fresh
            fresh += 1
    lut_keys = np.array(sorted(new))
    lut_vals = np.array([new[k] for k in lut_keys])
    pos = labels >= 0
    out[pos] = lut_vals[np.searchsorted(lut_keys, labels[pos])]
    return out


def write_gallery(path, items: Sequence[tuple], title: str | None = None,
                  columns: int = MESHES_PER_ROW, pixels: int = CELL_PIXELS) -> None:
    """Write one category's gallery PNG to ``path`` (atomically).

    items : sequence of ``(title, vertices [V, 3], faces [F, 3], predicted_labels [F],
        human_labels [F], rand_index_error)``: per mesh, the prediction and one human
        segmentation with the same k, both on the input's faces, and their 1 - RI (float;
        None or NaN prints as "n/a").
    title : optional heading of the figure (e.g. the category and the mean 1 - RI).
    columns : meshes per row; pixels : width of each picture (height from the meshes' shape,
        0.3-1 x the width).

    Both pictures of a mesh use the same camera (:func:`~torchakvf.io.render.best_view`).
    """
    from ..io.render import (best_view, new_figure as _figure, render_view, save_figure as _save,
                             view_aspect as _aspect)

    if not items:
        raise ValueError("write_gallery needs at least one item")
    columns = max(1, min(int(columns), len(items)))
    rows = (len(items) + columns - 1) // columns
    views = [best_view(np.asarray(it[1], float), np.asarray(it[2])) for it in items]
    img_h = int(round(pixels * max(_aspect(np.asarray(it[1], float), vw) for it, vw in zip(items, views))))
    head_h = 50 if title else 0
    label_h, gap = 46, 16
    cell_w = 2 * pixels + gap
    cell_h = img_h + label_h
    W, H = cell_w * columns, cell_h * rows + head_h
    fig = _figure(W, H)
    for i, ((name, v, f, pred, human, err), view) in enumerate(zip(items, views)):
        v, f = np.asarray(v, float), np.asarray(f)
        pred = np.asarray(pred).astype(np.int64)
        human = match_labels(pred, np.asarray(human).astype(np.int64))
        r, c = divmod(i, columns)
        top = head_h + r * cell_h
        for j, (lab, what) in enumerate(((pred, "prediction"), (human, "human"))):
            x0 = c * cell_w + j * (pixels + gap)
            ax = fig.add_axes([x0 / W, 1 - (top + label_h + img_h) / H, pixels / W, img_h / H])
            pic = render_view(v, f, lab, view, pixels, img_h)
            ax.imshow(pic.image, interpolation="antialiased")
            ax.set_axis_off()
            fig.text((x0 + pixels / 2) / W, 1 - (top + label_h - 10) / H, what, ha="center",
                     va="center", fontsize=9, color="0.35")
        k = len(np.unique(pred[pred >= 0]))
        k_human = len(np.unique(human[human >= 0]))
        err_text = "n/a" if err is None or not np.isfinite(err) else f"{float(err):.3f}"
        fig.text((c * cell_w + cell_w / 2) / W, 1 - (top + 14) / H, f"{name}   k={k}" + (f" (human {k_human})" if k_human != k else "") + f"   1-RI={err_text}",
                 ha="center", va="center", fontsize=11)
    if title:
        fig.text(0.5, 1 - (head_h / 2) / H, title, ha="center", va="center", fontsize=15)
    _save(fig, path, tight=False)


__all__ = ["write_gallery", "match_labels"]
