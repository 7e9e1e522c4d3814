"""Numbers read from text mesh formats, and where a token that is not one stands."""
from __future__ import annotations

import numpy as np

from ..errors import MeshError


def as_float_array(groups: list, name: str, what: str, first: int = 0) -> np.ndarray:
    """``groups`` (nested lists of number tokens, one group per vertex or facet) as a float64
    array; a token that is not a number raises :class:`~torchakvf.errors.MeshError` naming the
    group, numbered from ``first`` (``what``: e.g. "vertex", "facet"), and the token."""
    try:
        return np.array(groups, dtype=np.float64)
    except (ValueError, OverflowError):
        for i, group in enumerate(groups):
            for token in np.asarray(group, dtype=object).ravel():
                try:
                    float(token)
                except ValueError:
                    raise MeshError(name, f"{what} {i + first}: {token!r} is not a number") from None
        raise


__all__ = ["as_float_array"]
