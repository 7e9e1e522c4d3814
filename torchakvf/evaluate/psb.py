"""Access to the Princeton Segmentation Benchmark (PSB) data set on disk.

Layout (as prepared by ``datasets_scripts/prepare_psb.py``; see the README beside the data)::

    <root>/meshes/N.off[.gz]        N = 1..400 (Spring, 261..280, is not in the benchmark)
    <root>/gt/N/N_k.seg[.gz]        human segmentation k of mesh N, k = 0, 1, ...

The human segmentations of some categories may be held back for blind evaluation: such a mesh
has an empty ``seg_paths`` list, which means "no score", not an error.
"""
from __future__ import annotations

import gzip
import itertools
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..io.off import parse_off
from ..io.outputs import write_seg  # noqa: F401 - the one .seg writer, re-exported

__all__ = [
    "CATEGORIES",
    "ABSENT_CATEGORIES",
    "BENCHMARK_CATEGORIES",
    "PSBEntry",
    "category_of",
    "find_psb_meshes",
    "default_psb_root",
    "PSB_ENV",
    "read_seg",
    "write_seg",
    "human_segment_counts",
    "segment_count",
    "parse_digit_tokens",
    "parse_seg_tokens",
    "human_pairwise_rand_index_error",
    "read_off",
]

#: Category of mesh N is ``CATEGORIES[(N - 1) // 20]`` (the benchmark's ``data/README.txt``).
#: Index 13, Spring, keeps its slot so that the index arithmetic holds, but the benchmark has no
#: Spring meshes (see :data:`ABSENT_CATEGORIES`).
CATEGORIES: list[str] = [
    "Human", "Cup", "Glasses", "Airplane", "Ant", "Chair", "Octopus", "Table", "Teddy", "Hand",
    "Plier", "Fish", "Bird", "Spring", "Armadillo", "Bust", "Mech", "Bearing", "Vase", "Fourleg",
]
#: Categories whose slot exists in the numbering but which have no files in the benchmark.
ABSENT_CATEGORIES: frozenset[str] = frozenset({"Spring"})
#: The 19 categories of the benchmark, in index order.
BENCHMARK_CATEGORIES: list[str] = [c for c in CATEGORIES if c not in ABSENT_CATEGORIES]

MESHES_PER_CATEGORY = 20
MAX_MESH_ID = MESHES_PER_CATEGORY * len(CATEGORIES)  # 400

_MESH_NAME = re.compile(r"^(\d+)\.off(\.gz)?$")
_GZIP_MAGIC = b"\x1f\x8b"


@dataclass(frozen=True)
class PSBEntry:
    """One benchmark mesh and its human segmentations.

    Attributes
    ----------
    mesh_id : int
        N, 1..400.
    category : str
        ``category_of(mesh_id)``.
    mesh_path : Path
        ``meshes/N.off`` or ``meshes/N.off.gz``.
    seg_paths : list[Path]
        ``gt/N/N_k.seg[.gz]`` in increasing k; empty when the ground truth is held back.
    """

    mesh_id: int
    category: str
    mesh_path: Path
    seg_paths: list[Path] = field(default_factory=list)

    @property
    def has_gt(self) -> bool:
        """Whether human segmentations are available (otherwise: no score for this mesh)."""
        return len(self.seg_paths) > 0


def category_of(mesh_id: int) -> str:
    """Category name of PSB mesh ``mesh_id`` (1-based): ``CATEGORIES[(mesh_id - 1) // 20]``.

    Raises
    ------
    ValueError
        If ``mesh_id`` is not an integer in 1..400.
    """
    if isinstance(mesh_id, (bool, np.bool_)) or not isinstance(mesh_id, (int, np.integer)):
        raise ParameterError(f"PSB mesh id must be an integer, got {mesh_id!r}")
    if not 1 <= mesh_id <= MAX_MESH_ID:
        raise ParameterError(f"PSB mesh id must be in 1..{MAX_MESH_ID}, got {mesh_id}")
    return CATEGORIES[(int(mesh_id) - 1) // MESHES_PER_CATEGORY]


#: The environment variable that names the PSB folder when no ``--psb`` is given.
PSB_ENV = "TORCHAKVF_PSB"


def default_psb_root() -> Path | None:
    """The PSB folder ``$TORCHAKVF_PSB`` names, if it holds ``meshes/``; else None (callers,
    e.g. tests, then skip). The package looks nowhere else: a checkout's neighbours are no
    place of an installed library's (the tests' conftest sets the variable for a checkout).
    A set but missing folder also gives None, so a stale variable does not turn into an error
    here; :func:`find_psb_meshes` reports missing roots."""
    env = os.environ.get(PSB_ENV)
    if env and (Path(env) / "meshes").is_dir():
        return Path(env)
    return None


def find_psb_meshes(root, problems: list | None = None) -> list[PSBEntry]:
    """List the benchmark's meshes under ``root``, sorted by mesh id.

    Reads both ``N.off.gz`` and ``N.off`` (if both exist the uncompressed one is used) and the
    human segmentations ``gt/N/N_k.seg[.gz]`` in numeric order of k (``N_10`` after ``N_9``).

    Parameters
    ----------
    root : str or Path
        Folder holding ``meshes/`` and (optionally) ``gt/``.
    problems : a list to collect one line per misplaced file (naming it; the file is left out)
        instead of raising on the first one

    Returns
    -------
    list[PSBEntry]

    Raises
    ------
    FileNotFoundError
        If ``root`` is None (no folder given: :func:`default_psb_root` found none) or
        ``root`` or ``root/meshes`` does not exist.
    ParameterError (a ValueError)
        Without ``problems``: if a mesh file name has an id outside 1..400, or a segmentation
        file belongs to another mesh.
    """
    if root is None:
        raise FileNotFoundError(f"no PSB folder given: pass its folder (--psb DIR) or set {PSB_ENV}")
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"PSB root {str(root)!r} does not exist or is not a folder")
    mesh_dir = root / "meshes"
    if not mesh_dir.is_dir():
        raise FileNotFoundError(f"PSB root {str(root)!r} has no 'meshes' folder "
                                f"(expected meshes/N.off[.gz] and gt/N/N_k.seg[.gz])")
    meshes: dict[int, Path] = {}
    for path in mesh_dir.iterdir():
        m = _MESH_NAME.match(path.name)
        if not m or not path.is_file():
            continue  # READMEs and other stray files are not meshes
        mesh_id = int(m.group(1))
        if not 1 <= mesh_id <= MAX_MESH_ID:
            _problem(problems, f"{path}: PSB mesh ids are 1..{MAX_MESH_ID}, got {mesh_id}; file left out")
            continue
        # Prefer the uncompressed file when both exist: it is faster to read.
        if mesh_id not in meshes or not m.group(2):
            meshes[mesh_id] = path
    gt_dir = root / "gt"
    return [PSBEntry(mesh_id, category_of(mesh_id), meshes[mesh_id],
                     _find_segs(gt_dir / str(mesh_id), mesh_id, problems))
            for mesh_id in sorted(meshes)]


def _problem(problems: list | None, line: str) -> None:
    if problems is None:
        raise ParameterError(line)
    problems.append(line)


def _find_segs(folder: Path, mesh_id: int, problems: list | None = None) -> list[Path]:
    if not folder.is_dir():
        return []
    pattern = re.compile(r"^(\d+)_(\d+)\.seg(\.gz)?$")
    found: dict[int, Path] = {}
    for path in folder.iterdir():
        m = pattern.match(path.name)
        if not m or not path.is_file():
            continue
        if int(m.group(1)) != mesh_id:
            _problem(problems, f"{path}: a segmentation of mesh {m.group(1)} in the folder of mesh "
                               f"{mesh_id}; left out")
            continue
        k = int(m.group(2))
        if k not in found or not m.group(3):
            found[k] = path
    return [found[k] for k in sorted(found)]


def _read_bytes(path: Path) -> bytes:
    # Decide by content, not by name: a .seg that is really gzip (or the reverse) still reads.
    with open(path, "rb") as fh:
        data = fh.read()
    if data[:2] == _GZIP_MAGIC:
        try:
            data = gzip.decompress(data)
        except (OSError, EOFError) as exc:
            raise ParameterError(f"{path}: damaged gzip file ({exc})") from None
    return data


def read_seg(path) -> np.ndarray:
    """Read a ``.seg`` file (gzip-compressed or plain): one integer label per line, per face.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    array [F], int64
        The label of every face, in the order of the mesh's faces.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is empty or holds something other than integers (the message names the line).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"segmentation file {str(path)!r} does not exist")
    data = _read_bytes(path)
    if not data.strip():
        raise ParameterError(f"{path}: empty segmentation file")
    labels = parse_digit_tokens(data)
    if labels is not None:
        return labels
    # Fast path: numpy's C parser, much faster than int() per token over the benchmark's files.
    # It stops at the first bad token with a DeprecationWarning, which we turn into an error.
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", DeprecationWarning)
            labels = np.fromstring(data, dtype=np.int64, sep=" ")
        if labels.size == len(data.split()):
            return labels
    except (ValueError, DeprecationWarning, AttributeError):  # AttributeError: no fromstring
        pass
    return parse_seg_tokens(path, data)


#: Bytes of a file :func:`parse_digit_tokens` takes: decimal digits and blanks.
_DIGIT_OR_BLANK = np.zeros(256, dtype=bool)
_DIGIT_OR_BLANK[[ord(c) for c in "0123456789 \t\r\n"]] = True


def parse_digit_tokens(data: bytes) -> np.ndarray | None:
    """[T] int64 values of the whitespace-separated tokens of ``data`` when every byte is a
    decimal digit or a blank (the usual .seg file: unsigned labels), each token's digits
    weighted by powers of ten, all tokens at once (faster than numpy's ``fromstring`` and the
    token count it is checked against); None for anything else (signs, other bytes,
    tokens of more than 18 digits), which the general parsers read or reject."""
    a = np.frombuffer(data, dtype=np.uint8)
    if not _DIGIT_OR_BLANK[a].all():
        return None
    digit = a >= 48                                       # blanks are below '0'
    first = digit.copy()
    first[1:] &= ~digit[:-1]
    last = digit.copy()
    last[:-1] &= ~digit[1:]
    starts, ends = np.flatnonzero(first), np.flatnonzero(last) + 1
    lengths = ends - starts
    if len(starts) == 0 or lengths.max() > 18:
        return None
    if lengths.max() == 1:
        return (a[starts] - 48).astype(np.int64)
    at = np.flatnonzero(digit)
    power = np.repeat(ends - 1, lengths) - at             # place of each digit in its token
    values = (a[at] - 48).astype(np.int64) * 10 ** power
    return np.add.reduceat(values, np.r_[0, np.cumsum(lengths)[:-1]])


def segment_count(labels) -> int:
    """Distinct values of integer ``labels`` (= ``np.unique(labels).size``): by a bincount
    over their range where it is compact (segment labels), else np.unique."""
    labels = np.asarray(labels)
    if labels.size == 0:
        return 0
    lo, hi = int(labels.min()), int(labels.max())
    if hi - lo <= 4 * labels.size + 1024:
        return int(np.count_nonzero(np.bincount((labels - lo).astype(np.intp, copy=False))))
    return int(np.unique(labels).size)


def parse_seg_tokens(path: Path, data: bytes) -> np.ndarray:
    """[T] int64 labels of a .seg file's bytes, token by token: the general parser, which says
    exactly where a bad file goes wrong (ParameterError naming ``path`` and the line)."""
    out = []
    for lineno, line in enumerate(data.splitlines(), start=1):
        for token in line.split():
            try:
                out.append(int(token))
            except ValueError:
                shown = token[:40].decode("utf-8", "replace")
                raise ParameterError(f"{path}, line {lineno}: expected an integer segment label, "
                                     f"got {shown!r}") from None
    return np.asarray(out, dtype=np.int64)


def read_off(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh from an ``.off`` file (gzip-compressed or plain, told by content),
    faces in file order: the package's OFF parser (:func:`torchakvf.io.off.parse_off`).

    Returns
    -------
    vertices : array [V, 3], float64
    faces : array [F, 3], int64
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file {str(path)!r} does not exist")
    return parse_off(_read_bytes(path), str(path))


def human_segment_counts(entry: PSBEntry) -> list[int]:
    """Distinct labels in each human segmentation of ``entry`` (k order); [] without gt."""
    return [segment_count(read_seg(p)) for p in entry.seg_paths]


def human_pairwise_rand_index_error(entry: PSBEntry, segs: list[np.ndarray] | None = None) -> float:
    """Mean 1 - RI over all pairs of human segmentations of one mesh (the "human" score).

    Parameters
    ----------
    entry : PSBEntry
    segs : list of array [F], optional
        The segmentations, if already read (otherwise read from ``entry.seg_paths``).

    Returns
    -------
    float
        NaN when the mesh has fewer than two human segmentations (no pair, no score).
    """
    from .metrics import rand_index_error  # local: keep importing this module cheap

    if segs is None:
        segs = [read_seg(p) for p in entry.seg_paths]
    values = [rand_index_error(s, t) for s, t in itertools.combinations(segs, 2)]
    return float(np.mean(values)) if values else float("nan")
