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
``converged``          bool ()         every residual at most the solver tolerance (also in the
                                       manifest record, with ``max_residual``)
``descriptors``        float32 [F, d]  per-face descriptors invariant to the fields' order and sign,
                                       the same columns on every mesh: the field descriptors,
                                       then (unless ``--no-part-descriptors``) the part
                                       descriptors (docs/descriptors.md)
``descriptor_names``   str [d]         their column names, e.g. ``share1@8``, ``cut_distance@2``
``face_vectors``       float32 [F,n,3] untangled Whitney vectors (only with ``--face-vectors``)
``params_json``        str ()          the parameters and torchakvf version, as JSON
=====================  ==============  ==========================================================

With ``coarse_faces`` a mesh of more than 1.25x that many faces is solved decimated
(:mod:`torchakvf.mesh.coarse`) and each input face takes the values of the coarse face under
its barycenter (``face_vectors`` then lie in the coarse face's plane). Without it, a mesh whose
full-resolution solve would need more memory than the machine has (:func:`estimate_bytes`), or
more faces than ``max_faces``, is refused before it is loaded, with the option to use.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from ..errors import ParameterError, TorchAKVFError
from ..fields.descriptors import counts_for
from ..fields.untangle import DEFAULT_RESTARTS
from ..io import atomic_write_bytes, remove_stale_temp_files, write_npz
from ..operators.killing import DEFAULT_REMEDY

log = logging.getLogger("torchakvf.pipeline")

#: Peak memory of a full-resolution ``features`` solve, per face and field, and the fixed part
#: (bytes; CPU, float64): a linear fit of the peak resident size of solves on icospheres, so
#: that a mesh too big for the machine is refused before it is loaded (see docs/design.md).
BYTES_PER_FACE_FIELD = 540
BYTES_FIXED = 300 * 2**20
#: Face count to suggest for ``--coarse-faces`` when a mesh is refused.
SUGGESTED_COARSE_FACES = 20_000


def estimate_bytes(faces: int, n: int) -> int:
    """About how many bytes a features solve of ``faces`` faces and ``n`` fields peaks at."""
    return BYTES_FIXED + int(faces) * int(n) * BYTES_PER_FACE_FIELD


def device_memory(device) -> int | None:
    """The memory a solve on ``device`` may use: on CUDA the GPU's free memory
    (``torch.cuda.mem_get_info``), elsewhere the machine's physical memory."""
    if str(device).startswith("cuda"):
        import torch

        return int(torch.cuda.mem_get_info(torch.device(device))[0])
    return _physical_memory()


def estimate_device_bytes(faces: int, n: int) -> int:
    """About how many bytes of a GPU's memory a batched solve of one mesh of ``faces`` faces and
    ``n`` fields takes: its padded solver arrays (:func:`~torchakvf.pipeline.batches.solve_bytes`),
    with :data:`~torchakvf.pipeline.batches.FREE_MEMORY_SHARE` left for the rest."""
    from .batches import EDGES_PER_FACE, FREE_MEMORY_SHARE, solve_bytes

    return int(solve_bytes(int(EDGES_PER_FACE * faces) + 1, 1, n) / FREE_MEMORY_SHARE)


def _physical_memory() -> int | None:
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


class FeaturesTask:
    """AKVFs (``akvf``), their untangling and the per-face descriptors (``untangle``) per batch;
    writes one .npz a mesh."""

    name = "features"
    stages = ("akvf", "untangle")

    def __init__(self, n: int = 32, *, seed: int = 0, remedy: str = DEFAULT_REMEDY,
                 untangle_restarts: int = DEFAULT_RESTARTS, tol: float = 1e-6, face_vectors: bool = False,
                 cache_dir=None, coarse_faces: int | None = None, max_faces: int | None = None,
                 memory_bytes: int | None = None, batched: bool | None = None, device="cpu",
                 part_descriptors: bool = True):
        """coarse_faces : solve meshes above 1.25x this many faces decimated to about this many
        (None: full resolution). max_faces : refuse a mesh whose solve has more faces (None:
        no limit but memory). memory_bytes : the memory a solve may use (default
        :func:`device_memory`: on a GPU its free memory, checked against
        :func:`estimate_device_bytes`; else the machine's, against :func:`estimate_bytes`).
        batched : solve each batch as one (the accelerator's path; None: the device's way).
        device : where the solve runs (sets the memory checked). part_descriptors : add the part
        descriptors (:mod:`torchakvf.parts.part_descriptors`) to the field descriptors."""
        self.n, self.seed, self.remedy = int(n), int(seed), remedy
        self.untangle_restarts, self.tol, self.face_vectors = int(untangle_restarts), float(tol), bool(face_vectors)
        self.coarse_faces = int(coarse_faces) if coarse_faces else None
        self.max_faces = int(max_faces) if max_faces is not None else None
        self.on_device = str(device).startswith("cuda")
        self.memory_bytes = int(memory_bytes) if memory_bytes is not None else device_memory(device)
        self.batched = None if batched is None else bool(batched)
        self.part_descriptors = bool(part_descriptors)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        if self.cache_dir is not None:
            from .outdir import check_output_dir

            check_output_dir(self.cache_dir, "--cache")
            remove_stale_temp_files(self.cache_dir, older_than_s=3600)  # shared: only old ones

    @property
    def params(self) -> dict:
        from ..fields.descriptors import DESCRIPTOR_FRAME

        params = {"n": self.n, "seed": self.seed, "remedy": self.remedy,
                  "untangle_restarts": self.untangle_restarts, "untangle_frame": DESCRIPTOR_FRAME, "tol": self.tol,
                  "face_vectors": self.face_vectors, "coarse_faces": self.coarse_faces,
                  "descriptor_counts": list(counts_for(self.n)), "part_descriptors": self.part_descriptors}
        if self.batched is not None:    # the default leaves earlier manifests resumable
            params["batched"] = self.batched
        return params

    def output_paths(self, out_dir, stem: str) -> list[Path]:
        return [Path(out_dir) / f"{stem}.npz"]

    def solved_faces(self, faces: int) -> int:
        """Faces of the mesh the solver sees for an input of ``faces`` faces."""
        from ..mesh.coarse import DECIMATE_ABOVE

        if self.coarse_faces and faces > DECIMATE_ABOVE * self.coarse_faces:
            return self.coarse_faces
        return int(faces)

    def check_size(self, path, faces: int) -> None:
        """Refuse, before any work, a mesh too big for ``max_faces`` or for the memory."""
        solved = self.solved_faces(faces)
        estimate = estimate_device_bytes if self.on_device else estimate_bytes
        need = estimate(solved, self.n)
        fits = [SUGGESTED_COARSE_FACES]
        if self.max_faces is not None:
            fits.append(self.max_faces)
        if self.memory_bytes is not None:
            fits.append(int(solved * self.memory_bytes / max(need, 1)) if self.on_device
                        else (self.memory_bytes - BYTES_FIXED) // (self.n * BYTES_PER_FACE_FIELD))
        suggest = max(min(fits), 100)
        fix = (f"solve it decimated with --coarse-faces {suggest}" if not self.coarse_faces
               else f"lower --coarse-faces (now {self.coarse_faces})")
        if self.max_faces is not None and solved > self.max_faces:
            raise ParameterError(f"{path}: {solved:,} faces to solve is above --max-faces {self.max_faces} "
                                 f"(about {need / 2**30:.1f} GB for --n {self.n}); {fix}, or raise --max-faces")
        if self.memory_bytes is not None and need > self.memory_bytes:
            where = "free on the GPU" if self.on_device else "of memory"
            raise ParameterError(f"{path}: {solved:,} faces need about {need / 2**30:.1f} GB for --n {self.n}, "
                                 f"more than the {self.memory_bytes / 2**30:.1f} GB {where}; {fix}")

    def validate(self, item) -> None:
        from ..mesh.size_check import check_fields_fit

        check_fields_fit(str(item.path), item.clean.faces, self.n, fewer_hint="use a smaller --n")

    def process(self, items, device):
        from ..parts.input_descriptors import pack_for_descriptors

        t0 = time.perf_counter()
        # decimated in each surface's canonical frame: a moved or renumbered file gets the same rows
        batch = pack_for_descriptors([it.clean for it in items], self.coarse_faces, device=device)
        t_pack = time.perf_counter() - t0
        outs, seconds = self.descriptors_of(batch)
        seconds["akvf"] += t_pack     # the manifest has no stage of its own for packing
        return outs, seconds

    @staticmethod
    def cut(out: dict) -> dict:
        """The host half of the batched path (:mod:`.batched_run`): nothing left to do, the
        arrays are written as they come."""
        return out

    @staticmethod
    def coarse_mesh(clean, coarse_faces):
        """How the batched path's host workers decimate a mesh for this task (:mod:`.batched_run`):
        in its canonical frame, as :meth:`process` packs it."""
        from ..parts.input_descriptors import descriptor_coarse

        return descriptor_coarse(clean, coarse_faces)

    def solve_prepared(self, batch, items=None):
        """The batched path's solve (:mod:`.batched_run`): :meth:`descriptors_of` the batch the
        descriptors solve on (its meshes decimated by :meth:`coarse_mesh` in the host workers;
        :func:`~torchakvf.parts.input_descriptors.descriptor_batch` renumbers those at full
        resolution, as :meth:`process` packs them: the same arrays); ``items`` unused."""
        from ..parts.input_descriptors import descriptor_batch

        t0 = time.perf_counter()
        batch = descriptor_batch(batch)
        t_pack = time.perf_counter() - t0
        outs, seconds = self.descriptors_of(batch)
        seconds["akvf"] += t_pack
        return outs, seconds

    def descriptors_of(self, batch):
        """The AKVFs, their untangling and the descriptors of a batch packed for descriptors:
        (one dict of arrays per mesh, {"akvf": s, "untangle": s})."""
        from ..fields import akvf
        from ..parts.input_descriptors import solve_descriptor_batch, untangled_with_descriptors

        t0 = time.perf_counter()
        fields = solve_descriptor_batch(batch, lambda mb: akvf(mb, n=self.n, seed=self.seed, remedy=self.remedy,
                                                               tol=self.tol, batched=self.batched))
        batch = fields.batch        # a mesh whose canonical decimation failed is packed as segmentations pack it
        t1 = time.perf_counter()
        fields, unt, desc = untangled_with_descriptors(fields, counts_for(self.n), seed=self.seed,
                                                       restarts=self.untangle_restarts, parts=self.part_descriptors)
        names = np.array(desc.names)
        raw_norms = fields.face_vectors.norm(dim=-1)
        outs = []
        for b in range(len(batch)):
            f0, f1 = int(batch.face_ptr[b]), int(batch.face_ptr[b + 1])

            def on_input(values, b=b):
                """[the mesh's solved faces, ...] -> [input faces, ...] (zeros on dropped faces)."""
                return batch.to_input_faces(b, values.cpu().numpy().astype(np.float32))

            residuals = fields.residuals[b].cpu().numpy().astype(np.float64)
            out = {
                "akvf_norms": on_input(raw_norms[f0:f1]),
                "features": on_input(unt.mesh_features(b)),
                "descriptors": desc.values[b].astype(np.float32),
                "descriptor_names": names,
                "eigenvalues": fields.eigenvalues[b].cpu().numpy().astype(np.float64),
                "residuals": residuals,
                "converged": np.bool_(bool(np.all(residuals <= self.tol))),
            }
            if self.face_vectors:
                out["face_vectors"] = on_input(unt.mesh_face_vectors(b))
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

    def manifest_fields(self, out: dict) -> dict:
        """Flags a mesh whose eigensolve did not converge in its manifest record."""
        return {"converged": bool(out["converged"]), "max_residual": float(np.max(out["residuals"]))}

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
        """With a cache folder: copy a cached .npz of the same content + params + version, once
        it is checked whole (a truncated or corrupt entry is deleted and recomputed)."""
        from ..data.dataset import load_feature_file

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
        try:
            load_feature_file(hit)
        except TorchAKVFError as exc:
            log.warning("cache entry %s is damaged (%s); deleting it and computing %s again", hit, exc,
                        item.path)
            hit.unlink(missing_ok=True)
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
