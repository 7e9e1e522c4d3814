"""The meshes the operator tests assemble on: closed and open, with Euler characteristics."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch

import torchakvf as ta
from helpers.planar_meshes import golden_disk
from torchakvf import shapes

#: name -> (vertices, faces) maker
SHAPES = {
    "icosphere3": lambda: (shapes.icosphere(3).vertices, shapes.icosphere(3).faces),
    "torus": lambda: (shapes.torus(n_major=48).vertices, shapes.torus(n_major=48).faces),
    "open_tube": lambda: (shapes.open_tube(n_around=36).vertices, shapes.open_tube(n_around=36).faces),
    "golden_disk": golden_disk,
    "hemisphere3": lambda: (shapes.hemisphere(3).vertices, shapes.hemisphere(3).faces),
    "square_patch": lambda: (shapes.square_patch(14).vertices, shapes.square_patch(14).faces),
    "flat_disk": lambda: (shapes.flat_disk(n_boundary=60).vertices, shapes.flat_disk(n_boundary=60).faces),
}
#: name -> Euler characteristic
EULER = {"icosphere3": 2, "torus": 0, "open_tube": 0, "golden_disk": 1, "hemisphere3": 1,
         "square_patch": 1, "flat_disk": 1}


def shape_meshes() -> dict:
    return {k: ta.Mesh(*f(), name=k) for k, f in SHAPES.items()}


def per_mesh_sum(x: torch.Tensor, ptr: torch.Tensor) -> np.ndarray:
    return np.array([float(x[int(ptr[b]):int(ptr[b + 1])].sum()) for b in range(len(ptr) - 1)])


def as_scipy(a: torch.Tensor) -> sp.csr_matrix:
    a = a.coalesce()
    i = a.indices().cpu().numpy()
    return sp.csr_matrix((a.values().cpu().numpy(), (i[0], i[1])), shape=tuple(a.shape))
