"""torchakvf.evaluate.psb: reading the benchmark's files and naming its meshes and, when the
data set is present, the human-vs-human consistency of the benchmark."""
from __future__ import annotations

import gzip
import itertools
import math
import time

import numpy as np
import pytest

from torchakvf.evaluate.metrics import evaluate_segmentation, rand_index_error
from torchakvf.evaluate.psb import (
    BENCHMARK_CATEGORIES,
    CATEGORIES,
    category_of,
    find_psb_meshes,
    human_pairwise_rand_index_error,
    read_off,
    read_seg,
    write_seg,
)
from torchakvf.evaluate.psb import default_psb_root as psb_root  # noqa: E402

#: A tetrahedron, as an OFF file's bytes.
TETRA_OFF = (b"OFF\n4 4 6\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n"
             b"3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n")

needs_psb = pytest.mark.skipif(
    psb_root() is None,
    reason="PSB data not found: set TORCHAKVF_PSB or put it at <repo>/../shared/psb")


def test_default_root_is_the_variable_only(tmp_path, monkeypatch):
    """$TORCHAKVF_PSB when it holds meshes/, else None: never a folder beside the checkout."""
    monkeypatch.delenv("TORCHAKVF_PSB", raising=False)
    assert psb_root() is None
    monkeypatch.setenv("TORCHAKVF_PSB", str(tmp_path))
    assert psb_root() is None
    (tmp_path / "meshes").mkdir()
    assert psb_root() == tmp_path

# ---------------------------------------------------------------------------------------------
# reading and naming
# ---------------------------------------------------------------------------------------------

def test_read_write_seg_plain_and_gz(tmp_path):
    labels = np.array([0, 3, 3, 1, 2, 0])
    plain = write_seg(tmp_path / "a.seg", labels)
    assert plain.read_text() == "0\n3\n3\n1\n2\n0\n"
    packed = write_seg(tmp_path / "sub" / "a.seg.gz", labels)
    assert gzip.decompress(packed.read_bytes()).decode() == "0\n3\n3\n1\n2\n0\n"
    for path in (plain, packed):
        out = read_seg(path)
        assert out.dtype == np.int64 and out.tolist() == labels.tolist()
    # Content decides, not the name: a gzip file called .seg still reads.
    (tmp_path / "gz_named_plain.seg").write_bytes(packed.read_bytes())
    assert read_seg(tmp_path / "gz_named_plain.seg").tolist() == labels.tolist()
    # Windows line ends and a missing final newline are fine.
    (tmp_path / "crlf.seg").write_bytes(b"1\r\n2\r\n3")
    assert read_seg(tmp_path / "crlf.seg").tolist() == [1, 2, 3]


@pytest.mark.parametrize("lo, hi", [(0, 12), (-1, 40), (-7, -2), (5, 5), (-10**12, 10**12)])
def test_write_seg_text_is_one_decimal_per_line(tmp_path, lo, hi):
    """The labels' table of strings (narrow ranges) and str per label (wide ones) write the
    text Python's str gives, negatives and wide ranges included, every dtype widened alike."""
    labels = np.random.default_rng(lo & 0xFFFF).integers(lo, hi + 1, 3000)
    for dtype in (np.int64, np.int32) if abs(lo) < 2**31 and abs(hi) < 2**31 else (np.int64,):
        path = write_seg(tmp_path / f"{dtype.__name__}.seg", labels.astype(dtype))
        assert path.read_bytes() == "".join(f"{int(v)}\n" for v in labels).encode()


@pytest.mark.parametrize("data, vectorized", [
    (b"0\n3\n3\n1\n", True),
    (b"12\n007\n\n 40 5\t6\r\n999999999999999999", True),    # multi-digit, leading zeros, blanks
    (b"1\n2\n3", True),
    (b"-1\n2\n", False),                                         # a sign: the general parsers
    (b"+4\n2\n", False),
    (b"1\x0b2\n", False),
    (b"1234567890123456789\n", False),                            # 19 digits
])
def test_seg_digit_parser_equals_the_token_parser(data, vectorized, tmp_path):
    """The all-digits fast path of read_seg gives int() of every token; other files go to the
    general parsers, with the same values."""
    from torchakvf.evaluate.psb import parse_digit_tokens, parse_seg_tokens
    fast = parse_digit_tokens(data)
    ref = parse_seg_tokens(tmp_path / "x.seg", data)
    assert (fast is not None) == vectorized
    if fast is not None:
        assert fast.dtype == np.int64 and fast.tolist() == ref.tolist()
    (tmp_path / "x.seg").write_bytes(data)
    got = read_seg(tmp_path / "x.seg")
    assert got.dtype == np.int64 and got.tolist() == ref.tolist()


def test_segment_count_is_the_number_of_distinct_labels():
    from torchakvf.evaluate.psb import segment_count
    rng = np.random.default_rng(2)
    for labels in (np.array([4]), np.array([], dtype=np.int64), rng.integers(0, 7, 500),
                   rng.integers(-3, 3, 50), np.array([0, 10 ** 12, 5, 5]), rng.integers(0, 10 ** 6, 30)):
        assert segment_count(labels) == np.unique(labels).size


def test_read_seg_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.seg"):
        read_seg(tmp_path / "missing.seg")
    (tmp_path / "bad.seg").write_text("0\n1\nx2\n3\n")
    with pytest.raises(ValueError, match="line 3"):
        read_seg(tmp_path / "bad.seg")
    (tmp_path / "float.seg").write_text("0\n1.5\n")
    with pytest.raises(ValueError, match="line 2"):
        read_seg(tmp_path / "float.seg")
    (tmp_path / "empty.seg").write_text("\n\n")
    with pytest.raises(ValueError, match="empty"):
        read_seg(tmp_path / "empty.seg")
    with pytest.raises(ValueError, match="integers"):
        write_seg(tmp_path / "f.seg", np.array([0.5, 1.0]))


def test_find_psb_meshes_layout(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "10.off.gz").write_bytes(gzip.compress(TETRA_OFF))
    (tmp_path / "meshes" / "2.off").write_bytes(TETRA_OFF)
    (tmp_path / "meshes" / "2.off.gz").write_bytes(gzip.compress(TETRA_OFF))  # plain wins
    (tmp_path / "meshes" / "README.md").write_text("not a mesh")
    for k in (0, 2, 10, 1):
        write_seg(tmp_path / "gt" / "10" / f"10_{k}.seg.gz", [0, 0, 1, 1])
    entries = find_psb_meshes(tmp_path)
    assert [e.mesh_id for e in entries] == [2, 10]
    assert entries[0].mesh_path.name == "2.off" and entries[0].seg_paths == []
    assert [p.name for p in entries[1].seg_paths] == \
        ["10_0.seg.gz", "10_1.seg.gz", "10_2.seg.gz", "10_10.seg.gz"]

    with pytest.raises(FileNotFoundError, match="no_such_root"):
        find_psb_meshes(tmp_path / "no_such_root")
    with pytest.raises(FileNotFoundError, match="no PSB folder given: .*TORCHAKVF_PSB"):
        find_psb_meshes(None)                 # what default_psb_root() gives without the variable
    (tmp_path / "empty_root").mkdir()
    with pytest.raises(FileNotFoundError, match="meshes"):
        find_psb_meshes(tmp_path / "empty_root")


def test_categories():
    assert len(CATEGORIES) == 20 and len(BENCHMARK_CATEGORIES) == 19
    assert "Spring" not in BENCHMARK_CATEGORIES
    assert [category_of(i) for i in (1, 20, 21, 141, 260, 261, 281, 400)] == \
        ["Human", "Human", "Cup", "Table", "Bird", "Spring", "Armadillo", "Fourleg"]
    for bad in (0, 401, -3, 2.0, "5"):
        with pytest.raises(ValueError):
            category_of(bad)


# ---------------------------------------------------------------------------------------------
# the real benchmark: human-vs-human consistency
# ---------------------------------------------------------------------------------------------

PUBLISHED_HUMAN_RI_ERROR = 0.103  # Chen et al. 2009, Figure 5 (all 19 categories)


def human_consistency(per_category: int | None) -> tuple[float, dict[str, float], int]:
    """Mean over categories (of 20 meshes, so also over meshes) of the mesh's mean pairwise 1-RI."""
    entries = [e for e in find_psb_meshes(psb_root()) if e.has_gt]
    by_cat: dict[str, list[float]] = {}
    n_files = 0
    for e in entries:
        scores = by_cat.setdefault(e.category, [])
        if per_category is not None and len(scores) >= per_category:
            continue
        segs = [read_seg(p) for p in e.seg_paths]
        n_files += len(segs)
        assert len({s.size for s in segs}) == 1, f"mesh {e.mesh_id}: seg lengths differ"
        scores.append(human_pairwise_rand_index_error(e, segs))
    cat_means = {c: float(np.mean(v)) for c, v in by_cat.items()}
    return float(np.mean(list(cat_means.values()))), cat_means, n_files


def _per_face_rand_index_error(a: np.ndarray, b: np.ndarray) -> float:
    """1 - RI counted face by face (not from a contingency table): face i disagrees with every
    face j that shares its segment in exactly one of a, b; each pair is seen twice."""
    def same(keys):
        _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        return counts[inverse.reshape(-1)] - 1            # other faces in face i's (joint) segment
    n = len(a)
    a, b = a.astype(np.int64), b.astype(np.int64)
    joint = (a - a.min()) * (int(b.max() - b.min()) + 1) + (b - b.min())
    disagree_twice = np.sum(same(a) + same(b) - 2 * same(joint), dtype=np.int64)
    return float(disagree_twice / 2) / (n * (n - 1) / 2)


def _independent_human_consistency(per_category=None):
    """The benchmark's human-vs-human 1-RI (mean over categories of the per-mesh mean over
    pairs of human segmentations), with the files read by gzip/numpy directly."""
    by_cat: dict[str, list[float]] = {}
    for e in find_psb_meshes(psb_root()):
        if not e.has_gt:
            continue
        scores = by_cat.setdefault(e.category, [])
        if per_category is not None and len(scores) >= per_category:
            continue
        segs = []
        for path in e.seg_paths:
            opener = gzip.open if str(path).endswith(".gz") else open
            with opener(path, "rt") as fh:
                segs.append(np.array([int(line) for line in fh.read().split()], dtype=np.int64))
        scores.append(float(np.mean([_per_face_rand_index_error(x, y)
                                     for x, y in itertools.combinations(segs, 2)])))
    cats = {c: float(np.mean(v)) for c, v in by_cat.items()}
    return float(np.mean(list(cats.values()))), cats


def _report(label: str, overall: float, cat_means: dict[str, float], n_files: int, secs: float):
    print(f"\n[{label}] human-vs-human 1-RI = {overall:.4f} over {len(cat_means)} categories "
          f"({n_files} segmentations, {secs:.1f} s); published (19 categories): "
          f"{PUBLISHED_HUMAN_RI_ERROR}")
    for c, v in cat_means.items():
        print(f"    {c:10s} {v:.4f}")


@needs_psb
def test_psb_human_consistency_quick():
    start = time.perf_counter()
    overall, cat_means, n_files = human_consistency(per_category=2)
    _report("quick, 2 meshes per category", overall, cat_means, n_files,
            time.perf_counter() - start)
    assert len(cat_means) == 15
    # The published 0.103 covers 19 categories, 4 of which are held back here, so it cannot be
    # matched; the check is against an independent count of the same pairs instead.
    expected, expected_cats = _independent_human_consistency(per_category=2)
    assert overall == pytest.approx(expected, rel=1e-12, abs=0)
    assert cat_means == pytest.approx(expected_cats, rel=1e-12, abs=0)


@needs_psb
def test_psb_human_consistency_full():
    start = time.perf_counter()
    overall, cat_means, n_files = human_consistency(per_category=None)
    _report("all meshes with ground truth", overall, cat_means, n_files,
            time.perf_counter() - start)
    # 15 categories have ground truth here; 4 are held back.
    assert len(cat_means) == 15 and n_files > 3000
    expected, _ = _independent_human_consistency(per_category=None)
    assert overall == pytest.approx(expected, rel=1e-12, abs=0)


@needs_psb
def test_psb_held_back_meshes_have_no_score():
    entries = find_psb_meshes(psb_root())
    assert len(entries) == 380
    held = {e.category for e in entries if not e.has_gt}
    assert held <= {"Table", "Bird", "Bearing", "Fourleg"}
    for e in entries:
        if not e.has_gt:
            assert math.isnan(human_pairwise_rand_index_error(e))


@needs_psb
def test_psb_one_mesh_all_metrics():
    entry = find_psb_meshes(psb_root())[0]  # mesh 1, Human
    vertices, faces = read_off(entry.mesh_path)
    segs = [read_seg(p) for p in entry.seg_paths[:3]]
    assert all(s.size == len(faces) for s in segs)
    for a, b in itertools.combinations(segs, 2):
        r = evaluate_segmentation(vertices, faces, a, b)
        assert r["rand_index_error"] == rand_index_error(a, b)
        for key, value in r.items():
            assert 0.0 <= value < (5.0 if key == "cut_discrepancy" else 1.0), (key, value)
