"""Composite shapes with known parts: blobs joined by thin necks and disconnected tori,
with a ground-truth label per face."""
from __future__ import annotations

import numpy as np

from .implicit import fish, quadruped
from .revolution import blob_profile, revolve_profile, torus
from .shape import Shape


def _blob_chain(name: str, blobs, neck: float, n_around: int) -> Shape:
    """Blobs along z joined by necks; part label = number of necks below the face centroid."""
    z, r, neck_z = blob_profile(blobs, neck)
    vertices, faces = revolve_profile(z, r, n_around, ring_z=neck_z)
    labels = np.searchsorted(neck_z, vertices[faces, 2].mean(axis=1)).astype(np.int64)
    return Shape(name, vertices, faces, labels, len(blobs))


def dumbbell(radius: float = 1.0, center: float = 1.08, neck: float = 0.12,
             n_around: int = 84) -> Shape:
    """Two equal spheres at ``z = -center`` and ``z = +center`` joined by a smooth neck.

    The squared profile radius is a C2 smooth maximum of the two spheres' (parabolic)
    squared profiles; it equals the spheres exactly away from the neck and is narrowest,
    with radius ``neck``, at z = 0.

    Parameters
    ----------
    radius : float
        Sphere radius (length units).
    center : float
        Distance of each sphere centre from the origin along z (length units).
    neck : float
        Radius of the neck at z = 0 (length units).
    n_around : int
        Vertices on the spheres' equators (rounded to a multiple of 6); sets the edge
        length ``2 pi radius / n_around`` (defaults: about 10,000 faces).

    Returns
    -------
    Shape
        Closed genus-0 mesh; ``part_labels`` 0 for faces with centroid z < 0, 1 above;
        ``n_parts`` 2.
    """
    blobs = [(-center, radius, radius), (center, radius, radius)]
    return _blob_chain("dumbbell", blobs, neck, n_around)


def three_blobs(radii: tuple[float, float, float] = (1.0, 0.8, 0.95),
                centers: tuple[float, float, float] = (0.0, 1.95, 3.8),
                neck: float = 0.12, n_around: int = 84) -> Shape:
    """Three spheres along z joined by two smooth necks of radius ``neck``.

    Parameters
    ----------
    radii : (3,) floats
        Sphere radii, bottom to top (length units).
    centers : (3,) floats
        Increasing sphere centre heights on the z axis (length units).
    neck : float
        Narrowest radius of each neck (length units).
    n_around : int
        Vertices on the largest equator (rounded to a multiple of 6); sets the edge length
        (defaults: about 13,000 faces).

    Returns
    -------
    Shape
        Closed genus-0 mesh; ``part_labels`` 0, 1, 2 from bottom to top, split at the
        necks (the profile's local minima); ``n_parts`` 3.
    """
    blobs = [(c, rad, rad) for c, rad in zip(centers, radii)]
    return _blob_chain("three_blobs", blobs, neck, n_around)


def sphere_with_two_ellipsoids(neck: float = 0.12, n_around: int = 84) -> Shape:
    """A prolate spheroid, the unit sphere and an oblate spheroid along z, joined by necks.

    Bottom: semi-axes (0.7, 0.7, 1.2) centred at z = -2.36; middle: unit sphere at the
    origin; top: semi-axes (0.9, 0.9, 0.6) centred at z = 1.76 (gaps of 0.16 along the
    axis before blending).

    Parameters
    ----------
    neck : float
        Narrowest radius of each neck (length units).
    n_around : int
        Vertices on the sphere's equator (rounded to a multiple of 6); sets the edge
        length (defaults: about 12,000 faces).

    Returns
    -------
    Shape
        Closed genus-0 mesh; ``part_labels`` 0 (prolate), 1 (sphere), 2 (oblate);
        ``n_parts`` 3.
    """
    blobs = [(-2.36, 1.2, 0.7), (0.0, 1.0, 1.0), (1.76, 0.6, 0.9)]
    return _blob_chain("sphere_two_ellipsoids", blobs, neck, n_around)


def torus_chain(n: int = 3, n_major: int = 72) -> Shape:
    """``n`` disconnected tori of decreasing size side by side along z.

    Torus ``i`` has major radius ``0.8**i`` and minor radius ``0.4 * 0.8**i``; all share
    one edge length.  Each lies in the yz-plane (axis along x) and neighbours are 0.5
    apart, so like the other composite shapes the chain is slender along z, which keeps
    :func:`~torchakvf.shapes.bend` near-isometric on it.

    Parameters
    ----------
    n : int
        Number of tori (connected components).
    n_major : int
        Vertices on the outer equator of the largest torus (rounded to a multiple of 6)
        (defaults: about 5000 faces).

    Returns
    -------
    Shape
        Closed mesh of ``n`` genus-1 components, centred at the origin; ``part_labels`` =
        component index (bottom to top), ``n_parts`` = n.
    """
    scale = 0.8 ** np.arange(n)
    outer = 1.4 * scale                               # major + minor
    edge = 2 * np.pi * outer[0] / n_major
    center = np.cumsum(np.r_[0.0, outer[:-1] + 0.5 + outer[1:]])
    center -= (center[0] - outer[0] + center[-1] + outer[-1]) / 2
    vertices, faces, labels, offset = [], [], [], 0
    for i in range(n):
        part = torus(scale[i], 0.4 * scale[i], n_major=round(2 * np.pi * outer[i] / edge))
        x, y, z = part.vertices.T
        # rotation about y taking the torus axis z to x (proper: keeps faces outward)
        vertices.append(np.column_stack([z, y, center[i] - x]))
        faces.append(part.faces + offset)
        labels.append(np.full(len(part.faces), i, dtype=np.int64))
        offset += len(part.vertices)
    return Shape("torus_chain", np.vstack(vertices), np.vstack(faces), np.concatenate(labels), n)


BUILTIN_SHAPES = {
    "dumbbell": dumbbell,
    "three_blobs": three_blobs,
    "sphere_two_ellipsoids": sphere_with_two_ellipsoids,
    "torus_chain": torus_chain,
    "quadruped": quadruped,
    "fish": fish,
}
"""Composite shapes with ground-truth parts: name -> zero-argument constructor (the last two are
implicit surfaces, :mod:`.implicit`)."""
