"""torchakvf.parts.segmenter: a batch's segmentations at several k from one AKVF solve and kept
untanglings, equal to the plain functions' on the same AKVFs; a batch against its meshes alone;
the AKVF count's one name."""
from __future__ import annotations

import numpy as np
import pytest

import torchakvf as ta
from torchakvf import shapes
from torchakvf.parts import rounds as rounds_module
from torchakvf.parts import segment_each_k
from torchakvf.solvers.akvf_solver import AKVFSolver

FAST = dict(seed=0, refine=False, kmeans_restarts=3, untangle_restarts=1)


@pytest.fixture(scope="module")
def small():
    """Three small built-in shapes with known part counts: a dumbbell (2), three blobs (3) and a
    chain of three tori (3)."""
    return {"dumbbell": shapes.dumbbell(n_around=30), "three_blobs": shapes.three_blobs(n_around=20),
            "torus_chain": shapes.torus_chain(n_major=24)}


def mesh_of(small, name):
    s = small[name]
    return ta.Mesh(s.vertices, s.faces, name=name)


@pytest.fixture
def counted(monkeypatch):
    """{"solve": AKVF solves, "untangle": untangling calls} made from now on."""
    calls = {"solve": 0, "untangle": 0}
    solve, rotations = AKVFSolver.solve, rounds_module.orthomax_rotations

    def counting_solve(self, *args, **kwargs):
        calls["solve"] += 1
        return solve(self, *args, **kwargs)

    def counting_rotations(*args, **kwargs):
        calls["untangle"] += 1
        return rotations(*args, **kwargs)

    monkeypatch.setattr(AKVFSolver, "solve", counting_solve)
    monkeypatch.setattr(rounds_module, "orthomax_rotations", counting_rotations)
    return calls


def test_a_second_k_reuses_the_solve_and_the_untangling(small, counted):
    m = mesh_of(small, "three_blobs")
    sg = ta.Segmenter(m, **FAST)
    a = sg.segment(3)
    b = sg.segment(np.int64(5))
    # k = 3 and 5 need the same AKVFs and (method "merge", min_k 8) the same field count
    assert counted == {"solve": 1, "untangle": 1} and sg.solves == 1
    assert b.untangled is a.untangled
    # the same labels as the plain function, which solves and untangles for each k itself
    for k, got in ((3, a), (5, b)):
        plain = ta.segment(m, k, **FAST)
        np.testing.assert_array_equal(got[0].labels, plain[0].labels)
        assert got[0].cost == plain[0].cost and got[0].k == k
    assert counted["solve"] == 3


def test_the_cuts_mesh_arrays_are_made_once_across_calls(small, monkeypatch):
    """The crease patches and thickness of a mesh (what the cut makes of the mesh alone) are
    made by the first call and read by the next; labels as the plain function's."""
    from torchakvf.parts import cut

    made, real = [], cut.crease_patches
    monkeypatch.setattr(cut, "crease_patches", lambda *a, **kw: made.append(1) or real(*a, **kw))
    m = mesh_of(small, "torus_chain")
    sg = ta.Segmenter(m, **FAST)
    got = {k: sg.segment(k) for k in (3, 4)}
    assert len(made) == 1
    for k in (3, 4):
        np.testing.assert_array_equal(got[k][0].labels, ta.segment(m, k, **FAST)[0].labels)
    assert len(made) == 3                     # each plain call made its own


def test_a_k_that_needs_more_akvfs_solves_again_with_the_kept_solver(small, counted):
    m = mesh_of(small, "three_blobs")
    sg = ta.Segmenter(m, **FAST)
    sg.segment(3)
    n3 = sg.fields.n
    got = sg.segment(10)                    # 3 x 10 fields: more AKVFs than k = 3 solved
    assert sg.solves == 2 and sg.fields.n > n3
    again = sg.segment(3)                   # now from the larger solve: no third one
    assert sg.solves == 2 and counted["solve"] == 2
    assert again[0].k == 3
    plain = ta.segment(m, 10, **FAST)
    np.testing.assert_allclose(got[0].eigenvalues, plain[0].eigenvalues, rtol=1e-8, atol=1e-8)


def test_several_k_and_auto_from_one_solve(small, counted):
    m = mesh_of(small, "dumbbell")
    sg = ta.Segmenter(m, n=28, **FAST)      # a fixed AKVF count: every call uses this solve
    each = sg.segment_each_k([[2, 3, 4]])
    auto = sg.segment("auto", k_range=(1, 4))
    assert counted["solve"] == 1 and sg.fields.n == 28
    assert auto.chosen == [2] and auto[0].k == 2 and isinstance(auto, ta.AutoSegmentation)
    plain = segment_each_k(m, [[2, 3, 4]], n=28, **FAST)
    for k in (2, 3, 4):
        np.testing.assert_array_equal(each.meshes[0][k].labels, plain.meshes[0][k].labels)
    assert set(sg.seconds) == {"akvf", "untangle", "cluster"}


def test_batch_equals_one_at_a_time(small):
    """A Segmenter of a batch against one of each mesh alone, at given k's and k auto: the
    spectrum to round-off and the same parts (labels compared up to the numbering of the parts,
    as tests/test_segment.py does: on these exactly symmetric shapes round-off picks a basis
    inside degenerate clusters and may flip faces tied between parts)."""
    from test_segment import _agreement_up_to_numbering

    names = list(small)
    batch = ta.MeshBatch.from_meshes([mesh_of(small, n) for n in names])
    sg = ta.Segmenter(batch, **FAST)
    ks = [small[n].n_parts for n in names]
    given, auto = sg.segment(ks), sg.segment("auto", k_range=(2, 5))
    for i, name in enumerate(names):
        alone = ta.Segmenter(mesh_of(small, name), **FAST)
        a_given, a_auto = alone.segment(ks[i]), alone.segment("auto", k_range=(2, 5))
        assert a_auto.chosen == [auto.chosen[i]]
        for got, want in ((given[i], a_given[0]), (auto[i], a_auto[0])):
            np.testing.assert_allclose(got.eigenvalues, want.eigenvalues, rtol=1e-8, atol=1e-8)
            same = _agreement_up_to_numbering(got.labels, want.labels)
            assert same >= 0.999, f"{name}: batch and single labels agree on {same:.5f} of faces"


def test_the_akvf_count_has_one_name(small):
    m = mesh_of(small, "three_blobs")
    new = segment_each_k(m, 3, n=28, **FAST)
    old = segment_each_k(m, 3, n_akvf=28, **FAST)         # the old spelling keeps working
    assert new.fields.n == old.fields.n == 28
    np.testing.assert_array_equal(new.meshes[0][3].labels, old.meshes[0][3].labels)
    with pytest.raises(ta.ParameterError, match="old spelling of n"):
        segment_each_k(m, 3, n=28, n_akvf=32, **FAST)


def test_parameter_errors(small):
    m = mesh_of(small, "dumbbell")
    sg = ta.Segmenter(m, **FAST)
    with pytest.raises(ta.ParameterError, match="or 'auto'"):
        sg.segment("automatic")
    with pytest.raises(ta.ParameterError, match="apply to k='auto'"):
        sg.segment(2, k_range=(2, 5))
    with pytest.raises(ta.ParameterError, match="k_range"):
        ta.segment(m, "auto", k_range=(2, 3))
    with pytest.raises(ta.ParameterError, match="one integer"):
        ta.Segmenter(m, n_fields=[16], **FAST).segment("auto")
    with pytest.raises(ta.ParameterError, match="coarse_faces"):
        ta.Segmenter(ta.MeshBatch.from_meshes([m]), coarse_faces=100)
    assert sg.solves == 0 and sg.fields is None          # nothing solved for calls that failed
