"""The implicit built-in shapes with ground-truth parts (torchakvf.shapes.implicit) made for
protrusions: a four-legged animal and a fish. Closed, manifold, genus 0, one connected patch of
faces per part; and what the default segmentation makes of them at k = n_parts, measured.
(The table and the mug are checked in test_merge.py, where their failure modes are.)"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from test_shapes import _face_angles_deg, check_mesh

import torchakvf as ta
from torchakvf import shapes
from torchakvf.evaluate.metrics import matched_agreement, rand_index_error
from torchakvf.mesh import face_areas
from torchakvf.options import SegmentOptions
from torchakvf.parts.field_counts import akvf_count

pytestmark = pytest.mark.usefixtures("one_torch_thread")   # one intra-op thread (see conftest)

PARTS = {"quadruped": ["body", "head", "front left leg", "front right leg", "hind left leg", "hind right leg"],
         "fish": ["body", "tail", "dorsal fin", "left pectoral fin", "right pectoral fin"]}
#: Segmentation seeds measured: the merge's outcome on these shapes depends on the seed.
SEEDS = (0, 1, 2, 3)


@pytest.fixture(scope="module")
def built():
    return {name: shapes.BUILTIN_SHAPES[name]() for name in PARTS}


def _part_components(s, p: int) -> int:
    """Connected components of part p's faces (faces sharing an edge)."""
    faces = np.flatnonzero(s.part_labels == p)
    f = s.faces[faces]
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(f)), 3)
    _, key = np.unique(edges, axis=0, return_inverse=True)
    order = np.argsort(key, kind="stable")
    same = key[order][1:] == key[order][:-1]
    a, b = owner[order][:-1][same], owner[order][1:][same]
    graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(len(f), len(f)))
    return connected_components(graph, directed=False)[0]


@pytest.mark.parametrize("name", sorted(PARTS))
def test_shape_is_a_closed_genus_0_mesh_with_one_patch_per_part(built, name):
    s = built[name]
    assert s.name == name and s.n_parts == len(PARTS[name])
    check_mesh(s, closed=True, euler=2)
    assert 4000 <= len(s.faces) <= 10000
    assert _face_angles_deg(s.vertices, s.faces).min() > 10
    assert s.part_labels.shape == (len(s.faces),)
    assert set(np.unique(s.part_labels)) == set(range(s.n_parts))
    area = face_areas(s.vertices, s.faces)
    share = np.bincount(s.part_labels, weights=area) / area.sum()
    assert share.min() > 0.03 and share.argmax() == 0            # the body is the largest part
    for p in range(s.n_parts):
        assert _part_components(s, p) == 1, (name, PARTS[name][p])


def test_shapes_are_deterministic_and_symmetric(built):
    for name, s in built.items():
        again = shapes.BUILTIN_SHAPES[name]()
        np.testing.assert_array_equal(again.vertices, s.vertices)
        np.testing.assert_array_equal(again.faces, s.faces)
    # left and right parts mirror each other across y = 0: equal areas to the grid's accuracy
    for name, pairs in (("quadruped", ((2, 3), (4, 5))), ("fish", ((3, 4),))):
        s = built[name]
        area = np.bincount(s.part_labels, weights=face_areas(s.vertices, s.faces))
        for a, b in pairs:
            assert area[a] == pytest.approx(area[b], rel=0.05), (name, a, b)


@pytest.fixture(scope="module")
def segmented(built):
    """Per shape, the default segmentation at k = n_parts for each seed of SEEDS (one AKVF
    solve, the count the default segmentation solves for): matched area agreement and 1-RI."""
    out = {}
    for name, s in built.items():
        mesh = ta.Mesh(s.vertices, s.faces, name=name)
        fields = ta.akvf(mesh, n=akvf_count([[s.n_parts]], None, SegmentOptions().method, SegmentOptions().merge_min_k))
        area = face_areas(s.vertices, s.faces)
        rows = []
        for seed in SEEDS:
            labels = ta.segment(fields, k=s.n_parts, seed=seed)[0].labels
            rows.append((matched_agreement(labels, s.part_labels, area), rand_index_error(labels, s.part_labels),
                         labels))
        out[name] = (fields, rows)
    return out


def test_quadruped_segmentation(built, segmented):
    """Measured with the default options (fields of the seed-0 solve): matched area agreement
    0.969, 0.967, 0.969, 0.967 on seeds 0-3 (1-RI 0.039-0.042), every part found (IoU >= 0.90).
    Solved with each seed instead (``ta.segment(mesh, k=6, seed=1)``), seed 1 joins the two
    front legs into one part (agreement 0.869, 1-RI 0.055): the bounds leave room for that."""
    fields, rows = segmented["quadruped"]
    assert fields.remedies == ["none"]                 # a clean mesh: the paper's operator
    agree = np.array([r[0] for r in rows])
    err = np.array([r[1] for r in rows])
    assert agree.min() >= 0.80 and np.median(agree) >= 0.93, agree
    assert err.max() <= 0.08, err


def test_fish_segmentation(built, segmented):
    """Measured with the default options (fields of the seed-0 solve): matched area agreement
    0.978, 0.975, 0.973, 0.980 on seeds 0-3 (1-RI 0.033-0.043), every part found (IoU >= 0.89):
    the merge keeps the thin fins apart from the body (their thickness and size differ) and
    joins the body's pieces first. The fish's thin fins give its paper operator spurious modes:
    it gets the remedy."""
    fields, rows = segmented["fish"]
    assert fields.remedies == ["smooth"]
    agree = np.array([r[0] for r in rows])
    err = np.array([r[1] for r in rows])
    assert agree.min() >= 0.90 and np.median(agree) >= 0.93, agree
    assert err.max() <= 0.08, err


def _worst_part_iou(s, labels) -> tuple[str, float]:
    area = face_areas(s.vertices, s.faces)
    ious = []
    for p in range(s.n_parts):
        truth = s.part_labels == p
        ious.append(max(area[truth & (labels == q)].sum() / area[truth | (labels == q)].sum()
                        for q in np.unique(labels)))
    return PARTS[s.name][int(np.argmin(ious))], float(min(ious))


def test_quadruped_every_part_found_at_every_seed(built, segmented):
    s = built["quadruped"]
    for _, _, labels in segmented["quadruped"][1]:
        part, iou = _worst_part_iou(s, labels)
        assert iou >= 0.8, (part, iou)


def test_fish_every_part_found_at_every_seed(built, segmented):
    s = built["fish"]
    for _, _, labels in segmented["fish"][1]:
        part, iou = _worst_part_iou(s, labels)
        assert iou >= 0.8, (part, iou)
