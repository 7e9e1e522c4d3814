"""Crease patches (:mod:`torchakvf.parts.creases`): the band on a folded hinge by hand, no patch
across a part boundary on crease-delimited shapes (crisp voxel creases, rounded marching
creases), only concave creases where asked, one patch on smooth surfaces, a crease that encloses
no patch cutting the pieces it crosses, and the (label, patch) split."""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from helpers.planar_meshes import hinge

from torchakvf import shapes
from torchakvf.mesh.clean import face_areas
from torchakvf.parts.concavity import dual_edges
from torchakvf.parts.creases import (
    crease_band,
    crease_band_of,
    crease_patches,
    split_by_patches,
    unit_face_normals,
    unite_patch_fragments,
)
from torchakvf.parts.topology import face_adjacency
from torchakvf.shapes.implicit import _voxel_surface


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


def bored_hub(h: float = 0.1):
    """A plate (2.6 x 2.6 x 0.2) with a hub (1.8 x 1.8 x 0.6) on it and a square bore (1.0 x 1.0)
    through both, voxel size h: (vertices, faces, part [F] 0 plate 1 hub, bore [F] whether a face
    is on the bore's wall). The hub meets the plate in a concave crease all round, but the bore's
    wall joins the hub's top to the plate's underside over convex creases alone (its walls are
    wider than the bands of its concave corners)."""
    n, t_plate, hub, t_hub, bore = round(2.6 / h), round(0.2 / h), round(1.8 / h), round(0.6 / h), round(1.0 / h)
    occ = np.zeros((n, n, t_plate + t_hub), dtype=bool)
    part = np.zeros(occ.shape, dtype=np.int64)
    occ[:, :, :t_plate] = True
    lo = (n - hub) // 2
    occ[lo:lo + hub, lo:lo + hub, t_plate:] = True
    part[:, :, t_plate:] = 1
    b0 = (n - bore) // 2
    occ[b0:b0 + bore, b0:b0 + bore, :] = False
    v, f, owner = _voxel_surface(occ, h, (-1.3, -1.3, 0.0))
    c = v[f].mean(axis=1)
    half = bore * h / 2
    in_bore = (np.abs(c[:, 0]) <= half + 1e-9) & (np.abs(c[:, 1]) <= half + 1e-9)
    return v, f, part.reshape(-1)[owner], in_bore


def test_a_crease_that_encloses_no_patch_still_cuts_the_pieces_it_crosses():
    """On a bored hub the concave crease round the hub encloses no patch of the surface: the
    patches are one. Cut by a labelling's boundaries as well (the bore's wall one piece, the rest
    another), the rest falls apart along the crease into the plate and the hub, with no face of
    one in the other's patch; the bore's wall into its four sides (its corners are concave)."""
    v, f, part, in_bore = bored_hub()
    d = dual_edges(v, f)
    whole = crease_patches(v, f, d, concave_only=True)
    assert np.all(whole == whole[0])
    labels = in_bore.astype(np.int64)
    apart = labels[d.pairs[:, 0]] != labels[d.pairs[:, 1]]
    band = crease_band_of(v, f, d, concave_only=True)
    pieces = crease_patches(v, f, d, concave_only=True, cut=apart, band=band)
    np.testing.assert_array_equal(pieces, crease_patches(v, f, d, concave_only=True, cut=apart))
    rest = ~in_bore
    assert len(np.unique(pieces[rest])) == 2
    for q in np.unique(pieces[rest]):
        assert len(np.unique(part[rest & (pieces == q)])) == 1
    assert len(np.unique(pieces[in_bore])) == 4
    assert not set(pieces[in_bore]) & set(pieces[rest])


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


def test_unite_patch_fragments_by_hand():
    """Faces 0-9 in a chain (face i shares an edge with i + 1), each of area 1 (floor 0.25: 2.5
    faces). Patch 0 (faces 0-4) holds a large piece: left as it is. Patch 1 (faces 5-7, at the
    floor) is cut into pieces of 1 and 2 faces, both small: one piece, labelled as the larger.
    Patch 2 (faces 8-9, below the floor) is cut in two: left as it is."""
    adjacency = np.stack([np.arange(9), np.arange(1, 10)], axis=1)
    patches = np.array([0, 0, 0, 0, 0, 1, 1, 1, 2, 2])
    labels = np.array([3, 3, 3, 4, 4, 5, 6, 6, 7, 8])
    got = unite_patch_fragments(labels, patches, adjacency, np.ones(10), 0.25)
    np.testing.assert_array_equal(got, [3, 3, 3, 4, 4, 6, 6, 6, 7, 8])
    # a floor below every piece changes nothing; at 0.2 (2 faces) patch 2 is one piece too
    np.testing.assert_array_equal(unite_patch_fragments(labels, patches, adjacency, np.ones(10), 0.05), labels)
    np.testing.assert_array_equal(unite_patch_fragments(labels, patches, adjacency, np.ones(10), 0.2),
                                  [3, 3, 3, 4, 4, 5, 6, 6, 7, 7])
    # above every patch but the first, only the first (5 faces, all pieces small) is united
    np.testing.assert_array_equal(unite_patch_fragments(labels, patches, adjacency, np.ones(10), 0.45),
                                  [3, 3, 3, 3, 3, 5, 6, 6, 7, 8])


def test_a_leg_cut_across_by_k_means_is_one_piece_again():
    """A table's legs, each cut across into three bands (k-means pieces below the floor, as on a
    thin table): after the split by the concave creases' patches each leg is one piece; the slab's
    pieces, above the floor, are left as they are."""
    s = shapes.table(0.05)
    a = face_areas(s.vertices, s.faces)
    d = dual_edges(s.vertices, s.faces)
    patches = crease_patches(s.vertices, s.faces, d, concave_only=True)
    height = s.vertices[s.faces].mean(axis=1)[:, 2]
    # bands across the legs by height; the slab in two halves by x
    bands = np.digitize(height, np.quantile(height[s.part_labels > 0], [1 / 3, 2 / 3]))
    halves = (s.vertices[s.faces].mean(axis=1)[:, 0] > 0).astype(np.int64)
    labels = np.where(s.part_labels > 0, 2 + bands, halves)
    split, _ = split_by_patches(labels, patches)
    leg_share = np.bincount(s.part_labels, weights=a) / a.sum()
    floor = 0.9 * leg_share[1:].min()
    got = unite_patch_fragments(split, patches, face_adjacency(s.faces), a, floor)
    for part in range(1, s.n_parts):
        assert len(np.unique(split[s.part_labels == part])) == 3
        assert len(np.unique(got[s.part_labels == part])) == 1
    slab = s.part_labels == 0
    np.testing.assert_array_equal(got[slab], split[slab])
