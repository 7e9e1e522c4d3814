"""Boundaries (:mod:`torchakvf.parts.boundaries`): ``refine_along_isolines`` against the per-face
loop written out here, bitwise (same vertices, faces, labels and parents, in the same row order);
barycenter values by blocks, vertex distances and surface interpolation against their gathers."""
from __future__ import annotations

import numpy as np
import pytest

import torchakvf as ta
from torchakvf import shapes
from torchakvf.mesh.batch import mesh_edges
from torchakvf.mesh.clean import face_areas
from torchakvf.mesh.coarse import SurfacePoints
from torchakvf.parts import cut
from torchakvf.parts.boundaries import (
    RefinedMesh,
    barycenter_values,
    isoline_face_labels,
    refine_along_isolines,
    vertex_distances,
)
from torchakvf.parts.merge import merged_distances


def reference_refine(vertices: np.ndarray, faces: np.ndarray, vdist: np.ndarray) -> RefinedMesh:
    """The per-face loop: every edge gets an index (mesh_edges), cut edges a point, and each
    face whose corners belong to different parts is split in Python, one face at a time."""
    vlab = vdist.argmin(axis=1)
    edges, face_edges, _ = mesh_edges(faces)
    i, j = edges[:, 0], edges[:, 1]
    cut = vlab[i] != vlab[j]
    gi = vdist[i, vlab[i]] - vdist[i, vlab[j]]
    gj = vdist[j, vlab[i]] - vdist[j, vlab[j]]
    t = np.clip(np.where(cut, gi / np.where(cut, gi - gj, 1.0), 0.5), 0.0, 1.0)
    new_points = vertices[i[cut]] * (1 - t[cut, None]) + vertices[j[cut]] * t[cut, None]
    point_of_edge = np.full(len(edges), -1)
    point_of_edge[cut] = len(vertices) + np.arange(int(cut.sum()))
    verts = [vertices, new_points]
    n_verts = len(vertices) + len(new_points)

    out_f, out_l, out_p = [], [], []
    flab = vlab[faces]
    uniform = (flab[:, 0] == flab[:, 1]) & (flab[:, 1] == flab[:, 2])
    out_f.append(faces[uniform]), out_l.append(flab[uniform, 0]), out_p.append(np.flatnonzero(uniform))
    centroids = []
    for f in np.flatnonzero(~uniform):
        v = faces[f]
        lab = flab[f]
        m = point_of_edge[face_edges[f]]
        if len(set(lab.tolist())) == 2:
            k = int(np.flatnonzero((m >= 0) & (np.roll(m, 1) >= 0))[0])
            a, b, c = v[k], v[(k + 1) % 3], v[(k + 2) % 3]
            mab, mca = m[k], m[(k + 2) % 3]
            tris = [(a, mab, mca), (mab, b, c), (mab, c, mca)]
            labs = [lab[k], lab[(k + 1) % 3], lab[(k + 1) % 3]]
        else:
            centre = n_verts + len(centroids)
            centroids.append(vertices[v].mean(axis=0))
            tris, labs = [], []
            for k in range(3):
                tris += [(v[k], m[k], centre), (v[k], centre, m[(k + 2) % 3])]
                labs += [lab[k], lab[k]]
        out_f.append(np.array(tris)), out_l.append(np.array(labs)), out_p.append(np.full(len(tris), f))
    if centroids:
        verts.append(np.array(centroids))
    return RefinedMesh(vertices=np.concatenate(verts), faces=np.concatenate(out_f).astype(np.int64),
                       labels=np.concatenate(out_l).astype(np.int64),
                       parent=np.concatenate(out_p).astype(np.int64))


def assert_bitwise_equal(got: RefinedMesh, ref: RefinedMesh):
    for name in ("vertices", "faces", "labels", "parent"):
        a, b = getattr(got, name), getattr(ref, name)
        assert a.dtype == b.dtype and a.shape == b.shape, (name, a.dtype, a.shape, b.dtype, b.shape)
        assert a.tobytes() == b.tobytes(), name


def check(vertices, faces, vdist) -> RefinedMesh:
    with np.errstate(divide="ignore", invalid="ignore"):
        ref = reference_refine(vertices, faces, vdist)
        got = refine_along_isolines(vertices, faces, vdist)
    assert_bitwise_equal(got, ref)
    return got


def corner_label_counts(faces, vdist) -> np.ndarray:
    """[F] number of distinct parts among each face's corners."""
    flab = vdist.argmin(axis=1)[faces]
    return 1 + (flab[:, 0] != flab[:, 1]) + ((flab[:, 2] != flab[:, 0]) & (flab[:, 2] != flab[:, 1]))


@pytest.fixture
def recorded(monkeypatch):
    """Every call of refine_along_isolines a segmentation makes, checked against the loop."""
    calls = []

    def both(vertices, faces, vdist):
        calls.append(check(vertices, faces, vdist))
        return calls[-1]

    monkeypatch.setattr(cut, "refine_along_isolines", both)
    return calls


@pytest.mark.parametrize("name,k", [("dumbbell", 2), ("three_blobs", 3), ("three_blobs", 5),
                                    ("sphere_two_ellipsoids", 3), ("torus_chain", 3)])
def test_segment_refinement_of_builtin_shapes_is_the_loops(recorded, name, k):
    s = shapes.BUILTIN_SHAPES[name]()
    seg = ta.segment(ta.Mesh(s.vertices, s.faces), k=k, seed=0)
    assert len(recorded) == 1 and seg.meshes[0].refined is recorded[0]
    # torus_chain's parts are its connected components: nothing to cut there
    assert (len(recorded[0].faces) > len(s.faces)) == (name != "torus_chain")


@pytest.mark.parametrize("k,seed", [(2, 0), (3, 1), (5, 2), (8, 3)])
def test_random_labelings_with_two_and_three_part_faces(k, seed):
    s = shapes.icosphere(3)
    rng = np.random.default_rng(seed)
    vdist = rng.random((len(s.vertices), k))
    counts = corner_label_counts(s.faces, vdist)
    assert (counts == 2).any() and ((counts == 3).any() or k == 2)
    got = check(s.vertices, s.faces, vdist)
    assert len(got.faces) == (counts == 1).sum() + 3 * (counts == 2).sum() + 6 * (counts == 3).sum()


def test_smooth_labelings_and_ties():
    s = shapes.torus()
    rng = np.random.default_rng(4)
    centres = s.vertices[rng.choice(len(s.vertices), 6, replace=False)]
    vdist = np.linalg.norm(s.vertices[:, None] - centres[None], axis=-1)
    check(s.vertices, s.faces, vdist)
    # Ties (equal distances at a cut edge's end: the cut point on that vertex) as the loop's.
    check(s.vertices, s.faces, np.round(vdist * 2) / 2)
    # One part only: nothing is cut.
    got = check(s.vertices, s.faces, np.zeros((len(s.vertices), 1)))
    assert len(got.faces) == len(s.faces)


@pytest.mark.parametrize("make", [shapes.flat_disk, shapes.open_tube, shapes.hemisphere])
def test_meshes_with_boundary(make):
    s = make()
    rng = np.random.default_rng(5)
    for k in (2, 3, 4):
        check(s.vertices, s.faces, rng.random((len(s.vertices), k)))
    x = s.vertices[:, :1]
    check(s.vertices, s.faces, np.hstack([x, -x]))           # one straight cut across the boundary


def test_int32_faces():
    s = shapes.icosphere(2)
    vdist = np.random.default_rng(6).random((len(s.vertices), 3))
    a = refine_along_isolines(s.vertices, s.faces.astype(np.int32), vdist)
    assert_bitwise_equal(a, reference_refine(s.vertices, s.faces.astype(np.int64), vdist))


@pytest.mark.psb
def test_psb_mesh_full_resolution(psb, recorded):
    mesh = ta.load_mesh(psb / "meshes" / "1.off.gz")
    ta.segment(mesh, 5, seed=0)
    assert len(recorded) == 1
    clean = ta.clean_mesh(mesh)
    rng = np.random.default_rng(7)
    centres = clean.vertices[rng.choice(len(clean.vertices), 7, replace=False)]
    check(clean.vertices, clean.faces, np.linalg.norm(clean.vertices[:, None] - centres[None], axis=-1))


@pytest.mark.parametrize("k", [1, 7, 40])
def test_barycenter_values_by_blocks_are_the_gather_mean(k):
    """Several blocks (and a short last one) give ``vdist[faces].mean(axis=1)`` bitwise."""
    rng = np.random.default_rng(8)
    faces = rng.integers(0, 3000, (20011, 3))
    vdist = rng.random((3000, k))
    got = barycenter_values(faces, vdist)
    assert got.dtype == vdist.dtype and got.tobytes() == vdist[faces].mean(axis=1).tobytes()
    assert isoline_face_labels(faces, vdist).tobytes() == vdist[faces].mean(axis=1).argmin(axis=1).tobytes()


def test_merged_distances_and_vertex_distances_equal_their_loops():
    rng = np.random.default_rng(2)
    s = shapes.icosphere(2)
    before = rng.integers(0, 8, len(s.faces))
    after = np.array([0, 1, 0, 2, 1, 2, 0, 1])[before]
    before[:3] = -1
    dist = rng.random((len(s.vertices), 8))
    ref = np.full((len(s.vertices), 3), np.inf)
    for old, new in zip(before, after):
        if old >= 0:
            ref[:, new] = np.minimum(ref[:, new], dist[:, old])
    np.testing.assert_array_equal(merged_distances(dist, before, after), ref)
    feats, area = rng.normal(size=(len(s.faces), 5)), face_areas(s.vertices, s.faces)
    centers = rng.normal(size=(4, 5))
    centers /= np.linalg.norm(centers, axis=1, keepdims=True)
    unit = feats / np.linalg.norm(feats, axis=1, keepdims=True)
    acc = np.zeros((len(s.vertices), 5))
    np.add.at(acc, s.faces.reshape(-1), np.repeat(unit * area[:, None], 3, axis=0))
    acc /= np.linalg.norm(acc, axis=1, keepdims=True)
    np.testing.assert_array_equal(vertex_distances(s.vertices, s.faces, feats, area, centers), 1.0 - acc @ centers.T)


def test_barycenter_values_and_interpolation_equal_the_gathers():
    rng = np.random.default_rng(3)
    faces = rng.integers(0, 40, (70, 3))
    for v in (rng.random((40, 6)), rng.random(40)):
        np.testing.assert_array_equal(barycenter_values(faces, v), v[faces].mean(axis=1))
        bary = rng.random((90, 3))
        bary /= bary.sum(1, keepdims=True)
        pts = SurfacePoints(rng.integers(0, 70, 90), bary, np.zeros(90))
        corners = v[faces[pts.face]]
        ref = (corners * bary.reshape(bary.shape + (1,) * (corners.ndim - 2))).sum(axis=1)
        np.testing.assert_array_equal(pts.interpolate(faces, v), ref)
