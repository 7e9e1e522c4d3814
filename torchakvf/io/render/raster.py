"""The z-buffer rasterizer and its shading: one view of a mesh coloured by part.

Flat per-face Lambert shading with a key light (upper left) and a fill light (near the view
direction), a little ambient and a faint headlight highlight; the part colour is modulated by the
shading, so creases and facets read. Depth jumps (silhouettes) and part borders are drawn as thin
dark lines. The rasterizer supersamples 2x and averages down, so edges are anti-aliased.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..outputs import label_colors
from .camera import View, face_geometry

#: Supersampling factor of the rasterizer (anti-aliasing).
SUPERSAMPLE = 2
#: Key and fill light directions in camera coordinates (x right, y up, z toward the viewer);
#: the fill is near the view direction, so no face the camera sees is left black.
KEY_LIGHT = np.array([-0.45, 0.6, 0.66])
FILL_LIGHT = np.array([0.35, -0.25, 0.9])


#: Barycentric slack of the row spans (:func:`_row_spans`): far above the round-off of the exact
#: test's barycentric coordinates, so the spans keep every fragment the test accepts.
SPAN_SLACK = 1e-6
#: Faces of less area (pixels²) than this are tested over their whole bounding box: their
#: barycentric coordinates grow too large across it for the spans' slack.
SPAN_MIN_AREA = 1.0


def rasterize(xy: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int,
              chunk: int = 4_000_000) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer of triangles in pixel coordinates.

    xy : [V, 2] pixel coordinates (x right, y down); depth : [V], larger = nearer the viewer;
    faces : [F, 3]. Returns (face id [H, W] int64, -1 = background; depth [H, W], -inf = none).

    A pixel belongs to a face where its centre's barycentric coordinates are all >= -1e-9. The
    test runs on each row's span of pixel centres that can pass it (:func:`_row_spans`, a little
    wider than the triangle), not on the whole bounding box: the same fragments, in the same
    order, about a third of the candidates.
    """
    tri = xy[faces]                                                   # [F, 3, 2]
    z = depth[faces]
    corner_min = np.minimum(np.minimum(tri[:, 0], tri[:, 1]), tri[:, 2])  # tri.min(axis=1), faster
    corner_max = np.maximum(np.maximum(tri[:, 0], tri[:, 1]), tri[:, 2])
    lo = np.clip(np.floor(corner_min - 0.5).astype(np.int64) + 1, 0, [width - 1, height - 1])
    hi = np.clip(np.floor(corner_max - 0.5).astype(np.int64), -1, [width - 1, height - 1])
    span = np.maximum(hi - lo + 1, 0)
    count = span[:, 0] * span[:, 1]
    ids = np.full(width * height, -1, dtype=np.int64)
    zbuf = np.full(width * height, -np.inf)
    (x0, y0), (x1, y1), (x2, y2) = tri[:, 0].T, tri[:, 1].T, tri[:, 2].T
    e1x, e1y, e2x, e2y = x1 - x0, y1 - y0, x2 - x0, y2 - y0
    det = e1x * e2y - e2x * e1y
    ok = (count > 0) & (np.abs(det) > 1e-12)
    order = np.flatnonzero(ok)
    # one entry per (face, row of its bounding box): faces in order, rows ascending
    rows = span[order, 1]
    row_face = np.repeat(order, rows)
    row_y = lo[row_face, 1] + _run_offsets(rows)
    col_lo, col_hi = _row_spans(row_face, row_y, lo[:, 0], hi[:, 0], x0, y0, e1x, e1y, e2x, e2y, det)
    width_r = np.maximum(col_hi - col_lo + 1, 0)
    keep = np.flatnonzero(width_r > 0)
    row_face, row_y, col_lo, width_r = row_face[keep], row_y[keep], col_lo[keep], width_r[keep]
    cum = np.cumsum(width_r)
    start = 0
    while start < len(row_face):
        stop = int(np.searchsorted(cum, (cum[start - 1] if start else 0) + chunk, side="right"))
        stop = max(stop, start + 1)
        c = width_r[start:stop]
        face = np.repeat(row_face[start:stop], c)
        px = np.repeat(col_lo[start:stop], c) + _run_offsets(c)
        py = np.repeat(row_y[start:stop], c)
        start = stop
        # each face's values gathered once per fragment (a[face] - b[face] is (a - b)[face] to
        # the bit, so the coordinates are those of the per-corner expression)
        dx, dy = (px + 0.5) - x0[face], (py + 0.5) - y0[face]
        dt = det[face]
        b1 = (dx * e2y[face] - e2x[face] * dy) / dt
        b2 = (e1x[face] * dy - dx * e1y[face]) / dt
        b0 = 1.0 - b1 - b2
        inside = np.flatnonzero((b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9))
        pix = (py * width + px)[inside]
        face = face[inside]
        zz = (b0[inside] * z[face, 0] + b1[inside] * z[face, 1] + b2[inside] * z[face, 2])
        # nearest fragment per pixel, the first of them (in fragment order) on equal depths: the
        # largest depth per pixel, then the lowest index among the fragments at it (two scatters,
        # 3x a sort of the fragments by (pixel, -depth))
        near = np.full(width * height, -np.inf)
        np.fmax.at(near, pix, zz)                          # (a NaN depth never wins, as in a sort)
        at = np.flatnonzero(zz == near[pix])
        pick = np.full(width * height, len(zz))
        np.minimum.at(pick, pix[at], at)
        pix = np.flatnonzero(pick < len(zz))
        pick = pick[pix]
        zz, face = zz[pick], face[pick]
        nearer = zz > zbuf[pix]
        zbuf[pix[nearer]] = zz[nearer]
        ids[pix[nearer]] = face[nearer]
    return ids.reshape(height, width), zbuf.reshape(height, width)


def _run_offsets(counts: np.ndarray) -> np.ndarray:
    """[sum(counts)] 0, 1, ..., counts[i] - 1 for each run i in turn (a run's rows or pixels)."""
    return np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)


def _row_spans(face, py, col_lo, col_hi, x0, y0, e1x, e1y, e2x, e2y, det):
    """([R] first, [R] last pixel column) of each row ``py`` [R] of face ``face`` [R] whose
    centre can pass the barycentric test. Along a row each coordinate is linear in the centre's
    x, so each of the three tests bounds x from one side, at p·dy - q from corner 0 (p, q per
    face and test; dy the row centre's height over corner 0). The bounds are solved with
    :data:`SPAN_SLACK` of slack and rounded outwards, so no fragment the test accepts falls
    outside; faces under :data:`SPAN_MIN_AREA` keep their bounding box's columns (``col_lo``,
    ``col_hi`` [F])."""
    sign = np.sign(det)
    dt = np.abs(det)
    slack = SPAN_SLACK * dt
    # sign·(b·det) = a·dx - c·dy: b1, b2 >= -slack (a·dx >= c·dy - slack) and
    # b1 + b2 <= 1 + slack (a0·dx <= c0·dy + dt + slack)
    a1, c1 = sign * e2y, sign * e2x
    a2, c2 = -sign * e1y, -sign * e1x
    a0, c0 = a1 + a2, c1 + c2
    dy = (py + 0.5) - y0[face]
    lower = np.full(len(face), -np.inf)
    upper = np.full(len(face), np.inf)
    with np.errstate(divide="ignore", invalid="ignore"):
        for a, c, q, lower_side in ((a1, c1, slack, a1 > 0), (a2, c2, slack, a2 > 0),
                                    (a0, c0, -(dt + slack), a0 < 0)):
            upper_side = (a != 0) & ~lower_side
            pa, qa = c / a, q / a
            # each face's bound on its rows: from below (else -inf) or from above (else inf)
            lo_p, lo_q = np.where(lower_side, pa, 0.0), np.where(lower_side, qa, np.inf)
            hi_p, hi_q = np.where(upper_side, pa, 0.0), np.where(upper_side, qa, -np.inf)
            np.maximum(lower, np.take(lo_p, face) * dy - np.take(lo_q, face), out=lower)
            np.minimum(upper, np.take(hi_p, face) * dy - np.take(hi_q, face), out=upper)
        first = np.ceil(x0[face] + lower - 0.5 - 1e-6)
        last = np.floor(x0[face] + upper - 0.5 + 1e-6)
    box_lo, box_hi = col_lo[face], col_hi[face]
    small = (dt < SPAN_MIN_AREA)[face]
    first = np.where(small | ~(first > box_lo), box_lo, first).astype(np.int64)
    last = np.where(small | ~(last < box_hi), box_hi, last).astype(np.int64)
    return first, last


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


@dataclass
class Raster:
    """One view of a mesh rasterized (supersampled), before it is coloured: what every
    labelling of the mesh seen from that view shares (:func:`raster_view`, :func:`paint`)."""

    view: View
    width: int               # final-resolution pixels
    height: int
    scale: float             # pixels (supersampled) per world unit
    offset: np.ndarray       # [2] pixel position of camera (0, 0), supersampled
    face_ids: np.ndarray     # [H·ss, W·ss] face per pixel, -1 = background
    zbuf: np.ndarray         # [H·ss, W·ss] depth, -inf = none
    normals_cam: np.ndarray  # [F, 3] unit face normals in camera coordinates
    extent: float            # world units of the larger side of the projected mesh


def raster_view(vertices, faces, view: View, width: int, height: int, margin: float = 0.04) -> Raster:
    """Rasterize one view of a mesh into a width x height picture (supersampled), uncoloured."""
    v, f = np.asarray(vertices, float), np.asarray(faces)
    W, H = width * SUPERSAMPLE, height * SUPERSAMPLE
    p = view.apply(v)
    lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
    ext = np.maximum(hi - lo, 1e-12)
    scale = min(W * (1 - 2 * margin) / ext[0], H * (1 - 2 * margin) / ext[1])
    mid = (lo + hi) / 2
    offset = np.array([W / 2 - mid[0] * scale, H / 2 + mid[1] * scale])
    xy = np.stack([p[:, 0], -p[:, 1]], axis=1) * scale + offset
    ids, zbuf = rasterize(xy, p[:, 2], f, W, H)
    _, normals, _ = face_geometry(v, f)
    return Raster(view, int(width), int(height), scale, offset, ids, zbuf, normals @ view.rotation.T, float(max(ext)))


def paint(raster: Raster, labels, colors: np.ndarray | None = None) -> Picture:
    """The picture of a rasterized view coloured by part: shading, silhouettes and part borders.

    labels : [F] part per face; colors : optional [F, 3] RGB in [0, 1] instead of the parts'."""
    ss, ids, zbuf = SUPERSAMPLE, raster.face_ids, raster.zbuf
    H, W = ids.shape
    base = (label_colors(labels)[:, :3] / 255.0) if colors is None else colors
    rgb = shade_faces(raster.normals_cam, base)
    hit = ids >= 0
    edge, border = _outlines(hit, np.asarray(labels)[np.maximum(ids, 0)], zbuf, 0.02 * raster.extent)
    # the shaded colour per supersample (white background), darkened on outlines: scaling by
    # 0.25 is exact, so one factor 0.25 * 0.55 on a pixel both edge and border darkens it to the
    # bit as the two scalings one after the other would
    shade = np.where(edge, 0.25, 1.0) * np.where(border, 0.55, 1.0)
    palette = np.concatenate([rgb, np.ones((1, 3))])
    img = np.take(palette, np.where(hit, ids, len(rgb)), axis=0) * shade[..., None]
    small = _box_mean(img, raster.height, raster.width, ss)
    return Picture(small, raster.view, raster.scale, raster.offset, zbuf, ss, ids)


def _outlines(hit: np.ndarray, lab: np.ndarray, zbuf: np.ndarray, jump: float) -> tuple[np.ndarray, np.ndarray]:
    """(edge, border) [H, W] bool of a supersampled view: pixels on either side of a silhouette
    or a depth jump over ``jump`` (world units, like ``zbuf``), and of a border between parts
    (``lab`` [H, W], the part of each pixel's face) that is no edge."""
    edge = np.zeros(hit.shape, dtype=bool)
    border = np.zeros(hit.shape, dtype=bool)
    with np.errstate(invalid="ignore"):
        for a, b in (((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
                     ((slice(None), slice(1, None)), (slice(None), slice(None, -1)))):
            both = hit[a] & hit[b]
            # depths -inf off the mesh: a jump to it is inf (also a silhouette), between two
            # background pixels NaN, which compares False
            e = (hit[a] != hit[b]) | (np.abs(zbuf[a] - zbuf[b]) > jump)
            bd = (lab[a] != lab[b]) & both & ~e
            edge[a] |= e
            edge[b] |= e
            border[a] |= bd
            border[b] |= bd
    return edge, border


def _box_mean(img: np.ndarray, height: int, width: int, ss: int) -> np.ndarray:
    """[height, width, C] mean of each ss x ss block of ``img`` [height·ss, width·ss, C]: the sum
    in row-major order over the block, then divided by its size, as numpy's ``mean`` over the
    block axes sums (so the same numbers to the bit where it does)."""
    blocks = img.reshape(height, ss, width, ss, img.shape[-1])
    total = blocks[:, 0, :, 0].copy()
    for i in range(ss):
        for j in range(ss):
            if i or j:
                total += blocks[:, i, :, j]
    total /= ss * ss
    return total


def render_view(vertices, faces, labels, view: View, width: int, height: int,
                margin: float = 0.04, colors: np.ndarray | None = None) -> Picture:
    """Rasterize one view of a mesh coloured by part into a width x height picture
    (:func:`raster_view` then :func:`paint`; several labellings of one view share the first)."""
    return paint(raster_view(vertices, faces, view, width, height, margin), labels, colors)


__all__ = ["rasterize", "shade_faces", "Picture", "Raster", "raster_view", "paint", "render_view",
           "SUPERSAMPLE", "KEY_LIGHT", "FILL_LIGHT"]
