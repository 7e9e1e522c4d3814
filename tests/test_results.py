"""Output stems: every mesh extension read (glTF included) comes off, nothing escapes the folder;
a segmentation chosen with -k auto writes its .npz with the choice as plain arrays."""
from __future__ import annotations

import numpy as np

import torchakvf as ta
from torchakvf import Mesh, shapes
from torchakvf.io.results import flat_params, safe_stem, write_segmentation


def test_safe_stem_strips_every_mesh_extension():
    for name in ("a.off", "a.OBJ", "a.ply.gz", "a.stl", "a.glb", "dir/a.gltf", "a.GLB.gz"):
        assert safe_stem(name) == "a", name
    assert safe_stem("../../x y.glb") == "x_y"
    assert safe_stem(".glb") == "mesh"


def test_npz_of_a_k_auto_segmentation_holds_the_choice_as_plain_arrays(tmp_path):
    d = shapes.dumbbell(n_around=16)
    seg = ta.segment([Mesh(d.vertices, d.faces, name="dumbbell")], k="auto", seed=0, kmeans_restarts=2,
                     untangle_restarts=1)
    ms = seg.meshes[0]
    assert isinstance(ms.params["k_auto"], dict)
    written = write_segmentation(ms, d.vertices, d.faces, tmp_path, "dumbbell", formats=("npz",))
    with np.load(written["npz"], allow_pickle=False) as z:
        assert z["param_k_auto_ks"].tolist() == list(ms.params["k_auto"]["ks"])
        assert str(z["param_k_auto_rule"]) == ms.params["k_auto"]["rule"]
        assert int(z["param_k"]) == ms.k
    assert flat_params({"a": 1, "b": {"c": 2, "d": {"e": 3}}}) == {"a": 1, "b_c": 2, "b_d_e": 3}
