"""A corpus-runner task without a solver, for fast tests of the runner itself; and the check
that a CLI error is one line."""
from __future__ import annotations

from pathlib import Path

import torchakvf as ta


class FakeTask:
    """Writes <stem>.txt holding the mesh's face count (and ``tag``).

    A batch holding a mesh whose stem contains a key of ``fail`` raises that exception (the
    default: 'poison' -> RuntimeError, a bad input); ``pad`` bytes of padding go into each
    manifest record (through the ``manifest_fields`` hook).
    """

    name, stages = "fake", ("akvf",)

    def __init__(self, tag: str = "", fail=None, pad: int = 0):
        self.params, self.seed, self.batches = {"x": 1, "tag": tag}, 0, []
        self.tag, self.pad = tag, pad
        self.fail = {"poison": RuntimeError("poisoned batch")} if fail is None else fail

    def output_paths(self, out_dir, stem):
        return [Path(out_dir) / f"{stem}.txt"]

    def process(self, items, device):
        self.batches.append([it.stem for it in items])
        for it in items:
            for key, exc in self.fail.items():
                if key in it.stem:
                    raise exc
        return [len(it.clean.faces) for it in items], {"akvf": 1.0}

    def manifest_fields(self, out):
        return {"faces_seen": out, "pad": "x" * self.pad} if self.pad else {"faces_seen": out}

    def write(self, item, out, out_dir):
        path = self.output_paths(out_dir, item.stem)[0]
        ta.io.atomic_write_bytes(path, f"{out}{self.tag}".encode())
        return [path]


def assert_one_line_error(err: str, *parts: str) -> None:
    """stderr holds exactly one ``torchakvf: error: ...`` line naming ``parts`` (besides INFO
    log lines), and no traceback."""
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("INFO ")]
    assert len(lines) == 1 and lines[0].startswith("torchakvf: error: "), err
    assert "Traceback" not in err
    for part in parts:
        assert part in lines[0], lines[0]
