"""Output stems: every mesh extension read (glTF included) comes off, nothing escapes the folder."""
from __future__ import annotations

from torchakvf.io.results import safe_stem


def test_safe_stem_strips_every_mesh_extension():
    for name in ("a.off", "a.OBJ", "a.ply.gz", "a.stl", "a.glb", "dir/a.gltf", "a.GLB.gz"):
        assert safe_stem(name) == "a", name
    assert safe_stem("../../x y.glb") == "x_y"
    assert safe_stem(".glb") == "mesh"
