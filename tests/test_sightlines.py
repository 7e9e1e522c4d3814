"""Lines of sight between parts (torchakvf/parts/sightlines.py): counts on shapes whose answer
is known by hand, agreement with an independent segment-triangle test, and the same counts on a
moved, renumbered copy; each on both ray engines where the answer is known."""
import numpy as np
import pytest
from helpers.ray_engines import ENGINES
from helpers.voxel_meshes import voxel_u

from torchakvf.mesh.raycast import RayCaster
from torchakvf.parts.sightlines import SightLines
from torchakvf.shapes.implicit import _voxel_surface


def sight_lines(v, f, engine):
    """:class:`SightLines` of the mesh with its segments tested by ``engine``."""
    return SightLines(v, f, caster=RayCaster(v, f, engine))


def u_shape():
    """:func:`voxel_u` labelled by the voxel behind each face: 0 base (z < 2), 1 left arm,
    2 right arm."""
    v, f, x, z = voxel_u()
    return v, f, np.where(z < 2, 0, np.where(x < 4, 1, 2))


def test_a_convex_box_sees_itself_everywhere():
    occ = np.ones((4, 3, 2), dtype=bool)
    v, f, owner = _voxel_surface(occ, 0.25, (0.0, 0.0, 0.0))
    i = np.unravel_index(owner, occ.shape)[0]
    labels = (i >= 2).astype(np.int64)               # two halves of a convex solid
    seen, lines = SightLines(v, f).counts(labels, 2)
    assert lines[0, 1] == 64 and seen[0, 1] == 64
    # the diagonal: the 8 * 7 / 2 segments between a part's own samples, all inside
    assert np.array_equal(np.diag(lines), [28, 28]) and np.array_equal(np.diag(seen), [28, 28])
    assert np.array_equal(seen, seen.T)


@pytest.mark.parametrize("engine", ENGINES)
def test_the_arms_of_a_u_do_not_see_each_other(engine):
    v, f, labels = u_shape()
    seen, lines = sight_lines(v, f, engine).counts(labels, 3)
    # every segment from one arm to the other crosses the gap between them
    assert lines[1, 2] == 64 and seen[1, 2] == 0
    # an arm sees part of the base (its own end of it), not all of it
    assert 0 < seen[0, 1] < lines[0, 1] and 0 < seen[0, 2] < lines[0, 2]
    # each part is a box: it sees all of itself
    assert np.array_equal(np.diag(seen), [28, 28, 28]) and np.array_equal(np.diag(lines), [28, 28, 28])


def test_the_counts_do_not_depend_on_the_unit_of_length():
    # libigl's ray test compares a determinant (edges times the direction) with a fixed 1e-6:
    # cast unscaled, the U 50 micrometres across saw through its own gap everywhere
    v, f, labels = u_shape()
    seen, lines = SightLines(v, f).counts(labels, 3)
    for s in (2.0 ** -14, 2.0 ** 20):
        seen_s, lines_s = SightLines(v * s, f).counts(labels, 3)
        assert np.array_equal(seen_s, seen) and np.array_equal(lines_s, lines)
    # at a scale that is not a power of two, round-off may break the farthest-point sampling's
    # ties on this symmetric shape otherwise (other samples), but the arms still see nothing of
    # each other and all of themselves
    seen_s, _ = SightLines(v * 1e-4, f).counts(labels, 3)
    assert seen_s[1, 2] == 0 and np.array_equal(np.diag(seen_s), [28, 28, 28])


def segment_blocked(p, q, tri):
    """Whether the open segment p -> q crosses any of the triangles tri [T, 3, 3]
    (Moller-Trumbore, written apart from the package's ray caster)."""
    d = q - p
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    h = np.cross(d, e2)
    a = (e1 * h).sum(axis=1)
    ok = np.abs(a) > 1e-15
    f = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
    s = p - tri[:, 0]
    u = f * (s * h).sum(axis=1)
    qv = np.cross(s, e1)
    w = f * (qv @ d)
    t = f * (e2 * qv).sum(axis=1)
    return bool(np.any(ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0) & (t < 1)))


@pytest.mark.parametrize("engine", ENGINES)
def test_counts_agree_with_a_plain_segment_test(engine):
    from torchakvf.shapes.procedural import make_procedural

    shape = make_procedural("bracket", 3, detail=0.4).shape
    v, f = shape.vertices, shape.faces
    labels = np.asarray(shape.part_labels)
    K = int(labels.max()) + 1
    sight = sight_lines(v, f, engine)
    seen, lines = sight.counts(labels, K)
    pick = sight.part_samples(labels, K)
    tri = v[f]
    expect = np.zeros((K, K))
    for i in range(K):
        for j in range(i, K):
            for x, a in enumerate(pick[i][pick[i] >= 0]):
                for y, b in enumerate(pick[j][pick[j] >= 0]):
                    if i != j or y > x:
                        expect[i, j] += not segment_blocked(sight.inside[a], sight.inside[b], tri)
    expect += np.triu(expect, 1).T
    assert lines.sum() > 0
    assert np.array_equal(seen, expect)
    # the plates of a bracket meet at right angles: most segments between them leave the solid
    off = ~np.eye(K, dtype=bool)
    assert (seen[off] / lines[off]).mean() < 0.6


def test_a_moved_renumbered_copy_gets_the_same_counts():
    from torchakvf.shapes.procedural import make_procedural

    shape = make_procedural("wheel", 2, detail=0.4).shape
    v, f = shape.vertices, shape.faces
    labels = np.asarray(shape.part_labels)
    K = int(labels.max()) + 1
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    perm_v, perm_f = rng.permutation(len(v)), rng.permutation(len(f))
    inv_v = np.argsort(perm_v)
    v2 = (v @ q.T + [3.0, -1.0, 2.0])[perm_v]
    f2 = inv_v[f[perm_f]]
    a = SightLines(v, f).counts(labels, K)
    b = SightLines(v2, f2).counts(labels[perm_f], K)
    assert np.array_equal(a[1], b[1])
    assert np.abs(a[0] - b[0]).max() <= 1            # a sample on a round-off tie may move


def test_one_part_has_only_its_own_lines_and_none_has_none():
    v, f, _ = u_shape()
    sight = SightLines(v, f)
    seen, lines = sight.counts(np.zeros(len(f), dtype=np.int64), 1)
    assert lines.tolist() == [[28]] and 0 < seen[0, 0] < 28          # a U does not see all of itself
    seen, lines = sight.counts(np.zeros(len(f), dtype=np.int64), 0)
    assert seen.shape == lines.shape == (0, 0)


def test_counts_of_unions_are_those_the_merge_state_adds_up():
    from torchakvf.parts.merge_terms import MergeState
    from torchakvf.parts.sightlines import PartSight

    rng = np.random.default_rng(3)
    K = 6
    lines = rng.integers(1, 65, size=(K, K)).astype(np.float64)
    lines = np.triu(lines) + np.triu(lines, 1).T
    seen = np.floor(lines * rng.random((K, K)))
    seen = np.triu(seen) + np.triu(seen, 1).T
    state = MergeState(np.ones(K), np.zeros((K, 2)), np.ones((K, K)), np.zeros((K, K)), np.zeros((K, K)),
                       seen=seen.copy(), lines=lines.copy())
    state.merge(0, 3)
    state.merge(0, 5)
    state.merge(1, 4)
    owner = np.array([0, 1, 2, 0, 1, 0])
    got = PartSight(seen, lines).merged(owner, 3)
    keep = [0, 1, 2]
    np.testing.assert_array_equal(got.seen, state.seen[np.ix_(keep, keep)])
    np.testing.assert_array_equal(got.lines, state.lines[np.ix_(keep, keep)])
    np.testing.assert_array_equal(got.take([2, 0]).lines, state.lines[np.ix_([2, 0], [2, 0])])
    # by hand: parts 0 and 2 of three join; the union's own segments are 0's, 2's and those
    # between them (5 + 7 + 3), its segments to part 1 both parts' (2 + 4)
    hand = np.array([[5.0, 2, 3], [2, 6, 4], [3, 4, 7]])
    united = PartSight(hand, hand).merged(np.array([0, 1, 0]), 2)
    np.testing.assert_array_equal(united.lines, [[15, 6], [6, 6]])
    # a union no part joins has no segments
    np.testing.assert_array_equal(PartSight(hand, hand).merged(np.array([0, 1, 0]), 3).lines[2], 0)


def test_many_parts_get_fewer_samples_each():
    v, f, _ = u_shape()
    sight = SightLines(v, f)
    assert [sight.samples_per_part(K) for K in (1, 32, 33, 40, 64, 100)] == [8, 8, 7, 6, 4, 4]
    labels = np.arange(len(f)) % 40                       # 40 parts of at least 6 faces
    seen, lines = sight.counts(labels, 40)
    assert lines[0, 1] == 36 and lines[0, 0] == 15         # 6 x 6 between, 6 x 5 / 2 within


def test_counts_on_a_shared_ray_caster_are_the_same():
    """The segmentation casts the thickness and the lines of sight on one tree per mesh."""
    from torchakvf.mesh.raycast import RayCaster

    v, f, i, kz = voxel_u()
    labels = np.where(kz < 2, 0, np.where(i < 4, 1, 2))
    caster = RayCaster(v, f)
    shared = SightLines(v, f, caster=caster)
    assert shared.caster is caster
    for got, own in zip(shared.counts(labels, 3), SightLines(v, f).counts(labels, 3)):
        np.testing.assert_array_equal(got, own)
