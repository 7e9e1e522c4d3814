"""Headless pictures of segmentations: a small numpy z-buffer rasterizer shown with matplotlib's
Agg backend (no display, no OpenGL, no GPU).

One job a module:

* :mod:`~torchakvf.io.render.camera`  - framing: principal axes, the view showing the largest
  projected area, upright and from the side the area lies toward (:func:`best_view`);
* :mod:`~torchakvf.io.render.raster`  - the supersampled z-buffer rasterizer, flat two-light
  shading, silhouette and part-border lines (:func:`render_view` -> :class:`Picture`);
* :mod:`~torchakvf.io.render.flow`    - each part's symmetry generator as streamlines on that
  part only (:func:`generator_streamlines`), or arrows;
* :mod:`~torchakvf.io.render.figures` - the PNG files: one mesh in one or two views
  (:func:`render_png`), a grid of meshes (:func:`contact_sheet`), streamlines drawn where visible.

Every public name is importable from ``torchakvf.io.render``.
"""
from .camera import View, best_view, face_geometry, opposite_view, principal_axes, projected_area, view_aspect
from .figures import (
    DEFAULT_PIXELS,
    FLOW_COLOR,
    contact_sheet,
    figure_pixels,
    new_figure,
    render_png,
    save_figure,
    save_pixels,
)
from .flow import generator_arrows, generator_streamlines
from .raster import (
    FILL_LIGHT,
    KEY_LIGHT,
    SUPERSAMPLE,
    Picture,
    Raster,
    paint,
    raster_view,
    rasterize,
    render_view,
    shade_faces,
)

__all__ = ["render_png", "contact_sheet", "generator_streamlines", "generator_arrows", "best_view",
           "principal_axes", "projected_area", "render_view", "raster_view", "paint", "Raster", "rasterize", "View",
           "Picture",
           "DEFAULT_PIXELS", "opposite_view", "view_aspect", "face_geometry", "shade_faces",
           "new_figure", "save_figure", "figure_pixels", "save_pixels", "SUPERSAMPLE", "KEY_LIGHT", "FILL_LIGHT",
           "FLOW_COLOR"]
