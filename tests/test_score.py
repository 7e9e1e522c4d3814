"""torchakvf.evaluate.score: one mesh's predictions against its human segmentations."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf import shapes
from torchakvf.evaluate import metrics as M
from torchakvf.evaluate.score import score_segmentation


def test_score_segmentation_protocols():
    d = shapes.dumbbell(n_around=12)
    lab = d.part_labels
    gts = [lab, np.zeros_like(lab)]
    preds = {2: lab, 1: np.zeros_like(lab)}
    bs = score_segmentation(d.vertices, d.faces, preds, gts, "by-segmentation", metrics="rand")
    assert bs == {"rand_index_error": 0.0}
    bm = score_segmentation(d.vertices, d.faces, preds, gts, "by-model", metrics="rand", k=2)
    assert bm["rand_index_error"] == pytest.approx(M.rand_index_error(lab, gts[1]) / 2)
