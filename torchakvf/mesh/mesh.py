"""A single triangle mesh as the user gave it, before any cleaning."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import MeshError

#: Largest vertex coordinate magnitude accepted: float32's range. The per-face outputs (.ply,
#: .glb) hold the input's vertices in float32, where a larger coordinate becomes infinite, and
#: the renderer's face areas (products of four coordinates) stay finite in float64 below it. A
#: stray coordinate below this is handled by the clean-up (its faces are dropped for the solve).
MAX_COORDINATE = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh exactly as read or given: the face order is the file's.

    Parameters
    ----------
    vertices : array [V, 3], float (any units; the solver rescales to unit area internally)
    faces : array [F, 3], int, 0-based vertex indices
    name : str, what error messages and outputs call this mesh (a file path, or "<array>")

    Construction only checks shapes, finiteness (coordinates within :data:`MAX_COORDINATE`)
    and index range (cheap and always fatal);
    the geometric clean-up (duplicates, degenerate faces, orientation) happens in
    :func:`torchakvf.mesh.clean_mesh`, which keeps a map back to these faces.
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = "<array>"
    meta: dict = field(default_factory=dict, compare=False)

    def __post_init__(self):
        v = _as_array(self.vertices, np.float64, self.name, "vertices")
        f = _as_array(self.faces, None, self.name, "faces")
        if v.ndim != 2 or v.shape[1] != 3:
            raise MeshError(self.name, f"vertices must have shape [V, 3], got {list(v.shape)}")
        if f.ndim != 2 or f.shape[1] != 3:
            shape = list(f.shape)
            raise MeshError(self.name, f"faces must be triangles with shape [F, 3], got {shape}")
        if len(v) == 0 or len(f) == 0:
            raise MeshError(self.name, f"empty mesh ({len(v)} vertices, {len(f)} faces)")
        if not np.issubdtype(f.dtype, np.integer):
            if not np.all(np.isfinite(f)) or np.any(f != np.round(f)):
                raise MeshError(self.name, "face indices must be integers")
        f = f.astype(np.int64, copy=False)
        bad = ~np.isfinite(v).all(axis=1)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            raise MeshError(self.name, f"{int(bad.sum())} vertices have NaN or infinite "
                                       f"coordinates (first: vertex {first})")
        huge = (np.abs(v) > MAX_COORDINATE).any(axis=1)
        if huge.any():
            first = int(np.flatnonzero(huge)[0])
            raise MeshError(self.name, f"{int(huge.sum())} vertices have coordinates beyond "
                                       f"±{MAX_COORDINATE:.1e} (first: vertex {first}, "
                                       f"{float(np.abs(v[first]).max()):.3g}), too large for the "
                                       "float32 outputs; fix or delete them, or rescale the mesh")
        out = (f < 0) | (f >= len(v))
        if out.any():
            face = int(np.flatnonzero(out.any(axis=1))[0])
            raise MeshError(self.name, f"face {face} has vertex index {int(f[face][out[face]][0])} "
                                       f"outside 0..{len(v) - 1}")
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def __repr__(self) -> str:
        return f"Mesh({self.name!r}, V={self.n_vertices}, F={self.n_faces})"


def _as_array(x, dtype, name: str, what: str) -> np.ndarray:
    if hasattr(x, "detach"):  # a torch tensor
        x = x.detach().cpu().numpy()
    try:
        return np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise MeshError(name, f"{what} are not a numeric array ({exc})") from None
