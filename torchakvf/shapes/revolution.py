"""Surfaces of revolution built ring by ring with near-equilateral triangles (see the
package docstring): ellipsoids of revolution, tori, tubes, cylinders, and the blob profiles
the composite shapes are revolved from."""
from __future__ import annotations

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from .shape import RING_SYMMETRY, ROW_HEIGHT, Shape


def ring_counts(r: np.ndarray, edge: float) -> np.ndarray:
    """Vertices per ring of radius ``r`` for a spacing close to ``edge`` (multiple of 6)."""
    per_ring = np.rint(2 * np.pi * np.asarray(r) / (RING_SYMMETRY * edge)).astype(np.int64)
    return RING_SYMMETRY * np.maximum(per_ring, 1)


def _stitch(a: np.ndarray, phase_a: int, b: np.ndarray, phase_b: int) -> np.ndarray:
    """Triangulate the band between ring ``a`` and the next ring ``b`` along the profile.

    Vertex ``j`` of a ring with ``n`` vertices and phase ``p`` sits at angle
    ``(2 j + p) pi / n``.  Walking once around the band, each step adds a triangle on the
    next edge of one ring, with the current vertex of the other ring as apex; edges are
    taken in order of their midpoint angle, so each apex is the vertex of the other ring
    nearest to its base's midpoint (for equal counts with opposite phases this is the
    classic staggered strip).  Angles are compared as exact integers in units of
    ``pi / (n_a n_b)``, so the result has the rings' full rotational symmetry.  A ring of
    one vertex is a pole: its (degenerate) steps emit nothing, leaving a fan.
    """
    na, nb = len(a), len(b)
    start = phase_a * nb                           # angle of a[0]
    # first edge of b whose midpoint angle (2k + 1 + phase_b) na is >= start (ceil div)
    k0 = -((-(start - (1 + phase_b) * na)) // (2 * na))
    mid_a = (2 * np.arange(na) + 1 + phase_a) * nb
    mid_b = (2 * np.arange(k0, k0 + nb) + 1 + phase_b) * na
    on_a = np.r_[np.ones(na, bool), np.zeros(nb, bool)]
    step_a = on_a[np.lexsort((~on_a, np.r_[mid_a, mid_b]))]   # ties: a's edge first
    step_b = ~step_a
    j = np.cumsum(step_a) - step_a                 # current vertex on a before each step
    k = k0 + np.cumsum(step_b) - step_b            # current vertex on b before each step
    # (a_j, a_j+1, b_k) and (a_j, b_k+1, b_k) are both counter-clockwise seen from the
    # side the normal (ring tangent) x (profile tangent) points to.
    tri_a = np.column_stack([a[j % na], a[(j + 1) % na], b[k % nb]])[step_a & (na > 1)]
    tri_b = np.column_stack([a[j % na], b[(k + 1) % nb], b[k % nb]])[step_b & (nb > 1)]
    return np.vstack([tri_a, tri_b])


def _revolve(profile_z, profile_r, edge: float, ends: str = "poles"):
    """Revolve a profile curve about the z axis into a triangle mesh.

    Parameters
    ----------
    profile_z, profile_r : (R,) array_like
        Ring heights and radii, in order along the profile.  Walking along the profile,
        the outside of the surface must be on the right in the (r, z) half-plane (r to
        the right, z up): e.g. bottom pole to top pole, or counter-clockwise for a torus.
    edge : float
        Target edge length; each ring gets a multiple of 6 vertices spaced about
        ``edge`` apart.  For near-equilateral triangles, space the rings about
        ``sqrt(3)/2 * edge`` apart in arc length.
    ends : {"poles", "open", "loop"}
        "poles": first and last points are on the axis (r = 0) and become single pole
        vertices closed by fans; "open": both end rings are boundary loops; "loop": the
        profile is closed and the last ring is stitched back to the first (a torus).

    Returns
    -------
    vertices : (V, 3) float64
    faces : (F, 3) int64, outward-oriented
    """
    z = np.asarray(profile_z, dtype=np.float64)
    r = np.asarray(profile_r, dtype=np.float64)
    if ends not in ("poles", "open", "loop"):
        raise ValueError(f"ends must be 'poles', 'open' or 'loop', got {ends!r}")
    rings = slice(1, -1) if ends == "poles" else slice(None)
    if ends == "poles" and (r[0] != 0 or r[-1] != 0 or len(r) < 3):
        raise ValueError("ends='poles' needs a profile from axis to axis with a ring between")
    if np.any(r[rings] <= 0):
        raise ValueError("every ring except the poles must have a positive radius")
    counts = ring_counts(r, edge)
    if ends == "poles":
        counts[[0, -1]] = 1
    phase = np.arange(len(z)) % 2                  # stagger consecutive rings by half a step
    first = np.r_[0, np.cumsum(counts)]
    angle = np.concatenate([(2 * np.arange(n) + p) * np.pi / n for n, p in zip(counts, phase)])
    radius, height = np.repeat(r, counts), np.repeat(z, counts)
    vertices = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), height])
    ring = [np.arange(first[i], first[i + 1]) for i in range(len(z))]
    bands = [(i, i + 1) for i in range(len(z) - 1)] + ([(len(z) - 1, 0)] if ends == "loop" else [])
    faces = np.vstack([_stitch(ring[i], phase[i], ring[j], phase[j]) for i, j in bands])
    return vertices, faces.astype(np.int64)


def _arclength_rings(z: np.ndarray, r: np.ndarray, step: float, breaks=()):
    """Resample a dense profile polyline at near-equal arc-length steps.

    The polyline is cut at the point indices in ``breaks`` (increasing), and each piece
    gets a whole number of equal steps (at least 2) as close to ``step`` as fits, so the
    endpoints and every break point (e.g. a neck) are rings exactly.
    """
    bounds = [0, *breaks, len(z) - 1]
    ring_z, ring_r = [z[:1]], [r[:1]]
    for i, j in zip(bounds[:-1], bounds[1:]):
        piece_z, piece_r = z[i:j + 1], r[i:j + 1]
        s = np.r_[0.0, np.cumsum(np.hypot(np.diff(piece_z), np.diff(piece_r)))]
        t = np.linspace(0.0, s[-1], max(2, round(s[-1] / step)) + 1)[1:]
        ring_z.append(np.interp(t, s, piece_z))
        ring_r.append(np.interp(t, s, piece_r))
    return np.concatenate(ring_z), np.concatenate(ring_r)


def _smooth_max(a, b, k: float):
    """C2 smooth maximum: exactly ``max(a, b)`` where ``|a - b| >= k``, and ``k / 6``
    above it where ``a == b``.  Compact support keeps the blobs exact away from necks."""
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.maximum(a, b) + h ** 3 * k / 6.0


def _chain_r2(z, blobs, blends):
    """Squared profile radius of ellipsoids of revolution along z, each merged with the
    union of the previous ones by a smooth maximum of width ``blends[i]``.

    ``blobs`` holds ``(center_z, semi_axis_z, radius)``; each blob alone has the parabola
    ``r^2 = radius^2 (1 - ((z - center_z) / semi_axis_z)^2)`` as squared profile.
    """
    def blob_r2(center, semi_axis, radius):
        return radius ** 2 * (1.0 - ((z - center) / semi_axis) ** 2)

    r2 = blob_r2(*blobs[0])
    for blob, k in zip(blobs[1:], blends):
        r2 = _smooth_max(r2, blob_r2(*blob), k)
    return r2


def blob_profile(blobs, neck: float | None = None, n_dense: int = 20001):
    """Dense smooth profile of blobs (sorted by ``center_z``) joined by necks.

    Each junction's blend width is solved for so that the narrowest radius between the
    two blob centres is exactly ``neck``.

    Returns
    -------
    z, r : (n_dense + len(blobs) - 1,) float64
        Profile from the bottom pole to the top pole (r = 0 at both ends), including
        the neck points.
    neck_z : (len(blobs) - 1,) float64
        Heights of the necks (the profile's local minima of r).
    """
    blends, neck_z = [], []
    for i in range(1, len(blobs)):
        lo, hi = blobs[i - 1][0], blobs[i][0]

        def narrowest(k, i=i, lo=lo, hi=hi):
            return minimize_scalar(lambda zz: _chain_r2(zz, blobs[:i + 1], blends + [k]),
                                   bounds=(lo, hi), method="bounded",
                                   options={"xatol": 1e-10})

        def excess(k):
            return narrowest(k).fun - neck ** 2

        k_lo, k_hi = 1e-9, 1.0
        if excess(k_lo) >= 0:
            raise ValueError(f"blobs {i - 1} and {i} overlap too much for a neck of radius {neck}")
        while excess(k_hi) < 0:     # the narrowest radius grows with the blend width
            k_hi *= 2.0
        k = brentq(excess, k_lo, k_hi, xtol=1e-13)
        blends.append(k)
        neck_z.append(narrowest(k).x)
    bottom = blobs[0][0] - blobs[0][1]
    top = blobs[-1][0] + blobs[-1][1]
    # cosine spacing resolves the square-root behaviour of r(z) at the poles; the necks
    # themselves are included so they can become rings
    z = bottom + (top - bottom) * (1.0 - np.cos(np.linspace(0.0, np.pi, n_dense))) / 2.0
    z = np.sort(np.r_[z, neck_z])
    r = np.sqrt(np.clip(_chain_r2(z, blobs, blends), 0.0, None))
    r[[0, -1]] = 0.0
    if np.any(r[1:-1] <= 0):
        raise ValueError("the profile pinches off between blobs: move them closer")
    return z, r, np.asarray(neck_z)


def revolve_profile(z: np.ndarray, r: np.ndarray, n_around: int, ring_z=()):
    """Mesh a dense pole-to-pole profile with ~``n_around`` vertices on its widest ring,
    with a ring exactly at each of the profile points at heights ``ring_z``."""
    edge = 2 * np.pi * r.max() / n_around
    breaks = np.searchsorted(z, ring_z)
    ring_z, ring_r = _arclength_rings(z, r, ROW_HEIGHT * edge, breaks)
    return _revolve(ring_z, ring_r, edge, ends="poles")


def ellipsoid_of_revolution(a: float = 1.0, c: float = 1.6, n_around: int = 60) -> Shape:
    """Spheroid ``(x^2 + y^2) / a^2 + z^2 / c^2 = 1`` meshed as a surface of revolution.

    Parameters
    ----------
    a : float
        Equatorial semi-axis (length units).
    c : float
        Polar semi-axis along z (length units).
    n_around : int
        Vertices on the equator (rounded to a multiple of 6); sets the edge length
        ``2 pi a / n_around`` (defaults: about 3900 faces).

    Returns
    -------
    Shape
        Closed genus-0 mesh centred at the origin, exactly invariant under rotations by
        60 degrees about z, with a vertex on each pole.
    """
    z, r, _ = blob_profile([(0.0, c, a)])
    vertices, faces = revolve_profile(z, r, n_around)
    return Shape("ellipsoid_of_revolution", vertices, faces)


def torus(major: float = 1.0, minor: float = 0.4, n_major: int = 72,
          n_minor: int | None = None) -> Shape:
    """Ring torus about the z axis.

    Parameters
    ----------
    major : float
        Distance from the z axis to the tube centre (length units).
    minor : float
        Tube radius, ``0 < minor < major`` (length units).
    n_major : int
        Vertices on the outer equator (rounded to a multiple of 6); sets the edge length
        ``2 pi (major + minor) / n_major``.  Inner rings get proportionally fewer.
    n_minor : int, optional
        Number of rings around the tube; default: the even count giving near-equilateral
        triangles (even keeps the ring pair across the seam staggered).  Defaults give
        about 2500 faces.

    Returns
    -------
    Shape
        Closed genus-1 mesh centred at the origin.
    """
    if not 0 < minor < major:
        raise ValueError(f"need 0 < minor < major, got minor={minor}, major={major}")
    edge = 2 * np.pi * (major + minor) / n_major
    if n_minor is None:
        n_minor = 2 * max(2, round(np.pi * minor / (ROW_HEIGHT * edge)))
    t = 2 * np.pi * np.arange(n_minor) / n_minor
    # counter-clockwise in the (r, z) half-plane: outside on the right
    vertices, faces = _revolve(minor * np.sin(t), major + minor * np.cos(t), edge, ends="loop")
    return Shape("torus", vertices, faces)


def open_tube(radius: float = 1.0, length: float = 3.0, n_around: int = 48,
              n_rings: int | None = None) -> Shape:
    """Open cylinder about the z axis, from ``z = -length/2`` to ``length/2``.

    Parameters
    ----------
    radius, length : float
        Cylinder radius and length (length units).
    n_around : int
        Vertices per ring (rounded to a multiple of 6).
    n_rings : int, optional
        Number of rings; default: spacing for near-equilateral triangles
        (defaults: 27 rings, 2496 faces).

    Returns
    -------
    Shape
        Open mesh with two boundary loops (Euler characteristic 0).
    """
    edge = 2 * np.pi * radius / n_around
    if n_rings is None:
        n_rings = max(2, round(length / (ROW_HEIGHT * edge))) + 1
    z = np.linspace(-length / 2, length / 2, n_rings)
    vertices, faces = _revolve(z, np.full(n_rings, radius), edge, ends="open")
    return Shape("open_tube", vertices, faces)


def capped_cylinder(radius: float = 1.0, height: float = 3.0, n_around: int = 48) -> Shape:
    """Closed cylinder (flat caps, sharp rims) about the z axis, centred at the origin.

    Parameters
    ----------
    radius, height : float
        Cylinder radius and height (length units).
    n_around : int
        Vertices on the rim rings (rounded to a multiple of 6); sets the edge length
        (defaults: about 3400 faces).

    Returns
    -------
    Shape
        Closed genus-0 mesh with a vertex at the centre of each cap.
    """
    edge = 2 * np.pi * radius / n_around
    step = ROW_HEIGHT * edge
    # each straight piece gets its own whole number of steps so rings sit on the rims
    n_cap = max(1, round(radius / step))
    n_side = max(1, round(height / step))
    cap_r = radius * np.arange(n_cap + 1) / n_cap
    side_z = np.linspace(-height / 2, height / 2, n_side + 1)[1:-1]
    z = np.r_[np.full(n_cap + 1, -height / 2), side_z, np.full(n_cap + 1, height / 2)]
    r = np.r_[cap_r, np.full(n_side - 1, radius), cap_r[::-1]]
    vertices, faces = _revolve(z, r, edge, ends="poles")
    return Shape("capped_cylinder", vertices, faces)
