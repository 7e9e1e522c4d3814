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
from ..mesh.size_check import check_fields_fit
from ..mesh.subdivide import levels_to_fit, subdivide
from ..options import SegmentOptions, segment_options
from ..parts.field_counts import akvf_count
from ..parts.k_auto import DEFAULT_K_RANGE, DEFAULT_RULE, check_k_range, is_auto, scan_akvf_count, scan_options
from ..parts.results import Segmentation
from ..parts.rounds import cut_mesh_rounds, mesh_cut_job, segment_rounds
from ..parts.segment import segment_each_k
from ..parts.segmenter import Segmenter
from ..parts.solve import solve_akvfs


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
    """k parts per mesh (see the module notes).

    k : parts per mesh, or "auto": chosen per mesh from ``k_range`` by ``k_rule``
        (:mod:`torchakvf.parts.k_auto`; the manifest records the k each mesh got)
    options : the :class:`~torchakvf.options.SegmentOptions` (None: the defaults); ``refine``
        is off whatever it says, since the task writes labels only
    n_fields : fields untangled per mesh (None: segment's own choice, moved off degenerate
        eigenvalue clusters, from AKVFs computed with spare fields so a cluster cut can be seen)
    coarse_faces : solve on meshes decimated to about this many faces (None: full resolution);
        the labels are cut on the input's faces either way (:mod:`torchakvf.mesh.coarse`)
    formats : the outputs per mesh (:data:`torchakvf.io.OUTPUT_FORMATS`)
    subdivide : subdivide a mesh with too few edges for its fields at its edge midpoints until
        it has enough (:func:`~torchakvf.mesh.subdivide.subdivide`; labels stay one per face
        of the file); False: such a mesh fails with what the user can do
    overrides : SegmentOptions fields by name, e.g. ``SegmentTask(6, seed=1, method="paper")``
    """

    name = "segment"
    stages = ("akvf", "untangle", "cluster")

    def __init__(self, k, options: SegmentOptions | None = None, *, n_fields: int | None = None,
                 coarse_faces: int | None = None, formats=OUTPUT_FORMATS, subdivide: bool = False,
                 k_range=DEFAULT_K_RANGE, k_rule: str = DEFAULT_RULE, **overrides):
        self.auto = is_auto(k)
        self.k = "auto" if self.auto else int(k)
        self.k_range, self.k_rule = check_k_range(k_range), k_rule
        self.k_max = self.k_range[1] if self.auto else self.k       # the largest k a mesh may get
        # one-line errors before any work; k auto without options: the scan's merge weights
        opts = scan_options(options, overrides) if self.auto else segment_options(options, **overrides)
        self.options = opts.replace(refine=False)
        self.n_fields = int(n_fields) if n_fields is not None else None
        o = self.options
        if self.auto:
            self.n_akvf = scan_akvf_count(self.k_max, self.n_fields)
        else:
            self.n_akvf = (self.n_fields if n_fields is not None
                           else akvf_count([[self.k]], None, o.method, o.merge_min_k))
        self.formats = tuple(formats)
        self.coarse_faces = int(coarse_faces) if coarse_faces else None
        self.subdivide = bool(subdivide)

    @property
    def seed(self) -> int:
        return self.options.seed

    @property
    def params(self) -> dict:
        """What the manifest records: a run resumed under other options (merge weights and
        graph cut included) redoes its meshes."""
        o = self.options
        n_fields = self.n_fields if self.n_fields is not None else "auto"
        batched = {} if o.batched is None else {"batched": o.batched}   # earlier manifests resume
        auto = {"k_range": list(self.k_range), "k_rule": self.k_rule} if self.auto else {}
        return {**batched, "k": self.k, **auto, "eps": float(o.eps), "seed": int(o.seed), "n_fields": n_fields,
                "remedy": o.remedy, "formats": list(self.formats),
                "untangle_restarts": int(o.untangle_restarts), "kmeans_restarts": o.kmeans_restarts,
                "coarse_faces": self.coarse_faces, "subdivide": self.subdivide, "solver": o.solver,
                "method": o.method,
                "merge": o.merge_record(), "merge_choice": o.choice_record(),
                "graphcut": None if o.graphcut is None else dataclasses.asdict(o.graphcut)}

    def output_paths(self, out_dir, stem: str) -> list[Path]:
        return [Path(out_dir) / f"{stem}.{fmt}" for fmt in self.formats]

    def validate(self, item) -> None:
        n_faces = len(item.clean.faces)
        if self.k_max > n_faces:
            what = f"-k auto tries k up to {self.k_max}, which" if self.auto else f"-k {self.k}"
            raise ParameterError(f"{item.path}: {what} is larger than the mesh's {n_faces} faces")
        if self.subdivide:
            # the eigensolvers need more edges than fields
            levels = levels_to_fit(item.clean, self.n_akvf + 1)
            if levels:
                item.clean = subdivide(item.clean, levels)
        opts = self.options
        fields_for_k = ((lambda j: scan_akvf_count(j, self.n_fields)) if self.auto
                        else lambda j: akvf_count([[j]], self.n_fields, opts.method, opts.merge_min_k))
        check_fields_fit(str(item.path), item.clean.faces, self.n_akvf, k=self.k_max,
                         subdivide_hint="subdivide it (--subdivide)", fields_for_k=fields_for_k)

    def process(self, items, device):
        t0 = time.perf_counter()
        batch = MeshBatch.from_meshes([it.clean for it in items], device=device,
                                      coarse_faces=self.coarse_faces)
        t_pack = time.perf_counter() - t0
        if self.auto:
            sg = Segmenter(batch, self.options, n=self.n_akvf, n_fields=self.n_fields)
            seg, res = sg.segment("auto", k_range=self.k_range, k_rule=self.k_rule), sg
        else:
            res = segment_each_k(batch, self.k, self.options, n_fields=self.n_fields, n=self.n_akvf)
            seg = res.segmentation(self.k)
        # The untangled fields draw the PNG's generator arrows.
        vectors = [seg.face_vectors(b) if "png" in self.formats else None for b in range(len(items))]
        seconds = dict(res.seconds)
        seconds["akvf"] += t_pack     # the manifest has no stage of its own for packing
        return list(zip(seg.meshes, vectors)), seconds

    @property
    def overlappable(self) -> bool:
        """Whether the batched path may split this task into :meth:`solve_prepared` and
        :meth:`cut`: not with k auto, whose scan cuts every k of a mesh to read its merge costs
        (it runs whole, by :meth:`process`)."""
        return not self.auto

    def solve_prepared(self, batch, items=None):
        """The batched path's device half of :meth:`process` (:mod:`.batched_run`): the AKVFs,
        untangling and k-means of a packed batch, its parts not cut. Returns (one picklable cut
        input per mesh: its :class:`~torchakvf.parts.rounds.MeshCutJob` and PNG arrows,
        {"akvf", "untangle", "cluster", "jobs": seconds})."""
        t0 = time.perf_counter()
        fields, _ = solve_akvfs(batch, self.n_akvf, self.options)
        t1 = time.perf_counter()
        rounds = list(segment_rounds(fields, self.k, self.options, n_fields=self.n_fields, cut=False))
        t2 = time.perf_counter()
        seg = Segmentation([None] * len(batch), untangled=rounds[0].untangled)
        inputs = [(mesh_cut_job(fields, rounds, b), seg.face_vectors(b) if "png" in self.formats else None)
                  for b in range(len(batch))]
        seconds = {"akvf": t1 - t0, **rounds[0].seconds, "jobs": time.perf_counter() - t2}
        return inputs, seconds

    def cut(self, cut_input):
        """The host half of :meth:`process` for one mesh: its parts cut from its job, as
        :meth:`process` returns them."""
        job, vectors = cut_input
        (_, ms), = cut_mesh_rounds(job, self.options)
        return ms, vectors

    @staticmethod
    def manifest_fields(out) -> dict:
        """Per mesh, what the manifest records beside the runner's own fields: whether its
        eigensolve converged and its largest eigenpair residual, and with -k auto the k it got
        (``out``: from :meth:`process`)."""
        ms, _ = out
        chosen = {"k": ms.k} if "k_auto" in ms.params else {}      # the k a mesh got with -k auto
        return {"converged": bool(ms.converged), "max_residual": float(ms.max_residual), "remedy": ms.params["remedy"],
                **chosen}

    def write(self, item, out, out_dir) -> list[Path]:
        ms, vectors = out
        written = write_segmentation(ms, item.mesh.vertices, item.mesh.faces, out_dir, item.stem,
                                     formats=self.formats, face_vectors=vectors)
        return list(written.values())
