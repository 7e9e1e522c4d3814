"""A mesh with fewer edges than the fields asked of it: one line saying what to do."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from torchakvf.errors import ParameterError
from torchakvf.mesh.size_check import check_fields_fit


def test_a_cube_asked_for_too_many_fields():
    box = trimesh.creation.box()
    check_fields_fit("cube.off", box.faces, 17)                          # 18 edges: 17 fields fit
    with pytest.raises(ParameterError, match=r"\(18 edges\), too few for 18 fields"):
        check_fields_fit("cube.off", box.faces, 18)                      # as many fields as edges
    with pytest.raises(ParameterError) as info:
        check_fields_fit("cube.off", box.faces, 28, k=5)
    text = str(info.value)
    assert text == ("cube.off: mesh has 12 faces (18 edges), too few for k=5 (needs 28 fields): a mesh "
                    "takes fewer fields than it has edges; use a smaller k or subdivide it (torchakvf.mesh.subdivide)")
    with pytest.raises(ParameterError, match=r"use k <= 2 or subdivide it"):
        check_fields_fit("cube.off", box.faces, 28, k=5, fields_for_k=lambda k: 8 * k)
    with pytest.raises(ParameterError, match=r"\(needs 28 fields\): .* edges; use --subdivide$"):
        check_fields_fit("cube.off", box.faces, 28, k=5, fields_for_k=lambda k: 20 + k,
                         subdivide_hint="use --subdivide")
    with pytest.raises(ParameterError, match=r"too few for 30 fields"):
        check_fields_fit("cube.off", np.asarray(box.faces), 30)


def test_the_features_command_names_its_own_option():
    box = trimesh.creation.box()
    with pytest.raises(ParameterError, match=r"too few for 32 fields: .* edges; use a smaller --n or subdivide it"):
        check_fields_fit("cube.off", box.faces, 32, fewer_hint="use a smaller --n")
