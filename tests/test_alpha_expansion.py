"""Alpha-expansion on scipy's maximum_flow (:mod:`torchakvf.parts.alpha_expansion`): each
minimum cut against enumeration, each expansion against the brute-force largest minimizer of
its binary problem, whole runs against the brute-force optimum (exact for two labels, within
alpha-expansion's factor 2 for Potts) and against gco where gco-wrapper is installed."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from torchakvf.parts.alpha_expansion import expansion_step, min_cut_sink_side, potts_alpha_expansion, potts_energy
from torchakvf.parts.graphcut import gco_expansion


def _random_problem(rng, n, k, p_edge=0.4, top=6):
    """Integer Potts terms on a random graph; small ranges, so ties are common."""
    pairs = np.array([(i, j) for i in range(n) for j in range(i + 1, n) if rng.random() < p_edge],
                     dtype=np.int64).reshape(-1, 2)
    unary = rng.integers(0, top, size=(n, k))
    weights = rng.integers(0, top // 2 + 1, size=len(pairs))
    return unary, pairs, weights


def _brute_optimum(unary, pairs, weights):
    n, k = unary.shape
    return min(potts_energy(np.array(lab), unary, pairs, weights) for lab in itertools.product(range(k), repeat=n))


@pytest.mark.parametrize("seed", range(8))
def test_min_cut_sink_side_is_the_smallest_sink_side_of_the_minimum_cuts(seed):
    rng = np.random.default_rng(seed)
    m = 6
    src, sink = rng.integers(0, 4, m), rng.integers(0, 4, m)
    pairs = [(a, b) for a in range(m) for b in range(a + 1, m) if rng.random() < 0.5]
    i, j = np.array(pairs, dtype=np.int64).reshape(-1, 2).T
    cap = rng.integers(0, 4, len(i))
    cuts = {}
    for bits in itertools.product([False, True], repeat=m):       # True: on the sink side
        x = np.array(bits)
        cuts[bits] = src[x].sum() + sink[~x].sum() + cap[~x[i] & x[j]].sum()
    best = min(cuts.values())
    smallest = np.all([np.array(b) for b, c in cuts.items() if c == best], axis=0)   # their intersection
    got = min_cut_sink_side(m, src, sink, i, j, cap)
    assert cuts[tuple(got)] == best
    np.testing.assert_array_equal(got, smallest)


@pytest.mark.parametrize("seed", range(20))
def test_one_expansion_is_the_largest_minimizer_of_its_binary_problem(seed):
    """From a random labelling, one expansion on α equals enumeration over every α-move: the
    lowest energy, and among the moves reaching it the one where the most sites take α (kept
    only if it lowers the energy strictly). Small integer terms: ties and decided sites abound."""
    rng = np.random.default_rng(300 + seed)
    n, k = 7, 3
    unary, pairs, weights = _random_problem(rng, n, k, top=4)
    labels = rng.integers(0, k, n)
    alpha = int(rng.integers(0, k))
    movers = np.flatnonzero(labels != alpha)
    e0 = potts_energy(labels, unary, pairs, weights)
    best, best_set = e0, None
    for take in itertools.product([False, True], repeat=len(movers)):
        lab = labels.copy()
        lab[movers[np.array(take, dtype=bool)]] = alpha
        e = potts_energy(lab, unary, pairs, weights)
        if best_set is None or e < best or (e == best and sum(take) > best_set.sum()):
            best, best_set = e, np.array(take, dtype=bool)
    want = labels.copy()
    if best < e0:
        want[movers[best_set]] = alpha
    got = labels.copy()
    expansion_step(got, np.full(n, alpha), unary, pairs, weights, np.zeros(n, dtype=np.int64))
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(10))
def test_two_labels_give_the_optimum(seed):
    rng = np.random.default_rng(seed)
    unary, pairs, weights = _random_problem(rng, 9, 2)
    got = potts_alpha_expansion(unary, pairs, weights, cycles=2)
    assert potts_energy(got, unary, pairs, weights) == _brute_optimum(unary, pairs, weights)


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("start", ["first", "random"])
def test_more_labels_within_the_potts_bound(seed, start):
    """A labelling no expansion improves is within a factor 2 of the optimum (Boykov, Veksler &
    Zabih 2001, Potts); on these tiny cases usually at it."""
    rng = np.random.default_rng(100 + seed)
    unary, pairs, weights = _random_problem(rng, 7, 3)
    initial = None if start == "first" else rng.integers(0, 3, 7)
    got = potts_alpha_expansion(unary, pairs, weights, cycles=-1, initial=initial)
    best = _brute_optimum(unary, pairs, weights)
    assert best <= potts_energy(got, unary, pairs, weights) <= 2 * best
    for q in range(3):                                             # a local minimum: no move helps
        again = got.copy()
        expansion_step(again, np.full(7, q), unary, pairs, weights, np.zeros(7, dtype=np.int64))
        np.testing.assert_array_equal(again, got)


def test_groups_are_solved_as_separate_problems():
    rng = np.random.default_rng(5)
    u1, p1, w1 = _random_problem(rng, 8, 4)
    u2, p2, w2 = _random_problem(rng, 6, 4)
    unary = np.concatenate([u1, u2])
    pairs = np.concatenate([p1, p2 + 8])
    groups = np.r_[np.zeros(8, dtype=np.int64), np.ones(6, dtype=np.int64)]
    labs = [np.array([0, 2, 3]), np.array([1, 3])]
    start = np.r_[np.full(8, 2), np.full(6, 3)]
    weights = np.concatenate([w1, w2])
    for initial in (None, start):
        got = potts_alpha_expansion(unary, pairs, weights, cycles=3, groups=groups, group_labels=labs,
                                    initial=initial)
        for g, (sl, u, p, w) in enumerate([(slice(0, 8), u1, p1, w1), (slice(8, 14), u2, p2, w2)]):
            alone = potts_alpha_expansion(u[:, labs[g]], p, w, cycles=3,
                                          initial=None if initial is None else np.searchsorted(labs[g], initial[sl]))
            np.testing.assert_array_equal(got[sl], labs[g][alone])


def test_a_group_without_pairs_takes_its_cheapest_label_whatever_the_start():
    """As gco solves a problem without pairs (each component of the graph cut is one): the
    cheapest label, the first in the group's order on ties, not the start's."""
    unary = np.array([[3, 1, 1], [2, 2, 5], [0, 4, 4], [9, 9, 9]])
    pairs = np.array([[2, 3]])
    groups = np.array([0, 1, 2, 2])
    labs = [np.array([0, 1, 2]), np.array([2, 1, 0]), np.array([0, 1, 2])]
    got = potts_alpha_expansion(unary, pairs, np.array([1]), groups=groups, group_labels=labs,
                                initial=np.array([2, 0, 1, 1]))
    assert got[0] == 1 and got[1] == 1                   # ties: 1 before 2; 1 before 0 in group 1's order


def test_same_input_same_labels_and_no_pairs():
    rng = np.random.default_rng(9)
    unary, pairs, weights = _random_problem(rng, 30, 5, p_edge=0.15)
    first = potts_alpha_expansion(unary, pairs, weights)
    np.testing.assert_array_equal(first, potts_alpha_expansion(unary.copy(), pairs.copy(), weights.copy()))
    np.testing.assert_array_equal(potts_alpha_expansion(unary, np.zeros((0, 2), dtype=np.int64), np.zeros(0)),
                                  np.argmin(unary, axis=1))


@pytest.mark.parametrize("start", ["first", "random"])
def test_the_labels_of_gco(start):
    """The reference implementation's labels on 300 random integer problems (ties included),
    cycles 1, 2 and until converged, from its first-label start and from a given labelling."""
    pytest.importorskip("gco", reason="gco-wrapper (the optional engine: pip install 'torchakvf[gco]') "
                                            "not installed")
    rng = np.random.default_rng(11 if start == "first" else 12)
    for _ in range(100):
        n, k = int(rng.integers(2, 25)), int(rng.integers(2, 6))
        unary, pairs, weights = _random_problem(rng, n, k, p_edge=float(rng.uniform(0.05, 0.5)),
                                                top=int(rng.integers(2, 40)))
        initial = None if start == "first" else rng.integers(0, k, n)
        for cycles in (1, 2, -1):
            want = gco_expansion(unary, pairs, weights, cycles, initial)
            got = potts_alpha_expansion(unary, pairs, weights, cycles, initial=initial)
            np.testing.assert_array_equal(got, want)
