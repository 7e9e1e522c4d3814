"""Per-face descriptors from untangled AKVFs that mean the same thing on every mesh.

The untangled fields of a mesh have no order and no sign (any permutation and sign flip of the
columns of the orthomax rotation is as good), so their per-face norms φ_i(f) = |X_i(f)| cannot
be fed to a learning model column by column. Everything here is a function of the *set*
{(φ_i(f), energy_i, support_i)} over the fields i, or of the span of the fields, hence
invariant to their order and sign; everything is intrinsic or rotation-covariant and computed
in the unit-area frame, hence invariant to rigid motions and scale; and each column is one
number per face, so a renumbering of the vertices or faces only permutes the rows.

For each field count n of ``counts`` (the first n AKVFs, untangled), with the membership
p_i(f) = φ_i(f)² / Σ_j φ_j(f)² of face f in field i (a distribution over the n fields):

============================  ================================================================
column                        meaning, range
============================  ================================================================
``share1@n``                  largest p_i(f): how strongly one primitive owns the face; [1/n, 1]
``share2@n``, ``share3@n``    second and third largest p_i(f); [0, 1/2], [0, 1/3]
``entropy@n``                 Σ -p log p / log n: spread of the face over fields; [0, 1]
``log_density@n``             log(Σ_i φ_i(f)² / n): how much Killing motion the face carries
                              against the surface's mean (0); rotation-invariant, so the same
                              for the raw and untangled fields; about [-15, 5]
``energy@n``                  Σ_i p_i log(1 + max(E_i, 0)), E_i the Killing energy λ·area of
                              field i: how far from an isometry the fields carrying the face
                              are; [0, ~log(1 + λ_max·area)], about [0, 6]
``part_area@n``               Σ_i p_i A_i, A_i = (∫φ_i²)² / ∫φ_i⁴ the area fraction field i
                              is spread over (participation ratio): the size of the face's
                              part; (0, 1]
``contrast_r@n``              Hellinger distance between p(f) and p averaged by heat diffusion
                              at radius r (unit-area lengths, :data:`CONTRAST_RADII`): high
                              where the face's primitive changes within r (a part boundary);
                              [0, 1]
``coherence_r@n``             how much the span of the n fields at f agrees with their span
                              averaged by heat diffusion at radius r: with X(f) the [n, 3]
                              field vectors at f and Y(f) the diffused ones,
                              |X(f)ᵀY(f)|² / (|X(f)ᵀX(f)| |Y(f)ᵀY(f)|) (Frobenius). A function
                              of the raw AKVFs' span alone, so it does not depend on the
                              untangling (nor its seed) at all; low where the rigid motions
                              carried by the face change within r; [0, 1]
============================  ================================================================

The untangling-based columns untangle the fields from :data:`DESCRIPTOR_SEED`'s starts given
in the fields' moment frame (:func:`~torchakvf.fields.untangle.moment_frame`), which turns with
any basis of their span, so they repeat whatever solver start, eigensolver, pose or numbering
made the fields (to the solver's tolerance), also where eigenvalues are (nearly) equal. On an
exactly symmetric shape two untanglings that are mirror images of each other reach the same
objective, and which one is found can be decided by round-off (a moved copy's): there only
``log_density`` and the coherences are guaranteed to repeat.

Counts and radii make ``len(counts) * (7 + 2 * len(CONTRAST_RADII))`` columns, named by
:func:`descriptor_names` in the order :func:`face_descriptors` returns them.
"""
from __future__ import annotations

import numbers
from collections.abc import Mapping, Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla
import torch

from ..errors import ParameterError
from ..mesh.batch import mesh_edges
from ..mesh.clean import face_areas
from .akvf_result import AKVFResult
from .canonical import canonical_signs
from .untangle import DEFAULT_RESTARTS, UntangledFields, untangle

#: Field counts the descriptors are computed at by default: a few large primitives (8), the
#: segmentation's usual range (16) and finer ones (32).
DEFAULT_COUNTS = (8, 16, 32)
#: Heat-diffusion radii (lengths on the mesh scaled to unit area) of the contrast and coherence
#: columns: about 3 and 10 face widths of a mesh decimated to 4000 faces.
CONTRAST_RADII = (0.05, 0.15)
#: Per-count columns other than the contrasts, in output order.
BASE_COLUMNS = ("share1", "share2", "share3", "entropy", "log_density", "energy", "part_area")
#: Seed of the descriptors' own untangling, whatever seed solved the fields: with the fields'
#: canonical signs the columns then depend on the fields' span and eigenvalues alone.
DESCRIPTOR_SEED = 0
#: Frame of the descriptors' untangling starts (:data:`~torchakvf.fields.untangle.START_FRAMES`):
#: the fields' moment frame, so the columns repeat on exactly symmetric shapes too.
DESCRIPTOR_FRAME = "moments"
#: Floor of Σ φ² relative to its surface mean before the log (faces where no field moves).
DENSITY_FLOOR = 1e-12


def descriptor_names(counts: Sequence[int] = DEFAULT_COUNTS,
                     radii: Sequence[float] = CONTRAST_RADII) -> list[str]:
    """Column names of :func:`face_descriptors`' output, e.g. ``"share1@8"``,
    ``"contrast_0.05@32"``: for each count, :data:`BASE_COLUMNS`, one contrast per radius, then
    one coherence per radius."""
    return [f"{c}@{n}" for n in counts
            for c in list(BASE_COLUMNS) + [f"contrast_{r:g}" for r in radii]
            + [f"coherence_{r:g}" for r in radii]]


class FaceDiffusion:
    """Implicit heat diffusion of per-face values on one mesh, in the unit-area frame.

    The dual graph (faces joined across interior edges) with finite-volume weights
    |edge| / |centroid distance| is a discrete Laplace-Beltrami operator on face values; the
    mass is the face area. ``smooth(y, r)`` solves (M + r² L) x = M y, which averages y over
    about a geodesic radius r and keeps constants (so a row-stochastic ``y`` stays one).

    vertices : [V, 3], faces : [F, 3] (any scale: it is normalized to unit area here)
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        v = np.asarray(vertices, dtype=np.float64)
        f = np.asarray(faces, dtype=np.int64)
        area = face_areas(v, f)
        scale = 1.0 / np.sqrt(area.sum())
        self.area = area * scale ** 2                   # [F], sums to 1
        edges, face_edges, _ = mesh_edges(f)
        nf, ne = len(f), len(edges)
        inc = sp.coo_matrix((np.ones(3 * nf), (face_edges.ravel(), np.repeat(np.arange(nf), 3))),
                            shape=(ne, nf)).tocsr()
        two = np.flatnonzero(np.diff(inc.indptr) == 2)   # interior edges: exactly two faces
        first = inc.indices[inc.indptr[two]]
        second = inc.indices[inc.indptr[two] + 1]
        centroid = v[f].mean(axis=1) * scale
        length = np.linalg.norm(v[edges[two, 0]] - v[edges[two, 1]], axis=1) * scale
        dist = np.linalg.norm(centroid[first] - centroid[second], axis=1)
        w = length / np.maximum(dist, 1e-12 * max(length.max(initial=1.0), 1e-300))
        adj = sp.coo_matrix((np.concatenate([w, w]), (np.concatenate([first, second]),
                                                      np.concatenate([second, first]))),
                            shape=(nf, nf)).tocsr()
        self.laplacian = (sp.diags(np.asarray(adj.sum(axis=1)).ravel()) - adj).tocsc()
        self._factors: dict[float, object] = {}

    def smooth(self, values: np.ndarray, radius: float) -> np.ndarray:
        """[F, k] ``values`` [F, k] diffused to about geodesic radius ``radius`` (unit area)."""
        key = float(radius)
        if key not in self._factors:
            m = sp.diags(self.area).tocsc()
            self._factors[key] = sla.splu((m + key ** 2 * self.laplacian).tocsc())
        y = np.asarray(values, dtype=np.float64)
        return self._factors[key].solve(np.ascontiguousarray(self.area[:, None] * y))


def descriptor_block(phi: np.ndarray, energies: np.ndarray, area: np.ndarray,
                     diffusion: FaceDiffusion | None = None,
                     radii: Sequence[float] = CONTRAST_RADII) -> np.ndarray:
    """[F, 7 + len(radii)] the columns of one field count (see the module docstring).

    phi : [F, n] per-face norms of n untangled fields (any order, sign-free)
    energies : [n] their Killing energies λ·area
    area : [F] face areas (normalized to sum 1 here)
    diffusion : the mesh's :class:`FaceDiffusion` (needed when ``radii`` is not empty)
    """
    phi = np.asarray(phi, dtype=np.float64)
    nf, n = phi.shape
    a = np.asarray(area, dtype=np.float64)
    a = a / a.sum()
    sq = phi ** 2
    total = sq.sum(axis=1)
    mean_density = float(a @ total) / n
    empty = total <= DENSITY_FLOOR * max(mean_density, 1e-300) * n
    # a face no field moves belongs to no field more than another: uniform membership
    p = np.where(empty[:, None], 1.0 / n, sq / np.where(empty, 1.0, total)[:, None])
    top = -np.sort(-p, axis=1)
    shares = np.zeros((nf, 3))
    shares[:, :min(3, n)] = top[:, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        plogp = np.where(p > 0, p * np.log(p), 0.0)
    entropy = -plogp.sum(axis=1) / np.log(n) if n > 1 else np.zeros(nf)
    density = np.log(np.maximum(total / n, DENSITY_FLOOR * max(mean_density, 1e-300)) / mean_density) \
        if mean_density > 0 else np.zeros(nf)
    energy = p @ np.log1p(np.maximum(np.asarray(energies, dtype=np.float64)[:n], 0.0))
    second = a @ sq                                      # [n] ∫φ² (unit area)
    fourth = a @ (sq * sq)
    part = np.where(fourth > 0, second ** 2 / np.where(fourth > 0, fourth, 1.0), 0.0)
    cols = [shares, entropy[:, None], density[:, None], energy[:, None], (p @ part)[:, None]]
    if len(radii):
        if diffusion is None:
            raise ParameterError("contrast columns need the mesh's FaceDiffusion (or radii=())")
        sp_ = np.sqrt(p)
        for r in radii:
            q = np.maximum(diffusion.smooth(p, r), 0.0)
            cols.append(np.sqrt(np.maximum(1.0 - (sp_ * np.sqrt(q)).sum(axis=1), 0.0))[:, None])
    return np.concatenate(cols, axis=1)


def span_coherence(vectors: np.ndarray, diffusion: FaceDiffusion,
                   radii: Sequence[float] = CONTRAST_RADII) -> np.ndarray:
    """[F, len(radii)] the ``coherence`` columns (module docstring) of field vectors
    [F, n, 3] (any orthogonal mix of the fields gives the same values)."""
    x = np.asarray(vectors, dtype=np.float64)
    nf, n, _ = x.shape
    gram_x = np.linalg.norm(np.einsum("fni,fnj->fij", x, x).reshape(nf, 9), axis=1)
    out = np.empty((nf, len(radii)))
    for k, r in enumerate(radii):
        y = diffusion.smooth(x.reshape(nf, 3 * n), r).reshape(nf, n, 3)
        cross = np.einsum("fni,fnj->fij", x, y).reshape(nf, 9)
        gram_y = np.linalg.norm(np.einsum("fni,fnj->fij", y, y).reshape(nf, 9), axis=1)
        den = gram_x * gram_y
        out[:, k] = np.where(den > 0, (cross ** 2).sum(axis=1) / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(out, 0.0, 1.0)


def counts_for(n: int) -> tuple[int, ...]:
    """The field counts to describe a mesh solved with ``n`` fields: those of
    :data:`DEFAULT_COUNTS` below n, and n itself (e.g. 32 -> (8, 16, 32), 20 -> (8, 16, 20));
    none for a single field (one field has no membership to describe)."""
    n = int(n)
    return tuple(c for c in DEFAULT_COUNTS if c < n) + (n,) if n >= 2 else ()


def _counts(counts, available: int) -> list[int]:
    if isinstance(counts, numbers.Integral):
        counts = [counts]
    out = [int(c) for c in counts]
    if out and (min(out) < 2 or max(out) > available):
        raise ParameterError(f"descriptor field counts must be 2..{available} (the fields "
                             f"computed), got {list(counts)!r}")
    return out


def face_descriptors(fields: AKVFResult, counts: Sequence[int] | int = DEFAULT_COUNTS, *,
                     untangled: Mapping[int, UntangledFields] | None = None,
                     radii: Sequence[float] = CONTRAST_RADII, restarts: int = DEFAULT_RESTARTS,
                     seed: int = DESCRIPTOR_SEED,
                     tol: float = 1e-6) -> list[torch.Tensor]:
    """Order-, sign- and motion-invariant per-face descriptors of every mesh of a batch.

    fields : the batch's AKVFs (at least ``max(counts)`` of them)
    counts : field counts to untangle at; each gives the columns of :func:`descriptor_block`
        and :func:`span_coherence` (none: [F_b, 0] tensors)
    untangled : already untangled fields by count (reused instead of untangling again; to
        repeat across solves, from :func:`~torchakvf.fields.canonical.canonical_signs` of the
        fields with the same seed and restarts)
    restarts, seed, tol : :func:`~torchakvf.untangle`'s, for the counts not given (untangled
        from the fields with their canonical signs, so that the columns do not depend on the
        eigensolver's start, the solver, the pose or the numbering of the mesh)
    Returns one [F_b, d] tensor per mesh, on the faces of the packed mesh
    (``fields.batch.meshes[b]``: cleaned, decimated in a ``coarse_faces`` batch), in the
    fields' device and float type; d = ``len(descriptor_names(counts, radii))``.
    """
    counts = _counts(counts, fields.n)
    untangled = dict(untangled or {})
    canonical = None
    for n in counts:
        if n not in untangled:
            # the starts are given in the fields' moment frame, which turns with them: a seed
            # gives the same starts whatever basis of the fields' span (solver start, pose,
            # numbering, a symmetric shape's equal eigenvalues) the eigensolver returned
            canonical = canonical_signs(fields) if canonical is None else canonical
            untangled[n] = untangle(canonical, n, restarts=restarts, seed=seed, tol=tol, frame=DESCRIPTOR_FRAME)
    out = []
    for b, mesh in enumerate(fields.batch.meshes):
        diffusion = FaceDiffusion(mesh.vertices, mesh.faces) if len(radii) else None
        area = face_areas(np.asarray(mesh.vertices, dtype=np.float64), mesh.faces)
        f0, f1 = int(fields.batch.face_ptr[b]), int(fields.batch.face_ptr[b + 1])
        vectors = fields.face_vectors[f0:f1].detach().cpu().to(torch.float64).numpy()
        blocks = [np.zeros((len(mesh.faces), 0))]
        for n in counts:
            blocks.append(descriptor_block(untangled[n].mesh_features(b).detach().cpu().numpy()[:, :n],
                                           untangled[n].energies[b, :n].detach().cpu().numpy(),
                                           area, diffusion, radii))
            if len(radii):
                blocks.append(span_coherence(vectors[:, :n], diffusion, radii))
        out.append(torch.as_tensor(np.concatenate(blocks, axis=1), dtype=fields.forms.dtype,
                                   device=fields.forms.device))
    return out


__all__ = ["DEFAULT_COUNTS", "DESCRIPTOR_SEED", "DESCRIPTOR_FRAME", "CONTRAST_RADII", "BASE_COLUMNS", "FaceDiffusion",
           "descriptor_block", "counts_for", "descriptor_names", "face_descriptors", "span_coherence"]
