"""Corpus runs in the tests: a few small input meshes, a run's manifest by stem, the CLI run
in-process."""
from __future__ import annotations

from pathlib import Path

from helpers.meshfiles import write_off
from torchakvf import cli, shapes
from torchakvf.io.manifest import read_manifest


def small_meshes(root: Path, names=("a", "b", "c"), level: int = 1) -> list[Path]:
    """One icosphere(level) OFF file per name under root: ``root/<name>.off``."""
    s = shapes.icosphere(level)
    return [write_off(root / f"{n}.off", s.vertices, s.faces) for n in names]


def by_stem(out: Path) -> dict:
    """The manifest records of the run in ``out``, by input stem."""
    return {r["stem"]: r for r in read_manifest(out).values()}


def cli_run(argv, capsys) -> tuple[int, str, str]:
    """``torchakvf <argv>`` in this process (arguments str()-ed): exit code, stdout, stderr."""
    rc = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err
