"""The terms of a merge decision between two adjacent parts, and the parts' state as they merge.

What tells a protrusion (a fin, a leg, a handle) from half a body, as part perception describes
it: the minima rule (a boundary on a concave crease), the short-cut rule (a short boundary for
the part it cuts off), thickness (a fin or a leg is thinner than the body it joins: the shape
diameter function, the mean length of rays shot inwards), centricity (a protrusion lies away from
the middle), size against the parts wanted (A / k), and the symmetry of the untangled fields (two
parts moved by the same fields are one symmetric part cut in two).

:class:`MergeState` holds the additive sums of a region graph (areas, boundary lengths, bending
and thickness sums), so merging two parts is adding rows; :func:`pair_terms` reads the terms of
a set of parts with every other part off them. Host-side numpy; the per-face work
(:func:`face_thickness`, :func:`part_sums`) is vectorized.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..mesh.raycast import RayCaster
from .sightlines import join_counts

#: names of the columns of :func:`pair_terms`, in order (the learned merge's inputs)
TERM_NAMES = ("symmetry", "concavity", "convexity", "share", "small", "size_ratio", "short_cut",
              "thickness", "thin", "centricity", "sight", "sight_excess")

#: rays shot per sampled face by :func:`face_thickness` (in a 60° cone around the inward normal)
THICKNESS_RAYS = 8
#: faces sampled by :func:`face_thickness` (evenly by index): part means need no more
THICKNESS_FACES = 1000


def cone_directions(n_rays: int) -> np.ndarray:
    """[n_rays, 3] fixed unit directions in a 60° cone around -z (local frame: z the outward
    normal), on a golden-angle spiral: every mesh and every call shoots the same rays."""
    i = np.arange(n_rays) + 0.5
    cos_t = 1.0 - i / n_rays * (1.0 - math.cos(math.pi / 3))     # uniform in solid angle
    sin_t = np.sqrt(1.0 - cos_t ** 2)
    phi = i * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), -cos_t], axis=1)


def face_thickness(vertices: np.ndarray, faces: np.ndarray, n_rays: int = THICKNESS_RAYS,
                   max_faces: int = THICKNESS_FACES, caster: RayCaster | None = None) -> np.ndarray:
    """[F] shape diameter function (mesh units) at the centroids of about ``max_faces`` faces
    taken evenly by index, NaN at the others and where no ray hit.

    Each sampled face shoots ``n_rays`` fixed rays (:func:`cone_directions`) inwards, opposite
    its outward normal (faces counter-clockwise from outside); the thickness is the mean hit
    distance of the rays within 1.5 of their median (an SDF as Shapira et al. define it, without
    the random directions of libigl's, so the same mesh gets the same bits). Rays are cast on
    libigl's AABB tree at any unit of length (:class:`~torchakvf.mesh.raycast.RayCaster`; the
    mesh's own if at hand: ``caster``)."""
    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.ascontiguousarray(faces, dtype=np.int64)
    out = np.full(len(F), np.nan)
    if len(F) == 0:
        return out
    pick = np.unique(np.linspace(0, len(F) - 1, min(int(max_faces), len(F))).astype(np.int64))
    tri = V[F[pick]]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normal, axis=1)
    ok = norm > 0
    pick, tri, normal = pick[ok], tri[ok], normal[ok] / norm[ok, None]
    # an orthonormal frame (t1, t2, n) per face
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normal, t1)
    cone = cone_directions(n_rays)
    dirs = (cone[None, :, 0:1] * t1[:, None] + cone[None, :, 1:2] * t2[:, None]
            + cone[None, :, 2:3] * normal[:, None]).reshape(-1, 3)
    scale = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0))) or 1.0
    origin = np.repeat(tri.mean(axis=1), n_rays, axis=0) + 1e-7 * scale * dirs
    _, t = (caster or RayCaster(V, F)).first_hit(origin, dirs)
    t = t.reshape(-1, n_rays)
    t[~np.isfinite(t)] = np.nan
    # the median of the hits of each face (NaN where none hit), without nanmedian's warning
    n_hit = np.isfinite(t).sum(axis=1)
    srt = np.sort(t, axis=1)                                    # NaN last
    lo = srt[np.arange(len(t)), np.maximum(n_hit - 1, 0) // 2]
    hi = srt[np.arange(len(t)), np.maximum(n_hit, 1) // 2]
    med = np.where(n_hit > 0, 0.5 * (lo + hi), np.nan)
    with np.errstate(invalid="ignore"):
        near = np.abs(t - med[:, None]) <= 0.5 * med[:, None]
    out[pick] = np.where(n_hit > 0, np.where(near, t, 0.0).sum(axis=1) / np.maximum(near.sum(axis=1), 1), np.nan)
    return out


@dataclass
class MergeState:
    """Additive sums of the parts of a region graph (K parts), updated as parts merge.

    area : [K]; mean : [K, n] area-weighted mean unit feature row; length, concave, convex :
    [K, K] symmetric shared-boundary length and its length-weighted bending sums;
    thick, thick_area : [K] Σ a_f s_f and Σ a_f over the part's faces with a thickness s_f;
    centroid : [K, 3] Σ a_f c_f; center : [3] the surface's area centroid; radius : its RMS
    distance to it; total : the surface area; seen, lines : [K, K] of the segments between the
    parts' samples (the diagonal: between a part's own samples), those that stay inside the solid
    and all of them (:class:`~torchakvf.parts.sightlines.SightLines`); vector_area : [K, 3]
    Σ a_f n_f over each part's faces (n_f the unit outward normal; :meth:`flatness`). (thick,
    centroid, seen, vector_area None: not computed.)
    """

    area: np.ndarray
    mean: np.ndarray
    length: np.ndarray
    concave: np.ndarray
    convex: np.ndarray
    thick: np.ndarray | None = None
    thick_area: np.ndarray | None = None
    centroid: np.ndarray | None = None
    center: np.ndarray | None = None
    radius: float = 1.0
    thick_median: float = 1.0
    seen: np.ndarray | None = None
    lines: np.ndarray | None = None
    vector_area: np.ndarray | None = None

    @property
    def total(self) -> float:
        return max(float(self.area.sum()), 1e-300)

    def flatness(self) -> np.ndarray | None:
        """[K] |Σ a_f n_f| / Σ a_f of each part, in [0, 1]: 1 for a plane patch, 0 for a closed
        surface; for a part cut off a solid, the area of a surface spanning its boundary over
        its own. 0 for an emptied part; None without vector areas."""
        if self.vector_area is None:
            return None
        norm = np.linalg.norm(self.vector_area, axis=1)
        return np.where(self.area > 0, norm / np.maximum(self.area, 1e-300), 0.0)

    def merge(self, i: int, j: int) -> None:
        """Part j joins part i (j's rows become zero)."""
        tot = self.area[i] + self.area[j]
        self.mean[i] = (self.area[i] * self.mean[i] + self.area[j] * self.mean[j]) / max(tot, 1e-300)
        self.area[i], self.area[j] = tot, 0.0
        self.mean[j] = 0.0
        for vec in (self.thick, self.thick_area, self.centroid, self.vector_area):
            if vec is not None:
                vec[i] += vec[j]
                vec[j] = 0.0
        for mat in (self.seen, self.lines):
            if mat is not None:
                join_counts(mat, i, j)
        for mat in (self.length, self.concave, self.convex):
            mat[i, :] += mat[j, :]
            mat[:, i] = mat[i, :]
            mat[i, i] = 0.0
            mat[j, :] = mat[:, j] = 0.0


def part_sums(labels: np.ndarray, n_parts: int, face_area: np.ndarray, centroids: np.ndarray,
              thickness: np.ndarray | None) -> dict:
    """The per-part sums :class:`MergeState` adds beyond a region graph's: labels [F] compact
    part ids (negative: left out), face_area [F], centroids [F, 3] face centroids, thickness [F]
    (:func:`face_thickness`, NaN where not known; None: not computed)."""
    keep = labels >= 0
    lab, a = labels[keep], face_area[keep]
    c = centroids[keep]
    total = max(float(a.sum()), 1e-300)
    center = (a[:, None] * c).sum(axis=0) / total
    radius = math.sqrt(float((a * ((c - center) ** 2).sum(axis=1)).sum()) / total) or 1.0
    out = dict(centroid=np.stack([np.bincount(lab, weights=a * c[:, d], minlength=n_parts) for d in range(3)], axis=1),
               center=center, radius=radius)
    if thickness is not None:
        s = thickness[keep]
        known = np.isfinite(s)
        out["thick"] = np.bincount(lab[known], weights=(a * s)[known], minlength=n_parts)
        out["thick_area"] = np.bincount(lab[known], weights=a[known], minlength=n_parts)
        out["thick_median"] = float(np.median(s[known])) if known.any() else 1.0
    return out


def pair_terms(state: MergeState, rows: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """([len(rows), K, T] terms of each part of ``rows`` with every part, T = len(TERM_NAMES);
    [len(rows), K] whether the two are adjacent). Columns (each dimensionless):

    symmetry 1 - cos(m_i, m_j); concavity, convexity the length-weighted mean bending along the
    shared boundary; share 1 - L_ij / min(P_i, P_j); small min(A_i, A_j) k / A (the smaller part
    against the part size wanted); size_ratio log(A_max / A_min); short_cut
    log(L_ij / sqrt(A_min)) (a short cut for the part cut off); thickness |log(t_i / t_j)|
    (t a part's mean shape diameter); thin log(t_small / t_median), t of the smaller part
    against the mesh's median thickness; centricity (d_small - d_large) / R, d a part
    centroid's distance to the surface's centroid, R the RMS radius (a protrusion lies
    further out); sight 1 - seen_ij / lines_ij, the share of the segments between the two parts'
    samples that leave the solid (:mod:`torchakvf.parts.sightlines`); sight_excess that share less
    the mean of the two parts' own (a hollow part's inside and outside never see each other, a
    flat or convex one's always do). Terms whose sums are missing are 0."""
    rows = np.asarray(rows)
    area, length = state.area, state.length
    L = length[rows]
    adjacent = L > 0
    T = np.zeros(L.shape + (len(TERM_NAMES),))
    mn = np.linalg.norm(state.mean, axis=1)
    cos = (state.mean[rows] @ state.mean.T) / np.maximum(np.outer(mn[rows], mn), 1e-300)
    T[..., 0] = 1.0 - np.clip(cos, -1.0, 1.0)
    safe_l = np.where(adjacent, L, 1.0)
    T[..., 1] = np.where(adjacent, state.concave[rows] / safe_l, 0.0)
    T[..., 2] = np.where(adjacent, state.convex[rows] / safe_l, 0.0)
    perim = length.sum(axis=1)
    share = L / np.maximum(np.minimum.outer(perim[rows], perim), 1e-300)
    T[..., 3] = np.where(adjacent, 1.0 - np.clip(share, 0.0, 1.0), 0.0)
    a_min = np.maximum(np.minimum.outer(area[rows], area), 1e-300)
    a_max = np.maximum(np.maximum.outer(area[rows], area), 1e-300)
    T[..., 4] = a_min * k / state.total
    T[..., 5] = np.log(a_max / a_min)
    T[..., 6] = np.where(adjacent, np.log(safe_l / np.sqrt(a_min)), 0.0)
    i_small = area[rows][:, None] <= area[None, :]          # is the row's part the smaller one
    if state.thick is not None:
        t = state.thick / np.maximum(state.thick_area, 1e-300)
        t = np.where(state.thick_area > 0, t, state.thick_median)
        t = np.maximum(t, 1e-12 * max(state.thick_median, 1e-300))
        T[..., 7] = np.abs(np.log(t[rows][:, None] / t[None, :]))
        t_small = np.where(i_small, t[rows][:, None], t[None, :])
        T[..., 8] = np.log(t_small / max(state.thick_median, 1e-300))
    if state.centroid is not None:
        c = state.centroid / np.maximum(area, 1e-300)[:, None]
        d = np.linalg.norm(c - state.center, axis=1) / state.radius
        T[..., 9] = np.where(i_small, d[rows][:, None] - d[None, :], d[None, :] - d[rows][:, None])
    if state.seen is not None:
        lines = state.lines[rows]
        blocked = np.where(lines > 0, 1.0 - state.seen[rows] / np.maximum(lines, 1.0), 0.0)
        T[..., 10] = blocked
        own_lines = np.diag(state.lines)
        own = np.where(own_lines > 0, 1.0 - np.diag(state.seen) / np.maximum(own_lines, 1.0), 0.0)
        T[..., 11] = blocked - 0.5 * (own[rows][:, None] + own[None, :])
    T[~adjacent] = 0.0
    return T, adjacent


__all__ = ["TERM_NAMES", "THICKNESS_RAYS", "THICKNESS_FACES", "cone_directions", "face_thickness",
           "MergeState", "part_sums", "pair_terms"]
