"""Headless pictures of segmentations (matplotlib's Agg backend: no display, no OpenGL)."""
from __future__ import annotations

import io
from typing import Sequence

import numpy as np

from .outputs import atomic_write_bytes, label_colors

#: Faces drawn at most per mesh; larger meshes show a uniform sample (painter's algorithm
#: cost grows with faces, and at PNG resolution the sample looks the same).
MAX_DRAWN_FACES = 60000


def _axes_mesh(ax, vertices, faces, labels, title=None, arrows=None):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    v = np.asarray(vertices, dtype=float)
    v = v - v.mean(axis=0)
    # Look along the direction of least extent so elongated shapes show their length.
    _, _, vt = np.linalg.svd(v - v.mean(0), full_matrices=False)
    v = v @ vt.T[:, [0, 2, 1]]
    f = np.asarray(faces)
    colors = label_colors(labels) / 255.0
    if len(f) > MAX_DRAWN_FACES:
        pick = np.random.default_rng(0).choice(len(f), MAX_DRAWN_FACES, replace=False)
        f, colors = f[pick], colors[pick]
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    shade = 0.55 + 0.45 * np.abs(n @ np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]))
    colors = colors.copy()
    colors[:, :3] *= shade[:, None]
    ax.add_collection3d(Poly3DCollection(tri, facecolors=colors, edgecolors="none"))
    if arrows is not None and len(arrows[0]):
        base, vec = arrows
        base = (base - np.asarray(vertices, float).mean(axis=0)) @ vt.T[:, [0, 2, 1]]
        vec = vec @ vt.T[:, [0, 2, 1]]
        ax.quiver(base[:, 0], base[:, 1], base[:, 2], vec[:, 0], vec[:, 1], vec[:, 2],
                  color="k", linewidth=0.6, arrow_length_ratio=0.3)
    r = np.abs(v).max()
    ax.set_xlim(-r, r), ax.set_ylim(-r, r), ax.set_zlim(-r, r)
    ax.set_box_aspect((1, 1, 1))
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)


def generator_arrows(vertices, faces, labels, face_vectors, generators, per_part: int = 60,
                     seed: int = 0):
    """Arrow bases and vectors of each part's first (most Killing) generator on a sample of
    that part's faces. face_vectors : [F, n, 3]; generators : per part, list of SymmetryGenerator."""
    rng = np.random.default_rng(seed)
    centroids = np.asarray(vertices)[np.asarray(faces)].mean(axis=1)
    scale = np.linalg.norm(np.ptp(np.asarray(vertices), axis=0)) * 0.06
    bases, vecs = [], []
    for p, gens in enumerate(generators):
        if not gens:
            continue
        idx = np.flatnonzero(labels == p)
        if len(idx) == 0:
            continue
        idx = rng.choice(idx, min(per_part, len(idx)), replace=False)
        vec = face_vectors[idx, gens[0].field]
        norm = np.linalg.norm(vec, axis=1).max()
        bases.append(centroids[idx])
        vecs.append(vec / max(norm, 1e-300) * scale)
    if not bases:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(bases), np.concatenate(vecs)


def render_png(path, vertices, faces, labels, title: str | None = None, arrows=None, size: float = 4.0):
    """One mesh coloured by part (grey = connecting region), with optional generator arrows."""
    import matplotlib
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(size, size), dpi=110)
    ax = fig.add_subplot(projection="3d")
    _axes_mesh(ax, vertices, faces, labels, title, arrows)
    _save(fig, path)


def contact_sheet(path, items: Sequence[tuple], columns: int = 4, size: float = 3.0):
    """A grid of meshes; items are (vertices, faces, labels, title)."""
    import matplotlib
    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    rows = (len(items) + columns - 1) // columns
    fig = plt.figure(figsize=(size * columns, size * rows), dpi=100)
    for i, (v, f, lab, title) in enumerate(items):
        ax = fig.add_subplot(rows, columns, i + 1, projection="3d")
        _axes_mesh(ax, v, f, lab, title)
    _save(fig, path)


def _save(fig, path):
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
