"""Figures: PNG files of segmented meshes (one mesh in one or two views, or a grid of meshes),
drawn with matplotlib's Agg backend (no display, no OpenGL, no GPU), generator streamlines on top.
"""
from __future__ import annotations

import io
from typing import Sequence

import numpy as np

from ...errors import ParameterError
from ..outputs import atomic_write_bytes
from .camera import View, best_view, opposite_view, view_aspect
from .flow import generator_streamlines
from .raster import Picture, render_view

#: Default picture width in pixels (a picture with several views is wider).
DEFAULT_PIXELS = 900
#: Streamline colour (near black, as in the paper's Figure 10).
FLOW_COLOR = (0.08, 0.08, 0.1)


def _draw_lines(ax, pic: Picture, lines, width_px: float):
    """Visible runs of each polyline, with an arrowhead at its middle showing the direction."""
    lw = max(0.8, width_px / 700)
    for _, pts in lines:
        xy, vis = pic.to_pixels(pts)
        runs = np.split(np.arange(len(pts)), np.flatnonzero(np.diff(vis.astype(int)) != 0) + 1)
        for r in runs:
            if len(r) < 2 or not vis[r[0]]:
                continue
            ax.plot(xy[r, 0], xy[r, 1], color="white", lw=lw * 2.4, alpha=0.6, solid_capstyle="round")
            ax.plot(xy[r, 0], xy[r, 1], color=FLOW_COLOR, lw=lw, solid_capstyle="round")
        mid = len(pts) // 2
        if mid + 1 < len(pts) and vis[mid] and vis[mid + 1]:
            ax.annotate("", xy=xy[mid + 1], xytext=xy[mid],
                        arrowprops=dict(arrowstyle="-|>", color=FLOW_COLOR, lw=lw,
                                        mutation_scale=6 + 5 * lw, shrinkA=0, shrinkB=0))


def _draw_arrows(ax, pic: Picture, arrows):
    base, vec = arrows
    a, va = pic.to_pixels(base)
    b, _ = pic.to_pixels(base + vec)
    for i in np.flatnonzero(va):
        ax.annotate("", xy=b[i], xytext=a[i],
                    arrowprops=dict(arrowstyle="-|>", color=FLOW_COLOR, lw=0.8, mutation_scale=7))


def _views(vertices, faces, views: int) -> list[View]:
    first = best_view(vertices, faces)
    return [first] if views == 1 else [first, opposite_view(first)]


def _panel(ax, vertices, faces, labels, view, width, height, lines=None, flow=None, arrows=None):
    """Draw one view into ``ax`` (pixel coordinates); ``flow`` = (face_vectors, generators) is
    traced with seeds on the faces this view shows."""
    pic = render_view(vertices, faces, labels, view, width, height)
    ax.imshow(pic.image, interpolation="antialiased")
    if flow is not None and lines is None:
        face_vectors, generators = flow
        lines = generator_streamlines(vertices, faces, labels, face_vectors, generators,
                                      seed_faces=pic.visible_faces(len(faces)))
    if lines:
        _draw_lines(ax, pic, lines, width)
    if arrows is not None and len(arrows[0]):
        _draw_arrows(ax, pic, arrows)
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_axis_off()
    return pic


def new_figure(width_px: int, height_px: int, dpi: int = 100):
    """A blank matplotlib figure of width_px x height_px pixels on the Agg backend."""
    import matplotlib
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt.figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)


def save_figure(fig, path, tight: bool = True) -> None:
    """Write ``fig`` to ``path`` as PNG (atomically, white background) and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight" if tight else None, facecolor="white")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


def figure_pixels(fig) -> np.ndarray:
    """[H, W, 3] uint8 RGB of ``fig`` drawn on the Agg canvas (closes it)."""
    import matplotlib.pyplot as plt

    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    plt.close(fig)
    return rgb


def save_pixels(path, rgb: np.ndarray) -> None:
    """Write an [H, W, 3] uint8 RGB image to ``path`` as PNG (atomically), as it is."""
    import matplotlib.image

    buf = io.BytesIO()
    matplotlib.image.imsave(buf, np.ascontiguousarray(rgb, dtype=np.uint8), format="png")
    atomic_write_bytes(path, buf.getvalue())


def render_png(path, vertices, faces, labels, title: str | None = None, arrows=None, *,
               flow=None, streamlines=None, views: int = 1, pixels: int = DEFAULT_PIXELS) -> None:
    """One mesh coloured by part (grey = connecting region) as a PNG ``pixels`` wide per view
    (height from the mesh's shape in that view, 0.3-1 x the width).

    flow : optional (face_vectors [F, n, 3], generators per part): each part's first
        generator drawn as :func:`generator_streamlines` seeded on the faces the view shows;
    streamlines : optional precomputed output of :func:`generator_streamlines` instead;
    arrows : optional (bases [N, 3], vectors [N, 3]) from :func:`generator_arrows`;
    views : 1 (the view showing most area) or 2 (that view and the opposite side);
    pixels : width of each view in pixels.
    """
    if views not in (1, 2):
        raise ParameterError(f"views must be 1 or 2, got {views!r}")
    vs = _views(vertices, faces, views)
    w = int(pixels)
    h = max(int(round(w * view_aspect(vertices, vs[0]))), 1)
    title_h = 44 if title else 0
    fig = new_figure(w * views, h + title_h)
    for i, view in enumerate(vs):
        ax = fig.add_axes([i / views, 0, 1 / views, h / (h + title_h)])
        _panel(ax, vertices, faces, labels, view, w, h, lines=streamlines, flow=flow, arrows=arrows)
    if title:
        fig.text(0.5, 1 - 0.5 * title_h / (h + title_h), title, ha="center", va="center", fontsize=14)
    save_figure(fig, path, tight=False)


def contact_sheet(path, items: Sequence[tuple], columns: int = 4, size: float | None = None,
                  *, pixels: int = 560) -> None:
    """A grid of meshes, cells ``pixels`` wide (landscape when every mesh is); items are
    (vertices, faces, labels, title) with optionally a fifth entry, the flow
    (face_vectors, generators) as in :func:`render_png`."""
    if size is not None:
        pixels = max(int(size * 100), 150)
    columns = max(1, min(columns, len(items)))
    rows = (len(items) + columns - 1) // columns
    views = [best_view(it[0], it[1]) for it in items]
    aspect = max(view_aspect(it[0], vw) for it, vw in zip(items, views))
    cell_w, img_h, title_h = int(pixels), int(round(pixels * aspect)), 36
    cell_h = img_h + title_h
    fig = new_figure(cell_w * columns, cell_h * rows)
    H = cell_h * rows
    for i, (item, view) in enumerate(zip(items, views)):
        v, f, lab, title = item[:4]
        flow = item[4] if len(item) > 4 else None
        r, c = divmod(i, columns)
        ax = fig.add_axes([c / columns, 1 - ((r + 1) * cell_h) / H, 1 / columns, img_h / H])
        _panel(ax, v, f, lab, view, cell_w, img_h, flow=flow)
        fig.text((c + 0.5) / columns, 1 - (r * cell_h + title_h / 2) / H, title,
                 ha="center", va="center", fontsize=13)
    save_figure(fig, path, tight=False)


__all__ = ["render_png", "contact_sheet", "new_figure", "save_figure", "figure_pixels", "save_pixels",
           "DEFAULT_PIXELS", "FLOW_COLOR"]
