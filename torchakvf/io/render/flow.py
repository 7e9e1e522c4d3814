"""Symmetry generators as flow on the surface: streamlines (and arrows) of each part's generator.

Each part's first symmetry generator (``MeshSegmentation.generators[p][0]``) is traced as
streamlines on that part only, seeded evenly (farthest-point sampling of the part's face
centroids), in both directions; the figures clip them where hidden.
"""
from __future__ import annotations

import numpy as np

from .camera import face_geometry


def _farthest_points(points: np.ndarray, count: int, seed: int) -> np.ndarray:
    """Indices of ``count`` points spread evenly (greedy farthest-point sampling)."""
    rng = np.random.default_rng(seed)
    pick = [int(rng.integers(len(points)))]
    d = np.linalg.norm(points - points[pick[0]], axis=1)
    for _ in range(min(count, len(points)) - 1):
        i = int(d.argmax())
        pick.append(i)
        d = np.minimum(d, np.linalg.norm(points - points[i], axis=1))
    return np.array(pick)


def generator_streamlines(vertices, faces, labels, face_vectors, generators, seeds_total: int = 150,
                          seed: int = 0, which: int = 0, seed_faces: np.ndarray | None = None,
                          length: float = 3.5) -> list[tuple[int, np.ndarray]]:
    """Streamlines of each part's generator ``generators[p][which]``, on that part only.

    face_vectors : [F, n, 3] untangled Whitney vectors on the given faces
    (:meth:`~torchakvf.parts.Segmentation.face_vectors`); generators : per part, a list of
    :class:`~torchakvf.parts.generators.SymmetryGenerator`. Seeds are spread evenly over each
    part (count in proportion to the part's area, 8..60), each line is traced both ways with
    midpoint steps that follow the field of the nearest face on the part, and stops where the
    field fades (< 5% of its 95th percentile on the part), leaves the part or the surface, turns
    back, or reaches ``length`` seed spacings in all; a line shorter than 0.8 seed spacings, or
    running mostly within 0.35 spacings of a longer one, is dropped. seed_faces : optional [F] bool, faces
    a line may start on (a picture passes the faces it shows, so no seed is wasted on the
    hidden side). Returns [(part, [m, 3] points)].
    """
    from scipy.spatial import cKDTree

    v, f = np.asarray(vertices, float), np.asarray(faces)
    labels = np.asarray(labels)
    cent, normals, areas = face_geometry(v, f)
    total = max(areas.sum(), 1e-300)
    lines = []
    for p, gens in enumerate(generators):
        if len(gens) <= which:
            continue
        idx = np.flatnonzero(labels == p)
        if len(idx) < 3:
            continue
        field = np.asarray(face_vectors)[idx, gens[which].field].astype(float)
        nrm = normals[idx]
        field = field - (field * nrm).sum(axis=1, keepdims=True) * nrm   # tangent to each face
        mag = np.linalg.norm(field, axis=1)
        ref = np.percentile(mag, 95)
        if ref <= 0:
            continue
        part_area = areas[idx].sum()
        count = int(np.clip(round(seeds_total * part_area / total), 8, 60))
        spacing = np.sqrt(part_area / count)
        step = spacing / 8
        n_steps = max(int(round(length * 4)), 2)
        tree = cKDTree(cent[idx])
        # a point farther than this from every centroid of the part has left it (or the surface)
        reach = 1.5 * np.sqrt(areas[idx] * 4 / np.sqrt(3))              # ~1.5 edge lengths
        strong = mag > 0.2 * ref
        if seed_faces is not None:
            strong &= np.asarray(seed_faces, dtype=bool)[idx]
        strong = np.flatnonzero(strong)
        if len(strong) < 3:
            continue
        start = strong[_farthest_points(cent[idx][strong], count, seed + p)]
        unit = field / np.maximum(mag, 1e-300)[:, None]

        def advance(x, sign):
            _, i = tree.query(x)
            k1 = unit[i] * sign
            _, j = tree.query(x + 0.5 * step * k1)
            x_new = x + step * unit[j] * sign
            # back onto the plane of the nearest face: the line stays on the surface
            _, m = tree.query(x_new)
            x_new = x_new - ((x_new - cent[idx][m]) * nrm[m]).sum(axis=1, keepdims=True) * nrm[m]
            dist, m = tree.query(x_new)
            alive = (mag[m] > 0.05 * ref) & (dist < np.maximum(reach[m], step)) & ((unit[m] * k1).sum(axis=1) > 0.0)
            return x_new, alive

        halves = []
        for sign in (1.0, -1.0):
            x = cent[idx][start].copy()
            track = [x.copy()]
            alive = np.ones(len(x), dtype=bool)
            for _ in range(n_steps):
                x_new, ok = advance(x, sign)
                alive &= ok
                x = np.where(alive[:, None], x_new, x)
                track.append(np.where(alive[:, None], x, np.nan))
            halves.append(np.stack(track, axis=1))                      # [S, n_steps+1, 3]
        traced = []
        for s in range(len(start)):
            pts = np.concatenate([halves[1][s][::-1], halves[0][s][1:]])
            pts = pts[~np.isnan(pts[:, 0])]
            # a fragment shorter than a seed spacing shows no flow (it stopped at a singularity)
            if len(pts) >= 3 and np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() > 0.8 * spacing:
                traced.append(pts)
        # even spacing: longest lines first, drop a line that mostly runs beside a kept one
        kept_pts = np.zeros((0, 3))
        for pts in sorted(traced, key=len, reverse=True):
            if len(kept_pts):
                near = cKDTree(kept_pts).query(pts)[0] < 0.35 * spacing
                if near.mean() > 0.5:
                    continue
            lines.append((p, pts))
            kept_pts = np.concatenate([kept_pts, pts])
    return lines


def generator_arrows(vertices, faces, labels, face_vectors, generators, per_part: int = 60,
                     seed: int = 0):
    """Arrow bases [N, 3] and vectors [N, 3] of each part's first generator on a sample of that
    part's faces (kept for callers that want arrows; pictures draw
    :func:`generator_streamlines`). face_vectors : [F, n, 3]."""
    rng = np.random.default_rng(seed)
    centroids = np.asarray(vertices)[np.asarray(faces)].mean(axis=1)
    scale = np.linalg.norm(np.ptp(np.asarray(vertices), axis=0)) * 0.06
    bases, vecs = [], []
    for p, gens in enumerate(generators):
        if not gens:
            continue
        idx = np.flatnonzero(np.asarray(labels) == p)
        if len(idx) == 0:
            continue
        idx = rng.choice(idx, min(per_part, len(idx)), replace=False)
        vec = np.asarray(face_vectors)[idx, gens[0].field]
        norm = np.linalg.norm(vec, axis=1).max()
        bases.append(centroids[idx])
        vecs.append(vec / max(norm, 1e-300) * scale)
    if not bases:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(bases), np.concatenate(vecs)


__all__ = ["generator_streamlines", "generator_arrows"]
