"""torchakvf.evaluate.k_auto: choosing k per mesh."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf.errors import TorchAKVFError


def test_k_auto_pick_rules():
    from torchakvf.evaluate.k_auto import pick_k

    ks = [2, 3, 4, 5, 6]
    costs = [10.0, 6.0, 2.0, 1.8, 1.7]      # elbow at 4
    assert pick_k(ks, costs, "elbow") == 4
    assert pick_k(ks, costs, "knee") == 4
    lam = np.array([0, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 5, 6, 7, 8, 9, 10], dtype=float)
    assert pick_k(ks, costs, "spectrum", lam) == 4           # gap after 8 fields -> k = 4
    with pytest.raises(TorchAKVFError):
        pick_k(ks, costs, "best")
