"""Which PSB meshes an evaluation runs and which k's each needs (the batches are planned by
:mod:`torchakvf.pipeline.batches`).

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
from . import psb as P

PROTOCOLS = ("by-segmentation", "by-model")
#: k for meshes without human segmentations (given-k protocols): the median over the 300
#: labelled PSB meshes of their most common human segment count.
DEFAULT_K_NO_GT = 6

__all__ = ["PROTOCOLS", "DEFAULT_K_NO_GT", "PredictionPlan", "select_entries", "parse_ids",
           "find_entries", "plan_meshes", "human_mode"]


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
