"""Input checks shared by the segmentation metrics: labels, weights and meshes as the metrics
take them, each refused with a :class:`~torchakvf.errors.ParameterError` that says what is wrong."""
from __future__ import annotations

import numpy as np

from ..errors import ParameterError


def as_labels(labels, name: str) -> np.ndarray:
    arr = np.asarray(labels)
    if arr.ndim != 1:
        raise ParameterError(f"{name} must be a 1-D array of per-face segment labels, "
                             f"got shape {list(arr.shape)}")
    if arr.size == 0:
        raise ParameterError(f"{name} is empty: a segmentation needs at least one face")
    if arr.dtype == np.bool_ or not np.issubdtype(arr.dtype, np.integer):
        raise ParameterError(f"{name} must hold integer segment labels, got dtype {arr.dtype}")
    return arr.astype(np.int64, copy=False)


def label_pair(a, b, names=("a", "b")) -> tuple[np.ndarray, np.ndarray]:
    a = as_labels(a, names[0])
    b = as_labels(b, names[1])
    if a.shape != b.shape:
        raise ParameterError(f"{names[0]} has {a.size} labels but {names[1]} has {b.size}: "
                             f"both segmentations must label the same faces")
    return a, b


def as_weights(weights, n: int, name: str = "face_areas") -> np.ndarray:
    w = np.asarray(weights)
    if w.ndim != 1 or w.size != n:
        raise ParameterError(f"{name} must be a 1-D array with one value per face ({n}), "
                             f"got shape {list(w.shape)}")
    if not (np.issubdtype(w.dtype, np.floating) or np.issubdtype(w.dtype, np.integer)):
        raise ParameterError(f"{name} must be numeric, got dtype {w.dtype}")
    w = w.astype(np.float64, copy=False)
    if not np.all(np.isfinite(w)):
        raise ParameterError(f"{name} contains NaN or infinite values")
    if np.any(w < 0):
        raise ParameterError(f"{name} contains negative values")
    if not w.sum() > 0:
        raise ParameterError(f"{name} sum to zero: the total weight must be positive")
    return w


def as_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    v = np.asarray(vertices)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
        raise ParameterError(f"vertices must have shape [V, 3] with V > 0, got {list(v.shape)}")
    if not np.issubdtype(v.dtype, np.number) or v.dtype == np.bool_:
        raise ParameterError(f"vertices must be numeric, got dtype {v.dtype}")
    v = v.astype(np.float64, copy=False)
    if not np.all(np.isfinite(v)):
        raise ParameterError("vertices contain NaN or infinite coordinates")
    if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
        raise ParameterError(f"faces must be triangles with shape [F, 3] and F > 0, "
                             f"got {list(f.shape)}")
    if f.dtype == np.bool_ or not np.issubdtype(f.dtype, np.integer):
        raise ParameterError(f"faces must hold integer vertex indices, got dtype {f.dtype}")
    f = f.astype(np.int64, copy=False)
    if f.min() < 0 or f.max() >= len(v):
        raise ParameterError(f"faces index vertices outside 0..{len(v) - 1} "
                             f"(min {int(f.min())}, max {int(f.max())})")
    return v, f


def check_face_count(labels: np.ndarray, n_faces: int, name: str) -> None:
    if labels.size != n_faces:
        raise ParameterError(f"{name} has {labels.size} labels but the mesh has {n_faces} faces")


__all__ = ["as_labels", "label_pair", "as_weights", "as_mesh", "check_face_count"]
