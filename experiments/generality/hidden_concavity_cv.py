"""Concave bending hidden in a cavity as a merge term, held out by group (not adopted:
experiments/results/generality_not_adopted.md, "Hidden creases").

The crease at the bottom of a blind hole (a pipe fitting's socket, a cup's inside) is concave
but is where the hole ends, not where a part does. A face's openness is the share of its
``rays`` hemisphere rays (even in solid angle, a fixed frame per face) that travel ``reach``
sqrt(area) without crossing a face ("inf": to infinity); a concave dual edge bending more than
``bend`` degrees is hidden by 1 - min(1, o / ``enough``), o its two faces' mean openness. The
term ``hidden_concavity`` is the length-weighted mean of concave bending x hidden along the
shared boundary, beside TERM_NAMES (its weight can cancel concavity's where the crease is
hidden). Rays are cast only from the faces of the over-segmentations' boundary edges. The
package code this was measured with, end to end, is commit e264c9c (parts/openness.py there).

    PYTHONPATH=$PWD python3 experiments/generality/hidden_concavity_cv.py --capture /tmp/capture \\
        --prep /tmp/capture_prep --variants "16:0.25:0.5:10,32:inf:1:10"
"""
from __future__ import annotations

import argparse
import math
import pickle
import sys
from multiprocessing import get_context
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "segmentation"))
import merge_cv as M  # noqa: E402
import merge_learned_cv as L  # noqa: E402

from torchakvf.mesh.clean import face_cross_products  # noqa: E402
from torchakvf.mesh.raycast import RayCaster  # noqa: E402
from torchakvf.parts.concavity import dual_edges  # noqa: E402
from torchakvf.parts.creases import unit_face_normals  # noqa: E402
from torchakvf.parts.grouping import compact_labels  # noqa: E402
from torchakvf.parts.merge import boundary_bends  # noqa: E402
from torchakvf.parts.merge_terms import TERM_NAMES, MergeState  # noqa: E402
from torchakvf.parts.merge_terms import pair_terms as package_terms  # noqa: E402

NAMES = TERM_NAMES + ("hidden_concavity",)
PACKAGE_STATE = L.new_state


def hemisphere(n: int) -> np.ndarray:
    """[n, 3] unit directions even in solid angle over the hemisphere around +z."""
    i = np.arange(n) + 0.5
    cos_t = 1.0 - i / n
    sin_t = np.sqrt(1.0 - cos_t ** 2)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=1)


def openness(V, F, ids, caster, rays: int, reach: float) -> np.ndarray:
    """[len(ids)] share of the faces' hemisphere rays that travel ``reach`` free."""
    n = unit_face_normals(V, F[ids])
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)
    h = hemisphere(rays)
    d = (h[None, :, 0:1] * t1[:, None] + h[None, :, 1:2] * t2[:, None] + h[None, :, 2:3] * n[:, None]).reshape(-1, 3)
    size = math.sqrt(0.5 * float(np.linalg.norm(face_cross_products(V, F), axis=1).sum()))
    origin = np.repeat(V[F[ids]].mean(axis=1), rays, axis=0) + 1e-6 * size * d
    _, t = caster.first_hit(origin, d, max_t=reach * size)
    return (~np.isfinite(t)).reshape(-1, rays).mean(axis=1)


def hidden_sums(args) -> tuple[str, list]:
    """(key, [K, K] hidden concave bending of each over-segmentation's boundaries) of a capture
    under ``spec`` = "rays:reach:enough:bend"."""
    cap_file, spec = args
    rays, reach, enough, bend = spec.split(":")
    rays, reach = int(rays), (math.inf if reach == "inf" else float(reach))
    enough, bend = float(enough), math.radians(float(bend))
    rec = pickle.load(open(cap_file, "rb"))
    V = np.asarray(rec["mesh"].vertices, dtype=np.float64)
    F = np.asarray(rec["mesh"].faces, dtype=np.int64)
    dual = dual_edges(V, F)
    cav, _ = boundary_bends(dual)
    a, b = dual.pairs[:, 0], dual.pairs[:, 1]
    known = np.full(len(F), np.nan)
    caster = RayCaster(V, F)
    out = []
    for o in rec["overs"]:
        lab, K = compact_labels(o["labels"])
        la, lb = lab[a], lab[b]
        cut = (la != lb) & (la >= 0) & (lb >= 0)
        sel = cut & (dual.dihedral > bend)
        ids = np.unique(np.r_[a[sel], b[sel]])
        todo = ids[np.isnan(known[ids])]
        if len(todo):
            known[todo] = openness(V, F, todo, caster, rays, reach)
        hid = np.where(sel, cav * (1.0 - np.minimum(1.0, 0.5 * (np.nan_to_num(known[a], nan=1.0)
                                                              + np.nan_to_num(known[b], nan=1.0)) / enough)), 0.0)
        H = np.bincount(la[cut] * K + lb[cut], weights=hid[cut], minlength=K * K).reshape(K, K)
        out.append(H + H.T)
    return rec["key"], out


class HiddenState(MergeState):
    """A merge state that also sums the hidden concave bending between parts (``hidden``)."""

    hidden_sum = None

    def merge(self, i, j):
        super().merge(i, j)
        m = self.hidden_sum
        m[i, :] += m[j, :]
        m[:, i] = m[i, :]
        m[i, i] = 0.0
        m[j, :] = m[:, j] = 0.0


def new_state(over: dict) -> HiddenState:
    base = PACKAGE_STATE(over)
    state = HiddenState(**{f: getattr(base, f) for f in base.__dataclass_fields__})
    state.hidden_sum = over["hidden"].copy()
    return state


def pair_terms(state, rows, k):
    T, adjacent = package_terms(state, rows, k)
    L_rows = state.length[rows]
    h = np.where(adjacent, state.hidden_sum[rows] / np.where(adjacent, L_rows, 1.0), 0.0)
    return np.concatenate([T, h[..., None]], axis=-1), adjacent


# the shared merge loop and row recorder read this script's terms
M.use_terms(pair_terms, new_state, len(NAMES))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", required=True)
    ap.add_argument("--prep", required=True, help="merge_cv.py's preparation of the same captures")
    ap.add_argument("--variants", default="16:0.25:0.5:10", help="comma-separated rays:reach:enough:bend")
    ap.add_argument("--corpus-share", type=float, default=0.5)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    M.load_prep(Path(a.prep))
    files = sorted(Path(a.capture).glob("*.pkl"))
    ctx = get_context("fork")

    def setup(spec: str) -> str:
        with ctx.Pool(2) as pool:
            for key, sums in pool.map(hidden_sums, [(f, spec) for f in files]):
                for over, H in zip(M.PREP[key]["overs"], sums):
                    over["hidden"] = H
        return "rays {}, reach {}, enough {}, bend {}°".format(*spec.split(":"))

    results = M.held_out_with_term("hidden_concavity", NAMES, a.variants.split(","), setup,
                                   M.hand_set_policy(1), ctx, a.corpus_share)
    M.report(results, a.out)


if __name__ == "__main__":
    main()
