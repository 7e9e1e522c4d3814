"""The check every refused mesh file must pass: a MeshError of one line that starts with the
file's name and states the problem."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

import torchakvf as ta


def write_file(path: Path, data) -> Path:
    """Write text or bytes to ``path``; returns it."""
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def assert_refused(path: Path, problem: str) -> ta.MeshError:
    """``load_mesh(path)`` raises a one-line MeshError naming ``path`` whose problem matches the
    regex ``problem``."""
    with pytest.raises(ta.MeshError) as info:
        ta.load_mesh(path)
    err = info.value
    assert isinstance(err, ta.TorchAKVFError)
    assert err.source == str(path)
    assert str(err).startswith(f"{path}: ")
    assert "\n" not in str(err), str(err)
    assert re.search(problem, err.problem), err.problem
    return err
