"""Whether a mesh is big enough for the fields asked of it, said before any solve: a mesh has
at most one Killing field per edge, so k parts (which need n fields) need n edges."""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..errors import ParameterError
from .clean import undirected_edges


def check_fields_fit(name: str, faces: np.ndarray, n_fields: int, *, k: int | None = None,
                     fields_for_k: Callable[[int], int] | None = None,
                     subdivide_hint: str = "subdivide it (torchakvf.mesh.subdivide)",
                     fewer_hint: str = "use a smaller k") -> None:
    """Raise :class:`ParameterError` with what the user can do when ``faces`` [F, 3] (the
    cleaned mesh's) have no more edges than ``n_fields`` (the eigensolvers need fewer fields than edges).

    k : the parts asked for, named in the message; fields_for_k : the field count each k
        needs, to name the largest k this mesh can take; subdivide_hint : how the user asks
        for a subdivision (the library's function by default; a command names its option);
        fewer_hint : how the user asks for fewer fields (a smaller k by default; the features
        command's ``--n``).
    """
    n_edges = len(undirected_edges(np.asarray(faces)).unique)
    if n_fields < n_edges:
        return
    what = f"k={k} (needs {n_fields} fields)" if k is not None else f"{n_fields} fields"
    remedy = f"{fewer_hint} or {subdivide_hint}"
    if k is not None and fields_for_k is not None:
        fit = [j for j in range(1, int(k)) if fields_for_k(j) < n_edges]
        remedy = f"use k <= {max(fit)} or {subdivide_hint}" if fit else subdivide_hint
    raise ParameterError(f"{name}: mesh has {len(faces)} faces ({n_edges} edges), too few for "
                         f"{what}: a mesh takes fewer fields than it has edges; {remedy}")


__all__ = ["check_fields_fit"]
