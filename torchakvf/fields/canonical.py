"""AKVFs with a sign fixed by the surface: the same fields for any solver start, pose or numbering.

An eigensolver returns each field up to its sign, and which sign depends on its random start,
the solver and the numbering of the mesh. Anything that combines the raw fields with fixed
coefficients (the untangling's random starts, with a given seed) then depends on them too. Here
each field's sign is chosen so that third moments of two scalars odd in its sign add up to a
positive number (:func:`vorticity_moments`): ω_i(f) = (dX_i♭)(f) / area(f), the circulation of
field i around face f per unit area (intrinsic, independent of how the edges are oriented), and
the field's component away from the area centroid. A field for which both vanish (one a proper
symmetry of the surface reverses) keeps a sign that may still flip; so does any rotation inside
a degenerate eigenspace, which no sign can fix.
"""
from __future__ import annotations

import dataclasses

import torch

from .akvf_result import AKVFResult

#: Sign moments smaller than this (they are scale-free, O(0.01-1) on PSB meshes) are round-off
#: of a field a symmetry makes odd (a sphere's rotations): such a field keeps the solver's sign
#: rather than one decided by round-off, which would differ between float types or machines.
SIGN_MOMENT_FLOOR = 1e-6


def sign_statistics(fields: AKVFResult, b: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(area [F_b], omega [F_b, n], radial [F_b, n]) of mesh b: its face areas (unit total), the
    vorticity ω_i(f) of every field and its component r_i(f) = ⟨X_i(f), c(f) - c̄⟩ away from
    the area centroid (:func:`vorticity_moments`). Both are linear in the fields, so the
    statistics of a rotated set Φ A are ``omega @ A`` and ``radial @ A``."""
    batch = fields.batch
    forms = fields.forms.to(torch.float64)
    f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
    sign = batch.face_edge_sign[f0:f1].to(torch.float64)
    # circulations on the packed edges of this mesh: sum of the half-edges' signed values
    circ = (forms[batch.face_edges[f0:f1]] * sign[:, :, None]).sum(dim=1)              # [F_b, n]
    v = batch.verts[batch.faces[f0:f1]].to(torch.float64)
    area = 0.5 * torch.linalg.norm(torch.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], dim=-1), dim=-1)
    area = area / area.sum()
    omega = circ / torch.clamp(area, min=1e-300)[:, None]
    # the radial moment: how the field moves faces away from the area centroid
    centers = v.mean(dim=1)
    radial = torch.einsum("fnc,fc->fn", fields.face_vectors[f0:f1].to(torch.float64), centers - area @ centers)
    return area, omega, radial


def odd_moments(area: torch.Tensor, omega: torch.Tensor, radial: torch.Tensor) -> torch.Tensor:
    """[n] Σ a ω³ / (Σ a ω²)^{3/2} + Σ a r³ / (Σ a r²)^{3/2} of :func:`sign_statistics`' arrays
    (columns: fields)."""
    second = (area[:, None] * omega ** 2).sum(dim=0)
    third = (area[:, None] * omega ** 3).sum(dim=0)
    r2 = (area[:, None] * radial ** 2).sum(dim=0)
    r3 = (area[:, None] * radial ** 3).sum(dim=0)
    return third / torch.clamp(second, min=1e-300) ** 1.5 + r3 / torch.clamp(r2, min=1e-300) ** 1.5


def vorticity_moments(fields: AKVFResult) -> torch.Tensor:
    """[B, n] the sign moments of every mesh's fields: Σ a ω³ / (Σ a ω²)^{3/2} + Σ a r³ /
    (Σ a r²)^{3/2}, a = area(f) (unit total), ω_i(f) the vorticity and r_i(f) = ⟨X_i(f), c(f) -
    c̄⟩ the field's component away from the area centroid c̄ (c(f) the face's centroid). Both
    are scale-free third moments, odd in the field's sign and invariant to rigid motions and
    numbering. A mirror symmetry of the surface makes ω odd under it for a field it keeps, and
    r odd for a field it reverses: the sum is zero only where both are."""
    out = torch.zeros(len(fields.batch), fields.n, dtype=torch.float64, device=fields.forms.device)
    for b in range(len(fields.batch)):
        out[b] = odd_moments(*sign_statistics(fields, b))
    return out


def canonical_signs(fields: AKVFResult) -> AKVFResult:
    """``fields`` with every field's sign flipped where its sign moment
    (:func:`vorticity_moments`) is below -:data:`SIGN_MOMENT_FLOOR`; eigenvalues and norms are
    unchanged."""
    flip = torch.where(vorticity_moments(fields) < -SIGN_MOMENT_FLOOR, -1.0, 1.0)  # [B, n]
    batch = fields.batch
    edge_of = torch.repeat_interleave(torch.arange(len(batch), device=flip.device),
                                      (batch.edge_ptr[1:] - batch.edge_ptr[:-1]).to(flip.device))
    face_of = torch.repeat_interleave(torch.arange(len(batch), device=flip.device),
                                      (batch.face_ptr[1:] - batch.face_ptr[:-1]).to(flip.device))
    forms = fields.forms * flip[edge_of].to(fields.forms.dtype)
    face_vectors = fields.face_vectors * flip[face_of].to(fields.face_vectors.dtype)[:, :, None]
    return dataclasses.replace(fields, forms=forms, face_vectors=face_vectors)


__all__ = ["SIGN_MOMENT_FLOOR", "canonical_signs", "vorticity_moments", "sign_statistics", "odd_moments"]
