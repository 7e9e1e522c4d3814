"""Per-face AKVF features of one mesh on its input faces: the library-free core of the
interop transforms."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ..fields.untangle import DEFAULT_RESTARTS


@dataclass
class FaceFeatures:
    """AKVF descriptors of one mesh, on the faces as given (input order and count).

    features : [F, n] |X_i(f)| of the untangled fields (the paper's φ(f)); 0 on faces
        dropped as degenerate
    akvf_norms : [F, n] |X_i(f)| of the raw AKVFs
    eigenvalues : [n] Killing eigenvalues λ·area of the raw AKVFs, ascending
    energies : [n] Killing energy λ·area of each untangled field
    descriptors : [F, d] per-face descriptors that mean the same on every mesh (invariant to
        the fields' order and sign): the field descriptors (:mod:`torchakvf.fields.descriptors`)
        then the part descriptors (:mod:`torchakvf.parts.part_descriptors`), then, at the
        default counts (n ≥ 32), the crease cues and the boundary probability
        (:mod:`torchakvf.parts.boundary_probability`), docs/descriptors.md;
        None when asked for without them
    descriptor_names : the d column names, e.g. ``"share1@8"``, ``"cut_distance@2"`` (empty
        without descriptors)
    """

    features: np.ndarray
    akvf_norms: np.ndarray
    eigenvalues: np.ndarray
    energies: np.ndarray
    descriptors: np.ndarray | None = None
    descriptor_names: list = field(default_factory=list)


def face_features(batch, n: int = 32, *, seed: int = 0, remedy: str | None = None,
                  restarts: int = DEFAULT_RESTARTS, tol: float = 1e-6,
                  descriptors: bool = True, part_descriptors: bool = True) -> list[FaceFeatures]:
    """:class:`FaceFeatures` of every mesh of ``batch`` (a :class:`~torchakvf.MeshBatch`,
    optionally built with ``coarse_faces``: the fields are computed on the decimated mesh and
    reported on the input's faces; the mesh is decimated again in the surface's canonical frame,
    :func:`~torchakvf.parts.input_descriptors.descriptor_batch`, so that a moved or renumbered
    copy of the mesh gets the same features). ``remedy`` defaults to the segmentation's
    (:data:`torchakvf.operators.killing.DEFAULT_REMEDY`); the other arguments are
    :func:`~torchakvf.akvf`'s and :func:`~torchakvf.untangle`'s. ``descriptors=False`` skips
    the per-face descriptors (the field descriptors untangle again at 8 and 16 fields, about
    0.5 s of one core on a mesh of 4000 faces); ``part_descriptors=False`` keeps the field
    descriptors without the part ones (those segment the mesh 18 times, about 1 s of one core
    on a mesh decimated to 4000 faces)."""
    from ..fields.akvf import akvf_falling_back
    from ..fields.descriptors import counts_for
    from ..operators.killing import DEFAULT_REMEDY
    from ..parts.input_descriptors import descriptor_batch, solve_descriptor_batch, untangled_with_descriptors

    remedy = DEFAULT_REMEDY if remedy is None else remedy
    fields, _ = solve_descriptor_batch(descriptor_batch(batch),
                                       lambda mb: akvf_falling_back(mb, n=n, seed=seed, tol=tol, remedy=remedy))
    fields, unt, desc = untangled_with_descriptors(fields, counts_for(n) if descriptors else None, seed=seed,
                                                   restarts=restarts, parts=part_descriptors)
    batch = fields.batch              # the fallback may have re-packed meshes at full resolution
    raw = fields.face_vectors.norm(dim=-1)
    out = []
    for b in range(len(batch)):
        f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
        out.append(FaceFeatures(
            features=batch.to_input_faces(b, unt.mesh_features(b).detach().cpu().numpy()),
            akvf_norms=batch.to_input_faces(b, raw[f0:f1].detach().cpu().numpy()),
            eigenvalues=fields.eigenvalues[b].detach().cpu().numpy(),
            energies=unt.energies[b].detach().cpu().numpy(),
            descriptors=None if desc is None else desc.values[b],
            descriptor_names=[] if desc is None else desc.names))
    return out


def as_tensor_like(values: np.ndarray, like: torch.Tensor) -> torch.Tensor:
    """``values`` as a tensor on ``like``'s device, in its dtype when floating (else float32)."""
    dtype = like.dtype if like.is_floating_point() else torch.float32
    return torch.as_tensor(np.ascontiguousarray(values), dtype=dtype, device=like.device)
