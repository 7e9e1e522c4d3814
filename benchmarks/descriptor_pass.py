"""One pass over the PSB meshes computing, per mesh, everything the learning benchmarks
(``learn_boundaries.py``, ``classify_descriptors.py``) need, cached as one .npz per mesh.

Per mesh, on the batch the descriptors solve on (:func:`torchakvf.parts.input_descriptors.pack_for_descriptors`:
4000 faces, decimated in the surface's canonical frame; a mesh whose decimated solve fails is
solved at full resolution, as segmentation does), with the fields' canonical signs and the
descriptors' own untangling seed, as :func:`torchakvf.interop.face_features` computes them:

* ``akvf`` [F, 33]: :func:`torchakvf.fields.descriptors.face_descriptors` at 8, 16 and 32
  fields (``akvf_names``); ``akvf_parts`` [F, 8]:
  :func:`torchakvf.parts.part_descriptors.part_descriptors` (``akvf_parts_names``), cut on the
  full-resolution mesh, each decimated face given the value of the fine face under its
  barycenter; a labelled mesh is segmented with the merge weights fitted without its category
  (:data:`FOLD_WEIGHTS`); ``phi32`` [F, 32] the raw untangled norms at 32 (for the older
  histogram descriptor), ``eigenvalues`` [32], ``energies32`` [32]; ``cues`` [F, 6]
  (:func:`torchakvf.parts.boundary_cues.crease_cues` of the packed mesh, ``cue_names``) and
  ``akvf_boundary`` [F, 1] (:func:`torchakvf.parts.boundary_probability.boundary_probability`
  of the row's 41 columns and cues: the same function of the same columns as the package's
  ``boundary_probability`` column); ``packed_vertices``, ``packed_faces``: the mesh solved on;
* the classical groups of ``classical_descriptors.py`` and ``shapedna`` [32];
* ``target`` [F]: for meshes with human segmentations, the fraction of the people whose cut
  passes within :data:`BOUNDARY_RADIUS` (geodesic, on the dual graph, unit-area lengths) of the
  face; the human labels are carried to the decimated faces through the fine face closest to
  each decimated face's barycenter;
* ``area`` [F] (unit total), ``trivial`` [5], ``seconds_akvf`` (with the part descriptors'
  ``seconds_parts``) / ``seconds_classical`` (wall), ``cpu_seconds`` [3] (this process's CPU
  time: field descriptors with the solve, part descriptors with the cues and probability,
  classical).

Cache version 8: the descriptors' decimation collapses every mesh at one size
(:data:`torchakvf.mesh.coarse.FRAME_SIZE`), so a copy in another unit of length gets the same
columns. Version 7 collapsed each mesh at its own size and started the untangling in the
fields' moment frame; version 6 started it from the raw eigenbasis and added the cues, the
probability and the packed mesh to version 5.

Meshes with human segmentations are visited first, category-interleaved (1st mesh of every
category, then the 2nd, ...), so a pass stopped early covers every category about equally. Run::

    PYTHONPATH=$PWD nice -n 5 python benchmarks/descriptor_pass.py --cache DIR
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import sys
import time
from pathlib import Path

import classical_descriptors as classical
import numpy as np
import scipy.sparse as sp

COARSE_FACES = 4000
N_FIELDS = 32
SEED = 0
#: Geodesic radius (lengths at unit area) within which a face counts as on a person's cut:
#: about one and a half face rings of a mesh decimated to 4000 faces.
BOUNDARY_RADIUS = 0.02
CACHE_VERSION = "8"

#: Per labelled category, the learned merge weights fitted without it: the part descriptors of
#: a labelled mesh are cut with them, so no held-out category's labels shape its own columns.
FOLD_WEIGHTS = Path(__file__).resolve().parents[1] / "experiments" / "results" / "merge_weights_folds.json"

log = logging.getLogger("descriptor_pass")


def boundary_target(graph: sp.csr_matrix, labelings: list[np.ndarray]) -> np.ndarray:
    """[F] fraction of the labelings with a cut within BOUNDARY_RADIUS of each face (``graph``:
    :func:`torchakvf.parts.part_descriptors.dual_graph`)."""
    from torchakvf.parts.part_descriptors import cut_distance

    near = np.zeros(graph.shape[0])
    for lab in labelings:
        near += cut_distance(graph, lab, cap=2 * BOUNDARY_RADIUS) <= BOUNDARY_RADIUS
    return near / max(len(labelings), 1)


def packed_input_faces(batch) -> np.ndarray:
    """[F_packed] the input (file) face under each packed face of mesh 0: itself at full
    resolution, else the fine face closest to the decimated face's barycenter."""
    from torchakvf.mesh.coarse import locate_on_surface

    packed = batch.meshes[0]
    coarse = batch.coarse_of(0)
    if coarse is None:
        return np.asarray(packed.face_index)
    fine = coarse.fine
    at = locate_on_surface(fine.vertices, fine.faces, packed.vertices[packed.faces].mean(axis=1))
    return np.asarray(fine.face_index[at.face])


def labels_on_packed(batch, entry) -> list[np.ndarray]:
    """Every human segmentation of ``entry`` carried to the packed (decimated) faces."""
    from torchakvf.evaluate.psb import read_seg

    input_face = packed_input_faces(batch)
    return [read_seg(p)[input_face] for p in entry.seg_paths]


def trivial(mesh) -> np.ndarray:
    """log F, log V, principal extent ratios s2/s1, s3/s1, number of components (input mesh)."""
    from scipy.sparse.csgraph import connected_components

    v, f = np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
    s = np.linalg.svd(v - v.mean(0), compute_uv=False)
    nv = len(v)
    adj = sp.coo_matrix((np.ones(f.size), (f.ravel(), np.roll(f, 1, axis=1).ravel())), shape=(nv, nv))
    return np.array([np.log(len(f)), np.log(nv), s[1] / s[0], s[2] / s[0],
                     connected_components(adj, directed=False)[0]], dtype=np.float64)


def segment_options_for(entry):
    """The default segmentation, with the merge weights of ``entry``'s held-out fold
    (:data:`FOLD_WEIGHTS`) when its category is labelled (categories never trained on: the
    shipped weights)."""
    from torchakvf import SegmentOptions
    from torchakvf.options import MergeWeights

    folds = json.loads(FOLD_WEIGHTS.read_text())["folds"]
    if entry.category in folds:
        return SegmentOptions(merge=MergeWeights(**folds[entry.category]))
    return SegmentOptions()


def one_mesh(entry) -> dict:
    """Everything of the module docstring for one PSB entry."""
    from torchakvf import load_mesh
    from torchakvf.fields import untangle
    from torchakvf.fields.akvf import akvf_falling_back
    from torchakvf.fields.canonical import canonical_signs
    from torchakvf.fields.descriptors import DEFAULT_COUNTS, DESCRIPTOR_SEED, descriptor_names, face_descriptors
    from torchakvf.mesh import clean_mesh
    from torchakvf.operators.killing import DEFAULT_REMEDY
    from torchakvf.parts.boundary_cues import CUE_NAMES, crease_cues
    from torchakvf.parts.boundary_probability import boundary_probability
    from torchakvf.parts.input_descriptors import pack_for_descriptors, solve_descriptor_batch
    from torchakvf.parts.part_descriptors import dual_graph, part_descriptor_names, part_descriptors

    mesh = load_mesh(entry.mesh_path)
    t0, c0 = time.perf_counter(), time.process_time()
    # the descriptors' own batch: decimated in the surface's canonical frame, as face_features does
    batch = pack_for_descriptors([clean_mesh(mesh)], COARSE_FACES)
    fields, fell_back = solve_descriptor_batch(
        batch, lambda mb: akvf_falling_back(mb, n=N_FIELDS, seed=SEED, remedy=DEFAULT_REMEDY))
    fields = canonical_signs(fields)
    unt = {n: untangle(fields, n, seed=DESCRIPTOR_SEED) for n in DEFAULT_COUNTS}
    desc = face_descriptors(fields, DEFAULT_COUNTS, untangled=unt)[0].numpy()
    t_parts, c_parts = time.perf_counter(), time.process_time()
    # cut on the full-resolution mesh; each decimated face takes the value of the fine face under it
    parts = fields.batch.input_mesh(0).to_input_faces(part_descriptors(fields, options=segment_options_for(entry))[0])
    parts = parts[packed_input_faces(fields.batch)]
    packed = fields.batch.meshes[0]
    v, f = np.asarray(packed.vertices, dtype=np.float64), np.asarray(packed.faces, dtype=np.int64)
    cues = crease_cues(v, f)
    boundary = boundary_probability(np.concatenate([desc.astype(np.float64), parts], axis=1), cues)
    t1, c1 = time.perf_counter(), time.process_time()
    out = classical.classical_descriptors(v, f)
    t2, c2 = time.perf_counter(), time.process_time()
    _, area = classical.unit_area(v, f)
    out.update(akvf=desc.astype(np.float32), akvf_names=np.array(descriptor_names()),
               akvf_parts=parts.astype(np.float32), akvf_parts_names=np.array(part_descriptor_names()),
               akvf_boundary=boundary[:, None].astype(np.float32), cues=cues.astype(np.float32),
               cue_names=np.array(CUE_NAMES),
               seconds_parts=np.float64(t1 - t_parts),
               phi32=unt[N_FIELDS].mesh_features(0).numpy().astype(np.float32),
               eigenvalues=fields.eigenvalues[0].numpy(), energies32=unt[N_FIELDS].energies[0].numpy(),
               area=area, packed_vertices=v, packed_faces=f.astype(np.int32), trivial=trivial(mesh),
               fell_back=np.bool_(bool(fell_back)),
               seconds_akvf=np.float64(t1 - t0), seconds_classical=np.float64(t2 - t1),
               cpu_seconds=np.array([c_parts - c0, c1 - c_parts, c2 - c1]))
    if entry.seg_paths:
        out["target"] = boundary_target(dual_graph(v, f), labels_on_packed(fields.batch, entry))
    return out


def cache_path(cache: Path, entry, version: str = CACHE_VERSION) -> Path:
    h = hashlib.sha256(entry.mesh_path.read_bytes())
    h.update(json.dumps({"coarse": COARSE_FACES, "n": N_FIELDS, "seed": SEED, "r": BOUNDARY_RADIUS,
                         "v": version}).encode())
    return cache / f"{entry.mesh_id}_{h.hexdigest()[:16]}.npz"


def ordered_entries(psb: str, reverse: bool = False) -> list:
    """Meshes with human segmentations first, then the others; each group category-interleaved
    (``reverse``: each group in the opposite order, for a second worker sharing the cache)."""
    from torchakvf.evaluate.psb import find_psb_meshes

    groups = [[], []]
    for e in sorted(find_psb_meshes(psb), key=lambda e: ((e.mesh_id - 1) % 20, e.mesh_id)):
        groups[0 if e.seg_paths else 1].append(e)
    return [e for g in groups for e in (g[::-1] if reverse else g)]


def load_all(psb: str, cache: Path, compute: bool = True, reverse: bool = False) -> tuple[list[dict], list[int]]:
    """(one dict per mesh with mesh_id and category added, ids that failed or are not cached)."""
    from torchakvf import TorchAKVFError

    cache.mkdir(parents=True, exist_ok=True)
    data, missing = [], []
    for e in ordered_entries(psb, reverse):
        path = cache_path(cache, e)
        if not path.exists() and compute:
            t = time.perf_counter()
            try:
                d = one_mesh(e)
            except (TorchAKVFError, RuntimeError, ValueError) as exc:
                log.warning("mesh %d: %s (left out)", e.mesh_id, exc)
                missing.append(e.mesh_id)
                continue
            tmp = path.with_suffix(".tmp.npz")
            np.savez_compressed(tmp, **d)
            tmp.replace(path)
            log.info("mesh %d (%s): %.1f s (AKVF %.1f, classical %.1f)", e.mesh_id, e.category,
                     time.perf_counter() - t, d["seconds_akvf"], d["seconds_classical"])
        if not path.exists():
            missing.append(e.mesh_id)
            continue
        with np.load(path) as z:
            d = {k: z[k] for k in z.files}
        d["mesh_id"], d["category"] = e.mesh_id, e.category
        data.append(d)
    return data, missing


def cache_parser(description: str) -> argparse.ArgumentParser:
    """The descriptor benchmarks' common command line: --psb, --cache (required), --threads."""
    from torchakvf.evaluate.psb import default_psb_root

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--psb", default=default_psb_root(),
                    help="the PSB folder (default: $TORCHAKVF_PSB)")
    ap.add_argument("--cache", required=True, help="folder of the cached per-mesh descriptors")
    ap.add_argument("--threads", type=int, default=1)
    return ap


def cpu_sample(psb: str) -> None:
    """Print the CPU seconds (this process, one thread) of each stage of :func:`one_mesh` on
    the first mesh of every category, uncached: the per-mesh cost without other jobs' wall
    time in it."""
    from torchakvf.evaluate.psb import find_psb_meshes

    firsts = [e for e in find_psb_meshes(psb) if (e.mesh_id - 1) % 20 == 0]
    cpu = np.array([one_mesh(e)["cpu_seconds"] for e in firsts])
    for e, c in zip(firsts, cpu):
        print(f"mesh {e.mesh_id} ({e.category}): fields {c[0]:.2f} s, parts {c[1]:.2f} s, classical {c[2]:.2f} s")
    print(f"{len(firsts)} meshes, CPU seconds per mesh (mean): fields {cpu[:, 0].mean():.2f}, "
          f"parts {cpu[:, 1].mean():.2f}, classical {cpu[:, 2].mean():.2f}; median "
          f"{np.median(cpu[:, 0]):.2f}, {np.median(cpu[:, 1]):.2f}, {np.median(cpu[:, 2]):.2f}")


def main(argv=None) -> int:
    ap = cache_parser(__doc__.split("\n")[0])
    ap.add_argument("--reverse", action="store_true",
                    help="visit the meshes in the opposite order (a second worker on the same cache)")
    ap.add_argument("--cpu-sample", action="store_true",
                    help="only time the first mesh of each category in CPU seconds (nothing cached)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    import torch

    torch.set_num_threads(args.threads)
    if args.cpu_sample:
        cpu_sample(args.psb)
        return 0
    t = time.perf_counter()
    data, missing = load_all(args.psb, Path(args.cache), reverse=args.reverse)
    log.info("%d meshes in %.0f s; left out: %s", len(data), time.perf_counter() - t, missing)
    return 0


if __name__ == "__main__":
    sys.exit(main())
