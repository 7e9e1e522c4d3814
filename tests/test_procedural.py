"""The procedural corpus (torchakvf.shapes.procedural and its families in .mechanical and
.organic): every family at two seeds gives a closed, manifold, outward mesh, a label per face,
every part present and each one connected region; seeds reproduce their shape bit for bit;
thin parts keep both sides; the meshes load and clean through torchakvf unrepaired; and the
corpus script writes the same files whatever its worker count."""
from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

import torchakvf as ta
from torchakvf.errors import ParameterError
from torchakvf.mesh import MeshBatch, clean_mesh
from torchakvf.shapes.procedural import FAMILIES, family_rng, make_procedural, procedural_shape

pytestmark = pytest.mark.usefixtures("one_torch_thread")

#: A small detail: meshes of a few thousand faces, still two grid steps across thin parts.
SMALL = 0.05
SEEDS = (0, 1)
SCRIPT = Path(__file__).resolve().parents[1] / "datasets_scripts" / "make_parts_corpus.py"


@pytest.fixture(scope="module")
def corpus():
    return {(f, s): make_procedural(f, s, SMALL) for f in FAMILIES for s in SEEDS}


def _face_graph(faces: np.ndarray, keep: np.ndarray) -> sp.coo_matrix:
    """Faces (where keep) joined when they share an edge."""
    idx = np.flatnonzero(keep)
    f = faces[idx]
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(f)), 3)
    _, key = np.unique(e, axis=0, return_inverse=True)
    key = key.ravel()
    order = np.argsort(key, kind="stable")
    same = key[order][1:] == key[order][:-1]
    a, b = owner[order][:-1][same], owner[order][1:][same]
    return sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(len(f), len(f)))


def test_families_cover_both_kinds():
    kinds = [fam.kind for fam in FAMILIES.values()]
    assert len(FAMILIES) >= 12 and set(kinds) == {"organic", "mechanical"}
    assert abs(kinds.count("organic") - kinds.count("mechanical")) <= 2
    assert all(fam.about for fam in FAMILIES.values())


@pytest.mark.parametrize("family", list(FAMILIES))
def test_meshes_are_closed_manifold_outward(corpus, family):
    for seed in SEEDS:
        s = corpus[family, seed].shape
        v, f = s.vertices, s.faces
        assert v.dtype == np.float64 and f.dtype == np.int64 and np.isfinite(v).all()
        assert np.array_equal(np.unique(f), np.arange(len(v)))                 # every vertex used
        assert len(np.unique(np.round(v, 9), axis=0)) == len(v)                 # none repeated
        e = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, count = np.unique(e, axis=0, return_counts=True)
        assert np.all(count == 2)                                               # closed, edge-manifold
        directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        assert len(np.unique(directed, axis=0)) == len(directed)                # consistently oriented
        tri = v[f]
        cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        assert np.einsum("ij,ij->i", tri[:, 0], cross).sum() > 0                # outward
        lengths = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
        assert 0.5 * np.linalg.norm(cross, axis=1).min() > 1e-3 * lengths.mean() ** 2   # no degenerate face
        n, _ = connected_components(_face_graph(f, np.ones(len(f), bool)), directed=False)
        assert n == 1
        # vertex-manifold: each vertex's faces form one fan (as many faces as distinct edges).
        per_vertex = np.bincount(f.ravel(), minlength=len(v))
        edges_at = np.bincount(np.unique(e, axis=0).ravel(), minlength=len(v))
        assert np.array_equal(per_vertex, edges_at)


@pytest.mark.parametrize("family", list(FAMILIES))
def test_every_part_present_and_one_region(corpus, family):
    for seed in SEEDS:
        ps = corpus[family, seed]
        s = ps.shape
        assert s.part_labels.dtype == np.int64 and s.part_labels.shape == (len(s.faces),)
        assert np.array_equal(np.unique(s.part_labels), np.arange(s.n_parts))
        assert s.n_parts == len(ps.part_names) >= 2 and ps.kind == FAMILIES[family].kind
        for p in range(s.n_parts):
            n, _ = connected_components(_face_graph(s.faces, s.part_labels == p), directed=False)
            assert n == 1, (family, seed, ps.part_names[p])
        json.dumps(ps.params)                                                   # JSON-ready


def test_seed_reproduces_bits_and_others_differ():
    for family in ("shaft", "fish"):
        a, b = procedural_shape(family, 3, SMALL), procedural_shape(family, 3, SMALL)
        assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
        assert np.array_equal(a.part_labels, b.part_labels)
        c = procedural_shape(family, 4, SMALL)
        assert len(c.faces) != len(a.faces) or not np.allclose(c.vertices, a.vertices)
    with pytest.raises(ParameterError, match="unknown procedural family"):
        procedural_shape("teapot", 0)
    with pytest.raises(ParameterError, match="detail"):
        procedural_shape("shaft", 0, detail=0)


def _area_by_normal(ps, part: str, axis_local) -> tuple[float, float]:
    """Area of the faces of ``part`` facing along +axis and -axis (within 25 degrees), in the
    design's own units (the pose undone)."""
    s = ps.shape
    rot = np.asarray(ps.params["rotation"])
    v = s.vertices / ps.params["scale"] @ rot                   # world -> the design's frame
    tri = v[s.faces[s.part_labels == ps.part_names.index(part)]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    up = n @ np.asarray(axis_local, dtype=np.float64) / (2 * area)
    return float(area[up > 0.9].sum()), float(area[up < -0.9].sum())


def test_thin_disc_keeps_both_sides():
    """The first flanged hub with a disc under 0.1 of its radius thick, meshed coarsely (two
    grid steps across the disc): the disc has both flat faces, each about the annulus the hub
    leaves (less bolt holes)."""
    draw = FAMILIES["flanged_hub"].generator
    seed = next(s for s in range(40) if draw(family_rng("flanged_hub", s)).params["thickness"] < 0.1)
    ps = make_procedural("flanged_hub", seed, SMALL)
    assert ps.params["thickness"] < 0.1 and ps.params["steps_across"] == pytest.approx(2.0)
    rh = ps.params["hub_radius"]
    front, back = _area_by_normal(ps, "disc", (0, 0, 1))
    annulus = np.pi * (1 - rh ** 2)
    assert min(front, back) > 0.6 * annulus and max(front, back) < 1.05 * np.pi


def test_meshes_load_and_clean_unrepaired(corpus, tmp_path):
    meshes = []
    for (family, seed), ps in list(corpus.items())[::2]:          # one seed of each family
        path = ta.io.write_off(tmp_path / f"{family}_{seed}.off", ps.shape.vertices, ps.shape.faces)
        mesh = ta.load_mesh(path)
        assert np.array_equal(mesh.faces, ps.shape.faces)
        report = clean_mesh(mesh).report
        assert report["components"] == 1 and report["boundary_edges"] == 0
        for key in ("merged_vertices", "welded_vertices", "zero_area_faces", "repeated_faces", "flipped_faces",
                    "unreferenced_vertices"):
            assert report[key] == 0, (family, key)
        meshes.append(mesh)
    # Decimated for solving (the CLI's default), one mechanical and one organic mesh.
    big = [m for m, (family, _) in zip(meshes, list(corpus)[::2]) if family in ("table", "octopus")]
    batch = MeshBatch.from_meshes(big, coarse_faces=4000)
    assert all(c is not None and c.coarse.faces.shape[0] <= 4400 for c in batch.coarse)


@pytest.mark.parametrize("family", ["table", "fish"])
def test_fields_solve(corpus, family):
    s = corpus[family, 0].shape
    res = ta.akvf(ta.Mesh(s.vertices, s.faces, name=family), n=8)
    assert res.eigenvalues.shape == (1, 8) and bool(res.converged.all())


def _script():
    spec = importlib.util.spec_from_file_location("make_parts_corpus", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module            # the workers find make_one by its module's name
    spec.loader.exec_module(module)
    return module


def test_script_writes_the_same_corpus_with_any_worker_count(tmp_path):
    script = _script()
    args = ["--per-family", "2", "--families", "shaft,hand", "--seed", "1", "--detail", str(SMALL), "-q"]
    assert script.main(["--out", str(tmp_path / "one"), *args]) == 0
    assert script.main(["--out", str(tmp_path / "two"), "--workers", "2", *args]) == 0
    files = sorted(p.relative_to(tmp_path / "one") for p in (tmp_path / "one").rglob("*") if p.is_file())
    assert [str(p) for p in files] == ["hand/hand_000.off", "hand/hand_000.seg", "hand/hand_001.off",
                                       "hand/hand_001.seg", "index.json", "shaft/shaft_000.off",
                                       "shaft/shaft_000.seg", "shaft/shaft_001.off", "shaft/shaft_001.seg"]
    for p in files:
        assert (tmp_path / "one" / p).read_bytes() == (tmp_path / "two" / p).read_bytes(), p
    index = json.loads((tmp_path / "one" / "index.json").read_text())
    entry = index["shapes"][0]
    assert entry["name"] == "shaft_000" and entry["seed"] == 1000 and entry["kind"] == "mechanical"
    ps = make_procedural("shaft", 1000, SMALL)
    mesh = ta.load_mesh(tmp_path / "one" / "shaft" / "shaft_000.off")
    labels = np.loadtxt(tmp_path / "one" / "shaft" / "shaft_000.seg", dtype=np.int64)
    assert np.array_equal(mesh.vertices, ps.shape.vertices) and np.array_equal(labels, ps.shape.part_labels)
    assert entry["n_parts"] == ps.shape.n_parts and entry["faces"] == len(mesh.faces)
    assert script.main(["--out", str(tmp_path / "bad"), "--families", "teapot"]) == 1
