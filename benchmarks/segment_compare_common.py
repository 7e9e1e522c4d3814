"""What benchmarks/compare_segment.py and benchmarks/profile_segment.py share: run
``segment_rounds`` of one engine module and keep every (mesh, k)'s answer, and compare a
baseline's answers with the new code's (labels and costs bitwise, refined meshes where kept)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from torchakvf.evaluate import psb as P
from torchakvf.evaluate.metrics import rand_index_error
from torchakvf.io import load_mesh
from torchakvf.mesh import MeshBatch


@dataclass
class Answer:
    """One (mesh, k)'s result: labels [F] (input faces), k-means cost, the RefinedMesh or None."""

    labels: np.ndarray
    cost: float
    refined: object = None


def solved_psb_meshes(ids, engine, coarse_faces: int = 4000, n: int = 36):
    """Yields (position, PSB mesh id, its distinct human segment counts ascending, its AKVFs)
    for each of ``ids``: the mesh decimated to ``coarse_faces`` and n AKVFs solved with
    ``engine``'s solve_akvfs, as ``torchakvf eval`` solves them."""
    ents = {e.mesh_id: e for e in P.find_psb_meshes(P.default_psb_root())}
    for j, i in enumerate(ids):
        e = ents[i]
        mb = MeshBatch.from_meshes([load_mesh(e.mesh_path)], coarse_faces=coarse_faces)
        fields, _ = engine.solve_akvfs(mb, n, engine.SegmentOptions(refine=False))
        yield j, i, sorted(set(P.human_segment_counts(e))), fields


def segment_answers(eng, fields, ks, opts, prof=None, clock=time.process_time):
    """({(b, k): Answer} of ``eng.segment_rounds(fields, ks, opts)``, seconds on ``clock``).

    eng : an engine module (this checkout's or a baseline's); ks : per mesh, its k's;
    prof : a cProfile.Profile enabled around the rounds only, or None."""
    t0 = clock()
    if prof is not None:
        prof.enable()
    out = {}
    for rnd in eng.segment_rounds(fields, ks, opts):
        for b in rnd.active:
            m = rnd.meshes[b]
            out[(b, rnd.ks[b])] = Answer(np.asarray(m.labels).copy(), float(m.cost), m.refined)
    if prof is not None:
        prof.disable()
    return out, clock() - t0


def same_refined(a, b) -> bool:
    """Two RefinedMesh (or None) bitwise equal: vertices, faces, labels, parent."""
    if a is None or b is None:
        return a is b
    return all(getattr(a, n).dtype == getattr(b, n).dtype and getattr(a, n).shape == getattr(b, n).shape
               and getattr(a, n).tobytes() == getattr(b, n).tobytes()
               for n in ("vertices", "faces", "labels", "parent"))


@dataclass
class Difference:
    key: tuple          # (b, k)
    changed: float      # fraction of faces whose label id differs
    rand_error: float   # 1-RI between the two partitions (0: the same partition, other ids)


@dataclass
class AnswerComparison:
    """Running counts over every (mesh, k) compared: identical labels, costs, refined meshes."""

    total: int = 0
    same_labels: int = 0
    same_cost: int = 0
    same_refined: int = 0
    differ: list = field(default_factory=list)

    def add(self, base: dict, new: dict) -> list:
        """Compare ``base`` and ``new`` ({(b, k): Answer}, same keys); the new Differences."""
        found = []
        for key, a in base.items():
            n = new[key]
            self.total += 1
            self.same_labels += bool(np.array_equal(a.labels, n.labels))
            self.same_cost += a.cost == n.cost
            self.same_refined += same_refined(a.refined, n.refined)
            if not np.array_equal(a.labels, n.labels):
                found.append(Difference(key, float(np.mean(a.labels != n.labels)),
                                        float(rand_index_error(a.labels, n.labels))))
        self.differ += found
        return found
