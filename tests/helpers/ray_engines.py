"""The ray caster's engines as a pytest parameter: both where Embree's binding is installed, the
tree alone elsewhere (tests/test_raycast.py, tests/test_sightlines.py)."""
from __future__ import annotations

import pytest

from torchakvf.mesh.raycast import embree_available

#: "libigl", and "embree" skipped where ``embreex`` does not import
ENGINES = ["libigl", pytest.param("embree", marks=pytest.mark.skipif(
    not embree_available(), reason="embreex is not installed (it has wheels for x86-64 Linux and Windows only)"))]
