"""Per-face descriptors read off the parts: where the segmentation cuts at several part counts.

The field descriptors (:mod:`torchakvf.fields.descriptors`) describe the untangled fields
around a face; these describe what the whole method makes of them. The mesh is segmented with
the package's defaults (untangling, k-means, merge, graph cut; the over-segmentation
:data:`PART_OVERSEGMENTATION`) at each part count k of ``ks``
and each seed of ``seeds``, from one AKVF solve, and each face is described by how close the
cuts come to it. A part's labels have no order, so every column is a function of where the
labels change, never of a label's value: the columns mean the same on every mesh. The seeds
are averaged over, so the columns do not depend on one seed's k-means and untangling; they
vary with another seed list only where the segmentation itself does.

Lengths are measured in the unit-area frame (the mesh scaled to area 1) along the dual graph
(face centroids joined across shared edges), so rigid motions, scale and renumbering do not
change them (a renumbering permutes the rows).

==========================  =====================================================================
column                      meaning, range
==========================  =====================================================================
``cut_distance@k``          mean over the seeds of log(d + :data:`DISTANCE_FLOOR`), d the distance
                            from the face to the nearest face of another part at k parts, capped
                            at :data:`DISTANCE_CAP`; about [-5.3, -1.6] (low: on a cut)
``cut_share_r``             the fraction of all (k, seed) segmentations cutting within r of the
                            face (r in :data:`NEAR_RADII`); [0, 1]
==========================  =====================================================================

The segmentations read the fields with their canonical signs
(:func:`~torchakvf.fields.canonical.canonical_signs`), untangle them from starts in their
moment frame (:data:`~torchakvf.fields.descriptors.DESCRIPTOR_FRAME`) and cut a decimated mesh's
full-resolution mesh numbered from its surface
(:func:`fine_meshes_numbered_canonically`), so another solver start, eigensolver, pose or
numbering gives the same cuts wherever the fields repeat. A scaled copy gets them where its
decimation is the same (the collapse's thresholds are absolute: inside
:data:`~torchakvf.mesh.coarse.DECIMATE_SIZE` a mesh is decimated at its own size).

Cuts are those of the segmentation's own boundary step, which places them on concave creases
(:mod:`torchakvf.parts.graphcut`): unlike the field descriptors, these columns are not purely
intrinsic.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from ..errors import ParameterError
from ..fields.akvf_result import AKVFResult
from ..fields.canonical import canonical_signs
from ..fields.descriptors import DESCRIPTOR_FRAME
from ..mesh.batch import MeshBatch
from ..mesh.clean import face_areas
from ..mesh.coarse import canonical_numbering
from ..mesh.surface_map import SurfacePoints
from ..options import MergeWeights, OverSegmentation, SegmentOptions, segment_options
from .field_counts import akvf_count
from .topology import face_adjacency

#: Part counts the mesh is segmented at: from two parts (the main cut) to the eight people
#: rarely exceed on whole objects.
PART_KS = (2, 3, 4, 5, 6, 8)
#: Seeds averaged over (the k-means' and the untangling's).
PART_SEEDS = (0, 1, 2)
#: The over-segmentation the segmentations merge from: the one the columns' usefulness,
#: stability and cost were measured with (docs/descriptors.md), fixed here so that the columns
#: a model was trained on do not move when the segmentation's own default is chosen again (a
#: finer one would make the 18 segmentations cost more; neither its columns nor those with the
#: crease patches' fragments united were measured).
PART_OVERSEGMENTATION = OverSegmentation(ratio=3.0, extra_max=16, unite_fragments=False)
#: The segmentations' options: that over-segmentation, and the first merge's parts alone (no
#: :class:`~torchakvf.options.ConcaveChoice`) without the sheet rule
#: (``MergeWeights.sheet_flatness``), as the columns were measured with.
PART_OPTIONS = SegmentOptions(overseg=PART_OVERSEGMENTATION, merge_choice=None,
                              merge=MergeWeights(sheet_flatness=None))
#: Distance (unit-area lengths) beyond which a cut is "far": about ten face widths at 4000 faces.
DISTANCE_CAP = 0.2
#: Added to a distance before the log, so a face on a cut (d = 0) has a finite value.
DISTANCE_FLOOR = 0.005
#: Radii (unit-area lengths) of the ``cut_share`` columns: about 1.5 and 4 face rings at 4000
#: faces.
NEAR_RADII = (0.02, 0.06)


def part_descriptor_names(ks: Sequence[int] = PART_KS, radii: Sequence[float] = NEAR_RADII) -> list[str]:
    """Column names of :func:`part_descriptors`' output, in order: ``cut_distance@k`` for each
    k (ascending), then ``cut_share_r`` for each radius."""
    return [f"cut_distance@{k}" for k in sorted({int(k) for k in ks})] + [f"cut_share_{r:g}" for r in radii]


def dual_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """[F, F] faces joined across shared edges, weighted by the distance between their
    centroids in the unit-area frame."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    scale = 1.0 / np.sqrt(max(face_areas(v, f).sum(), 1e-300))
    pairs = face_adjacency(f)
    c = v[f].mean(axis=1) * scale
    # a zero weight would read as no edge: two faces on one centroid are a tiny step apart
    w = np.maximum(np.linalg.norm(c[pairs[:, 0]] - c[pairs[:, 1]], axis=1), 1e-12)
    nf = len(f)
    return sp.coo_matrix((np.concatenate([w, w]), (np.concatenate([pairs[:, 0], pairs[:, 1]]),
                                                   np.concatenate([pairs[:, 1], pairs[:, 0]]))),
                         shape=(nf, nf)).tocsr()


def cut_distance(graph: sp.csr_matrix, labels: np.ndarray, cap: float = DISTANCE_CAP) -> np.ndarray:
    """[F] distance along ``graph`` from each face to the nearest face with a neighbour of
    another label (0 on such faces), capped at ``cap``; ``cap`` everywhere when there is one
    label."""
    coo = graph.tocoo()
    lab = np.asarray(labels)
    differ = lab[coo.row] != lab[coo.col]
    return distance_to_faces(graph, np.unique(coo.row[differ]), cap)


def distance_to_faces(graph: sp.csr_matrix, sources: np.ndarray, cap: float = DISTANCE_CAP) -> np.ndarray:
    """[F] distance along ``graph`` from each face to the nearest of the faces ``sources`` (0 on
    them), capped at ``cap``; ``cap`` everywhere when there is none."""
    if len(sources) == 0:
        return np.full(graph.shape[0], float(cap))
    d = dijkstra(graph, directed=False, indices=sources, min_only=True, limit=cap)
    return np.minimum(d, cap)


def describe_labelings(vertices: np.ndarray, faces: np.ndarray, labelings: Sequence[Sequence[np.ndarray]],
                       radii: Sequence[float] = NEAR_RADII) -> np.ndarray:
    """[F, K + len(radii)] the columns of the module docstring from labelings[s][j], the
    labels [F] of seed s at the j-th of K part counts, on one mesh (vertices [V, 3], faces
    [F, 3])."""
    if not labelings or not labelings[0]:
        raise ParameterError("part descriptors need at least one seed and one part count")
    graph = dual_graph(vertices, faces)
    dist = np.stack([np.stack([cut_distance(graph, lab) for lab in per_k], axis=1)
                     for per_k in labelings])                        # [S, F, K]
    share = [(dist <= r).mean(axis=(0, 2)) for r in radii]
    return np.concatenate([np.log(dist + DISTANCE_FLOOR).mean(axis=0),
                           np.stack(share, axis=1) if share else np.zeros((dist.shape[1], 0))], axis=1)


def fine_meshes_numbered_canonically(batch: MeshBatch) -> MeshBatch:
    """``batch`` with the full-resolution mesh of each decimated mesh numbered and placed by
    :func:`~torchakvf.mesh.coarse.canonical_numbering` (vertices and faces, in the principal
    frame at its one size, rounded to its grid; the packed meshes, and so the fields, are
    untouched). The cut's tie-breaks follow the numbering of the mesh it cuts and
    round-off of its coordinates: numbered and placed from the surface, a moved or renumbered
    copy of a mesh, in any unit of length, is cut where the mesh is (the cut reads lengths in
    the unit-area frame and casts its rays at any unit). Results on the input's faces
    (through ``face_index``) mean the same either way."""
    coarse = []
    for b in range(len(batch)):
        c = batch.coarse_of(b)
        if c is not None:
            order, faces, face_order, frame = canonical_numbering(c.fine.vertices, c.fine.faces)
            fine = dataclasses.replace(c.fine, vertices=frame, faces=faces,
                                       face_index=c.fine.face_index[face_order],
                                       face_component=c.fine.face_component[face_order])
            at = lambda p, rows: SurfacePoints(p.face[rows], p.bary[rows], p.distance[rows])  # noqa: E731
            c = dataclasses.replace(c, fine=fine, vertices_on_coarse=at(c.vertices_on_coarse, order),
                                    faces_on_coarse=at(c.faces_on_coarse, face_order))
        coarse.append(c)
    return dataclasses.replace(batch, coarse=coarse) if batch.coarse else batch


def part_descriptors(fields: AKVFResult, ks: Sequence[int] = PART_KS, seeds: Sequence[int] = PART_SEEDS,
                     options: SegmentOptions | None = None, radii: Sequence[float] = NEAR_RADII
                     ) -> list[np.ndarray]:
    """Per-face part descriptors of every mesh of a batch (module docstring).

    fields : the batch's AKVFs (from :func:`~torchakvf.akvf`): the segmentations untangle as
        many as :func:`~torchakvf.segment` does when ``fields.n`` covers
        :func:`~torchakvf.parts.field_counts.akvf_count` of ``ks``, else all ``fields.n``
    ks : part counts (columns in ascending k; a mesh with fewer faces is cut at its face count
        there); seeds : seeds averaged over; options : the segmentation's settings (default
        :data:`PART_OPTIONS`; its seed is replaced by each of
        ``seeds``; ε must be 0)
    Returns one float64 [F_b, len(ks) + len(radii)] array per mesh, on the faces the parts
    are cut on: those of ``fields.batch.input_mesh(b)`` (the full-resolution cleaned mesh of a
    decimated one; ``input_mesh(b).to_input_faces`` puts them on the file's faces).
    """
    from .cut import MeshCache
    from .rounds import segment_rounds

    opts = segment_options(options) if options is not None else PART_OPTIONS
    if opts.eps != 0:
        raise ParameterError("part descriptors describe plain segmentations: eps must be 0")
    ks = sorted({int(k) for k in ks})
    if not ks or ks[0] < 2 or not seeds:
        raise ParameterError(f"part descriptors need part counts >= 2 and a seed, got ks={list(ks)!r}, "
                             f"seeds={list(seeds)!r}")
    # the segmentations' random starts act on the fields' coefficients: with the signs the
    # surface fixes, each seed starts the same whatever solver, pose or numbering made the fields
    batch = fields.batch              # the columns are on its input meshes' faces
    fields = dataclasses.replace(canonical_signs(fields), batch=fine_meshes_numbered_canonically(batch))
    enough = fields.n >= akvf_count([ks], None, opts.method, opts.overseg.min_k)
    n_fields = None if enough else fields.n
    # a segmentation asks for at most one part per face: a smaller mesh is segmented at its face count
    ks_of = [[min(k, len(batch.meshes[b].faces)) for k in ks] for b in range(len(batch))]
    labels = [[[] for _ in seeds] for _ in range(len(batch))]
    # what the cut makes of each mesh alone (crease patches, thickness, dual edges) is made once
    # for all the seeds: the same arrays each seed's own call would make
    caches = [MeshCache() for _ in range(len(batch))]
    for s, seed in enumerate(seeds):
        each = [{} for _ in range(len(batch))]
        for rnd in segment_rounds(fields, [sorted(set(kb)) for kb in ks_of], segment_options(opts, seed=int(seed)),
                                  n_fields=n_fields, mesh_caches=caches, untangle_frame=DESCRIPTOR_FRAME,
                                  extras=False):
            for b in rnd.active:
                each[b][rnd.ks[b]] = rnd.meshes[b].labels
        for b in range(len(batch)):
            index = batch.input_mesh(b).face_index       # the input face of each cleaned face
            labels[b][s] = [np.asarray(each[b][k])[index] for k in ks_of[b]]
    out = []
    for b in range(len(batch)):
        mesh = batch.input_mesh(b)
        out.append(describe_labelings(mesh.vertices, mesh.faces, labels[b], radii))
    return out


__all__ = ["PART_KS", "PART_SEEDS", "PART_OVERSEGMENTATION", "PART_OPTIONS", "DISTANCE_CAP", "DISTANCE_FLOOR",
           "NEAR_RADII",
           "part_descriptor_names",
           "dual_graph", "cut_distance", "distance_to_faces", "fine_meshes_numbered_canonically", "describe_labelings",
           "part_descriptors"]
