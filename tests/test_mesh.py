"""Meshes given as arrays: shapes, finiteness, index range and integer faces checked on
construction, torch tensors and lists taken as numpy arrays."""
from __future__ import annotations

import re

import numpy as np
import pytest
import torch

import torchakvf as ta


def test_mesh_from_numpy_and_torch(ico2_shuffled):
    V, F = ico2_shuffled
    a = ta.Mesh(V, F)
    assert a.name == "<array>" and a.n_vertices == len(V) and a.n_faces == len(F)
    assert a.vertices.dtype == np.float64 and a.faces.dtype == np.int64
    b = ta.Mesh(torch.tensor(V, dtype=torch.float32), torch.tensor(F, dtype=torch.int32), name="t")
    assert b.name == "t" and b.vertices.dtype == np.float64 and b.faces.dtype == np.int64
    np.testing.assert_array_equal(b.faces, F)
    np.testing.assert_allclose(b.vertices, V, atol=1e-6)
    # lists work too; float faces holding integers are accepted
    c = ta.Mesh(V.tolist(), F.astype(np.float64))
    np.testing.assert_array_equal(c.faces, F)



@pytest.mark.parametrize("case", ["empty", "nan", "inf", "huge", "out_of_range", "negative", "quad",
                                  "bad_shape", "non_numeric", "non_integer"])
def test_bad_arrays_raise_mesh_error(case):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    problem = {
        "empty": r"empty mesh", "nan": r"NaN", "inf": r"NaN or infinite",
        "huge": r"1 vertices have coordinates beyond ±3.4e\+38 \(first: vertex 1, 1e\+300\).*rescale",
        "out_of_range": r"index 3 outside", "negative": r"index -2 outside",
        "quad": r"triangles", "bad_shape": r"\[V, 3\]", "non_numeric": r"not a numeric",
        "non_integer": r"integers"}[case]
    if case == "empty":
        F = np.zeros((0, 3), int)
    elif case == "nan":
        V[1, 2] = np.nan
    elif case == "inf":
        V[2, 0] = -np.inf
    elif case == "huge":
        V[1, 1] = -1e300          # finite, but beyond float32's range (the outputs') and areas overflow
    elif case == "out_of_range":
        F = np.array([[0, 1, 3]])
    elif case == "negative":
        F = np.array([[0, -2, 1]])
    elif case == "quad":
        F = np.array([[0, 1, 2, 0]])
    elif case == "bad_shape":
        V = V[:, :2]
    elif case == "non_numeric":
        V = [["a", "b", "c"]] * 3
    elif case == "non_integer":
        F = np.array([[0, 1, 1.5]])
    with pytest.raises(ta.MeshError) as info:
        ta.Mesh(V, F, name="my-array-mesh")
    assert str(info.value).startswith("my-array-mesh: ")
    assert re.search(problem, info.value.problem), info.value.problem


