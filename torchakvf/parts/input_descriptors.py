"""Every per-face descriptor of a batch on the input files' faces: the field descriptors
(:mod:`torchakvf.fields.descriptors`) beside the part descriptors
(:mod:`torchakvf.parts.part_descriptors`), as the ``features`` command, ``interop.face_features``
and the PyG transform hand them out (docs/descriptors.md)."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import TorchAKVFError
from ..fields.akvf_result import AKVFResult
from ..fields.descriptors import descriptor_names, face_descriptors
from ..fields.untangle import DEFAULT_RESTARTS, UntangledFields
from ..mesh.batch import MeshBatch
from ..mesh.coarse import coarse_mesh
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
    (:func:`~torchakvf.mesh.coarse.decimate` with ``canonical=True``), so that a moved or
    renumbered copy of a mesh solves on the same coarse surface. Meshes at full resolution,
    already canonical, or whose canonical decimation fails keep theirs. Segmentations never
    use it: their coarse mesh is ``batch``'s own."""
    coarse = list(batch.coarse)
    changed = False
    for b, c in enumerate(coarse):
        if c is None or c.canonical or c.faces_asked is None:
            continue
        try:
            coarse[b] = coarse_mesh(c.fine, c.faces_asked, canonical=True) or c
        except TorchAKVFError:
            continue                  # the batch's own coarse mesh is still a correct input
        changed = True
    if not changed:
        return batch
    meshes = [m if c is None else c.coarse for m, c in zip(batch.meshes, coarse)]
    out = MeshBatch.from_meshes(meshes, device=batch.device, dtype=batch.dtype)
    out.coarse = coarse
    return out


def input_face_descriptors(fields: AKVFResult, counts: Sequence[int], *,
                           untangled: Mapping[int, UntangledFields] | None = None, seed: int = 0,
                           restarts: int = DEFAULT_RESTARTS, parts: bool = True) -> InputDescriptors:
    """The field descriptors at field counts ``counts`` and (``parts``, when there is a count)
    the part descriptors of every mesh of ``fields.batch``, on the input's faces.

    A decimated mesh's field columns are those of the coarse face under each input face; its
    part columns are computed where its parts are cut, on the full-resolution mesh.
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
    values = []
    for b in range(len(batch)):
        v = batch.to_input_faces(b, field_values[b].detach().cpu().numpy().astype(np.float64))
        if part_values is not None:
            v = np.concatenate([v, batch.input_mesh(b).to_input_faces(part_values[b])], axis=1)
        values.append(v)
    names = descriptor_names(counts) + (part_descriptor_names() if parts else [])
    return InputDescriptors(values=values, names=names)


__all__ = ["InputDescriptors", "descriptor_batch", "input_face_descriptors"]
