"""torchakvf.parts.k_auto: choosing k per mesh, as ``segment(..., k="auto")`` and as the
evaluation's ``-k auto``."""
from __future__ import annotations

import numpy as np
import pytest
from helpers.meshfiles import write_off, write_seg

import torchakvf as ta
from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.mesh import Mesh
from torchakvf.options import SegmentOptions
from torchakvf.parts.k_auto import MERGE_TAU, KChoice, choose_k, scan_k, scan_overseg, segment_auto


def test_k_auto_pick_rules():
    from torchakvf.parts.k_auto import pick_k

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


def test_the_scan_keeps_the_over_segmentation_its_threshold_was_chosen_with():
    """Without an over-segmentation given, the scan cuts each k into 3 pieces per part (at most
    16 beyond k), every k on its own, crease patches' fragments not united, whatever the
    segmentation's default is."""
    from torchakvf.options import OverSegmentation

    d = shapes.dumbbell(n_around=16)
    mesh = Mesh(d.vertices, d.faces, name="dumbbell")
    fast = dict(kmeans_restarts=2, untangle_restarts=1)
    pinned = OverSegmentation(ratio=3.0, extra_max=16, min_k=1, unite_fragments=False)
    assert scan_overseg(None) == pinned and OverSegmentation().ratio != pinned.ratio
    assert OverSegmentation().unite_fragments != pinned.unite_fragments
    given = scan_k([mesh], (1, 3), overseg=pinned, **fast)
    assert scan_k([mesh], (1, 3), **fast).costs.tolist() == given.costs.tolist()


def test_the_evaluation_imports_the_same_algorithm():
    from torchakvf.evaluate import k_auto as old
    from torchakvf.parts import k_auto as new
    for name in old.__all__:
        assert getattr(old, name) is getattr(new, name), name


FAST = dict(seed=0, refine=False, kmeans_restarts=3, untangle_restarts=1)


@pytest.fixture(scope="module")
def small():
    """Small built-in shapes whose part count the merge rule finds: a dumbbell (2 parts), three
    blobs (3) and a chain of three tori (3)."""
    return {"dumbbell": shapes.dumbbell(n_around=30), "three_blobs": shapes.three_blobs(n_around=20),
            "torus_chain": shapes.torus_chain(n_major=24)}


def test_segment_auto_finds_the_parts_of_built_in_shapes(small):
    meshes = [ta.Mesh(s.vertices, s.faces, name=n) for n, s in small.items()]
    seg = ta.segment(ta.MeshBatch.from_meshes(meshes), k="auto", **FAST)
    truth = [s.n_parts for s in small.values()]
    assert isinstance(seg, ta.AutoSegmentation) and seg.chosen == truth
    for m, c, k in zip(seg.meshes, seg.k_auto, truth):
        assert isinstance(c, KChoice) and c.k == m.k == k and c.rule == "merge" and c.ks == tuple(range(2, 11))
        assert len(np.unique(m.labels)) == k
        # the merge rule: the largest k whose cheapest merge costs more than the threshold
        above = [kk for kk, nc in zip(c.ks, c.next_costs) if nc > MERGE_TAU]
        assert k == max(above)
    assert seg.untangled is not None and seg.face_vectors(0).shape[0] == len(meshes[0].faces)


def test_segment_auto_chooses_what_eval_k_auto_chooses(small, tmp_path):
    """The same meshes and settings through the evaluation (``eval -k auto``: PSB files, its
    batches, its default options) and through ``segment(k="auto")``: the same k per mesh and
    the same parts."""
    from test_segment import _agreement_up_to_numbering

    from torchakvf.evaluate.harness import evaluate_psb
    from torchakvf.evaluate.settings import eval_segment_options
    from torchakvf.io import load_mesh

    root = tmp_path / "psb"
    ids = {"three_blobs": 1, "torus_chain": 141}          # 1 (Human) with a human segmentation, 141 none
    for name, i in ids.items():
        s = small[name]
        write_off(root / "meshes" / f"{i}.off", s.vertices, s.faces)
    write_seg(root / "gt" / "1" / "1_0.seg", small["three_blobs"].part_labels)
    restarts = dict(kmeans_restarts=3, untangle_restarts=1)
    summary = evaluate_psb(root, tmp_path / "eval", ids=list(ids.values()), k_mode="auto", k_range=(2, 6),
                           progress=False, metrics="rand", **restarts)
    options = eval_segment_options(None, restarts, auto=True)
    for name, i in ids.items():
        mesh = load_mesh(root / "meshes" / f"{i}.off")
        seg = ta.segment(mesh, "auto", options, k_range=(2, 6))
        k = seg.chosen[0]
        assert k == small[name].n_parts
        if i == 1:
            assert summary.row(1).k_auto["chosen"] == k
        pred = tmp_path / "eval" / "pred" / str(i) / f"{i}_k{k}.seg"
        labels = np.loadtxt(pred, dtype=int)
        assert sorted(p.name for p in pred.parent.glob("*.seg")) == [pred.name]
        assert _agreement_up_to_numbering(labels, seg[0].labels) >= 0.999
