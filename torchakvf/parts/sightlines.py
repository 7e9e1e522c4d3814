"""Lines of sight between parts: how much of the segment between two parts stays inside the solid.

Two pieces of one convex part see each other through the inside of the shape; a segment from a
plate of an L bracket to the other plate, from a spoke to the rim, from a leg to the body it
hangs off leaves the solid. This is the convexity cue of part perception at the scale of whole
parts (weakly convex decompositions are built on it), where the bending of the shared boundary
(:mod:`torchakvf.parts.concavity`) only sees the boundary: when an over-segmentation's piece
wraps round a plate's outer edge, the concave crease is no longer on the boundary the merge
reads, but the plates still do not see each other.

Each part is sampled at ``samples`` face centroids (fewer past 32 parts: :data:`SIGHT_BUDGET`),
moved a little inside the surface (``offset`` of the bounding-box diagonal against the outward
normal); a pair of samples sees each other when the segment between them crosses no face. The
counts over all pairs of parts, and over each part's own pairs of samples, are additive, so a
merged part's counts are sums of its pieces' (:class:`~torchakvf.parts.merge_terms.MergeState`,
:meth:`PartSight.merged`). The samples are chosen by geometry alone (farthest-point sampling
from the face nearest the part's centroid), so a moved or renumbered mesh gets the same ones.
The segments are tested by the mesh's :class:`~torchakvf.mesh.raycast.RayCaster` (Embree's
occlusion query where it is installed, else libigl's AABB tree, which also casts the
thickness), at any unit of length.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..mesh.raycast import RayCaster
from .creases import unit_face_normals

#: face centroids sampled per part: 8 x 8 = 64 segments per pair of parts
SIGHT_SAMPLES = 8
#: samples over all parts: past 32 parts each part gets fewer (at least
#: :data:`SIGHT_MIN_SAMPLES`), so the segments cast (about half the square of the samples) stay
#: near 33,000 up to 64 parts, where a large k's over-segmentation would otherwise cast 100,000s
SIGHT_BUDGET = 256
SIGHT_MIN_SAMPLES = 4
#: how far inside the surface a sample sits, relative to the bounding-box diagonal (well below
#: half the thickness of a thin plate or fin, well above the ray caster's round-off)
SIGHT_OFFSET = 1e-4


class SightLines:
    """A mesh's ray caster and inward-moved face centroids, made once per mesh and read for
    every labelling of it (:meth:`counts`).

    vertices : [V, 3]; faces : [F, 3] outward-oriented (counter-clockwise from outside);
    caster : the mesh's :class:`~torchakvf.mesh.raycast.RayCaster` if at hand."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, samples: int = SIGHT_SAMPLES,
                 offset: float = SIGHT_OFFSET, budget: int = SIGHT_BUDGET, caster: RayCaster | None = None):
        self.vertices = np.ascontiguousarray(vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.samples = int(samples)
        self.budget = int(budget)
        self.centroids = self.vertices[self.faces].mean(axis=1) if len(self.faces) else np.zeros((0, 3))
        extent = np.ptp(self.vertices, axis=0) if len(self.vertices) else np.ones(3)
        diag = float(np.linalg.norm(extent))
        self.inside = self.centroids - offset * diag * unit_face_normals(self.vertices, self.faces)
        self.caster = caster or RayCaster(self.vertices, self.faces)

    def samples_per_part(self, n_parts: int) -> int:
        """``samples``, fewer where n_parts of them would pass the budget (at least
        :data:`SIGHT_MIN_SAMPLES`)."""
        return int(min(self.samples, max(SIGHT_MIN_SAMPLES, self.budget // max(int(n_parts), 1))))

    def part_samples(self, labels: np.ndarray, n_parts: int) -> np.ndarray:
        """[n_parts, S] face ids of each part's samples, S = :meth:`samples_per_part` (-1 where a
        part has fewer faces): farthest-point sampling of the face centroids, from the face nearest
        the part's centroid (ties to the lower face id)."""
        labels = np.asarray(labels)
        S = self.samples_per_part(n_parts)
        out = np.full((n_parts, S), -1, dtype=np.int64)
        order = np.argsort(labels, kind="stable")
        bounds = np.searchsorted(labels[order], np.arange(n_parts + 1))
        for p in range(n_parts):
            ids = order[bounds[p]:bounds[p + 1]]
            if len(ids) == 0:
                continue
            c = self.centroids[ids]
            first = int(np.argmin(((c - c.mean(axis=0)) ** 2).sum(axis=1)))
            d = ((c - c[first]) ** 2).sum(axis=1)
            pick = [first]
            for _ in range(min(S, len(ids)) - 1):
                j = int(np.argmax(d))
                pick.append(j)
                d = np.minimum(d, ((c - c[j]) ** 2).sum(axis=1))
            out[p, :len(pick)] = ids[pick]
        return out

    def counts(self, labels: np.ndarray, n_parts: int) -> tuple[np.ndarray, np.ndarray]:
        """(seen [K, K], lines [K, K]) for ``labels`` [F] compact part ids (negative: left out),
        K = n_parts: of the segments between a sample of part i and one of part j (i != j), or
        between two samples of part i (the diagonal), how many cross no face, and how many there
        are. Symmetric."""
        K = int(n_parts)
        seen, lines = np.zeros((K, K)), np.zeros((K, K))
        if K < 1:
            return seen, lines
        pick = self.part_samples(labels, K)
        ok = pick >= 0
        pts = self.inside[np.maximum(pick, 0)]
        iu, ju = np.triu_indices(K, 0)
        S = pick.shape[1]
        valid = ok[iu][:, :, None] & ok[ju][:, None, :]
        # within a part, each unordered pair of distinct samples once
        valid[iu == ju] &= np.triu(np.ones((S, S), dtype=bool), 1)
        src = np.broadcast_to(pts[iu][:, :, None, :], (len(iu), S, S, 3))[valid]
        dst = np.broadcast_to(pts[ju][:, None, :, :], (len(iu), S, S, 3))[valid]
        visible = np.zeros(valid.shape, dtype=bool)
        if len(src):
            # the ray is src + t (dst - src): a face crossed with t < 1 blocks the segment
            visible[valid] = ~self.caster.blocked(src, dst - src)
        seen[iu, ju] = visible.sum(axis=(1, 2))
        lines[iu, ju] = valid.sum(axis=(1, 2))
        diag = np.diag(seen).copy(), np.diag(lines).copy()
        seen, lines = seen + seen.T, lines + lines.T
        seen[np.diag_indices(K)], lines[np.diag_indices(K)] = diag
        return seen, lines


def join_counts(mat: np.ndarray, i: int, j: int) -> None:
    """Part j joins part i in the symmetric counts ``mat`` [K, K] (seen or lines), in place: the
    union's segments to any other part are both parts' (summed), its own (the diagonal) both
    parts' own and those between them; j's row and column become zero."""
    inner = mat[i, i] + mat[j, j] + mat[i, j]
    mat[i, :] += mat[j, :]
    mat[:, i] = mat[i, :]
    mat[i, i] = inner
    mat[j, :] = mat[:, j] = 0.0


@dataclass(frozen=True)
class PartSight:
    """Counts of :meth:`SightLines.counts` of a labelling, by its part ids: seen, lines [K, K]."""

    seen: np.ndarray
    lines: np.ndarray

    def merged(self, owner: np.ndarray, n_parts: int) -> "PartSight":
        """The counts of the unions of parts, ``owner`` [K] the union (0..n_parts-1) each part
        joins, each part joining the union's first (:func:`join_counts`, as
        :meth:`~torchakvf.parts.merge_terms.MergeState.merge` joins them); a union of no part
        has zero counts."""
        seen, lines = self.seen.copy(), self.lines.copy()
        first = np.full(int(n_parts), -1, dtype=np.int64)
        for part, union in enumerate(np.asarray(owner)):
            if first[union] < 0:
                first[union] = part
            else:
                join_counts(seen, first[union], part)
                join_counts(lines, first[union], part)
        present = first >= 0
        rows = np.ix_(first[present], first[present])
        out = PartSight(np.zeros((len(first), len(first))), np.zeros((len(first), len(first))))
        out.seen[np.ix_(present, present)] = seen[rows]
        out.lines[np.ix_(present, present)] = lines[rows]
        return out

    def take(self, ids: np.ndarray) -> "PartSight":
        """The counts of parts ``ids`` (in that order)."""
        ix = np.ix_(np.asarray(ids), np.asarray(ids))
        return PartSight(self.seen[ix], self.lines[ix])


__all__ = ["SIGHT_SAMPLES", "SIGHT_BUDGET", "SIGHT_MIN_SAMPLES", "SIGHT_OFFSET", "SightLines", "PartSight",
           "join_counts"]
