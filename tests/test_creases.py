"""Crease patches (:mod:`torchakvf.parts.creases`): the band on a folded hinge by hand, no patch
across a part boundary on crease-delimited shapes (crisp voxel creases, rounded marching
creases), only concave creases where asked, one patch on smooth surfaces, and the (label, patch) split."""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from helpers.planar_meshes import hinge

from torchakvf import shapes
from torchakvf.mesh.clean import face_areas
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.creases import crease_band, crease_patches, split_by_patches, unit_face_normals
from torchakvf.parts.topology import face_adjacency


def misassigned_area(s, patches) -> float:
    """Share of the surface whose patch's largest part is another part."""
    a = face_areas(s.vertices, s.faces)
    wrong = 0.0
    for q in np.unique(patches):
        c = np.bincount(s.part_labels[patches == q], weights=a[patches == q])
        wrong += c.sum() - c.max()
    return wrong / a.sum()


@pytest.mark.parametrize("fold, band", [(math.radians(90), True), (math.radians(30), False)])
def test_band_of_a_hinge_by_hand(fold, band):
    v, f = hinge(fold)
    got = crease_band(unit_face_normals(v, f), face_adjacency(f), angle=math.radians(60), rings=1)
    assert got.tolist() == [band, band]


@pytest.mark.parametrize("fold, concave", [(math.radians(90), True), (math.radians(-90), False)])
def test_only_a_valley_is_a_concave_band(fold, concave):
    # fold > 0 folds the second triangle up over the first's normal side: a valley
    v, f = hinge(fold)
    centroids = v[f].mean(axis=1)
    got = crease_band(unit_face_normals(v, f), face_adjacency(f), angle=math.radians(60), rings=1,
                      centroids=centroids)
    assert got.tolist() == [concave, concave]


@pytest.mark.parametrize("rings", [1, 2, 3])
@pytest.mark.parametrize("concave", [False, True])
def test_band_against_every_pair_within_the_rings(rings, concave):
    """The band against a face-by-face reference: each face against every face at most ``rings``
    dual hops away (scipy's unweighted shortest paths), in float64; faces whose least cosine
    lies within 1e-4 of the threshold are left out (the band tests in float32)."""
    from scipy.sparse.csgraph import shortest_path

    from torchakvf.parts.creases import dual_ball, dual_graph

    s = shapes.table(0.1)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces)
    v = v + 0.01 * np.sin(7.0 * v[:, [1, 2, 0]])         # bent a little: cosines of every size
    adjacency = face_adjacency(f)
    normals, centroids = unit_face_normals(v, f), v[f].mean(axis=1)
    hops = shortest_path(dual_graph(adjacency, len(f)), unweighted=True)
    within = hops <= rings
    ball = dual_ball(adjacency, len(f), rings).toarray() > 0
    np.testing.assert_array_equal(ball, within)
    cos = normals @ normals.T
    if concave:
        bend = np.einsum("fgk,fgk->fg", centroids[None] - centroids[:, None], normals[None] - normals[:, None])
        cos = np.where(bend < 0, cos, 1.0)
    least = np.where(within, cos, 1.0).min(axis=1)
    angle = math.radians(30)
    got = crease_band(normals, adjacency, angle, rings, centroids if concave else None)
    clear = np.abs(least - math.cos(angle)) > 1e-4
    assert got.any() and (~got).any()
    np.testing.assert_array_equal(got[clear], (least < math.cos(angle))[clear])


def test_concave_creases_cut_a_table_into_its_parts_and_leave_a_box_whole():
    # the legs meet the slab in concave creases; every other crease of the table and of a box is
    # convex, the edge of one part
    s = shapes.table(0.05)
    patches = crease_patches(s.vertices, s.faces, dual_edges(s.vertices, s.faces), concave_only=True)
    assert misassigned_area(s, patches) == 0.0
    assert len(np.unique(patches)) == s.n_parts
    box = trimesh.creation.box().subdivide().subdivide()
    d = dual_edges(box.vertices, box.faces)
    assert len(np.unique(crease_patches(box.vertices, box.faces, d))) >= 6
    assert np.all(crease_patches(box.vertices, box.faces, d, concave_only=True) == 0)


def test_crisp_creases_of_a_voxel_table_bound_its_parts():
    # every face of the slab and the legs is flat and meets the next part at 90° over one edge;
    # the legs are 3 voxels wide, narrower than a 3-ring band on both sides
    s = shapes.table(0.05)
    patches = crease_patches(s.vertices, s.faces, dual_edges(s.vertices, s.faces))
    assert misassigned_area(s, patches) == 0.0
    assert len(np.unique(patches)) >= s.n_parts


def test_a_smooth_surface_is_one_patch():
    s = shapes.icosphere(3)
    d = dual_edges(s.vertices, s.faces)
    assert not crease_band(unit_face_normals(s.vertices, s.faces), d.pairs).any()
    assert np.all(crease_patches(s.vertices, s.faces, d) == 0)


def test_split_by_patches_keeps_the_label_and_separates_the_pairs():
    labels = np.array([0, 0, 1, 1, 2])
    patches = np.array([0, 1, 1, 1, 0])
    split, n = split_by_patches(labels, patches)
    assert n == 2
    np.testing.assert_array_equal(split // n, labels)
    assert len(np.unique(split)) == 4            # (0,0) (0,1) (1,1) (2,0)
