"""The ``features`` task: per-face AKVF features of every mesh, one ``<stem>.npz`` each.

Keys of the .npz (plain arrays, ``np.load(path, allow_pickle=False)`` reads them; every per-face
array is in the input file's face order, zeros on faces dropped as degenerate):

=====================  ==============  ==========================================================
``faces_input_count``  int64 ()        F, faces of the input file
``vertices``           float32 [V, 3]  as in the file
``faces``              int32 [F, 3]    as in the file
``akvf_norms``         float32 [F, n]  |X_i(f)| of the n raw AKVFs at each face's barycenter
``features``           float32 [F, n]  |X_i(f)| of the untangled fields (the paper's φ(f))
``eigenvalues``        float64 [n]     Killing eigenvalues λ·area of the raw AKVFs, ascending
``residuals``          float64 [n]     relative residual of each eigenpair
``converged``          bool ()         every residual below the solver tolerance
``face_vectors``       float32 [F,n,3] untangled Whitney vectors (only with ``--face-vectors``)
``params_json``        str ()          the parameters and torchakvf version, as JSON
=====================  ==============  ==========================================================
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import numpy as np

from ..io import atomic_write_bytes, write_npz
from ..parts.segment import DEFAULT_REMEDY


class FeaturesTask:
    """AKVFs (``akvf``) and their untangling (``untangle``) per batch; writes one .npz a mesh."""

    name = "features"
    stages = ("akvf", "untangle")

    def __init__(self, n: int = 32, *, seed: int = 0, remedy: str = DEFAULT_REMEDY,
                 untangle_restarts: int = 8, tol: float = 1e-6, face_vectors: bool = False,
                 cache_dir=None):
        self.n, self.seed, self.remedy = int(n), int(seed), remedy
        self.untangle_restarts, self.tol, self.face_vectors = int(untangle_restarts), float(tol), bool(face_vectors)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        if self.cache_dir is not None:
            from .runner import check_output_dir

            check_output_dir(self.cache_dir)

    @property
    def params(self) -> dict:
        return {"n": self.n, "seed": self.seed, "remedy": self.remedy,
                "untangle_restarts": self.untangle_restarts, "tol": self.tol,
                "face_vectors": self.face_vectors}

    def output_paths(self, out_dir, stem: str) -> list[Path]:
        return [Path(out_dir) / f"{stem}.npz"]

    def validate(self, item) -> None:
        from ..errors import ParameterError
        from ..mesh.batch import mesh_edges

        n_edges = len(mesh_edges(item.clean.faces)[0])
        if self.n > n_edges:
            raise ParameterError(f"{item.path}: --n {self.n} fields asked for but the mesh has only "
                                 f"{n_edges} edges")

    def process(self, items, device):
        from ..fields import akvf, untangle
        from ..mesh import MeshBatch

        t0 = time.perf_counter()
        batch = MeshBatch.from_meshes([it.clean for it in items], device=device)
        fields = akvf(batch, n=self.n, seed=self.seed, remedy=self.remedy, tol=self.tol)
        t1 = time.perf_counter()
        unt = untangle(fields, seed=self.seed, restarts=self.untangle_restarts)
        raw_norms = fields.face_vectors.norm(dim=-1)
        outs = []
        for b, it in enumerate(items):
            clean = it.clean
            f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])
            out = {
                "akvf_norms": clean.to_input_faces(raw_norms[f0:f1].cpu().numpy().astype(np.float32)),
                "features": clean.to_input_faces(unt.features[f0:f1].cpu().numpy().astype(np.float32)),
                "eigenvalues": fields.eigenvalues[b].cpu().numpy().astype(np.float64),
                "residuals": fields.residuals[b].cpu().numpy().astype(np.float64),
                "converged": np.bool_(bool(fields.converged[b])),
            }
            if self.face_vectors:
                out["face_vectors"] = clean.to_input_faces(
                    unt.face_vectors[f0:f1].cpu().numpy().astype(np.float32))
            outs.append(out)
        t2 = time.perf_counter()
        return outs, {"akvf": t1 - t0, "untangle": t2 - t1}

    def npz_arrays(self, item, out: dict) -> dict:
        from .. import __version__

        mesh = item.mesh
        params = dict(self.params, version=__version__)
        return {"faces_input_count": np.int64(mesh.n_faces),
                "vertices": mesh.vertices.astype(np.float32),
                "faces": mesh.faces.astype(np.int32),
                **out,
                "params_json": np.str_(json.dumps(params, sort_keys=True))}

    def write(self, item, out: dict, out_dir) -> list[Path]:
        path = self.output_paths(out_dir, item.stem)[0]
        write_npz(path, **self.npz_arrays(item, out))
        return [path]

    # ---- optional content cache -----------------------------------------------------------
    def cache_key(self, path) -> str:
        from .. import __version__

        h = hashlib.sha256()
        h.update(Path(path).read_bytes())
        h.update(json.dumps(self.params, sort_keys=True).encode())
        h.update(__version__.encode())
        return h.hexdigest()

    def cache_lookup(self, item, out_dir) -> bool:
        """With a cache folder: copy a cached .npz of the same content + params + version."""
        if self.cache_dir is None:
            return False
        try:
            key = self.cache_key(item.path)
        except OSError:
            return False  # unreadable input: the load reports it
        item.extra["cache_key"] = key
        hit = self.cache_dir / f"{key}.npz"
        if not hit.exists():
            return False
        atomic_write_bytes(self.output_paths(out_dir, item.stem)[0], hit.read_bytes())
        return True

    def cache_store(self, item, written) -> None:
        key = item.extra.get("cache_key")
        if self.cache_dir is None or key is None:
            return
        dest = self.cache_dir / f"{key}.npz"
        if not dest.exists():
            atomic_write_bytes(dest, Path(written[0]).read_bytes())
