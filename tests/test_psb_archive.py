"""torchakvf.evaluate.psb_archive (and the safe extraction of torchakvf.evaluate.archive): preparing
the PSB from its official archive, also through datasets_scripts/prepare_psb.py."""
from __future__ import annotations

import gzip
import importlib.util
import io
import os
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from torchakvf.evaluate.psb import (
    find_psb_meshes,
    human_segment_counts,
    read_off,
    read_seg,
)
from torchakvf.evaluate.psb_archive import ArchiveError, prepare_psb, safe_extract

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "datasets_scripts" / "prepare_psb.py"

# ---------------------------------------------------------------------------------------------
# archive builders
# ---------------------------------------------------------------------------------------------

def add_tar_bytes(tf: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    tf.addfile(info, io.BytesIO(data))


def add_tar_link(tf: tarfile.TarFile, name: str, target: str, hard: bool = False) -> None:
    info = tarfile.TarInfo(name)
    info.type = tarfile.LNKTYPE if hard else tarfile.SYMTYPE
    info.linkname = target
    tf.addfile(info)


def make_zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(zipfile.ZipInfo(name), data)  # ZipInfo keeps the name verbatim
    return path


def make_tar(path: Path, members: dict[str, bytes], mode: str = "w") -> Path:
    with tarfile.open(path, mode) as tf:
        for name, data in members.items():
            add_tar_bytes(tf, name, data)
    return path


def truncate(path: Path, fraction: float = 0.5) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])
    return path


TETRA_OFF = (b"OFF\n4 4 6\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
             b"3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")


def seg_bytes(labels) -> bytes:
    return ("\n".join(str(x) for x in labels) + "\n").encode()


def fake_benchmark() -> dict[str, bytes]:
    """A tiny MeshsegBenchmark-1.0: meshes 1, 2 (Human), 21 (Cup); gt for 1 (11 segs) and 21."""
    top = "MeshsegBenchmark-1.0/"
    m = {top + "README.txt": b"fake\n"}
    for mesh_id in (1, 2, 21):
        m[f"{top}data/off/{mesh_id}.off"] = TETRA_OFF
    for k in range(11):
        m[f"{top}data/seg/Benchmark/1/1_{k}.seg"] = seg_bytes([0, 0, k % 2, 1])
    m[f"{top}data/seg/Benchmark/21/21_0.seg"] = seg_bytes([0, 1, 2, 3])
    m[f"{top}data/seg/RandCuts/1/1_0.seg"] = seg_bytes([5, 5, 5, 5])  # not human: ignored
    return m


# ---------------------------------------------------------------------------------------------
# archive safety
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad_name", ["../evil.txt", "good/../../evil.txt", "/tmp/abs_evil.txt",
                                      "..\\evil.txt", "C:/evil.txt"])
def test_zip_unsafe_member_refused(tmp_path, bad_name):
    archive = make_zip(tmp_path / "a.zip", {"ok.txt": b"fine", bad_name: b"evil"})
    assert bad_name in zipfile.ZipFile(archive).namelist()  # the name really is in the archive
    dest = tmp_path / "dest"
    with pytest.raises(ArchiveError, match="refusing member"):
        safe_extract(archive, dest)
    # Checked before writing: nothing extracted, nothing outside.
    assert not (dest / "ok.txt").exists()
    assert not (tmp_path / "evil.txt").exists()


@pytest.mark.parametrize("bad_name", ["../evil.txt", "/tmp/torchakvf_abs_evil.txt", "a/../../evil"])
def test_tar_unsafe_member_refused(tmp_path, bad_name):
    archive = tmp_path / "a.tar.gz"
    with tarfile.open(archive, "w:gz") as tf:
        add_tar_bytes(tf, "ok.txt", b"fine")
        add_tar_bytes(tf, bad_name, b"evil")
    assert bad_name in tarfile.open(archive).getnames()
    dest = tmp_path / "dest"
    with pytest.raises(ArchiveError, match="refusing member"):
        safe_extract(archive, dest)
    assert not (dest / "ok.txt").exists()
    assert not (tmp_path / "evil.txt").exists()
    assert not Path("/tmp/torchakvf_abs_evil.txt").exists()


@pytest.mark.parametrize("target, hard", [("../../outside", False), ("/etc/passwd", False),
                                          ("ok/../../../x", False), ("../x", True)])
def test_tar_link_out_refused(tmp_path, target, hard):
    archive = tmp_path / "links.tar"
    with tarfile.open(archive, "w") as tf:
        add_tar_bytes(tf, "sub/file.txt", b"fine")
        add_tar_link(tf, "sub/link", target, hard)
    with pytest.raises(ArchiveError, match="refusing link"):
        safe_extract(archive, tmp_path / "dest")
    assert not (tmp_path / "dest" / "sub").exists()


def test_tar_links_inside_are_kept(tmp_path):
    archive = tmp_path / "links.tar"
    with tarfile.open(archive, "w") as tf:
        add_tar_bytes(tf, "data/file.txt", b"content")
        add_tar_link(tf, "data/alias.txt", "file.txt")           # symlink, same folder
        add_tar_link(tf, "copy.txt", "data/file.txt", hard=True)  # hard link, archive path
    dest = tmp_path / "dest"
    safe_extract(archive, dest)
    assert (dest / "data" / "alias.txt").is_symlink()
    assert (dest / "data" / "alias.txt").read_bytes() == b"content"
    assert (dest / "copy.txt").read_bytes() == b"content"


def test_zip_symlink_out_refused(tmp_path):
    archive = tmp_path / "ln.zip"
    info = zipfile.ZipInfo("link")
    info.external_attr = (0o120777 << 16)  # S_IFLNK
    with zipfile.ZipFile(archive, "w") as zf:
        zf.writestr(info, "../../etc")
    with pytest.raises(ArchiveError, match="refusing link"):
        safe_extract(archive, tmp_path / "dest")


@pytest.mark.parametrize("kind", ["zip", "tar", "tar.gz"])
def test_truncated_archive_clear_error(tmp_path, kind):
    rng = np.random.default_rng(0)
    members = {f"f{i}.bin": rng.bytes(20_000) for i in range(5)}  # incompressible
    if kind == "zip":
        archive = make_zip(tmp_path / "t.zip", members)
    else:
        archive = make_tar(tmp_path / f"t.{kind}", members, "w" if kind == "tar" else "w:gz")
    truncate(archive, 0.6)
    with pytest.raises(ArchiveError, match="truncated|damaged") as info:
        safe_extract(archive, tmp_path / "dest")
    message = str(info.value)
    assert str(archive) in message and "\n" not in message


def test_not_an_archive(tmp_path):
    path = tmp_path / "notes.zip"
    path.write_text("hello")
    with pytest.raises(ArchiveError, match="not a zip or tar"):
        safe_extract(path, tmp_path / "dest")
    with pytest.raises(FileNotFoundError, match="missing.zip"):
        safe_extract(tmp_path / "missing.zip", tmp_path / "dest")


def run_script(*args) -> subprocess.CompletedProcess:
    """The CLI as a user runs it (a separate process: exit status and stderr as seen outside)."""
    return subprocess.run([sys.executable, str(SCRIPT), *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def script_main(*args) -> int:
    """The CLI's main() in this process (faster than a subprocess for the other checks)."""
    spec = importlib.util.spec_from_file_location("prepare_psb_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.main([str(a) for a in args])


def test_script_truncated_archive_one_line_error(tmp_path):
    archive = truncate(make_zip(tmp_path / "psb.zip", fake_benchmark()), 0.5)
    proc = run_script(archive, "--out", tmp_path / "out")
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("prepare_psb: error:"), proc.stderr
    assert "psb.zip" in lines[0]
    assert not (tmp_path / "out" / "meshes").exists()



def test_script_missing_archive(tmp_path, capsys):
    assert script_main(tmp_path / "nope.zip", "--out", tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert "nope.zip" in err and len(err.strip().splitlines()) == 1


def test_script_refuses_unsafe_archive(tmp_path, capsys):
    members = fake_benchmark()
    members["../escape.seg"] = b"0\n"
    archive = make_zip(tmp_path / "psb.zip", members)
    assert script_main(archive, "--out", tmp_path / "out") == 1
    assert "refusing member" in capsys.readouterr().err
    assert not (tmp_path / "escape.seg").exists() and not (tmp_path / "out" / "escape.seg").exists()


# ---------------------------------------------------------------------------------------------
# layout conversion
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["zip", "tar.gz"])
def test_prepare_converts_layout(tmp_path, kind):
    members = fake_benchmark()
    if kind == "zip":
        archive = make_zip(tmp_path / "MeshsegBenchmark-1.0.zip", members)
    else:
        archive = make_tar(tmp_path / "MeshsegBenchmark-1.0.tar.gz", members, "w:gz")
    out = tmp_path / "psb"
    report = prepare_psb(archive, out)
    assert (report.n_meshes, report.n_segmentations, report.meshes_with_gt) == (3, 12, 2)
    assert sorted(p.name for p in (out / "meshes").iterdir()) == \
        ["1.off.gz", "2.off.gz", "21.off.gz"]
    assert sorted(os.listdir(out)) == ["gt", "meshes"]  # the temporary folder is gone
    assert gzip.decompress((out / "meshes" / "1.off.gz").read_bytes()) == TETRA_OFF

    entries = find_psb_meshes(out)
    assert [(e.mesh_id, e.category, len(e.seg_paths)) for e in entries] == \
        [(1, "Human", 11), (2, "Human", 0), (21, "Cup", 1)]
    # k in numeric order: 1_10 comes after 1_9.
    assert [p.name for p in entries[0].seg_paths][-2:] == ["1_9.seg.gz", "1_10.seg.gz"]
    assert not entries[1].has_gt
    for k, path in enumerate(entries[0].seg_paths):
        assert read_seg(path).tolist() == [0, 0, k % 2, 1]
    assert human_segment_counts(entries[0]) == [2, 2] * 5 + [2]
    assert human_segment_counts(entries[1]) == []
    assert human_segment_counts(entries[2]) == [4]
    vertices, faces = read_off(entries[0].mesh_path)
    assert vertices.shape == (4, 3) and faces.tolist()[0] == [0, 2, 1]

    # An existing result is not overwritten silently.
    with pytest.raises(ArchiveError, match="overwrite"):
        prepare_psb(archive, out)
    with pytest.raises(ArchiveError, match="unknown categories"):
        prepare_psb(archive, out, overwrite=True, withhold=["Spring"])
    report = prepare_psb(archive, out, overwrite=True, compress=False, withhold=["Cup"])
    assert report.withheld_meshes == [21]
    entries = find_psb_meshes(out)
    assert entries[0].mesh_path.name == "1.off"
    assert entries[0].seg_paths[0].name == "1_0.seg"
    assert entries[2].seg_paths == []


def test_prepare_rejects_wrong_seg_length(tmp_path):
    members = fake_benchmark()
    members["MeshsegBenchmark-1.0/data/seg/Benchmark/21/21_0.seg"] = seg_bytes([0, 1, 2])
    archive = make_zip(tmp_path / "psb.zip", members)
    with pytest.raises(ArchiveError, match="3 labels but mesh 21 has 4 faces"):
        prepare_psb(archive, tmp_path / "out")
    assert not (tmp_path / "out").exists()  # created by the call, removed after the failure


def test_prepare_rejects_non_benchmark_archive(tmp_path):
    archive = make_zip(tmp_path / "other.zip", {"x/readme.txt": b"hi"})
    with pytest.raises(ArchiveError, match="no benchmark data"):
        prepare_psb(archive, tmp_path / "out")


def test_script_success(tmp_path, capsys):
    archive = make_tar(tmp_path / "psb.tar", fake_benchmark())
    assert script_main(archive, "--out", tmp_path / "out", "--withhold", "Cup") == 0
    assert "done: 3 meshes" in capsys.readouterr().out
    assert (tmp_path / "out" / "gt" / "1" / "1_0.seg.gz").is_file()
    assert not (tmp_path / "out" / "gt" / "21").exists()
