"""Which restart wins (:mod:`torchakvf.restarts`): the best value, round-off ties to the first,
the same pick in torch and numpy."""
from __future__ import annotations

import numpy as np
import torch

from torchakvf.restarts import best_restart


def test_best_restart_breaks_round_off_ties_towards_the_first():
    """Values within round-off of the best are a tie, won by the earliest restart; a genuinely
    better later restart still wins; NaN never wins."""
    base = 478.4012129587086
    costs = torch.tensor([[650.66, 637.18, base * (1 + 2e-16), base],        # round-off tie: 2
                          [5.0, 4.0, 4.0 * (1 - 1e-9), 6.0],                  # 1e-9 better: 2
                          [float("nan"), 3.0, 3.0, 2.0],                      # NaN first: 3
                          [1.0, 1.0, 1.0, 1.0]], dtype=torch.float64)
    assert best_restart(costs, largest=False).tolist() == [2, 2, 3, 0]
    scores = torch.tensor([[7.0, 9.0 * (1 - 1e-15), 9.0, 8.0],               # round-off tie: 1
                           [7.0, 9.0 * (1 - 1e-9), 9.0, 8.0],                  # 2 is better: 2
                           [-2.0, -1.0 - 1e-14, -1.0, -3.0]], dtype=torch.float64)  # negative: 1
    assert best_restart(scores, largest=True).tolist() == [1, 2, 1]
    assert best_restart(torch.full((1, 3), float("nan")), largest=True).tolist() == [0]
    inf = float("inf")
    assert best_restart(torch.tensor([[1.0, inf, inf], [2.0, -inf, 2.0]]), largest=True).tolist() == [1, 0]
    assert best_restart(torch.tensor([[inf, -inf, 3.0, -inf]]), largest=False).tolist() == [1]


def test_first_near_min_breaks_round_off_ties_towards_the_first():
    """The merge's pick among candidate costs: the first entry (row-major) within round-off of
    the smallest; a genuinely smaller later entry still wins; NaN never wins; nothing finite
    gives the first smallest (an inf the merge loop stops at)."""
    from torchakvf.restarts import first_near_min

    inf, nan = float("inf"), float("nan")
    assert first_near_min(np.array([[inf, 0.3 * (1 + 1e-15)], [0.3, inf]])) == 1     # tie: first
    assert first_near_min(np.array([[inf, 0.3], [0.3 * (1 - 1e-9), inf]])) == 2      # smaller: it
    assert first_near_min(np.array([nan, 2.0, 1.0])) == 2
    assert first_near_min(np.array([[inf, inf], [nan, inf]])) == 0
    assert first_near_min(np.array([-1.0 - 1e-14, -1.0, -2.0])) == 2                 # negative
    assert first_near_min(np.array([0.0, 5e-324, 0.0])) == 0


def test_first_near_min_is_best_restarts_pick():
    """The merge's numpy pick and the restarts' torch pick are one rule: equal on random cost
    matrices with infinities, NaN, exact and round-off ties."""
    import torch

    from torchakvf.restarts import best_restart, first_near_min

    rng = np.random.default_rng(7)
    for trial in range(200):
        k = int(rng.integers(1, 12))
        c = rng.random((k, k))
        c[rng.random((k, k)) < 0.4] = np.inf
        c[rng.random((k, k)) < 0.1] = np.nan
        if trial % 3 == 0 and np.isfinite(c).sum() >= 2:
            finite = np.flatnonzero(np.isfinite(c.ravel()))
            a, b = rng.choice(finite, 2, replace=False)
            c.flat[b] = c.flat[a] * (1 + rng.choice([0.0, 1e-15, -1e-15, 1e-9]))
        want = int(best_restart(torch.from_numpy(c.reshape(1, -1)), largest=False)[0])
        assert first_near_min(c) == want, c
