"""torchakvf.pipeline.outdir: the output folder of a run (one run at a time, file modes)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.faketask import FakeTask, assert_one_line_error
from helpers.runs import small_meshes

import torchakvf as ta
from torchakvf.errors import TorchAKVFError
from torchakvf.pipeline import outdir
from torchakvf.pipeline.runner import run_corpus

REPO = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONWARNINGS="ignore", OMP_NUM_THREADS="1", PYTHONPATH=str(REPO))


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_outputs_get_the_umask_mode(tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        ta.io.write_seg(tmp_path / "x.seg", np.array([0, 1]))
        ta.io.atomic_write_bytes(tmp_path / "y.bin", b"1")
    finally:
        os.umask(old)
    for name in ("x.seg", "y.bin"):
        assert (tmp_path / name).stat().st_mode & 0o777 == mode


def test_two_runs_on_one_out_at_once(tmp_path, capsys):
    paths = small_meshes(tmp_path / "in", names=("a",))
    out = tmp_path / "out"
    out.mkdir()
    with outdir.OutputLock(out):                           # a run in progress
        with pytest.raises(TorchAKVFError, match=f"another torchakvf run \\(pid {os.getpid()}\\)"):
            run_corpus(paths, out, FakeTask(), progress=False)
        proc = subprocess.run([sys.executable, "-m", "torchakvf.cli", "features", str(paths[0]),
                               "--out", str(out), "--n", "4"], capture_output=True, text=True,
                              cwd=REPO, env=ENV)
        assert proc.returncode == 2
        assert_one_line_error(proc.stderr, "another torchakvf run", "wait for it")
    assert not (out / "a.txt").exists()
    done = run_corpus(paths, out, FakeTask(), progress=False)   # released: runs
    assert done.ok == 1
