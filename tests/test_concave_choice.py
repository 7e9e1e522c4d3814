"""Between two merges, the one whose flattest boundary lies on a crease
(:mod:`torchakvf.parts.concave_choice`): the boundary sums on hand-computed dual graphs, and on a
spoked wheel the second (hand-set) merge taking over from the learned one."""
from __future__ import annotations

import math

import numpy as np
import pytest

import torchakvf as ta
from torchakvf.evaluate.metrics import rand_index_error
from torchakvf.parts.concave_choice import boundary_concavity, prefers_other, same_partition, weakest_boundary
from torchakvf.parts.concavity import DualEdges
from torchakvf.shapes.procedural import make_procedural

# four faces in a ring: (0, 1) bends 90° concave, (1, 2) 45° concave, (2, 3) 60° convex, (0, 3) flat
DUAL = DualEdges(pairs=np.array([[0, 1], [1, 2], [2, 3], [0, 3]]), length=np.array([1.0, 2.0, 1.0, 3.0]),
                 dihedral=np.array([math.pi / 2, math.pi / 4, -math.pi / 3, 0.0]))


def test_boundary_concavity_by_hand():
    """Per pair of adjacent parts, in (smaller, larger) order, Σ length · max(dihedral, 0) / π
    over Σ length along their boundary; edges inside a part and convex bends add nothing."""
    # parts 0 | 1 meet at edge (1, 2): 45° -> 0.25; 0 | 2 at (0, 3): flat; 1 | 2 at (2, 3): convex
    assert boundary_concavity(np.array([0, 0, 1, 2]), DUAL) == pytest.approx([0.25, 0.0, 0.0])
    # one boundary of two edges: (0, 1) 90° (length 1) and (2, 3) convex (length 1) -> 0.5 / 2
    assert boundary_concavity(np.array([0, 1, 1, 0]), DUAL) == pytest.approx([0.25])
    # faces without a part (-1) bound no part; the remaining pair is 1 | 2 at (2, 3)
    assert boundary_concavity(np.array([-1, -1, 1, 2]), DUAL) == pytest.approx([0.0])


def test_weakest_boundary_is_the_flattest_pair():
    """The least of the pairs' means; inf with one part (no boundary to judge)."""
    assert weakest_boundary(np.array([0, 0, 1, 1]), DUAL) == pytest.approx((2 * 0.25 + 3 * 0.0) / 5)
    assert weakest_boundary(np.array([0, 1, 1, 1]), DUAL) == pytest.approx((1 * 0.5 + 3 * 0.0) / 4)
    assert weakest_boundary(np.array([0, 0, 1, 2]), DUAL) == 0.0
    assert weakest_boundary(np.array([3, 3, 3, 3]), DUAL) == math.inf


def test_same_partition_ignores_names():
    assert same_partition(np.array([0, 0, 1, 2]), np.array([5, 5, 0, 1]))
    assert not same_partition(np.array([0, 0, 1, 2]), np.array([0, 1, 1, 2]))
    assert not same_partition(np.array([0, 0, 1, 1]), np.array([0, 0, 0, 1]))


def test_prefers_other_needs_ratio_and_floor():
    """[0, 0, 1, 1] has weakest 0.1 (its one boundary, 0.5 / 5); [0, 1, 1, 1] 0.125."""
    flat, bent = np.array([0, 0, 1, 2]), np.array([0, 0, 1, 1])        # weakest 0 and 0.1
    assert prefers_other(flat, bent, DUAL, ratio=3.0, floor=0.05)          # 0.1 > 0.05 and > 3 x 0
    assert not prefers_other(flat, bent, DUAL, ratio=3.0, floor=0.1)       # not above the floor
    assert not prefers_other(bent, np.array([0, 1, 1, 1]), DUAL, ratio=3.0, floor=0.0)   # 0.125 < 0.3
    assert prefers_other(bent, np.array([0, 1, 1, 1]), DUAL, ratio=1.2, floor=0.0)       # 0.125 > 0.12
    assert not prefers_other(flat, np.array([1, 1, 1, 1]), DUAL, ratio=1.0, floor=0.0)   # one part: never


def test_spoked_wheel_takes_the_second_merge():
    """A procedural wheel (rim, hub and spokes, solved as it is): the learned merge leaves the
    rim in arcs (1-RI above 0.3); the hand-set merge's parts meet at the spokes' concave fillets,
    their flattest boundary well above three times the learned one's, and they are kept."""
    shape = make_procedural("wheel", 7, detail=0.3)
    mesh, truth = ta.Mesh(shape.shape.vertices, shape.shape.faces), shape.shape.part_labels
    k = len(shape.part_names)
    chosen = ta.segment([mesh], k=k)[0]
    first = ta.segment([mesh], k=k, merge_choice=None)[0]
    assert chosen.params["merge_second"] is True
    assert "merge_second" not in first.params
    assert rand_index_error(first.labels, truth) > 0.3
    assert rand_index_error(chosen.labels, truth) < 0.05


def test_choice_off_is_the_first_merge():
    """Where the second merge is not kept, the labels are the first merge's, bit for bit."""
    shape = make_procedural("humanoid", 3, detail=0.3)
    mesh = ta.Mesh(shape.shape.vertices, shape.shape.faces)
    k = len(shape.part_names)
    chosen = ta.segment([mesh], k=k)[0]
    first = ta.segment([mesh], k=k, merge_choice=None)[0]
    assert chosen.params["merge_second"] is False
    np.testing.assert_array_equal(chosen.labels, first.labels)
