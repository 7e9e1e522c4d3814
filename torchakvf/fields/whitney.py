"""The per-face feature of a field: |X_f| of its Whitney vectors. The interpolation itself
(1-forms to face vectors) is an operator, :func:`torchakvf.operators.whitney.whitney_face_vectors`,
importable from here too."""
from __future__ import annotations

import torch

from ..operators.whitney import whitney_face_vectors

__all__ = ["face_norms", "whitney_face_vectors"]


def face_norms(face_vectors: torch.Tensor) -> torch.Tensor:
    """[ΣF, n, 3] -> [ΣF, n]: the per-face feature |X_f| of each field."""
    return torch.linalg.norm(face_vectors, dim=-1)
