"""Pictures: framing (principal axes, view of largest area), the rasterizer, streamlines that
stay on their part and follow the field, and the files render_png / contact_sheet write."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf import shapes
from torchakvf.errors import ParameterError
from torchakvf.io.render import (
    DEFAULT_PIXELS,
    best_view,
    contact_sheet,
    generator_streamlines,
    paint,
    principal_axes,
    projected_area,
    raster_view,
    rasterize,
    render_png,
    render_view,
)
from torchakvf.parts.generators import SymmetryGenerator


def _read_png(path):
    import matplotlib.image

    return matplotlib.image.imread(str(path))


def _normals_areas(v, f):
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    a = np.linalg.norm(n, axis=1)
    return n / a[:, None], a / 2


def test_principal_axes_of_an_ellipsoid_are_its_semi_axes():
    s = shapes.ellipsoid(axes=(1.0, 1.3, 1.7), level=3)
    rot = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))[0]
    v = s.vertices @ rot.T + np.array([3.0, -2.0, 1.0])
    center, axes = principal_axes(v, s.faces)
    np.testing.assert_allclose(center, [3.0, -2.0, 1.0], atol=1e-6)
    # largest extent first: the 1.7 axis (z before rotation), then 1.3 (y), then 1.0 (x)
    expected = rot.T[[2, 1, 0]]
    np.testing.assert_allclose(np.abs(np.sum(axes * expected, axis=1)), 1.0, atol=1e-3)


def test_projected_area_of_a_sphere_is_its_disc():
    s = shapes.icosphere(level=4)
    n, a = _normals_areas(s.vertices, s.faces)
    for d in (np.array([0, 0, 1.0]), np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])):
        assert projected_area(n, a, d) == pytest.approx(np.pi, rel=0.01)


def test_best_view_looks_at_a_flat_patch_face_on():
    s = shapes.square_patch(n=12, jitter=0.0)
    view = best_view(s.vertices, s.faces, tilt=0.4)
    normal = np.array([0.0, 0.0, 1.0])
    # the main axis of the oblique view is the patch normal: |d·n| = 1/sqrt(1 + 2·0.4²)
    assert abs(view.rotation[2] @ normal) == pytest.approx(1 / np.sqrt(1.32), abs=1e-6)
    np.testing.assert_allclose(view.rotation @ view.rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(view.rotation) == pytest.approx(1.0)


def test_best_view_puts_the_long_axis_across_the_picture():
    s = shapes.ellipsoid(axes=(1.0, 1.3, 3.0), level=3)
    view = best_view(s.vertices, s.faces)
    p = view.apply(s.vertices)
    ext = np.ptp(p, axis=0)
    assert ext[0] > 1.8 * ext[1]             # the 3.0 axis is horizontal


def test_rasterize_coverage_and_occlusion():
    # a square of two triangles over 0..40 px, and a nearer triangle over its lower-left half
    xy = np.array([[0, 0], [40, 0], [40, 40], [0, 40], [0, 0], [40, 40], [0, 40]], dtype=float)
    depth = np.array([0, 0, 0, 0, 1, 1, 1], dtype=float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]])
    ids, z = rasterize(xy, depth, faces, 50, 50)
    assert (ids >= 0).sum() == 40 * 40                          # pixel centres inside the square
    assert (ids == 2).sum() == pytest.approx(40 * 41 / 2, abs=41)   # the nearer triangle wins
    assert (ids == 1).sum() == 0                                 # face 1 is entirely behind face 2
    np.testing.assert_allclose(z[ids == 2], 1.0, rtol=1e-12)
    assert np.all(np.isinf(z[ids < 0]))


def _rasterize_by_sorting(xy, depth, faces, width, height):
    """The z-buffer written plainly: every pixel center inside a face's bounding box, tested by
    its barycentric coordinates; per pixel the nearest fragment, the first in face order among
    equal depths (a stable sort by pixel, then by -depth; NaN depths sort last)."""
    pix_all, z_all, face_all = [], [], []
    for fi, (a, b, c) in enumerate(faces):
        (x0, y0), (x1, y1), (x2, y2) = xy[a], xy[b], xy[c]
        det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        lo = np.clip(np.floor(np.minimum(np.minimum(xy[a], xy[b]), xy[c]) - 0.5).astype(int) + 1,
                     0, [width - 1, height - 1])
        hi = np.clip(np.floor(np.maximum(np.maximum(xy[a], xy[b]), xy[c]) - 0.5).astype(int),
                     -1, [width - 1, height - 1])
        if abs(det) <= 1e-12:
            continue
        for py in range(lo[1], hi[1] + 1):
            for px in range(lo[0], hi[0] + 1):
                dx, dy = (px + 0.5) - x0, (py + 0.5) - y0
                b1 = (dx * (y2 - y0) - (x2 - x0) * dy) / det
                b2 = ((x1 - x0) * dy - dx * (y1 - y0)) / det
                b0 = 1.0 - b1 - b2
                if b0 >= -1e-9 and b1 >= -1e-9 and b2 >= -1e-9:
                    pix_all.append(py * width + px)
                    z_all.append(b0 * depth[a] + b1 * depth[b] + b2 * depth[c])
                    face_all.append(fi)
    ids, zbuf = np.full(width * height, -1), np.full(width * height, -np.inf)
    order = np.lexsort((-np.array(z_all), np.array(pix_all)))
    seen = set()
    for i in order:
        if pix_all[i] not in seen:
            seen.add(pix_all[i])
            if z_all[i] > zbuf[pix_all[i]]:
                ids[pix_all[i]], zbuf[pix_all[i]] = face_all[i], z_all[i]
    return ids.reshape(height, width), zbuf.reshape(height, width)


@pytest.mark.parametrize("chunk", [4_000_000, 150])
def test_rasterize_equals_a_plain_z_buffer_with_ties_and_nan_depths(chunk):
    """Overlapping triangles, some at equal depths (the first face wins), some with a NaN corner
    depth (never nearer), cut into chunks of fragments or not: the face ids and depths of a
    plain per-pixel z-buffer."""
    rng = np.random.default_rng(4)
    xy = rng.random((60, 2)) * 30
    depth = rng.integers(0, 4, 60).astype(float)         # few distinct depths: many ties
    depth[::11] = np.nan
    faces = rng.integers(0, 60, (80, 3))
    ids, zbuf = rasterize(xy, depth, faces, 32, 24, chunk=chunk)
    want_ids, want_z = _rasterize_by_sorting(xy, depth, faces, 32, 24)
    np.testing.assert_array_equal(ids, want_ids)
    np.testing.assert_array_equal(zbuf, want_z)


def test_rasterize_row_spans_keep_every_fragment_of_skinny_and_tiny_triangles():
    """The row spans the test runs on lose no pixel the barycentric test accepts: slivers along
    and across the rows, near-horizontal and near-vertical edges, sub-pixel and pixel-sized
    triangles, centres on edges, at several scales: the plain z-buffer's ids and depths."""
    rng = np.random.default_rng(11)
    tris = []
    for _ in range(60):
        p = rng.random(2) * 40
        d = rng.standard_normal(2) * rng.choice([0.3, 3, 30])
        tris.append([p, p + d, p + d * rng.random() + rng.standard_normal(2) * rng.choice([1e-7, 1e-3, 0.5])])
    tris.append([[2.0, 5.0], [30.0, 5.0 + 1e-9], [16.0, 9.0]])          # an edge along a row of centres' y
    tris.append([[10.5, 1.0], [10.5 + 1e-9, 30.0], [14.0, 12.0]])       # an edge through pixel centres
    tris.append([[3.5, 3.5], [4.5, 3.5], [3.5, 4.5]])                   # corners on centres
    xy = np.asarray(tris, dtype=float).reshape(-1, 2)
    faces = np.arange(len(xy)).reshape(-1, 3)
    depth = rng.integers(0, 5, len(xy)).astype(float)
    for scale in (1.0, 3.7):
        ids, zbuf = rasterize(xy * scale, depth, faces, int(45 * scale), int(45 * scale))
        want_ids, want_z = _rasterize_by_sorting(xy * scale, depth, faces, int(45 * scale), int(45 * scale))
        np.testing.assert_array_equal(ids, want_ids)
        np.testing.assert_array_equal(zbuf, want_z)
        assert (ids >= 0).sum() > 100 * scale ** 2       # the triangles cover pixels: a real test


def test_sphere_fills_its_picture(tmp_path):
    s = shapes.icosphere(level=3)
    labels = np.zeros(len(s.faces), dtype=np.int64)
    view = best_view(s.vertices, s.faces)
    pic = render_view(s.vertices, s.faces, labels, view, 300, 300, margin=0.04)
    covered = (pic.image.sum(axis=2) < 2.95).mean()
    assert covered == pytest.approx(np.pi / 4 * 0.92 ** 2, abs=0.03)
    # shading: the lit side is brighter than the side away from the key light
    img = pic.image.sum(axis=2)
    assert img[100, 100] > img[200, 200] + 0.2


def test_labellings_of_one_view_share_its_raster():
    """Two labellings painted on one raster are the pictures each renders alone; the part border
    between the dumbbell's halves darkens pixels that one colour leaves plain."""
    s = shapes.dumbbell(n_around=24)
    view = best_view(s.vertices, s.faces)
    one = np.zeros(len(s.faces), dtype=np.int64)
    raster = raster_view(s.vertices, s.faces, view, 120, 80)
    pics = [paint(raster, lab) for lab in (s.part_labels, one)]
    for pic, lab in zip(pics, (s.part_labels, one)):
        alone = render_view(s.vertices, s.faces, lab, view, 120, 80)
        np.testing.assert_array_equal(pic.image, alone.image)
        np.testing.assert_array_equal(pic.face_ids, alone.face_ids)
    assert pics[0].image.shape == (80, 120, 3)
    grey = lambda img: img.sum(axis=2)  # noqa: E731
    assert (grey(pics[0].image) < grey(pics[1].image) - 0.1).any()     # the border line


def _paint_plainly(raster, labels):
    """paint's picture written plainly: the full-resolution image, outlines with NaN depths off
    the mesh, each darkening applied in turn, numpy's mean of each 2 x 2 block."""
    from torchakvf.io.outputs import label_colors
    from torchakvf.io.render import shade_faces

    ids, zbuf = raster.face_ids, raster.zbuf
    rgb = shade_faces(raster.normals_cam, label_colors(labels)[:, :3] / 255.0)
    hit = ids >= 0
    img = np.ones(ids.shape + (3,))
    img[hit] = rgb[ids[hit]]
    lab = np.where(hit, labels[np.maximum(ids, 0)], -2)
    zf = np.where(hit, zbuf, np.nan)
    edge, border = np.zeros(ids.shape, bool), np.zeros(ids.shape, bool)
    for a, b in (((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
                 ((slice(None), slice(1, None)), (slice(None), slice(None, -1)))):
        e = (hit[a] != hit[b]) | (np.nan_to_num(np.abs(zf[a] - zf[b]), nan=0.0) > 0.02 * raster.extent)
        bd = (lab[a] != lab[b]) & hit[a] & hit[b] & ~e
        edge[a] |= e
        edge[b] |= e
        border[a] |= bd
        border[b] |= bd
    img[edge] = img[edge] * 0.25
    img[border] = img[border] * 0.55
    return img.reshape(raster.height, 2, raster.width, 2, 3).mean(axis=(1, 3))


def test_paint_equals_the_picture_written_plainly():
    """Parts with borders, the connecting region (-1), silhouettes and depth jumps (two spheres,
    one behind the other): paint's picture is the plain one's (the same numbers but for the
    order of the 2 x 2 block sums, which a reduction may choose)."""
    a, b = shapes.icosphere(level=3), shapes.icosphere(level=2)
    v = np.concatenate([a.vertices, 0.6 * b.vertices + [0.9, 0.3, -1.5]])
    f = np.concatenate([a.faces, b.faces + len(a.vertices)])
    labels = (v[f].mean(axis=1)[:, 0] > 0.2).astype(np.int64) + 2 * (np.arange(len(f)) >= len(a.faces))
    labels[::7] = -1
    raster = raster_view(v, f, best_view(v, f), 90, 70)
    pic = paint(raster, labels)
    want = _paint_plainly(raster, labels)
    assert pic.image.shape == (70, 90, 3)
    assert (want < 0.3).any() and (want == 1.0).any()        # outlines and background are there
    np.testing.assert_allclose(pic.image, want, rtol=0, atol=1e-12)


def test_render_png_default_size_pixels_and_views(tmp_path):
    s = shapes.dumbbell(n_around=32)
    labels = s.part_labels
    render_png(tmp_path / "a.png", s.vertices, s.faces, labels, title="dumbbell")
    img = _read_png(tmp_path / "a.png")
    assert img.shape[1] >= 800 and img.shape[1] == DEFAULT_PIXELS
    render_png(tmp_path / "b.png", s.vertices, s.faces, labels, pixels=300, views=2)
    assert _read_png(tmp_path / "b.png").shape[1] == 600
    with pytest.raises(ParameterError, match="views must be 1 or 2"):
        render_png(tmp_path / "c.png", s.vertices, s.faces, labels, views=3)


def _rotation_field(v, f, axis=np.array([0.0, 0.0, 1.0])):
    c = v[f].mean(axis=1)
    return np.cross(axis, c)[:, None, :]                         # [F, 1, 3]


def test_streamlines_follow_a_rotation_and_stay_on_their_part():
    s = shapes.icosphere(level=4)
    v, f = s.vertices, s.faces
    c = v[f].mean(axis=1)
    labels = np.where(c[:, 2] > 0.0, 0, -1)                      # part 0: the upper hemisphere
    gens = [[SymmetryGenerator(0, 1.0, 0.0)]]
    lines = generator_streamlines(v, f, labels, _rotation_field(v, f), gens)
    assert len(lines) >= 6
    for part, pts in lines:
        assert part == 0
        r = np.linalg.norm(pts, axis=1)
        assert np.all(np.abs(r - 1.0) < 0.02)                    # on the surface
        assert np.all(pts[:, 2] > -0.03)                        # on part 0 only
        # a rotation about z has circles of latitude as streamlines: the height stays put
        assert np.ptp(pts[:, 2]) < 0.08 + 0.05 * np.ptp(pts[:, :2], axis=0).max()
        assert np.ptp(pts[:, :2], axis=0).max() > 0.05           # and the line goes somewhere


def test_streamlines_skip_parts_without_generators_and_respect_seed_faces():
    s = shapes.icosphere(level=3)
    v, f = s.vertices, s.faces
    labels = np.zeros(len(f), dtype=np.int64)
    assert generator_streamlines(v, f, labels, _rotation_field(v, f), [[]]) == []
    none = np.zeros(len(f), dtype=bool)
    gens = [[SymmetryGenerator(0, 1.0, 0.0)]]
    assert generator_streamlines(v, f, labels, _rotation_field(v, f), gens, seed_faces=none) == []


def test_render_png_with_flow_and_contact_sheet(tmp_path):
    s = shapes.icosphere(level=3)
    v, f = s.vertices, s.faces
    labels = np.zeros(len(f), dtype=np.int64)
    flow = (_rotation_field(v, f), [[SymmetryGenerator(0, 1.0, 0.0)]])
    render_png(tmp_path / "flow.png", v, f, labels, flow=flow)
    render_png(tmp_path / "plain.png", v, f, labels)
    a, b = _read_png(tmp_path / "flow.png"), _read_png(tmp_path / "plain.png")
    assert a.shape == b.shape
    dark = lambda img: (img[..., :3].sum(axis=2) < 0.5).sum()    # noqa: E731  streamline ink
    assert dark(a) > dark(b) + 500
    contact_sheet(tmp_path / "sheet.png", [(v, f, labels, "one"), (v, f, labels, "two", flow)], columns=2)
    sheet = _read_png(tmp_path / "sheet.png")
    assert sheet.shape[1] == 2 * 560


def test_best_view_stands_a_table_on_its_legs():
    # a slab (most of the area) on four thin legs below it: the legs point down in the picture
    import trimesh

    top = trimesh.creation.box(extents=(2.0, 1.2, 0.1))
    top.apply_translation((0, 0, 1.0))
    parts = [top]
    for x in (-0.9, 0.9):
        for y in (-0.5, 0.5):
            leg = trimesh.creation.box(extents=(0.06, 0.06, 1.0))
            leg.apply_translation((x, y, 0.5))
            parts.append(leg)
    m = trimesh.util.concatenate(parts)
    rot = np.linalg.qr(np.random.default_rng(3).standard_normal((3, 3)))[0]
    v = np.asarray(m.vertices) @ rot.T
    view = best_view(v, np.asarray(m.faces))
    up_world = rot @ np.array([0.0, 0.0, 1.0])
    assert view.rotation[1] @ up_world > 0.2        # legs down in the picture (oblique: not 1)
    assert view.rotation[2] @ up_world > 0.5        # and the camera is above the top
