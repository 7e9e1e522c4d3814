"""GLB export: one scene node per part (and one for the connecting region), part colours,
every face exactly once."""
from __future__ import annotations

import numpy as np
import pytest

from torchakvf import shapes
from torchakvf.errors import TorchAKVFError
from torchakvf.io.glb import CONNECTING_REGION, write_glb
from torchakvf.io.outputs import label_colors


def _load(path):
    import trimesh

    return trimesh.load(str(path), force="scene", process=False)


@pytest.mark.parametrize("with_region", [False, True])
def test_glb_has_one_node_per_part(tmp_path, with_region):
    s = shapes.three_blobs(n_around=24)
    labels = s.part_labels.copy()
    k = int(labels.max()) + 1
    if with_region:
        labels[: len(labels) // 10] = -1
    write_glb(tmp_path / "m.glb", s.vertices, s.faces, labels)
    scene = _load(tmp_path / "m.glb")
    expected = {f"part_{p}" for p in range(k)} | ({CONNECTING_REGION} if with_region else set())
    assert len(scene.geometry) == k + with_region
    assert set(scene.geometry) == expected
    nodes = {n for n in scene.graph.nodes_geometry}
    assert nodes == expected
    assert sum(len(g.faces) for g in scene.geometry.values()) == len(s.faces)
    colors = label_colors(labels)
    for p in range(k):
        g = scene.geometry[f"part_{p}"]
        assert len(g.faces) == int((labels == p).sum())
        np.testing.assert_array_equal(np.asarray(g.visual.material.baseColorFactor),
                                      colors[np.flatnonzero(labels == p)[0]])
        # the part's geometry is the part's faces: same total area
        sel = labels == p
        v, f = s.vertices, s.faces[sel]
        area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
        assert g.area == pytest.approx(area, rel=1e-5)


def test_glb_refuses_wrong_label_count(tmp_path):
    s = shapes.icosphere(level=1)
    with pytest.raises(TorchAKVFError, match="labels"):
        write_glb(tmp_path / "m.glb", s.vertices, s.faces, np.zeros(3, dtype=int))
    assert not (tmp_path / "m.glb").exists()


def test_write_segmentation_writes_glb(tmp_path):
    from torchakvf.io.results import OUTPUT_FORMATS, write_segmentation

    assert "glb" in OUTPUT_FORMATS

    class Seg:            # the fields write_segmentation reads for the "glb" format
        labels = shapes.dumbbell(n_around=24).part_labels

    s = shapes.dumbbell(n_around=24)
    out = write_segmentation(Seg(), s.vertices, s.faces, tmp_path, "d", formats=("glb",))
    assert set(out) == {"glb"}
    assert len(_load(out["glb"]).geometry) == 2
