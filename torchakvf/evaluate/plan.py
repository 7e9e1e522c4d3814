"""Which PSB meshes an evaluation runs, which k's each needs, and in which batches.

Problems with one input (an unreadable mesh header, a bad human ``.seg``, a corrupt meta file)
are collected as lines naming the file, so that the rest of the run goes on: see
:class:`PredictionPlan` ``.problems`` and :func:`plan_meshes`.
"""
from __future__ import annotations

import collections
import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import MeshError, ParameterError, TorchAKVFError
from ..io import load_mesh, peek_face_count
from ..mesh.coarse import DECIMATE_ABOVE
from ..pipeline.runner import default_batch_faces
from ..pipeline.batches import cut_by_budget
from . import psb as P

PROTOCOLS = ("by-segmentation", "by-model")
#: k for meshes without human segmentations (given-k protocols): the median over the 300
#: labelled PSB meshes of their most common human segment count.
DEFAULT_K_NO_GT = 6

__all__ = ["PROTOCOLS", "DEFAULT_K_NO_GT", "PredictionPlan", "select_entries", "parse_ids",
           "find_entries", "plan_meshes", "settings_guard", "make_batches", "balanced_batches", "mesh_work",
           "solved_face_counts", "default_eval_batch_faces", "human_mode", "batches_per_worker"]


def human_mode(counts) -> int:
    """Most common segment count (ties: the smaller)."""
    c = collections.Counter(int(v) for v in counts)
    return min(c, key=lambda v: (-c[v], v))



@dataclass
class PredictionPlan:
    """One mesh of an evaluation: what it needs and where its predictions go.

    entry : the PSB entry, its ``seg_paths`` reduced to the human segmentations that can be used
    counts : their segment counts (k order), [] without usable ones
    ks : the k's this mesh's score needs (empty with k = auto)
    faces : the input's face count (from the header)
    problems : one line per bad input of this mesh (a human .seg left out, a corrupt meta file)
    failure : why the mesh cannot be evaluated at all, or None
    """

    entry: P.PSBEntry
    counts: list
    ks: list
    pred_dir: Path
    faces: int = 0
    problems: list = field(default_factory=list)
    failure: str | None = None

    @property
    def mesh_id(self) -> int:
        return self.entry.mesh_id

    def pred_path(self, k: int) -> Path:
        return self.pred_dir / f"{self.mesh_id}_k{k}.seg"

    @property
    def meta_path(self) -> Path:
        return self.pred_dir / f"{self.mesh_id}_meta.json"

    def meta(self) -> dict:
        """The mesh's meta file ({} when there is none); TorchAKVFError naming it when corrupt."""
        try:
            text = self.meta_path.read_text()
        except FileNotFoundError:
            return {}
        except OSError as exc:
            raise TorchAKVFError(f"{self.meta_path}: cannot read ({exc})") from None
        try:
            meta = json.loads(text)
            if not isinstance(meta, dict):
                raise ValueError("not a JSON object")
        except ValueError as exc:
            raise TorchAKVFError(f"{self.meta_path}: corrupt meta file ({exc}); delete it (and "
                                 f"the mesh's predictions) to predict the mesh again") from None
        return meta

    def auto_k(self) -> int | None:
        k = self.meta().get("auto", {}).get("chosen")
        return int(k) if k is not None else None

    def missing(self, auto: bool) -> list:
        if auto:
            k = self.auto_k()
            return ["auto"] if k is None or not self.pred_path(k).is_file() else []
        return [k for k in self.ks if not self.pred_path(k).is_file()]


def parse_ids(text: str) -> list[int]:
    """``"1,5,21-23"`` -> [1, 5, 21, 22, 23]."""
    out = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if "-" in part:
                a, b = part.split("-", 1)
                out.extend(range(int(a), int(b) + 1))
            else:
                out.append(int(part))
        except ValueError:
            raise TorchAKVFError(f"bad mesh id {part!r} in --ids (use e.g. 1,5,21-23)") from None
    return out


def select_entries(entries, categories=None, ids=None, per_category=None) -> list:
    """The entries of the given categories (names, or a comma string), ids (ints, or a string
    like "1,5,21-23") and at most ``per_category`` per category (the first by id)."""
    if categories is not None:
        if isinstance(categories, str):
            categories = [c for c in categories.split(",") if c.strip()]
        lookup = {c.lower(): c for c in P.BENCHMARK_CATEGORIES}
        wanted = []
        for c in categories:
            c = c.strip()
            if c.lower() in {a.lower() for a in P.ABSENT_CATEGORIES}:
                raise TorchAKVFError(f"category {c!r} has no meshes in the benchmark")
            if c.lower() not in lookup:
                raise TorchAKVFError(f"unknown PSB category {c!r}; choose from "
                                     f"{', '.join(P.BENCHMARK_CATEGORIES)}")
            wanted.append(lookup[c.lower()])
        entries = [e for e in entries if e.category in set(wanted)]
    if ids is not None:
        if isinstance(ids, str):
            ids = parse_ids(ids)
        ids = sorted({int(i) for i in ids})
        have = {e.mesh_id for e in entries}
        missing = [i for i in ids if i not in have]
        if missing:
            raise TorchAKVFError(f"PSB mesh id(s) {', '.join(map(str, missing[:10]))} not found "
                                 f"(among the selected categories)")
        entries = [e for e in entries if e.mesh_id in set(ids)]
    if per_category is not None:
        if int(per_category) < 1:
            raise TorchAKVFError(f"per_category must be >= 1, got {per_category}")
        seen = collections.Counter()
        kept = []
        for e in entries:  # sorted by id: the first N of each category
            if seen[e.category] < int(per_category):
                kept.append(e)
                seen[e.category] += 1
        entries = kept
    return entries




def find_entries(root: Path) -> tuple[list, list]:
    """(PSB entries, problem lines): :func:`torchakvf.evaluate.psb.find_psb_meshes`, except that
    a mesh file with an id outside 1..400 or a ``.seg`` in another mesh's folder is a problem
    line naming the file (left out) instead of the end of the run."""
    problems: list = []
    try:
        entries = P.find_psb_meshes(root, problems=problems)
    except FileNotFoundError as exc:
        raise TorchAKVFError(str(exc)) from None
    return entries, problems


def _usable_humans(entry, faces: int) -> tuple[list, list, list]:
    """(seg paths that can be scored against, their segment counts, problem lines)."""
    ok, counts, problems = [], [], []
    for s in entry.seg_paths:
        try:
            lab = P.read_seg(s)
        except (ParameterError, OSError) as exc:   # empty, non-integer, unreadable
            problems.append(f"{exc if str(s) in str(exc) else f'{s}: {exc}'}; human segmentation left out")
            continue
        if faces and lab.size != faces:
            problems.append(f"{s}: {lab.size} labels for the mesh's {faces} faces; human "
                            f"segmentation left out")
            continue
        ok.append(s)
        counts.append(P.segment_count(lab))
    return ok, counts, problems


def plan_meshes(entries, out: Path, protocol: str, auto: bool, default_k: int) -> list:
    """One :class:`PredictionPlan` per entry: its face count, usable humans and k's."""
    plans = []
    for e in entries:
        plan = PredictionPlan(e, [], [], out / "pred" / str(e.mesh_id))
        plans.append(plan)
        try:
            faces = peek_face_count(e.mesh_path)
            if faces is None:
                faces = load_mesh(e.mesh_path).n_faces
        except MeshError as exc:
            plan.failure = str(exc)
            continue
        plan.faces = int(faces)
        segs, counts, plan.problems = _usable_humans(e, plan.faces)
        if e.seg_paths and not segs:
            plan.failure = "none of its human segmentations can be used (see the problems above)"
        plan.entry, plan.counts = dataclasses.replace(e, seg_paths=segs), counts
        try:
            plan.meta()
        except TorchAKVFError as exc:
            plan.problems.append(str(exc))
            plan.failure = f"corrupt meta file {plan.meta_path.name} (kept, not replaced)"
            continue
        if auto:
            plan.ks = []
        elif not counts:
            plan.ks = [int(default_k)]
        elif protocol == "by-segmentation":
            plan.ks = sorted(set(counts))
        else:
            plan.ks = [human_mode(counts)]
    return plans


def settings_guard(out: Path, prediction_settings: dict) -> None:
    """Refuse to mix predictions made with different settings in one folder (a corrupt
    settings.json is an error naming it, not silently replaced)."""
    path = out / "settings.json"
    if path.is_file():
        try:
            old = json.loads(path.read_text()).get("prediction")
        except (ValueError, AttributeError) as exc:
            raise TorchAKVFError(f"{path}: corrupt settings file ({exc}); delete it (with the "
                                 f"predictions it describes) or use another --out") from None
        diff = [] if old is None else sorted(k for k in set(old) | set(prediction_settings)
                                             if old.get(k) != prediction_settings.get(k))
        if diff:  # a setting added later, absent from an old file, reads as its default None
            raise TorchAKVFError(f"{out}: holds predictions made with other settings "
                                 f"({', '.join(diff)} differ); use another --out or delete it")


def default_eval_batch_faces(device, coarse_faces=None) -> int:
    """The face budget of a batch by default: the corpus runner's for the device; on CPU with
    decimation, one decimated mesh per batch (the cores are used by worker processes instead,
    and a batch re-solves every mesh when one of them needs more eigenpairs)."""
    if coarse_faces and str(device).startswith("cpu"):
        return int(DECIMATE_ABOVE * coarse_faces)
    return default_batch_faces(device)


def solved_face_counts(faces_of: dict, coarse_faces) -> dict:
    """{mesh id: faces of the mesh the solver sees}: the input's, or about ``coarse_faces`` for
    a mesh that will be decimated (the face budget of a batch counts what is solved)."""
    if not coarse_faces:
        return dict(faces_of)
    return {i: (f if f <= DECIMATE_ABOVE * coarse_faces else int(coarse_faces)) for i, f in faces_of.items()}


#: Batches per worker on the CPU: as many as there are meshes (each mesh its own batch) where
#: several workers share the meshes. A CPU batch is solved one mesh at a time inside, so its
#: size gains nothing and only sets how finely the work is shared; coarser shares lose to the
#: error of the work estimate. PSB 1-40 decimated, 2 workers, batched / one mesh per batch in
#: wall time: 0.90 at a budget of 80,000 faces with one batch per worker
#: (benchmarks/results/bench_budget_sweep_cpu_v4_base.md), 1.00 with 4 per worker
#: (bench_budget_sweep_cpu_v4.md), then 0.96 at 20,000 faces in a later run with 4 per worker
#: (bench_budget_sweep_cpu_v5_base.md): never better than one mesh per batch.
CPU_BATCHES_PER_WORKER = None


def batches_per_worker(device) -> int | None:
    """:data:`CPU_BATCHES_PER_WORKER` on the CPU (None: one mesh per batch where there are
    several workers); 1 elsewhere (on a GPU batching is the gain)."""
    return CPU_BATCHES_PER_WORKER if str(device).startswith("cpu") else 1


def make_batches(plans, faces_of: dict, budget: int, *, workers: int = 1, work_of: dict | None = None,
                 per_worker: int | None = 1) -> list:
    """Plans grouped into batches of at most ``budget`` faces (``faces_of``: by mesh id); a mesh
    larger than the budget is a batch alone.

    One worker: consecutive plans (the caller's order groups meshes alike, which keeps the
    batch's padding small). Several workers, with ``work_of`` (estimated work by mesh id):
    batches of equal work instead, at least one per worker, still under the budget: with as
    few batches as workers, consecutive meshes sorted by their k's gave one worker the
    meshes with the most k's (PSB 1-40 at a budget of 80,000 faces: 43.4 s against 33.1 s one
    mesh per batch). With ``per_worker``, at least that many batches per worker (where there
    are meshes enough), for a finer share of the work; None: one mesh per batch
    (:func:`batches_per_worker`). Each mesh's answer depends on that mesh alone, so the grouping
    changes no answer."""
    consecutive = cut_by_budget(plans, lambda p: faces_of[p.mesh_id], budget)
    if workers <= 1 or work_of is None or len(plans) <= 1:
        return consecutive
    wanted = len(plans) if per_worker is None else workers * max(1, int(per_worker))
    count = max(len(consecutive), min(wanted, len(plans)))
    return balanced_batches(plans, faces_of, budget, work_of, count)


def balanced_batches(plans, faces_of: dict, budget: int, work_of: dict, count: int) -> list:
    """``count`` batches (more where the budget needs them) of about equal work: the plans,
    heaviest first, each into the lightest batch it fits in under ``budget`` faces (a new batch
    where it fits in none). Each batch keeps the plans' given order; empty batches are dropped."""
    index = {id(p): i for i, p in enumerate(plans)}
    bins: list = [[] for _ in range(count)]
    work, faces = [0.0] * count, [0] * count
    for p in sorted(plans, key=lambda p: (-work_of[p.mesh_id], index[id(p)])):
        f = faces_of[p.mesh_id]
        fits = [j for j in range(len(bins)) if not bins[j] or faces[j] + f <= budget]
        if not fits:
            bins.append([]), work.append(0.0), faces.append(0)
            fits = [len(bins) - 1]
        j = min(fits, key=lambda j: (work[j], j))
        bins[j].append(p)
        work[j] += work_of[p.mesh_id]
        faces[j] += f
    return [sorted(b, key=lambda p: index[id(p)]) for b in bins if b]


def mesh_work(faces_of: dict, ks_of: dict) -> dict:
    """{mesh id: estimated work}: faces x (1 + k's to segment); the parts are cut on the
    input's faces once per k (``faces_of``: input faces, ``ks_of``: k's still to segment)."""
    return {i: faces_of[i] * (1 + ks_of[i]) for i in ks_of}


def heaviest_first(batches: list, faces_of: dict, ks_of: dict) -> list:
    """The batches in the order to hand them to workers: the most work first (longest
    processing time first), ties in the given order. Work is estimated as Σ faces x (1 + k's)
    over a batch's meshes (``faces_of``, ``ks_of``: input faces and k's still to segment, by
    mesh id): the parts are cut on the input's faces once per k.

    The batches themselves are not changed, so neither is any answer; with the heaviest last
    (as sorted for batching), one worker finished a 41 s mesh alone at the end of the PSB run."""
    per_mesh = mesh_work(faces_of, ks_of)
    work = [sum(per_mesh[p.mesh_id] for p in b) for b in batches]
    return [batches[i] for i in sorted(range(len(batches)), key=lambda i: -work[i])]
