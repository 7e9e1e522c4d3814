"""Every per-face descriptor of a batch on the input files' faces: the field descriptors
(:mod:`torchakvf.fields.descriptors`) beside the part descriptors
(:mod:`torchakvf.parts.part_descriptors`), as the ``features`` command, ``interop.face_features``
and the PyG transform hand them out (docs/descriptors.md)."""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch

from ..errors import SolverError, TorchAKVFError
from ..fields.akvf_result import AKVFResult
from ..fields.canonical import canonical_signs
from ..fields.descriptors import DEFAULT_COUNTS, DESCRIPTOR_FRAME, DESCRIPTOR_SEED, descriptor_names, face_descriptors
from ..fields.untangle import DEFAULT_RESTARTS, UntangledFields, untangle
from ..mesh.batch import MeshBatch, coarse_or_none
from ..mesh.clean import CleanMesh
from ..mesh.coarse import DECIMATE_ABOVE, CoarseMesh, canonical_numbering, coarse_mesh
from .boundary_cues import CUE_NAMES, crease_cues
from .boundary_probability import PROBABILITY_NAME, boundary_probability
from .part_descriptors import part_descriptor_names, part_descriptors


@dataclass
class InputDescriptors:
    """values : [B] float64 [F_input_b, d] arrays, on each input file's faces (0 on faces
    dropped as degenerate); names : the d column names (field columns first, then part
    columns)."""

    values: list
    names: list


def descriptor_batch(batch: MeshBatch) -> MeshBatch:
    """The batch the descriptors solve on: ``batch`` with each decimated mesh decimated again
    from its full-resolution mesh, to the same face count, in the surface's canonical frame
    (:func:`~torchakvf.mesh.coarse.decimate` with ``canonical=True``), and each mesh at full
    resolution renumbered from its surface (:func:`~torchakvf.mesh.coarse.canonical_numbering`,
    coordinates kept), so that a moved or renumbered copy of a mesh solves on the same surface
    in the same numbering. A mesh whose canonical decimation fails keeps the batch's own coarse
    mesh. Segmentations never use it: their coarse mesh is ``batch``'s own.
    :func:`pack_for_descriptors` makes the same batch from meshes, decimating once."""
    coarse = list(batch.coarse)
    for b, c in enumerate(coarse):
        if c is not None and not c.canonical and c.faces_asked is not None:
            coarse[b] = _canonical_coarse(c.fine, c.faces_asked) or c
    return _pack([batch.input_mesh(b) for b in range(len(batch))], coarse, batch.device, batch.dtype)


def descriptor_coarse(mesh: CleanMesh, coarse_faces: int | None) -> CoarseMesh | None:
    """The coarse mesh the descriptors solve ``mesh`` on: decimated to about ``coarse_faces``
    faces in its canonical frame; where that fails, as the segmentations decimate it
    (:func:`~torchakvf.mesh.batch.coarse_or_none`); None where the mesh is solved as it is."""
    if coarse_faces is None:
        return None
    found = _canonical_coarse(mesh, coarse_faces)
    if found is None and len(mesh.faces) > DECIMATE_ABOVE * coarse_faces:
        found = coarse_or_none(mesh, coarse_faces)
    return found


def pack_for_descriptors(meshes: Sequence[CleanMesh], coarse_faces: int | None = None, *,
                         device: str | torch.device = "cpu", dtype: torch.dtype = torch.float64) -> MeshBatch:
    """:func:`descriptor_batch` of ``MeshBatch.from_meshes(meshes, device, dtype,
    coarse_faces)`` (cleaned meshes), each mesh decimated once (:func:`descriptor_coarse`)."""
    coarse = [descriptor_coarse(m, coarse_faces) for m in meshes] if coarse_faces is not None else []
    return _pack(list(meshes), coarse, device, dtype)


Solved = TypeVar("Solved")


def solve_descriptor_batch(batch: MeshBatch, solve: Callable[[MeshBatch], Solved]) -> Solved:
    """``solve(batch)`` on a batch from :func:`descriptor_batch` or :func:`pack_for_descriptors`;
    where a mesh's canonical decimation cannot be solved (a :class:`SolverError` naming it in
    ``failed_meshes``: no shift makes its operator definite, at that decimation nor at full
    resolution), that mesh takes the segmentations' decimation instead and the batch is solved
    again, so the descriptors fail only where a segmentation would (PSB 226 and 227: their
    canonical coarse meshes cannot be factored, the eval's can)."""
    try:
        return solve(batch)
    except SolverError as exc:
        failed = [b for b in getattr(exc, "failed_meshes", None) or []
                  if batch.coarse_of(b) is not None and batch.coarse_of(b).canonical]
        if not failed:
            raise
        coarse = list(batch.coarse)
        for b in failed:
            c = coarse[b]
            coarse[b] = coarse_or_none(c.fine, c.faces_asked)
        return solve(_pack([batch.input_mesh(b) for b in range(len(batch))], coarse, batch.device, batch.dtype))


def _canonical_coarse(fine: CleanMesh, faces: int) -> CoarseMesh | None:
    try:
        return coarse_mesh(fine, faces, canonical=True)
    except TorchAKVFError:
        return None


def _pack(fine: list, coarse: list, device, dtype) -> MeshBatch:
    """The batch of the input meshes ``fine``, each packed as its ``coarse`` mesh where it has
    one, else renumbered from its surface."""
    meshes = [_numbered_canonically(m) if not coarse or coarse[b] is None else coarse[b].coarse
              for b, m in enumerate(fine)]
    out = MeshBatch.from_meshes(meshes, device=device, dtype=dtype)
    out.coarse = coarse
    return out


def _numbered_canonically(mesh: CleanMesh) -> CleanMesh:
    order, faces, face_order, _ = canonical_numbering(mesh.vertices, mesh.faces)
    return dataclasses.replace(mesh, vertices=np.ascontiguousarray(mesh.vertices[order]), faces=faces,
                               face_index=mesh.face_index[face_order],
                               face_component=mesh.face_component[face_order])


def input_face_descriptors(fields: AKVFResult, counts: Sequence[int], *,
                           untangled: Mapping[int, UntangledFields] | None = None, seed: int = 0,
                           restarts: int = DEFAULT_RESTARTS, parts: bool = True) -> InputDescriptors:
    """The field descriptors at field counts ``counts`` and (``parts``, when there is a count)
    the part descriptors of every mesh of ``fields.batch``, on the input's faces.

    A decimated mesh's field columns are those of the coarse face under each input face; its
    part columns are computed where its parts are cut, on the full-resolution mesh. With the
    part columns at the default counts (8, 16, 32) the boundary columns follow: the crease cues
    (:mod:`~torchakvf.parts.boundary_cues`) of the coarse face under each input face, then
    ``boundary_probability`` (:func:`~torchakvf.parts.boundary_probability.boundary_probability`)
    of the face's columns and cues (0 on faces dropped as degenerate).
    untangled, seed, restarts : :func:`~torchakvf.fields.descriptors.face_descriptors`'; the
    seed is the descriptors' own (0 by default, whatever seed solved the fields: callers pass
    ``untangled`` only when it was made with it); the part descriptors use their own seeds
    (:data:`~torchakvf.parts.part_descriptors.PART_SEEDS`).
    """
    batch = fields.batch
    # one field has no membership to describe and too few fields to cut parts from
    parts = parts and len(counts) > 0
    field_values = face_descriptors(fields, counts, untangled=untangled, seed=seed, restarts=restarts)
    part_values = part_descriptors(fields) if parts else None
    # the probability's model reads the default columns: other counts have no column for it
    probability = parts and tuple(counts) == DEFAULT_COUNTS
    values = []
    for b in range(len(batch)):
        v = batch.to_input_faces(b, field_values[b].detach().cpu().numpy().astype(np.float64))
        if part_values is not None:
            v = np.concatenate([v, batch.input_mesh(b).to_input_faces(part_values[b])], axis=1)
        if probability:
            v = np.concatenate([v, _boundary_columns(batch, b, v)], axis=1)
        values.append(v)
    names = descriptor_names(counts) + (part_descriptor_names() if parts else [])
    return InputDescriptors(values=values, names=names + (list(CUE_NAMES) + [PROBABILITY_NAME] if probability else []))


def untangled_with_descriptors(fields: AKVFResult, counts: Sequence[int] | None, *, seed: int = 0,
                               restarts: int = DEFAULT_RESTARTS, parts: bool = True
                               ) -> tuple[AKVFResult, UntangledFields, InputDescriptors | None]:
    """(the fields with their canonical signs, their untangling at all ``fields.n``, the
    descriptors at ``counts`` or None where ``counts`` is None): what ``interop.face_features``
    and the ``features`` command hand out, made one way. The untangling starts from ``seed``'s
    rotations in the fields' moment frame (:data:`~torchakvf.fields.descriptors.DESCRIPTOR_FRAME`),
    as the descriptors' own do, and serves them at ``fields.n`` when ``seed`` is their seed."""
    fields = canonical_signs(fields)
    unt = untangle(fields, seed=seed, restarts=restarts, frame=DESCRIPTOR_FRAME)
    if counts is None:
        return fields, unt, None
    # the descriptors untangle with their own seed, so that they do not depend on the solve's
    desc = input_face_descriptors(fields, counts, untangled={fields.n: unt} if seed == DESCRIPTOR_SEED else None,
                                  restarts=restarts, parts=parts)
    return fields, unt, desc


def _boundary_columns(batch: MeshBatch, b: int, columns: np.ndarray) -> np.ndarray:
    """[F_input, 7] the crease cues of the packed (solved) mesh b carried to its input faces, and
    the boundary probability of those faces from their field and part ``columns`` [F_input, 41]
    and cues (all 0 on faces dropped as degenerate)."""
    packed = batch.meshes[b]
    cues = batch.to_input_faces(b, crease_cues(packed.vertices, packed.faces))
    kept = np.zeros(len(columns), dtype=bool)
    kept[batch.input_mesh(b).face_index] = True
    return np.concatenate([cues, np.where(kept, boundary_probability(columns, cues), 0.0)[:, None]], axis=1)


__all__ = ["InputDescriptors", "descriptor_batch", "descriptor_coarse", "input_face_descriptors",
           "pack_for_descriptors", "solve_descriptor_batch", "untangled_with_descriptors"]
