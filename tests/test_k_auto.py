"""torchakvf.evaluate.k_auto: choosing k per mesh."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.evaluate.k_auto import choose_k, scan_k, scan_overseg, segment_auto
from torchakvf.mesh import Mesh
from torchakvf.options import SegmentOptions


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


def test_a_dumbbell_is_two_parts_by_options_or_keywords():
    d = shapes.dumbbell(n_around=16)
    mesh = Mesh(d.vertices, d.faces, name="dumbbell")
    fast = dict(kmeans_restarts=2, untangle_restarts=1)
    seg = segment_auto([mesh], (1, 3), **fast)
    assert seg.meshes[0].k == 2 and seg.meshes[0].params["k_auto"]["ks"] == [1, 2, 3]
    assert choose_k([mesh], (1, 3), **fast) == [2]
    # the same scan from one options object (given whole: its over-segmentation as it is)
    by_options = scan_k([mesh], (1, 3), SegmentOptions(overseg=scan_overseg(None), **fast))
    assert by_options.chosen == [2] and by_options.costs.tolist() == scan_k([mesh], (1, 3), **fast).costs.tolist()
