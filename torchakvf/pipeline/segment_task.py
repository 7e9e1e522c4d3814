"""The ``segment`` task: k parts per mesh, written as ``<stem>.seg`` (+ ``.npz``, ``.ply``, ``.png``).

Stages per batch (:func:`torchakvf.parts.segment_each_k`, one k): ``akvf`` (the AKVFs, once),
``untangle`` (Algorithm 1 on them; its face vectors also draw the PNG's generator arrows) and
``cluster`` (spherical k-means, boundaries, generators). A mesh whose eigensolve did not
converge is recorded so in the manifest (:meth:`SegmentTask.manifest_fields`).
"""
from __future__ import annotations

import dataclasses

import time
from pathlib import Path

from ..errors import ParameterError, TorchAKVFError
from ..io import OUTPUT_FORMATS, write_segmentation
from ..mesh import MeshBatch
from .batches import require_edges
from ..parts.engine import (DEFAULT_METHOD, DEFAULT_REMEDY, UNTANGLE_RESTARTS, SegmentOptions, akvf_count,
                            merge_min_k, segment_each_k)


def parse_formats(text: str) -> tuple[str, ...]:
    """``"seg,npz"`` -> ("seg", "npz"); raises TorchAKVFError naming an unknown format."""
    fmts = tuple(dict.fromkeys(f.strip().lower() for f in str(text).split(",") if f.strip()))
    if not fmts:
        raise TorchAKVFError(f"--formats: name at least one of {','.join(OUTPUT_FORMATS)}")
    bad = [f for f in fmts if f not in OUTPUT_FORMATS]
    if bad:
        raise TorchAKVFError(f"--formats: unknown format {bad[0]!r} (choose from {','.join(OUTPUT_FORMATS)})")
    return fmts


class SegmentTask:
    name = "segment"
    stages = ("akvf", "untangle", "cluster")

    def __init__(self, k: int, *, eps: float = 0.0, seed: int = 0, n_fields: int | None = None,
                 remedy: str = DEFAULT_REMEDY, formats=OUTPUT_FORMATS, untangle_restarts: int = UNTANGLE_RESTARTS,
                 kmeans_restarts: int | None = None, coarse_faces: int | None = None, solver: str = "auto",
                 method: str = DEFAULT_METHOD, graphcut: bool = True):
        self.k, self.eps, self.seed = int(k), float(eps), int(seed)
        self.solver, self.method, self.graphcut = str(solver), str(method), bool(graphcut)
        # one-line errors before any work; the options' merge weights and graph cut are
        # recorded in params, so a run resumed under other defaults redoes its meshes
        self.options = SegmentOptions(eps=self.eps, solver=self.solver, method=self.method,
                                      graphcut=self.graphcut, kmeans_restarts=kmeans_restarts)
        # None: segment's own choice (2k in [16, 32]; with method "merge" 3 max(k, 8) in multiples of 8; moved off
        # degenerate eigenvalue clusters),
        # from AKVFs computed with SPARE_FIELDS to spare so a cluster cut can be seen.
        self.n_fields = int(n_fields) if n_fields is not None else None
        self.n_akvf = self.n_fields if n_fields is not None else akvf_count([[self.k]], None, self.method, merge_min_k(self.options))
        self.remedy, self.formats = remedy, tuple(formats)
        self.untangle_restarts, self.kmeans_restarts = int(untangle_restarts), self.options.kmeans_restarts
        # Solve on meshes decimated to about this many faces (None: full resolution); the
        # labels are cut on the input's faces either way (torchakvf.mesh.coarse).
        self.coarse_faces = int(coarse_faces) if coarse_faces else None

    @property
    def params(self) -> dict:
        n_fields = self.n_fields if self.n_fields is not None else "auto"
        return {"k": self.k, "eps": self.eps, "seed": self.seed, "n_fields": n_fields,
                "remedy": self.remedy, "formats": list(self.formats),
                "untangle_restarts": self.untangle_restarts, "kmeans_restarts": self.kmeans_restarts,
                "coarse_faces": self.coarse_faces, "solver": self.solver, "method": self.method,
                "merge": dataclasses.asdict(self.options.merge),
                "graphcut": None if self.options.graphcut is None else dataclasses.asdict(self.options.graphcut)}

    def output_paths(self, out_dir, stem: str) -> list[Path]:
        return [Path(out_dir) / f"{stem}.{fmt}" for fmt in self.formats]

    def validate(self, item) -> None:
        n_faces = len(item.clean.faces)
        if self.k > n_faces:
            raise ParameterError(f"{item.path}: -k {self.k} is larger than the mesh's {n_faces} faces")
        require_edges(item, self.n_akvf, f"{self.n_akvf} fields needed")

    def process(self, items, device):
        t0 = time.perf_counter()
        batch = MeshBatch.from_meshes([it.clean for it in items], device=device,
                                      coarse_faces=self.coarse_faces)
        t_pack = time.perf_counter() - t0
        res = segment_each_k(batch, self.k, eps=self.eps, seed=self.seed, n_fields=self.n_fields,
                             remedy=self.remedy, solver=self.solver, method=self.method,
                             untangle_restarts=self.untangle_restarts,
                             kmeans_restarts=self.kmeans_restarts, refine=False, n_akvf=self.n_akvf,
                             graphcut=self.graphcut)
        seg = res.segmentation(self.k)
        # The untangled fields draw the PNG's generator arrows.
        vectors = [seg.face_vectors(b) if "png" in self.formats else None for b in range(len(items))]
        seconds = dict(res.seconds)
        seconds["akvf"] += t_pack     # packing the batch is charged to the solve, as before
        return list(zip(seg.meshes, vectors)), seconds

    @staticmethod
    def manifest_fields(out) -> dict:
        """Per mesh, what the manifest records beside the runner's own fields: whether its
        eigensolve converged and its largest eigenpair residual (``out``: from :meth:`process`)."""
        ms, _ = out
        return {"converged": bool(ms.converged), "max_residual": float(ms.max_residual)}

    def write(self, item, out, out_dir) -> list[Path]:
        ms, vectors = out
        written = write_segmentation(ms, item.mesh.vertices, item.mesh.faces, out_dir, item.stem,
                                     formats=self.formats, face_vectors=vectors)
        return list(written.values())
