"""Progress: logging lines (throttled) when the stream is not a terminal, a tqdm bar when it is."""
from __future__ import annotations

import io
import logging

import pytest

from torchakvf import progress as P


class _FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_non_terminal_stream_gives_throttled_log_lines(caplog, monkeypatch):
    monkeypatch.setattr(P, "LOG_EVERY_S", 1e9)            # only the first and the last update log
    stream = io.StringIO()
    with caplog.at_level(logging.INFO, logger="torchakvf.progress"):
        with P.progress(total=5, desc="eval", unit="meshes", stream=stream) as bar:
            assert bar.bar is None
            for i in range(5):
                bar.update(1, note=f"mesh {i}")
            bar.write("a whole line")
    lines = [r.getMessage() for r in caplog.records if r.name == "torchakvf.progress"]
    assert len(lines) == 2
    assert lines[0].startswith("eval: 1/5 meshes (20%)") and lines[0].endswith("; mesh 0")
    assert lines[1].startswith("eval: 5/5 meshes (100%)") and lines[1].endswith("; mesh 4")
    assert stream.getvalue() == "a whole line\n"               # no bar drawn on a log stream
    assert bar.done == 5 and bar.last == "mesh 4"


def test_terminal_stream_gets_a_tqdm_bar(caplog):
    pytest.importorskip("tqdm")
    stream = _FakeTTY()
    with caplog.at_level(logging.INFO, logger="torchakvf.progress"):
        with P.progress(total=4, desc="features", unit="meshes", stream=stream) as bar:
            assert bar.bar is not None
            bar.update(3, note="three")
            assert bar.bar.n == 3                              # the bar counts what was done
            bar.write("between bars")
    out = stream.getvalue()
    assert "features" in out and "between bars\n" in out
    assert "0/4" in out                                        # tqdm drew its bar on the stream
    assert not [r for r in caplog.records if r.name == "torchakvf.progress"]   # no log lines
    assert bar.bar is None                                    # closed on exit


def test_disabled_reports_nothing(caplog):
    stream = _FakeTTY()
    with caplog.at_level(logging.INFO, logger="torchakvf.progress"):
        bar = P.progress(total=2, desc="x", stream=stream, enabled=False)
        bar.update(2, note="done")
        bar.close()
    assert stream.getvalue() == "" and not caplog.records and bar.done == 2


