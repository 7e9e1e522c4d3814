"""Eval galleries: one PNG per category, each mesh's predicted parts next to a human
segmentation of the same k, with the Rand index error (1 - RI) of the pair
(:func:`write_galleries`, in worker processes where there are enough meshes to repay their
start-up; :func:`write_gallery` draws one).

The human segmentation's labels are renumbered to match the prediction's (maximum face
overlap, Hungarian assignment), so a part and its human counterpart share a colour.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import TorchAKVFError
from ..io import load_mesh
from ..pipeline.parallel import map_batches
from . import psb as P
from .metrics import rand_index_error

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

    Both pictures of a mesh use the same camera (:func:`~torchakvf.io.render.best_view`). The
    pictures are pasted into one canvas (:func:`gallery_canvas`) and matplotlib only draws the
    captions, on a blank figure laid over it (no text touches a picture; the darker of the two
    at each pixel): an axes and a resampled image per picture cost more than the pictures.
    """
    from ..io.render import figure_pixels, new_figure, save_pixels

    canvas, texts = gallery_canvas(items, title, columns, pixels)
    H, W = canvas.shape[:2]
    fig = new_figure(W, H)
    for x, y, text, size, color in texts:
        fig.text(x / W, 1 - y / H, text, ha="center", va="center", fontsize=size, color=color)
    save_pixels(path, np.minimum(figure_pixels(fig), canvas))


#: Gallery layout in pixels: the heading's height (with a title), the height of a mesh's caption
#: and picture labels above its pictures, and the gap between the two pictures of a mesh.
HEAD_PIXELS, LABEL_PIXELS, GAP_PIXELS = 50, 46, 16


def gallery_canvas(items: Sequence[tuple], title: str | None = None, columns: int = MESHES_PER_ROW,
                   pixels: int = CELL_PIXELS) -> tuple[np.ndarray, list]:
    """The pictures of a gallery (``items`` as in :func:`write_gallery`) on one white canvas, and
    the texts to write on it.

    Returns (canvas [H, W, 3] uint8, texts [(x, y, text, fontsize, colour)]): each picture's
    RGB (:func:`~torchakvf.io.render.paint`, scaled to 0-255 and truncated, as matplotlib turns
    a float image into bytes) sits at its pixel position unresampled; a text's (x, y) is its
    centre in pixels from the canvas's top left.
    """
    from ..io.render import best_view, paint, raster_view, view_aspect

    if not items:
        raise ValueError("write_gallery needs at least one item")
    columns = max(1, min(int(columns), len(items)))
    rows = (len(items) + columns - 1) // columns
    meshes = [(np.asarray(it[1], float), np.asarray(it[2])) for it in items]
    views = [best_view(v, f) for v, f in meshes]
    img_h = int(round(pixels * max(view_aspect(v, vw) for (v, _), vw in zip(meshes, views))))
    head_h = HEAD_PIXELS if title else 0
    cell_w, cell_h = 2 * pixels + GAP_PIXELS, img_h + LABEL_PIXELS
    W, H = cell_w * columns, cell_h * rows + head_h
    canvas = np.full((H, W, 3), 255, dtype=np.uint8)
    texts = [(W / 2, head_h / 2, title, 15, "black")] if title else []
    for i, ((name, _, _, pred, human, err), (v, f), view) in enumerate(zip(items, meshes, views)):
        pred = np.asarray(pred).astype(np.int64)
        human = match_labels(pred, np.asarray(human).astype(np.int64))
        r, c = divmod(i, columns)
        top = head_h + r * cell_h
        raster = raster_view(v, f, view, pixels, img_h)          # one camera: rasterized once
        for j, (lab, what) in enumerate(((pred, "prediction"), (human, "human"))):
            x0 = c * cell_w + j * (pixels + GAP_PIXELS)
            y0 = top + LABEL_PIXELS
            canvas[y0:y0 + img_h, x0:x0 + pixels] = (paint(raster, lab).image * 255).astype(np.uint8)
            texts.append((x0 + pixels / 2, y0 - 10, what, 9, "0.35"))
        k = len(np.unique(pred[pred >= 0]))
        k_human = len(np.unique(human[human >= 0]))
        err_text = "n/a" if err is None or not np.isfinite(err) else f"{float(err):.3f}"
        also = f" (human {k_human})" if k_human != k else ""
        texts.append((c * cell_w + cell_w / 2, top + 14, f"{name}   k={k}{also}   1-RI={err_text}", 11, "black"))
    return canvas, texts


__all__ = ["write_gallery", "gallery_canvas", "write_galleries", "gallery_workers", "gallery_item", "match_labels"]


def gallery_item(plan, row):
    """(title, V, F, prediction, human, 1-RI) of one scored mesh: its first human segmentation
    with a prediction at that human's segment count (by-segmentation), else the first human
    beside the prediction at the mesh's own k (by-model, k auto)."""
    ks = [k for k in row.ks if plan.pred_path(k).is_file()]
    if not ks:
        return None
    counts = plan.counts                  # the segment counts of plan.entry.seg_paths, in order
    pick = next((i for i, c in enumerate(counts) if c in ks), 0)
    k = counts[pick] if counts[pick] in ks else ks[0]
    pred, human = P.read_seg(plan.pred_path(k)), P.read_seg(plan.entry.seg_paths[pick])
    mesh = load_mesh(plan.entry.mesh_path)
    if not (len(pred) == len(human) == mesh.n_faces):
        return None
    return (str(plan.mesh_id), mesh.vertices, mesh.faces, pred, human,
            rand_index_error(pred, human))


#: Scored meshes per gallery worker process: a pool gets one worker per this many meshes (at
#: most the workers asked for, one per category), none below twice as many. A spawned worker
#: spends about 3.5 CPU s importing torch, torchakvf and matplotlib before it draws anything;
#: drawing one mesh (its mesh and segmentations read, rasterized once, painted twice, its share
#: of the PNG) takes about 0.22 s (30 PSB meshes, one thread): a worker started for fewer meshes
#: than start-up over drawing cost finishes later than this process would have drawn them.
MESHES_PER_GALLERY_WORKER = 16


def gallery_workers(meshes: int, categories: int, workers: int) -> int:
    """Processes to draw ``meshes`` meshes' galleries in ``categories`` galleries with at most
    ``workers``: one per :data:`MESHES_PER_GALLERY_WORKER` meshes, at most one per category, 1
    (this process, no pool) when that leaves fewer than two. With w >= 2 workers each draws at
    least a start-up's worth of meshes, so the pool's wall time (start-up, then N/w meshes) is
    below drawing all N here: N·c·(1 - 1/w) >= start-up for N >= w·start-up/c."""
    w = min(int(workers), int(categories), int(meshes) // MESHES_PER_GALLERY_WORKER)
    return w if w >= 2 else 1


def write_galleries(out: Path, plans, rows, workers: int = 1) -> dict:
    """``gallery/<Category>.png`` per category with scored meshes: each mesh's prediction next to
    one human segmentation at the same k, with its 1-RI (:func:`~torchakvf.evaluate.gallery.
    write_gallery`). Returns {category: path relative to ``out``}, in the plans' order.

    workers : processes at most drawing categories side by side (:func:`gallery_workers`
        chooses how many from the number of meshes: on the PSB, 300 scored meshes, drawing is
        about 65 CPU s; the 30 meshes of a quick run about 6.5 s, less than two workers' start-up
        and half the drawing)."""
    by_id = {r.mesh_id: r for r in rows}
    pairs: dict = {}
    for p in plans:
        r = by_id.get(p.mesh_id)
        if r is not None and r.scored:
            pairs.setdefault(r.category, []).append((p, r))
    batches = [[(cat, ps)] for cat, ps in pairs.items()]
    written, errors = {}, []
    procs = gallery_workers(sum(len(ps) for ps in pairs.values()), len(batches), workers)
    for res in map_batches(batches, _draw_galleries, (out,), workers=procs):
        if res.error is not None:
            errors.append(res.error)
        elif not res.split:
            written.update(res.result)
    if errors:
        raise TorchAKVFError(f"{out / 'gallery'}: {len(errors)} gallery(ies) could not be drawn: {errors[0]}")
    return {cat: written[cat] for cat in pairs if cat in written}


def _draw_galleries(batch, out: Path) -> dict:
    """{category: path relative to out} of the galleries of ``batch`` [(category, [(plan, row)])]
    (a module-level function: it may run in a worker process)."""
    written = {}
    for cat, pairs in batch:
        its = [it for it in (gallery_item(p, r) for p, r in pairs) if it is not None]
        if not its:
            continue
        rel = Path("gallery") / f"{cat}.png"
        mean = float(np.mean([it[5] for it in its]))
        write_gallery(out / rel, its, title=f"{cat}: prediction | human, 1-RI per mesh (mean {mean:.3f})")
        written[cat] = rel.as_posix()
    return written
