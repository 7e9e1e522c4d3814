"""Reading meshes (every format, face order kept), refusing bad input with a MeshError naming the
file and the problem, and the clean-up (merge, drop, re-orient, components) with its maps back to
the input's faces."""
from __future__ import annotations

import gzip
import re

import numpy as np
import pytest
import torch
import trimesh

import torchakvf as ta
from torchakvf import shapes

from threads import one_torch_thread  # noqa: F401 - autouse fixture




# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def ico2_shuffled():
    """icosphere(2) with its faces in a random order (so 'order kept' is a real check)."""
    s = shapes.icosphere(2)
    perm = np.random.default_rng(7).permutation(len(s.faces))
    return s.vertices, s.faces[perm]


def _write(path, data):
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def _off_text(vertices, faces, header_inline=False):
    head = f"OFF {len(vertices)} {len(faces)} 0\n" if header_inline else \
        f"OFF\n# a comment line\n{len(vertices)} {len(faces)} 0\n"
    body = "".join(f"{float(x)!r} {float(y)!r} {float(z)!r}\n" for x, y, z in vertices)
    body += "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    return head + body


def _akvf_eigs(mesh, n=12):
    return ta.akvf(mesh, n=n).eigenvalues[0].numpy()


def _moebius(n=24, twisted=True):
    t = 2 * np.pi * np.arange(n) / n
    centre = np.c_[np.cos(t), np.sin(t), 0 * t]
    if twisted:
        d = 0.3 * np.c_[np.cos(t / 2) * np.cos(t), np.cos(t / 2) * np.sin(t), np.sin(t / 2)]
    else:
        d = 0.3 * np.c_[0 * t, 0 * t, np.ones(n)]
    vertices = np.vstack([centre + d, centre - d])
    a, b = np.arange(n), np.arange(n) + n
    faces = []
    for i in range(n):
        if i < n - 1:
            faces += [[a[i], b[i], a[i + 1]], [a[i + 1], b[i], b[i + 1]]]
        elif twisted:  # after a half turn the strip's sides are swapped
            faces += [[a[i], b[i], b[0]], [b[0], b[i], a[0]]]
        else:
            faces += [[a[i], b[i], a[0]], [a[0], b[i], b[0]]]
    return vertices, np.array(faces)


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("ext,kw", [("off", {}), ("obj", {}), ("ply", {}),
                                    ("ply", {"encoding": "ascii"})])
def test_load_indexed_formats_keep_faces(tmp_path, ico2_shuffled, ext, kw):
    V, F = ico2_shuffled
    path = tmp_path / f"mesh.{ext}"
    trimesh.Trimesh(V, F, process=False).export(path, **kw)
    m = ta.load_mesh(path)
    assert isinstance(m, ta.Mesh)
    assert m.name == str(path)
    assert m.faces.shape == F.shape and m.vertices.shape == V.shape
    np.testing.assert_array_equal(m.faces, F)           # same order and count
    np.testing.assert_allclose(m.vertices, V, rtol=0, atol=1e-6)


def test_load_stl_soup_keeps_face_order(tmp_path, ico2_shuffled):
    V, F = ico2_shuffled
    path = tmp_path / "mesh.stl"
    trimesh.Trimesh(V, F, process=False).export(path)
    m = ta.load_mesh(path)
    assert m.faces.shape == F.shape
    # one vertex per corner, but every triangle is the same one, in file order
    np.testing.assert_allclose(m.vertices[m.faces], V[F], atol=1e-6)
    c = ta.clean_mesh(m)
    assert c.report["merged_vertices"] == m.n_vertices - len(V)
    assert len(c.vertices) == len(V)
    np.testing.assert_array_equal(c.face_index, np.arange(len(F)))


def test_load_hand_written_off_and_gzip(tmp_path, ico2_shuffled):
    V, F = ico2_shuffled
    for inline in (False, True):
        p = _write(tmp_path / f"h{int(inline)}.off", _off_text(V, F, inline))
        m = ta.load_mesh(p)
        np.testing.assert_array_equal(m.faces, F)
        np.testing.assert_array_equal(m.vertices, V)     # repr round-trips exactly
    gz = tmp_path / "h.off.gz"
    gz.write_bytes(gzip.compress(_off_text(V, F).encode()))
    m = ta.load_mesh(gz)
    assert m.name == str(gz)
    np.testing.assert_array_equal(m.faces, F)
    np.testing.assert_array_equal(m.vertices, V)
    # a gzipped OBJ goes through the other reader
    obj = tmp_path / "h.obj"
    trimesh.Trimesh(V, F, process=False).export(obj)
    (tmp_path / "h.obj.gz").write_bytes(gzip.compress(obj.read_bytes()))
    np.testing.assert_array_equal(ta.load_mesh(tmp_path / "h.obj.gz").faces, F)


def test_mesh_from_numpy_and_torch(ico2_shuffled):
    V, F = ico2_shuffled
    a = ta.Mesh(V, F)
    assert a.name == "<array>" and a.n_vertices == len(V) and a.n_faces == len(F)
    assert a.vertices.dtype == np.float64 and a.faces.dtype == np.int64
    b = ta.Mesh(torch.tensor(V, dtype=torch.float32), torch.tensor(F, dtype=torch.int32), name="t")
    assert b.name == "t" and b.vertices.dtype == np.float64 and b.faces.dtype == np.int64
    np.testing.assert_array_equal(b.faces, F)
    np.testing.assert_allclose(b.vertices, V, atol=1e-6)
    # lists work too; float faces holding integers are accepted
    c = ta.Mesh(V.tolist(), F.astype(np.float64))
    np.testing.assert_array_equal(c.faces, F)


# ---------------------------------------------------------------------------------------------
# bad input: MeshError "<file>: <problem>"
# ---------------------------------------------------------------------------------------------

_TRI = "0 0 0\n1 0 0\n0 1 0\n"
_RNG_BYTES = np.random.default_rng(0).bytes(600)

BAD_FILES = {
    # name: (file name, content or None for "do not create", problem regex)
    "missing": ("absent.off", None, r"not found"),
    "empty": ("empty.off", "", r"empty"),
    "empty_obj": ("empty.obj", "   \n", r"empty"),
    "zero_faces": ("nofaces.off", "OFF\n3 0 0\n" + _TRI, r"empty mesh .*0 faces"),
    "nan": ("nan.off", "OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", r"NaN or infinite"),
    "inf": ("inf.off", "OFF\n3 1 0\n0 0 0\n1 inf 0\n0 1 0\n3 0 1 2\n", r"NaN or infinite"),
    "nan_obj": ("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", r"NaN or infinite"),
    "out_of_range": ("oor.off", "OFF\n3 1 0\n" + _TRI + "3 0 1 3\n", r"index 3 outside 0\.\.2"),
    "negative": ("neg.off", "OFF\n3 1 0\n" + _TRI + "3 0 -1 2\n", r"index -1 outside 0\.\.2"),
    "out_of_range_ply": ("oor.ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                         "property float y\nproperty float z\nelement face 1\n"
                         "property list uchar int vertex_indices\nend_header\n" + _TRI + "3 0 1 5\n",
                         r"index 5 outside"),
    "off_quad": ("quad.off", "OFF\n4 1 0\n" + _TRI + "1 1 0\n4 0 1 3 2\n", r"4 vertices.*triangle"),
    "obj_quad": ("quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n",
                 r"non-triangle"),
    "garbage_off": ("garbage.off", _RNG_BYTES, r"garbage|binary|header"),
    "garbage_ply": ("garbage.ply", _RNG_BYTES, r"cannot parse|no triangles"),
    "garbage_obj": ("garbage.obj", _RNG_BYTES, r"cannot parse|no triangles"),
    "garbage_stl": ("garbage.stl", _RNG_BYTES, r"cannot parse|no triangles"),
    "ply_truncated_body": ("short.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 100\n"
                           b"property float x\nproperty float y\nproperty float z\nelement face 50\n"
                           b"property list uchar int vertex_indices\nend_header\n" + _RNG_BYTES[:200],
                           r"cannot parse"),
    "truncated_off": ("trunc.off", "OFF\n3 2 0\n" + _TRI + "3 0 1 2\n", r"truncated"),
    "bad_vertex_line": ("badv.off", "OFF\n3 1 0\n0 0 0\n1 x 0\n0 1 0\n3 0 1 2\n", r"vertex line"),
    "bad_gzip": ("bad.off.gz", b"this is not gzip data", r"gzip"),
    "unknown_ext": ("mesh.xyz", _TRI, r"unknown mesh format '\.xyz'"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_files_raise_mesh_error(tmp_path, case):
    fname, content, problem = BAD_FILES[case]
    path = tmp_path / fname
    if content is not None:
        _write(path, content)
    with pytest.raises(ta.MeshError) as info:
        ta.load_mesh(path)
    err = info.value
    assert isinstance(err, ta.TorchAKVFError)
    assert err.source == str(path)
    assert str(err).startswith(f"{path}: ")
    assert re.search(problem, err.problem), err.problem


@pytest.mark.parametrize("case", ["non_manifold", "moebius"])
def test_bad_topology_in_file_raises_on_cleaning(tmp_path, case):
    if case == "non_manifold":   # edge (0, 1) shared by 3 faces
        V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
        F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
        problem = r"non-manifold edge .* 3 faces"
    else:
        V, F = _moebius()
        problem = r"not orientable"
    path = _write(tmp_path / f"{case}.off", _off_text(V, F))
    mesh = ta.load_mesh(path)          # parses fine: the topology is checked by the clean-up
    for call in (ta.clean_mesh, lambda m: ta.akvf(m, n=4)):
        with pytest.raises(ta.MeshError) as info:
            call(mesh)
        assert info.value.source == str(path)
        assert re.search(problem, info.value.problem), info.value.problem


def test_untwisted_strip_is_accepted():
    """Control for the Moebius case: the same strip without the twist is an orientable annulus."""
    V, F = _moebius(twisted=False)
    c = ta.clean_mesh(ta.Mesh(V, F, "annulus"))
    assert c.report["boundary_edges"] == 48 and c.report["flipped_faces"] == 0


def test_non_manifold_message_uses_input_vertex_indices():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    with pytest.raises(ta.MeshError) as info:
        ta.clean_mesh(ta.Mesh(V, F, "nm"))
    assert "(0, 1)" in info.value.problem, info.value.problem


@pytest.mark.parametrize("case", ["empty", "nan", "inf", "out_of_range", "negative", "quad",
                                  "bad_shape", "non_numeric", "non_integer"])
def test_bad_arrays_raise_mesh_error(case):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    F = np.array([[0, 1, 2]])
    problem = {
        "empty": r"empty mesh", "nan": r"NaN", "inf": r"NaN or infinite",
        "out_of_range": r"index 3 outside", "negative": r"index -2 outside",
        "quad": r"triangles", "bad_shape": r"\[V, 3\]", "non_numeric": r"not a numeric",
        "non_integer": r"integers"}[case]
    if case == "empty":
        F = np.zeros((0, 3), int)
    elif case == "nan":
        V[1, 2] = np.nan
    elif case == "inf":
        V[2, 0] = -np.inf
    elif case == "out_of_range":
        F = np.array([[0, 1, 3]])
    elif case == "negative":
        F = np.array([[0, -2, 1]])
    elif case == "quad":
        F = np.array([[0, 1, 2, 0]])
    elif case == "bad_shape":
        V = V[:, :2]
    elif case == "non_numeric":
        V = [["a", "b", "c"]] * 3
    elif case == "non_integer":
        F = np.array([[0, 1, 1.5]])
    with pytest.raises(ta.MeshError) as info:
        ta.Mesh(V, F, name="my-array-mesh")
    assert str(info.value).startswith("my-array-mesh: ")
    assert re.search(problem, info.value.problem), info.value.problem


def test_everything_degenerate_raises():
    V = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    with pytest.raises(ta.MeshError, match=r"^flat: .*repeat"):
        ta.clean_mesh(ta.Mesh(V, np.array([[0, 0, 1], [1, 2, 2]]), "flat"))
    with pytest.raises(ta.MeshError, match=r"^line: .*zero area"):
        ta.clean_mesh(ta.Mesh(V, np.array([[0, 1, 2]]), "line"))


# ---------------------------------------------------------------------------------------------
# cleaning
# ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def ico3():
    s = shapes.icosphere(3)
    return s.vertices, s.faces


@pytest.fixture(scope="module")
def ico3_eigs(ico3):
    return _akvf_eigs(ta.Mesh(*ico3))


def test_clean_mesh_is_identity_on_a_good_mesh(ico3):
    V, F = ico3
    c = ta.clean_mesh(ta.Mesh(V, F))
    assert c.report == {"merged_vertices": 0, "repeated_index_faces": 0, "zero_area_faces": 0,
                        "repeated_faces": 0, "unreferenced_vertices": 0, "flipped_faces": 0,
                        "components": 1, "boundary_edges": 0}
    np.testing.assert_array_equal(c.face_index, np.arange(len(F)))
    assert c.n_input_faces == len(F) and c.n_components == 1
    # same triangles (vertices may be renumbered)
    np.testing.assert_array_equal(c.vertices[c.faces], V[F])


def test_triangle_soup_merges_to_the_indexed_spectrum(ico3, ico3_eigs):
    V, F = ico3
    soup = ta.Mesh(V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3), "soup")
    c = ta.clean_mesh(soup)
    assert c.report["merged_vertices"] == 3 * len(F) - len(V)
    assert len(c.vertices) == len(V) and len(c.faces) == len(F)
    np.testing.assert_allclose(_akvf_eigs(soup), ico3_eigs, rtol=1e-9, atol=1e-10)


def test_unreferenced_vertices_removed(ico3, ico3_eigs):
    V, F = ico3
    extra = np.array([[5.0, 5.0, 5.0], [-3.0, 1.0, 2.0], [0.1, 0.2, 0.3]])
    # put two of the extra vertices first so every face index moves
    V2 = np.vstack([extra[:2], V, extra[2:]])
    mesh = ta.Mesh(V2, F + 2)
    c = ta.clean_mesh(mesh)
    assert c.report["unreferenced_vertices"] == 3
    assert len(c.vertices) == len(V)
    # The kept vertices (in the merge's lexicographic order), the faces renumbered onto them.
    np.testing.assert_array_equal(c.vertices, np.unique(V, axis=0))
    np.testing.assert_array_equal(c.vertices[c.faces], V[F])
    np.testing.assert_allclose(_akvf_eigs(mesh), ico3_eigs, rtol=1e-9, atol=1e-10)


def test_renumbering_and_orientation_with_unreferenced_vertices_scattered(ico3):
    # Unreferenced vertices among the used ones and flipped faces: the clean mesh's vertices are
    # the referenced ones (in the duplicate merge's order), every edge's two faces traverse it
    # in opposite directions, and each face is its input face up to the flip.
    V, F = ico3
    rng = np.random.default_rng(7)
    order = rng.permutation(len(V) + 9)
    V2 = np.vstack([V, rng.random((9, 3)) + 3.0])[np.argsort(order)]
    F2 = order[F]
    F2[::3] = F2[::3, ::-1]
    c = ta.clean_mesh(ta.Mesh(V2, F2))
    # The vertices the faces use, in the duplicate merge's (lexicographic) order.
    np.testing.assert_array_equal(c.vertices, np.unique(V2[np.unique(F2)], axis=0))
    assert c.report["unreferenced_vertices"] == 9
    input_id = {tuple(v): i for i, v in enumerate(V2.tolist())}
    ids = np.array([input_id[tuple(v)] for v in c.vertices.tolist()])[c.faces]
    np.testing.assert_array_equal(c.face_index, np.arange(len(F2)))
    np.testing.assert_array_equal(np.sort(ids, axis=1), np.sort(F2, axis=1))
    assert c.report["flipped_faces"] in (len(F2[::3]), len(F2) - len(F2[::3]))
    half = np.stack([c.faces, c.faces[:, [1, 2, 0]]], axis=2).reshape(-1, 2)
    assert len({tuple(h) for h in half.tolist()}) == len(half)      # no half-edge twice


def test_degenerate_faces_dropped_outputs_sized_to_input(ico3):
    V, F = ico3
    nv = len(V)
    a, b = F[100, 0], F[100, 1]
    mid = 0.5 * (V[a] + V[b])                          # collinear with the edge a-b
    V2 = np.vstack([V, mid])
    bad = np.array([[a, a, b],                         # repeated index
                    [a, nv, b],                        # zero area
                    [F[5, 0], F[5, 1], F[5, 1]],       # repeated index elsewhere
                    F[200]])                           # the same face twice
    insert_at = np.array([10, 11, 600, 900])
    F2 = F.copy()
    for pos, face in zip(insert_at, bad):
        F2 = np.insert(F2, pos, face, axis=0)
    np.testing.assert_array_equal(F2[insert_at], bad)
    mesh = ta.Mesh(V2, F2, "dirty")
    c = ta.clean_mesh(mesh)
    assert c.report["repeated_index_faces"] == 2
    assert c.report["zero_area_faces"] == 1
    assert c.report["repeated_faces"] == 1
    assert c.report["unreferenced_vertices"] == 1      # the midpoint, only used by the dropped face
    assert c.n_input_faces == len(F2) and len(c.faces) == len(F)
    kept = np.setdiff1d(np.arange(len(F2)), insert_at)
    np.testing.assert_array_equal(c.face_index, kept)

    res = ta.akvf(mesh, n=6)
    clean_res = ta.akvf(ta.Mesh(V, F), n=6)
    np.testing.assert_allclose(res.eigenvalues.numpy(), clean_res.eigenvalues.numpy(),
                               rtol=1e-9, atol=1e-10)
    fv = res.mesh_face_vectors(0)
    assert fv.shape == (len(F2), 6, 3)
    assert np.all(fv[insert_at] == 0)
    assert np.all(np.linalg.norm(fv[kept], axis=-1) > 0)
    # per-face norms land on the right input faces: compare |X| summed over a cluster (basis-free)
    ref_fv = clean_res.mesh_face_vectors(0)
    np.testing.assert_allclose((fv[kept, 3:6] ** 2).sum(axis=(1, 2)),
                               (ref_fv[:, 3:6] ** 2).sum(axis=(1, 2)), rtol=1e-6, atol=1e-10)

    # labels: the kept faces of the cleaned mesh get labels by the sign of their centroid's z;
    # every dropped face lies where all faces around it carry one label, and takes it.
    cz = c.vertices[c.faces].mean(axis=1)[:, 2]
    labels = (cz > 0).astype(np.int64)
    out = c.labels_to_input_faces(labels)
    assert out.shape == (len(F2),)
    np.testing.assert_array_equal(out[kept], labels)
    for f in insert_at:
        touching = np.isin(F2[kept], F2[f]).any(axis=1)
        neighbour_labels = out[kept][touching]
        assert len(neighbour_labels) > 0
        assert out[f] == np.bincount(neighbour_labels).argmax()
    # to_input_faces fills dropped faces
    filled = c.to_input_faces(np.arange(len(c.faces)) + 1, fill=-7)
    assert np.all(filled[insert_at] == -7)
    np.testing.assert_array_equal(filled[kept], np.arange(len(c.faces)) + 1)


def test_labels_of_dropped_face_follow_its_neighbours():
    """A dropped sliver between two label regions takes the majority label of the faces touching it."""
    s = shapes.flat_disk()
    V, F = s.vertices, s.faces
    # a zero-area face on an interior edge: (a, midpoint, b)
    a, b = F[50, 0], F[50, 1]
    V2 = np.vstack([V, 0.5 * (V[a] + V[b])])
    F2 = np.vstack([F, [[a, len(V), b]]])
    c = ta.clean_mesh(ta.Mesh(V2, F2))
    assert c.report["zero_area_faces"] == 1
    np.testing.assert_array_equal(c.face_index, np.arange(len(F)))   # cleaned face i = input face i
    labels = np.zeros(len(c.faces), dtype=np.int64)
    touch_a = np.isin(F, a).any(axis=1)
    touch_b_only = np.isin(F, b).any(axis=1) & ~touch_a
    labels[touch_a] = 5
    labels[touch_b_only] = 3
    assert touch_a.sum() > touch_b_only.sum()          # label 5 is the majority around the sliver
    out = c.labels_to_input_faces(labels)
    np.testing.assert_array_equal(out[:-1], labels)
    assert out[-1] == 5, (out[-1], touch_a.sum(), touch_b_only.sum())


def test_inconsistent_orientation_repaired(ico3, ico3_eigs):
    V, F = ico3
    F2 = F.copy()
    flip = np.zeros(len(F), bool)
    flip[1::2] = True                                   # half the faces, face 0 kept
    F2[flip] = F2[flip][:, ::-1]
    mesh = ta.Mesh(V, F2, "flipped")
    c = ta.clean_mesh(mesh)
    assert c.report["flipped_faces"] == int(flip.sum())
    # the cleaned faces are the original (outward) ones again
    np.testing.assert_array_equal(c.vertices[c.faces], V[F])
    np.testing.assert_allclose(_akvf_eigs(mesh), ico3_eigs, rtol=1e-9, atol=1e-10)

    # flipping face 0 too: the whole mesh comes out inward, which must not change the spectrum
    F3 = F.copy()
    F3[0::2] = F3[0::2][:, ::-1]
    c3 = ta.clean_mesh(ta.Mesh(V, F3))
    assert c3.report["flipped_faces"] == len(F) // 2
    np.testing.assert_array_equal(c3.vertices[c3.faces], V[F][:, ::-1])
    np.testing.assert_allclose(_akvf_eigs(ta.Mesh(V, F3)), ico3_eigs, rtol=1e-9, atol=1e-10)


def test_two_components_union_spectrum():
    """Two disjoint spheres of different radii and meshes: the spectrum is the union of the
    components' spectra, each rescaled from its own area to the total area."""
    s1 = shapes.icosphere(3, radius=1.0)
    s2 = shapes.icosphere(2, radius=2.0)
    V = np.vstack([s1.vertices, s2.vertices + [5.0, 0.0, 0.0]])
    F = np.vstack([s1.faces, s2.faces + len(s1.vertices)])
    mesh = ta.Mesh(V, F, "two spheres")
    c = ta.clean_mesh(mesh)
    assert c.report["components"] == 2 and c.n_components == 2
    comp_faces = np.bincount(c.face_component)
    assert sorted(comp_faces.tolist()) == sorted([len(s1.faces), len(s2.faces)])

    def area(v, f):
        p = v[f]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()

    a1, a2 = area(s1.vertices, s1.faces), area(s2.vertices, s2.faces)
    n = 16
    mu1 = ta.akvf(ta.Mesh(s1.vertices, s1.faces), n=n, remedy="none").eigenvalues[0].numpy()
    mu2 = ta.akvf(ta.Mesh(s2.vertices, s2.faces), n=n, remedy="none").eigenvalues[0].numpy()
    # lambda_phys = mu_c / A_c; reported lambda_phys * A_total
    union = np.sort(np.r_[mu1 * (a1 + a2) / a1, mu2 * (a1 + a2) / a2])[:n]
    both = ta.akvf(mesh, n=n, remedy="none").eigenvalues[0].numpy()
    np.testing.assert_allclose(both, union, rtol=1e-6)
    # both components contribute their 3 rotations: 6 small eigenvalues, then a gap
    assert np.all(both[:6] < 0.1) and both[6] > 5


# ---------------------------------------------------------------------------------------------
# one OFF reader, one .seg writer (issue 10)
# ---------------------------------------------------------------------------------------------

def test_psb_read_off_is_load_mesh(tmp_path):
    from torchakvf.evaluate.psb import read_off

    s = shapes.dumbbell(n_around=10)
    text = "OFF\n# a comment\n" + f"{len(s.vertices)} {len(s.faces)} 0\n"
    text += "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in s.vertices.tolist())
    text += "".join(f"3 {a} {b} {c}\n" for a, b, c in s.faces.tolist())
    (tmp_path / "m.off.gz").write_bytes(gzip.compress(text.encode()))
    v, f = read_off(tmp_path / "m.off.gz")
    mesh = ta.load_mesh(tmp_path / "m.off.gz")
    np.testing.assert_array_equal(v, mesh.vertices)
    np.testing.assert_array_equal(f, mesh.faces)
    np.testing.assert_array_equal(v, s.vertices)
    assert ta.io.peek_face_count(tmp_path / "m.off.gz") == len(s.faces)
    (tmp_path / "q.off").write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n4 0 1 2 3\n")
    for reader in (read_off, ta.load_mesh):   # the same strict parser: no silent split
        with pytest.raises(ta.errors.MeshError, match="face 0 has 4 vertices"):
            reader(tmp_path / "q.off")


def test_write_seg_is_checked(tmp_path):
    for bad, problem in [(np.array([0.5, 1.0]), "must be integers"), (np.array([True]), "must be integers"),
                         (np.zeros((2, 2), int), "1-D"), (np.array([], int), "non-empty")]:
        with pytest.raises(ta.errors.ParameterError, match=problem) as info:
            ta.io.write_seg(tmp_path / "x.seg", bad)
        assert "x.seg" in str(info.value)
    assert not (tmp_path / "x.seg").exists()
    a = ta.io.write_seg(tmp_path / "a.seg.gz", np.array([3, 1, 2]))
    b = ta.io.write_seg(tmp_path / "b.seg.gz", np.array([3, 1, 2], dtype=np.int32))
    assert a.read_bytes() == b.read_bytes() and gzip.decompress(a.read_bytes()) == b"3\n1\n2\n"


def test_write_seg_is_atomic(tmp_path, monkeypatch):
    path = ta.io.write_seg(tmp_path / "x.seg", np.array([0, 1, 1]))

    def fail(src, dst):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(ta.io.outputs.os, "replace", fail)
    with pytest.raises(ta.errors.TorchAKVFError, match="x.seg: cannot write output"):
        ta.io.write_seg(path, np.array([2, 2, 2]))
    assert path.read_text() == "0\n1\n1\n"                       # the old file, whole
    assert not list(tmp_path.glob(f".*{ta.io.TEMP_SUFFIX}"))     # no temp file left


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


@pytest.mark.parametrize("text", [
    "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    "OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
    "off\r\n3 1 0\r\n\r\n0.5e1 -0 .25\r\n1 0 0 255 0 0\r\n0 1 0\r\n\t3 0 1 2 7 7 7\r\n",   # extras, CRLF
    "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 2 1 0\n",   # a line past the counts
])
def test_vectorized_off_reader_equals_the_line_reader(text):
    from torchakvf.io.off import _parse_off_by_lines, _parse_plain_off, parse_off
    raw = text.encode()
    fast = _parse_plain_off(raw)
    assert fast is not None                                   # taken by the fast reader
    ref = _parse_off_by_lines(raw, "x.off")
    for a, b in zip(fast, ref):
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert all(np.array_equal(a, b) for a, b in zip(parse_off(raw, "x.off"), ref))


@pytest.mark.parametrize("body, by_text_reader", [
    ("0.1 -2.5e-3 7\n1e-320 .5 -0\n3.14159265358979323846264 1E+2 +4\n3 0 1 2\n", True),
    ("0.1 -2.5e-3 7\n\n1 0 0\n0 1 0\n\n3 +0 1 2\n", True),          # blank lines, a signed index
    ("1 0 0\n0 1 0\n0 0 1\n3 0 1 2", True),                             # no newline at the end
    ("nan 0 0\n1 0 0\n0 1 inf\n3 0 1 2\n", False),                    # read as Python's float does
    ("1_0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", False),
    ("1 0 0\n1 0 0\n0 1 0\n3 0 1_0 2\n", False),
])
def test_off_text_reader_equals_the_line_reader_bitwise(body, by_text_reader, monkeypatch):
    """The usual file goes to numpy's text reader (:func:`_read_sections`), whose numbers are
    Python's float/int bit for bit (correctly rounded, subnormals too); bytes it is not given
    (nan, underscores) go the token way, with the same values as the line reader."""
    from torchakvf.io import off
    raw = ("OFF\n3 1 0\n" + body).encode()
    taken, real = [], off._read_sections
    monkeypatch.setattr(off, "_read_sections", lambda *a: taken.append(real(*a)) or taken[-1])
    fast = off.parse_off(raw, "x.off")
    assert (len(taken) == 1 and taken[0] is not None) == by_text_reader
    ref = off._parse_off_by_lines(raw, "x.off")
    for a, b in zip(fast, ref):
        assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_off_text_reader_on_random_digits_equals_python_float():
    from torchakvf.io.off import parse_off
    rng = np.random.default_rng(5)
    x = rng.normal(size=(200, 3)) * 10.0 ** rng.integers(-30, 30, size=(200, 3))
    text = "".join(" ".join(repr(float(t)) if i % 3 else f"{t:.25g}" for i, t in enumerate(row)) + "\n"
                   for row in x)
    raw = f"OFF\n200 1 0\n{text}3 0 1 2\n".encode()
    expect = np.array([[float(t) for t in line.split()] for line in text.splitlines()])
    assert parse_off(raw, "x.off")[0].tobytes() == expect.tobytes()


@pytest.mark.parametrize("text, problem", [
    ("OFF\n3 1 0\n0 0 0\n1 0\n0 1 0\n3 0 1 2\n", "vertex line"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2 0\n", "only triangle"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n", "fewer than 3"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2.5\n", "non-integer"),
    ("OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "truncated"),
    ("# c\nOFF\n3 1 0\n0 0 0\n1 0 0\n0 x 0\n3 0 1 2\n", "3 numbers"),
])
def test_off_files_the_fast_reader_declines_get_the_line_readers_error(text, problem):
    from torchakvf.io.off import _parse_plain_off, parse_off
    assert _parse_plain_off(text.encode()) is None
    with pytest.raises(ta.MeshError, match=problem):
        parse_off(text.encode(), "x.off")


def test_vectorized_off_reader_on_psb_files_equals_the_line_reader():
    import os
    from pathlib import Path
    from torchakvf.io.off import _parse_off_by_lines, _parse_plain_off
    root = Path(os.environ.get("TORCHAKVF_PSB", Path(__file__).parents[2] / "shared" / "psb"))
    if not (root / "meshes").is_dir():
        pytest.skip(f"PSB not found at {root} (set TORCHAKVF_PSB)")
    for i in (1, 21, 121, 351):
        raw = gzip.decompress((root / "meshes" / f"{i}.off.gz").read_bytes())
        fast, ref = _parse_plain_off(raw), _parse_off_by_lines(raw, str(i))
        assert fast is not None and all(np.array_equal(a, b) for a, b in zip(fast, ref))


def _sphere_with_a_needle():
    """icosphere(2) with one edge (A, C) split at its midpoint B on one side only, and the
    needle face (A, C, B) of zero area closing the other side (as on PSB 351)."""
    s = shapes.icosphere(2)
    v, f = s.vertices.copy(), s.faces.copy()
    a, c = int(f[0, 0]), int(f[0, 1])
    x = int(f[0, 2])
    b = len(v)
    v = np.concatenate([v, (v[a] + v[c])[None] / 2])
    f = np.concatenate([f[1:], [[a, b, x], [b, c, x], [a, c, b]]])
    return s, ta.Mesh(v, f, name="needle")


def test_zip_cracks_closes_the_hole_a_needle_face_leaves():
    s, mesh = _sphere_with_a_needle()
    plain = ta.clean_mesh(mesh, zip_cracks=False)
    assert plain.report["zero_area_faces"] == 1 and plain.report["boundary_edges"] == 3   # a crack
    zipped = ta.clean_mesh(mesh)                           # the default zips
    assert zipped.report["zipped_cracks"] == 1 and zipped.report["boundary_edges"] == 0
    assert len(zipped.faces) == len(s.faces) + 2           # the face across the crack is split
    area = ta.mesh.face_areas(zipped.vertices, zipped.faces).sum()
    assert np.isclose(area, ta.mesh.face_areas(s.vertices, s.faces).sum())
    # Every kept face maps to an input face; both halves of the split face to the same one.
    assert np.bincount(zipped.face_index).max() == 2
    # A closed sphere again: its three rotations are Killing fields (λ·area near 0).
    lam = ta.akvf(zipped, n=4).eigenvalues[0].numpy()
    ref = ta.akvf(ta.Mesh(s.vertices, s.faces), n=4).eigenvalues[0].numpy()
    assert np.all(np.abs(lam[:3]) < 0.5) and lam[3] > 5 and np.allclose(lam, ref, rtol=0.2, atol=0.3)
    # Without zipping, the crack's boundary terms cost a rotation (2.36 against 0.12, measured).
    assert ta.akvf(plain, n=4).eigenvalues[0, 2] > 1.0
