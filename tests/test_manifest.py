"""The one manifest reader: a torn last line (a killed run) is no record."""
from __future__ import annotations

import torchakvf as ta


def test_one_manifest_reader_tolerates_a_torn_tail(tmp_path):
    from torchakvf.io.manifest import read_manifest_records

    (tmp_path / "manifest.jsonl").write_bytes(
        b'{"path": "/a.off", "stem": "a", "status": "ok", "task": "features"}\n'
        b'not json\n[1, 2]\n'
        b'{"path": "/b.off", "stem": "b", "status": "ok", "task": "features"}\n'
        b'{"path": "/c.off", "stem": "c", "sta')
    assert [r["stem"] for r in read_manifest_records(tmp_path)] == ["a", "b"]
    for stem in ("a", "b", "c"):
        (tmp_path / f"{stem}.npz").write_bytes(b"")
    assert [f.name for f in ta.data.FeatureDataset(tmp_path).files] == ["a.npz", "b.npz"]


