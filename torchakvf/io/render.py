"""Headless pictures of segmentations: a small numpy z-buffer rasterizer shown with matplotlib's
Agg backend (no display, no OpenGL, no GPU).

What a picture does, and why:

* **Framing.** The mesh is put on its principal axes (PCA of the area-weighted face
  centroids), and the camera looks from the oblique direction, among a few around each
  principal axis, that shows the largest projected area (``0.5 Σ A_f |n_f · d|``), with the
  longest visible principal axis horizontal. Of the two opposite directions it looks from the
  side the area lies toward, and turns the picture upright (most of the area above the
  middle). A reclining human is seen from above at full length, a table from above at an angle
  rather than edge-on, a four-legged animal standing on its legs.
* **Shading.** Flat per-face Lambert shading with a key light (upper left) and a fill light
  (near the view direction), a little ambient and a faint headlight highlight; the part colour is
  modulated by the shading, so creases and facets read. Depth jumps (silhouettes) and part
  borders are drawn as thin dark lines.
* **Generators.** Each part's first symmetry generator (``MeshSegmentation.generators[p][0]``)
  is drawn as streamlines on that part only, seeded evenly (farthest-point sampling of the
  part's face centroids), traced on the surface in both directions and clipped where hidden.

The rasterizer supersamples 2x and averages down, so edges are anti-aliased.
"""
from __future__ import annotations

import io
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..mesh.clean import face_cross_products
from .outputs import atomic_write_bytes, label_colors

#: Default picture width in pixels (a picture with several views is wider).
DEFAULT_PIXELS = 900
#: Supersampling factor of the rasterizer (anti-aliasing).
SUPERSAMPLE = 2
#: Key and fill light directions in camera coordinates (x right, y up, z toward the viewer);
#: the fill is near the view direction, so no face the camera sees is left black.
KEY_LIGHT = np.array([-0.45, 0.6, 0.66])
FILL_LIGHT = np.array([0.35, -0.25, 0.9])
#: Streamline colour (near black, as in the paper's Figure 10).
FLOW_COLOR = (0.08, 0.08, 0.1)


# ---- camera -----------------------------------------------------------------------------
@dataclass(frozen=True)
class View:
    """An orthographic camera: ``rotation`` [3, 3] rows (right, up, toward viewer) applied to
    ``vertices - center``."""

    rotation: np.ndarray
    center: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """[N, 3] camera coordinates of world points [N, 3] (z toward the viewer)."""
        return (np.asarray(points, float) - self.center) @ self.rotation.T


def _face_geometry(v: np.ndarray, f: np.ndarray):
    tri = v[f]
    n = face_cross_products(v, f)
    area2 = np.linalg.norm(n, axis=1)
    return tri.mean(axis=1), n / np.maximum(area2, 1e-300)[:, None], 0.5 * area2


def principal_axes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(center [3], axes [3, 3]): the area-weighted centroid and the principal axes of the
    surface (rows, largest extent first), from the area-weighted covariance of the face
    centroids (vertex density does not bias it)."""
    c, _, a = _face_geometry(np.asarray(vertices, float), np.asarray(faces))
    w = a / max(a.sum(), 1e-300)
    center = w @ c
    d = c - center
    cov = (d * w[:, None]).T @ d
    _, vecs = np.linalg.eigh(cov)
    axes = vecs[:, ::-1].T.copy()
    if np.linalg.det(axes) < 0:
        axes[2] *= -1
    return center, axes


def projected_area(normals: np.ndarray, areas: np.ndarray, direction: np.ndarray) -> float:
    """Silhouette area of a closed surface seen along ``direction``: ``0.5 Σ A_f |n_f · d|``."""
    return 0.5 * float(areas @ np.abs(normals @ direction))


def best_view(vertices: np.ndarray, faces: np.ndarray, tilt: float = 0.4) -> View:
    """The oblique view (``tilt`` toward the two other axes) around a principal axis that
    shows the largest projected area; the longest principal axis visible across the picture
    is horizontal."""
    v, f = np.asarray(vertices, float), np.asarray(faces)
    center, axes = principal_axes(v, f)
    _, normals, areas = _face_geometry(v, f)
    best = None
    for i in range(3):
        j, k = [a for a in range(3) if a != i]
        for sj in (1, -1):
            for sk in (1, -1):
                d = axes[i] + tilt * (sj * axes[j] + sk * axes[k])
                d /= np.linalg.norm(d)
                score = projected_area(normals, areas, d)
                if best is None or score > best[0] * (1 + 1e-9):
                    best = (score, d, j)
    _, d, j = best
    # d and -d show the same area; look from the side the surface's area lies toward (a
    # table from above its top, not from under its legs)
    cent, _, a = _face_geometry(v, f)
    bulk = (a @ cent) / max(a.sum(), 1e-300)
    mid = 0.5 * ((cent @ d).max() + (cent @ d).min())
    if bulk @ d < mid:
        d = -d
    right = axes[j] - (axes[j] @ d) * d               # longest axis not looked along, in the image plane
    right /= np.linalg.norm(right)
    up = np.cross(d, right)
    # upright: the bulk of the area above the middle, thin protrusions (legs) below; turning
    # the picture half a turn about the view direction keeps the camera a rotation
    h = cent @ up
    if bulk @ up < 0.5 * (h.max() + h.min()):
        right, up = -right, -up
    return View(np.stack([right, up, d]), center)


def opposite_view(view: View) -> View:
    """The same framing seen from behind (turned about the vertical image axis)."""
    r = view.rotation
    return View(np.stack([-r[0], r[1], -r[2]]), view.center)


# ---- rasterizer -------------------------------------------------------------------------
def rasterize(xy: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int,
              chunk: int = 4_000_000) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer of triangles in pixel coordinates.

    xy : [V, 2] pixel coordinates (x right, y down); depth : [V], larger = nearer the viewer;
    faces : [F, 3]. Returns (face id [H, W] int64, -1 = background; depth [H, W], -inf = none).
    """
    tri = xy[faces]                                                   # [F, 3, 2]
    z = depth[faces]
    lo = np.clip(np.floor(tri.min(axis=1) - 0.5).astype(np.int64) + 1, 0, [width - 1, height - 1])
    hi = np.clip(np.floor(tri.max(axis=1) - 0.5).astype(np.int64), -1, [width - 1, height - 1])
    span = np.maximum(hi - lo + 1, 0)
    count = span[:, 0] * span[:, 1]
    ids = np.full(width * height, -1, dtype=np.int64)
    zbuf = np.full(width * height, -np.inf)
    (x0, y0), (x1, y1), (x2, y2) = tri[:, 0].T, tri[:, 1].T, tri[:, 2].T
    det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    ok = (count > 0) & (np.abs(det) > 1e-12)
    order = np.flatnonzero(ok)
    cum = np.cumsum(count[order])
    start = 0
    while start < len(order):
        stop = int(np.searchsorted(cum, (cum[start - 1] if start else 0) + chunk, side="right"))
        stop = max(stop, start + 1)
        sel = order[start:stop]
        start = stop
        c = count[sel]
        face = np.repeat(sel, c)
        local = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        w = span[face, 0]
        px = lo[face, 0] + local % w
        py = lo[face, 1] + local // w
        cx, cy = px + 0.5, py + 0.5
        dt = det[face]
        b1 = ((cx - x0[face]) * (y2[face] - y0[face]) - (x2[face] - x0[face]) * (cy - y0[face])) / dt
        b2 = ((x1[face] - x0[face]) * (cy - y0[face]) - (cx - x0[face]) * (y1[face] - y0[face])) / dt
        b0 = 1.0 - b1 - b2
        inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
        face, px, py = face[inside], px[inside], py[inside]
        zz = (b0[inside] * z[face, 0] + b1[inside] * z[face, 1] + b2[inside] * z[face, 2])
        pix = py * width + px
        # nearest fragment per pixel: sort by (pixel, -depth), keep the first of each pixel
        srt = np.lexsort((-zz, pix))
        pix, zz, face = pix[srt], zz[srt], face[srt]
        first = np.ones(len(pix), dtype=bool)
        first[1:] = pix[1:] != pix[:-1]
        pix, zz, face = pix[first], zz[first], face[first]
        nearer = zz > zbuf[pix]
        zbuf[pix[nearer]] = zz[nearer]
        ids[pix[nearer]] = face[nearer]
    return ids.reshape(height, width), zbuf.reshape(height, width)


def shade_faces(normals_cam: np.ndarray, base_rgb: np.ndarray) -> np.ndarray:
    """[F, 3] shaded colours: key + fill Lambert (two-sided), ambient, faint highlight."""
    n = normals_cam * np.where(normals_cam[:, 2:3] < 0, -1.0, 1.0)   # light the side we see
    key = KEY_LIGHT / np.linalg.norm(KEY_LIGHT)
    fill = FILL_LIGHT / np.linalg.norm(FILL_LIGHT)
    half = key + np.array([0.0, 0.0, 1.0])
    half /= np.linalg.norm(half)
    diffuse = 0.2 + 0.55 * np.clip(n @ key, 0, 1) + 0.4 * np.clip(n @ fill, 0, 1)
    spec = 0.12 * np.clip(n @ half, 0, 1) ** 24
    return np.clip(base_rgb * diffuse[:, None] + spec[:, None], 0.0, 1.0)


@dataclass
class Picture:
    """One rendered view: RGB image [H, W, 3] in [0, 1] (final resolution), the camera, and
    the supersampled z-buffer for occlusion tests of overlays."""

    image: np.ndarray
    view: View
    scale: float             # pixels (supersampled) per world unit
    offset: np.ndarray       # [2] pixel position of camera (0, 0), supersampled
    zbuf: np.ndarray
    ss: int
    face_ids: np.ndarray     # [H, W] supersampled face id per pixel, -1 = background

    def visible_faces(self, n_faces: int) -> np.ndarray:
        """[n_faces] bool, faces covering at least one pixel."""
        mask = np.zeros(n_faces, dtype=bool)
        mask[self.face_ids[self.face_ids >= 0]] = True
        return mask

    def to_pixels(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(xy [N, 2] final-resolution pixels, visible [N] bool) of world points."""
        p = self.view.apply(points)
        xy = np.stack([p[:, 0], -p[:, 1]], axis=1) * self.scale + self.offset
        h, w = self.zbuf.shape
        ix = np.clip(xy[:, 0].astype(np.int64), 0, w - 1)
        iy = np.clip(xy[:, 1].astype(np.int64), 0, h - 1)
        # a point on the surface is visible if nothing is in front of it (tolerance: a few
        # pixels of depth, the rasterized surface is piecewise flat); look at a 3x3 window
        tol = 3.0 / self.scale
        near = -np.inf
        for dy in (-2, 0, 2):
            for dx in (-2, 0, 2):
                near = np.maximum(near, self.zbuf[np.clip(iy + dy, 0, h - 1), np.clip(ix + dx, 0, w - 1)])
        visible = p[:, 2] >= near - tol
        return xy / self.ss, visible


def render_view(vertices, faces, labels, view: View, width: int, height: int,
                margin: float = 0.04, colors: np.ndarray | None = None) -> Picture:
    """Rasterize one view of a mesh coloured by part into a width x height picture."""
    v, f = np.asarray(vertices, float), np.asarray(faces)
    ss = SUPERSAMPLE
    W, H = width * ss, height * ss
    p = view.apply(v)
    lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
    ext = np.maximum(hi - lo, 1e-12)
    scale = min(W * (1 - 2 * margin) / ext[0], H * (1 - 2 * margin) / ext[1])
    mid = (lo + hi) / 2
    offset = np.array([W / 2 - mid[0] * scale, H / 2 + mid[1] * scale])
    xy = np.stack([p[:, 0], -p[:, 1]], axis=1) * scale + offset
    ids, zbuf = rasterize(xy, p[:, 2], f, W, H)
    _, normals, _ = _face_geometry(v, f)
    base = (label_colors(labels)[:, :3] / 255.0) if colors is None else colors
    rgb = shade_faces(normals @ view.rotation.T, base)
    img = np.ones((H, W, 3))
    hit = ids >= 0
    img[hit] = rgb[ids[hit]]
    # outlines: silhouettes / depth jumps, and borders between parts
    lab = np.where(hit, np.asarray(labels)[np.maximum(ids, 0)], -2)
    zf = np.where(hit, zbuf, np.nan)
    jump = 0.02 * float(max(ext))            # world units, like zbuf
    edge = np.zeros((H, W), dtype=bool)
    border = np.zeros((H, W), dtype=bool)
    for a, b in (((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
                 ((slice(None), slice(1, None)), (slice(None), slice(None, -1)))):
        dz = np.abs(zf[a] - zf[b])
        e = (hit[a] != hit[b]) | (np.nan_to_num(dz, nan=0.0) > jump)
        bd = (lab[a] != lab[b]) & hit[a] & hit[b] & ~e
        edge[a] |= e
        edge[b] |= e
        border[a] |= bd
        border[b] |= bd
    img[edge] = img[edge] * 0.25
    img[border] = img[border] * 0.55
    small = img.reshape(height, ss, width, ss, 3).mean(axis=(1, 3))
    return Picture(small, view, scale, offset, zbuf, ss, ids)


# ---- generators as streamlines ----------------------------------------------------------
def _farthest_points(points: np.ndarray, count: int, seed: int) -> np.ndarray:
    """Indices of ``count`` points spread evenly (greedy farthest-point sampling)."""
    rng = np.random.default_rng(seed)
    pick = [int(rng.integers(len(points)))]
    d = np.linalg.norm(points - points[pick[0]], axis=1)
    for _ in range(min(count, len(points)) - 1):
        i = int(d.argmax())
        pick.append(i)
        d = np.minimum(d, np.linalg.norm(points - points[i], axis=1))
    return np.array(pick)


def generator_streamlines(vertices, faces, labels, face_vectors, generators, seeds_total: int = 150,
                          seed: int = 0, which: int = 0, seed_faces: np.ndarray | None = None,
                          length: float = 3.5) -> list[tuple[int, np.ndarray]]:
    """Streamlines of each part's generator ``generators[p][which]``, on that part only.

    face_vectors : [F, n, 3] untangled Whitney vectors on the given faces
    (:meth:`~torchakvf.parts.Segmentation.face_vectors`); generators : per part, a list of
    :class:`~torchakvf.parts.generators.SymmetryGenerator`. Seeds are spread evenly over each
    part (count in proportion to the part's area, 8..60), each line is traced both ways with
    midpoint steps that follow the field of the nearest face on the part, and stops where the
    field fades (< 5% of its 95th percentile on the part), leaves the part or the surface, turns
    back, or reaches ``length`` seed spacings in all; a line shorter than 0.8 seed spacings, or
    running mostly within 0.35 spacings of a longer one, is dropped. seed_faces : optional [F] bool, faces
    a line may start on (a picture passes the faces it shows, so no seed is wasted on the
    hidden side). Returns [(part, [m, 3] points)].
    """
    from scipy.spatial import cKDTree

    v, f = np.asarray(vertices, float), np.asarray(faces)
    labels = np.asarray(labels)
    cent, normals, areas = _face_geometry(v, f)
    total = max(areas.sum(), 1e-300)
    lines = []
    for p, gens in enumerate(generators):
        if len(gens) <= which:
            continue
        idx = np.flatnonzero(labels == p)
        if len(idx) < 3:
            continue
        field = np.asarray(face_vectors)[idx, gens[which].field].astype(float)
        nrm = normals[idx]
        field = field - (field * nrm).sum(axis=1, keepdims=True) * nrm   # tangent to each face
        mag = np.linalg.norm(field, axis=1)
        ref = np.percentile(mag, 95)
        if ref <= 0:
            continue
        part_area = areas[idx].sum()
        count = int(np.clip(round(seeds_total * part_area / total), 8, 60))
        spacing = np.sqrt(part_area / count)
        step = spacing / 8
        n_steps = max(int(round(length * 4)), 2)
        tree = cKDTree(cent[idx])
        # a point farther than this from every centroid of the part has left it (or the surface)
        reach = 1.5 * np.sqrt(areas[idx] * 4 / np.sqrt(3))              # ~1.5 edge lengths
        strong = mag > 0.2 * ref
        if seed_faces is not None:
            strong &= np.asarray(seed_faces, dtype=bool)[idx]
        strong = np.flatnonzero(strong)
        if len(strong) < 3:
            continue
        start = strong[_farthest_points(cent[idx][strong], count, seed + p)]
        unit = field / np.maximum(mag, 1e-300)[:, None]

        def advance(x, sign):
            _, i = tree.query(x)
            k1 = unit[i] * sign
            _, j = tree.query(x + 0.5 * step * k1)
            x_new = x + step * unit[j] * sign
            # back onto the plane of the nearest face: the line stays on the surface
            _, m = tree.query(x_new)
            x_new = x_new - ((x_new - cent[idx][m]) * nrm[m]).sum(axis=1, keepdims=True) * nrm[m]
            dist, m = tree.query(x_new)
            alive = (mag[m] > 0.05 * ref) & (dist < np.maximum(reach[m], step)) & ((unit[m] * k1).sum(axis=1) > 0.0)
            return x_new, alive

        halves = []
        for sign in (1.0, -1.0):
            x = cent[idx][start].copy()
            track = [x.copy()]
            alive = np.ones(len(x), dtype=bool)
            for _ in range(n_steps):
                x_new, ok = advance(x, sign)
                alive &= ok
                x = np.where(alive[:, None], x_new, x)
                track.append(np.where(alive[:, None], x, np.nan))
            halves.append(np.stack(track, axis=1))                      # [S, n_steps+1, 3]
        traced = []
        for s in range(len(start)):
            pts = np.concatenate([halves[1][s][::-1], halves[0][s][1:]])
            pts = pts[~np.isnan(pts[:, 0])]
            # a fragment shorter than a seed spacing shows no flow (it stopped at a singularity)
            if len(pts) >= 3 and np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() > 0.8 * spacing:
                traced.append(pts)
        # even spacing: longest lines first, drop a line that mostly runs beside a kept one
        kept_pts = np.zeros((0, 3))
        for pts in sorted(traced, key=len, reverse=True):
            if len(kept_pts):
                near = cKDTree(kept_pts).query(pts)[0] < 0.35 * spacing
                if near.mean() > 0.5:
                    continue
            lines.append((p, pts))
            kept_pts = np.concatenate([kept_pts, pts])
    return lines


def generator_arrows(vertices, faces, labels, face_vectors, generators, per_part: int = 60,
                     seed: int = 0):
    """Arrow bases [N, 3] and vectors [N, 3] of each part's first generator on a sample of that
    part's faces (kept for callers that want arrows; pictures draw
    :func:`generator_streamlines`). face_vectors : [F, n, 3]."""
    rng = np.random.default_rng(seed)
    centroids = np.asarray(vertices)[np.asarray(faces)].mean(axis=1)
    scale = np.linalg.norm(np.ptp(np.asarray(vertices), axis=0)) * 0.06
    bases, vecs = [], []
    for p, gens in enumerate(generators):
        if not gens:
            continue
        idx = np.flatnonzero(np.asarray(labels) == p)
        if len(idx) == 0:
            continue
        idx = rng.choice(idx, min(per_part, len(idx)), replace=False)
        vec = np.asarray(face_vectors)[idx, gens[0].field]
        norm = np.linalg.norm(vec, axis=1).max()
        bases.append(centroids[idx])
        vecs.append(vec / max(norm, 1e-300) * scale)
    if not bases:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(bases), np.concatenate(vecs)


# ---- figures ----------------------------------------------------------------------------
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


def _aspect(vertices, view: View) -> float:
    """Height / width of the mesh's picture in this view, clamped to [0.3, 1] (landscape)."""
    p = view.apply(np.asarray(vertices, float))
    ext = np.ptp(p[:, :2], axis=0)
    return float(np.clip(ext[1] / max(ext[0], 1e-12), 0.3, 1.0))


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


def _figure(width_px: int, height_px: int, dpi: int = 100):
    import matplotlib
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt.figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)


def render_png(path, vertices, faces, labels, title: str | None = None, arrows=None,
               size: float | None = None, *, flow=None, streamlines=None, views: int = 1,
               pixels: int = DEFAULT_PIXELS) -> None:
    """One mesh coloured by part (grey = connecting region) as a PNG ``pixels`` wide per view
    (height from the mesh's shape in that view, 0.3-1 x the width).

    flow : optional (face_vectors [F, n, 3], generators per part): each part's first
        generator drawn as :func:`generator_streamlines` seeded on the faces the view shows;
    streamlines : optional precomputed output of :func:`generator_streamlines` instead;
    arrows : optional (bases [N, 3], vectors [N, 3]) from :func:`generator_arrows`;
    views : 1 (the view showing most area) or 2 (that view and the opposite side);
    size : legacy figure size in inches (100 px each), overrides ``pixels`` when given.
    """
    if views not in (1, 2):
        raise ValueError(f"views must be 1 or 2, got {views!r}")
    if size is not None:
        pixels = max(int(size * 100), 200)
    vs = _views(vertices, faces, views)
    w = int(pixels)
    h = max(int(round(w * _aspect(vertices, vs[0]))), 1)
    title_h = 44 if title else 0
    fig = _figure(w * views, h + title_h)
    for i, view in enumerate(vs):
        ax = fig.add_axes([i / views, 0, 1 / views, h / (h + title_h)])
        _panel(ax, vertices, faces, labels, view, w, h, lines=streamlines, flow=flow, arrows=arrows)
    if title:
        fig.text(0.5, 1 - 0.5 * title_h / (h + title_h), title, ha="center", va="center", fontsize=14)
    _save(fig, path, tight=False)


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
    aspect = max(_aspect(it[0], vw) for it, vw in zip(items, views))
    cell_w, img_h, title_h = int(pixels), int(round(pixels * aspect)), 36
    cell_h = img_h + title_h
    fig = _figure(cell_w * columns, cell_h * rows)
    H = cell_h * rows
    for i, (item, view) in enumerate(zip(items, views)):
        v, f, lab, title = item[:4]
        flow = item[4] if len(item) > 4 else None
        r, c = divmod(i, columns)
        ax = fig.add_axes([c / columns, 1 - ((r + 1) * cell_h) / H, 1 / columns, img_h / H])
        _panel(ax, v, f, lab, view, cell_w, img_h, flow=flow)
        fig.text((c + 0.5) / columns, 1 - (r * cell_h + title_h / 2) / H, title,
                 ha="center", va="center", fontsize=13)
    _save(fig, path, tight=False)


def _save(fig, path, tight: bool = True):
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight" if tight else None, facecolor="white")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


__all__ = ["render_png", "contact_sheet", "generator_streamlines", "generator_arrows", "best_view",
           "principal_axes", "projected_area", "render_view", "rasterize", "View", "Picture",
           "DEFAULT_PIXELS"]
