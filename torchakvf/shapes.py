"""Built-in triangle meshes generated in code (pure numpy + scipy).

They serve two purposes:

1. test oracles for eigenvalue tables of the discrete Killing operator (spheres,
   ellipsoids, tori, tubes, flat patches, ...);
2. composite shapes with *known* parts (blobs joined by thin necks, disconnected tori)
   for segmentation tests and the demo, with a ground-truth label per face.

Conventions for every mesh: faces are counter-clockwise seen from outside (outward
normals; +z for the planar ones), the mesh is manifold, and it has no duplicate vertices
and no degenerate faces.  Lengths are in arbitrary units (the unit sphere has radius 1).

Triangle quality drives the accuracy and conditioning of the operator, so surfaces of
revolution are built ring by ring with near-equilateral triangles of one target edge
length: rings are spaced sqrt(3)/2 edge apart in arc length along the profile, each ring
gets about circumference/edge vertices, consecutive rings are staggered by half a step,
and a pole is closed by a fan over a 6-vertex ring (a regular hexagonal cap).  Every
ring count is a multiple of 6, so these meshes are exactly invariant under rotations by
60 degrees about z.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, minimize_scalar
from scipy.spatial import Delaunay

__all__ = [
    "Shape",
    "icosphere",
    "ellipsoid",
    "ellipsoid_of_revolution",
    "torus",
    "open_tube",
    "capped_cylinder",
    "flat_disk",
    "square_patch",
    "hemisphere",
    "dumbbell",
    "three_blobs",
    "sphere_with_two_ellipsoids",
    "torus_chain",
    "bend",
    "BUILTIN_SHAPES",
]

# Ring vertex counts are multiples of this: exact 6-fold symmetry about z, and the ring
# next to a pole is a hexagon whose fan triangles are near-equilateral.
_SYMMETRY = 6
# Height of an equilateral triangle with unit edge: the profile arc-length step per unit
# of target edge length.
_ROW = np.sqrt(3.0) / 2.0


@dataclass(eq=False)  # array fields: the generated element-wise __eq__ would be ambiguous
class Shape:
    """A named triangle mesh with optional ground-truth part labels.

    Attributes
    ----------
    name : str
        Short identifier (the key in :data:`BUILTIN_SHAPES` for composite shapes).
    vertices : np.ndarray, shape (V, 3), float64
        Vertex positions.
    faces : np.ndarray, shape (F, 3), int64
        0-based vertex indices, counter-clockwise seen from outside.
    part_labels : np.ndarray, shape (F,), int64, or None
        Ground-truth part of each face, in ``0 .. n_parts - 1``; None for one-part shapes.
    n_parts : int
        Number of ground-truth parts (1 for shapes without labels).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    part_labels: np.ndarray | None = None
    n_parts: int = 1


# ---------------------------------------------------------------------------------------
# Icosphere family
# ---------------------------------------------------------------------------------------

def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit icosahedron with a vertex on each pole of the z axis, faces outward.

    This orientation (rather than the usual one with coordinate mirror planes) leaves no
    face symmetric about z = 0, so :func:`hemisphere`'s centroid test never sees a tie.
    """
    k = np.arange(5)
    z_ring, r_ring = 1.0 / np.sqrt(5.0), 2.0 / np.sqrt(5.0)
    upper = np.column_stack([r_ring * np.cos(2 * np.pi * k / 5),
                             r_ring * np.sin(2 * np.pi * k / 5), np.full(5, z_ring)])
    lower = np.column_stack([r_ring * np.cos(2 * np.pi * (k + 0.5) / 5),
                             r_ring * np.sin(2 * np.pi * (k + 0.5) / 5), np.full(5, -z_ring)])
    vertices = np.vstack([[0.0, 0.0, 1.0], upper, lower, [0.0, 0.0, -1.0]])
    u, w = 1 + k, 1 + (k + 1) % 5           # consecutive upper-ring vertices
    lo, lo_next = 6 + k, 6 + (k + 1) % 5    # lower-ring vertex between them, and the next
    faces = np.vstack([
        np.column_stack([np.zeros(5, int), u, w]),     # top cap
        np.column_stack([u, lo, w]),                   # band, pointing down
        np.column_stack([w, lo, lo_next]),             # band, pointing up
        np.column_stack([np.full(5, 11), lo_next, lo]),  # bottom cap
    ])
    return vertices, faces.astype(np.int64)


def _subdivide_on_sphere(vertices: np.ndarray, faces: np.ndarray):
    """Split every triangle into 4 at its edge midpoints, pushed onto the unit sphere."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    midpoints = vertices[unique].mean(axis=1)
    midpoints /= np.linalg.norm(midpoints, axis=1, keepdims=True)
    m01, m12, m20 = (inverse.reshape(-1, 3) + len(vertices)).T
    a, b, c = faces.T
    new_faces = np.vstack([np.column_stack([a, m01, m20]), np.column_stack([b, m12, m01]),
                           np.column_stack([c, m20, m12]), np.column_stack([m01, m12, m20])])
    return np.vstack([vertices, midpoints]), new_faces


def icosphere(level: int = 3, radius: float = 1.0) -> Shape:
    """Subdivided icosahedron projected onto a sphere.

    Parameters
    ----------
    level : int
        Number of 1-to-4 subdivisions: ``20 * 4**level`` faces, ``30 * 4**level`` edges,
        ``10 * 4**level + 2`` vertices (level 3: 1280 faces; level 4: 5120 faces).
    radius : float
        Sphere radius (length units).

    Returns
    -------
    Shape
        Closed genus-0 mesh centred at the origin, with a vertex on each pole.
    """
    vertices, faces = _icosahedron()
    for _ in range(level):                 # each child keeps its parent's orientation
        vertices, faces = _subdivide_on_sphere(vertices, faces)
    return Shape("icosphere", radius * vertices, faces.astype(np.int64))


def ellipsoid(axes: tuple[float, float, float] = (1.0, 1.3, 1.7), level: int = 4) -> Shape:
    """Icosphere scaled along x, y, z into a triaxial ellipsoid.

    Parameters
    ----------
    axes : (3,) floats
        Semi-axes along x, y, z (length units).
    level : int
        Icosphere subdivision level (level 4: 5120 faces).

    Returns
    -------
    Shape
        Closed genus-0 mesh centred at the origin.
    """
    sphere = icosphere(level)
    return Shape("ellipsoid", sphere.vertices * np.asarray(axes, dtype=np.float64), sphere.faces)


def hemisphere(level: int = 4) -> Shape:
    """Upper half (faces with centroid z > 0) of the unit ``icosphere(level)``.

    Parameters
    ----------
    level : int
        Subdivision level of the sphere it is cut from (level 4: 2560 faces).

    Returns
    -------
    Shape
        Open disk-like mesh (one boundary loop near z = 0), unreferenced vertices removed.
    """
    sphere = icosphere(level)
    keep = sphere.vertices[sphere.faces, 2].mean(axis=1) > 0
    used, faces = np.unique(sphere.faces[keep], return_inverse=True)
    return Shape("hemisphere", sphere.vertices[used], faces.reshape(-1, 3).astype(np.int64))


# ---------------------------------------------------------------------------------------
# Surfaces of revolution
# ---------------------------------------------------------------------------------------

def _ring_counts(r: np.ndarray, edge: float) -> np.ndarray:
    """Vertices per ring of radius ``r`` for a spacing close to ``edge`` (multiple of 6)."""
    per_ring = np.rint(2 * np.pi * np.asarray(r) / (_SYMMETRY * edge)).astype(np.int64)
    return _SYMMETRY * np.maximum(per_ring, 1)


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
    counts = _ring_counts(r, edge)
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


def _blob_profile(blobs, neck: float | None = None, n_dense: int = 20001):
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


def _revolve_profile(z: np.ndarray, r: np.ndarray, n_around: int, ring_z=()):
    """Mesh a dense pole-to-pole profile with ~``n_around`` vertices on its widest ring,
    with a ring exactly at each of the profile points at heights ``ring_z``."""
    edge = 2 * np.pi * r.max() / n_around
    breaks = np.searchsorted(z, ring_z)
    ring_z, ring_r = _arclength_rings(z, r, _ROW * edge, breaks)
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
    z, r, _ = _blob_profile([(0.0, c, a)])
    vertices, faces = _revolve_profile(z, r, n_around)
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
        n_minor = 2 * max(2, round(np.pi * minor / (_ROW * edge)))
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
        n_rings = max(2, round(length / (_ROW * edge))) + 1
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
    step = _ROW * edge
    # each straight piece gets its own whole number of steps so rings sit on the rims
    n_cap = max(1, round(radius / step))
    n_side = max(1, round(height / step))
    cap_r = radius * np.arange(n_cap + 1) / n_cap
    side_z = np.linspace(-height / 2, height / 2, n_side + 1)[1:-1]
    z = np.r_[np.full(n_cap + 1, -height / 2), side_z, np.full(n_cap + 1, height / 2)]
    r = np.r_[cap_r, np.full(n_side - 1, radius), cap_r[::-1]]
    vertices, faces = _revolve(z, r, edge, ends="poles")
    return Shape("capped_cylinder", vertices, faces)


# ---------------------------------------------------------------------------------------
# Planar meshes
# ---------------------------------------------------------------------------------------

def _planar_delaunay(xy: np.ndarray):
    """Delaunay triangulation of 2-D points, embedded at z = 0 with normals along +z."""
    faces = Delaunay(xy).simplices.astype(np.int64)
    e1 = xy[faces[:, 1]] - xy[faces[:, 0]]
    e2 = xy[faces[:, 2]] - xy[faces[:, 0]]
    clockwise = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] < 0
    faces[clockwise] = faces[clockwise][:, ::-1]
    return np.column_stack([xy, np.zeros(len(xy))]), faces


def flat_disk(radius: float = 1.0, n_boundary: int = 84) -> Shape:
    """Planar disk at z = 0: Delaunay triangulation of concentric rings of points.

    Rings are spaced ``sqrt(3)/2`` times the boundary spacing apart, each with about
    circumference/spacing points (a multiple of 6), staggered ring to ring, plus the
    centre: near-equilateral triangles throughout.

    Parameters
    ----------
    radius : float
        Disk radius (length units).
    n_boundary : int
        Points on the boundary circle (rounded to a multiple of 6); defaults give
        about 1300 faces.

    Returns
    -------
    Shape
        Open disk-like mesh (Euler characteristic 1) with normals along +z.
    """
    edge = 2 * np.pi * radius / n_boundary
    n_rings = max(1, round(radius / (_ROW * edge)))
    ring_r = radius * np.arange(1, n_rings + 1) / n_rings
    points = [np.zeros((1, 2))]
    for i, (rho, n) in enumerate(zip(ring_r, _ring_counts(ring_r, edge))):
        angle = (2 * np.arange(n) + i % 2) * np.pi / n
        points.append(rho * np.column_stack([np.cos(angle), np.sin(angle)]))
    vertices, faces = _planar_delaunay(np.vstack(points))
    return Shape("flat_disk", vertices, faces)


def square_patch(n: int = 24, jitter: float = 0.2, seed: int = 0) -> Shape:
    """Planar unit square ``[0, 1]^2`` at z = 0: Delaunay triangulation of a jittered grid.

    Parameters
    ----------
    n : int
        Grid points per side (``n * n`` vertices, ``2 (n - 1)^2`` faces; default 1058).
    jitter : float
        Interior points move uniformly by up to ``jitter`` grid spacings along x and y;
        boundary points stay put so the boundary is the exact square.
    seed : int
        Seed for ``np.random.default_rng``.

    Returns
    -------
    Shape
        Open disk-like mesh (Euler characteristic 1) with normals along +z.
    """
    spacing = 1.0 / (n - 1)
    x, y = np.meshgrid(np.linspace(0.0, 1.0, n), np.linspace(0.0, 1.0, n), indexing="xy")
    xy = np.column_stack([x.ravel(), y.ravel()])
    interior = np.all((xy > spacing / 2) & (xy < 1 - spacing / 2), axis=1)
    rng = np.random.default_rng(seed)
    xy[interior] += rng.uniform(-jitter, jitter, size=(interior.sum(), 2)) * spacing
    vertices, faces = _planar_delaunay(xy)
    return Shape("square_patch", vertices, faces)


# ---------------------------------------------------------------------------------------
# Composite shapes with known parts
# ---------------------------------------------------------------------------------------

def _blob_chain(name: str, blobs, neck: float, n_around: int) -> Shape:
    """Blobs along z joined by necks; part label = number of necks below the face centroid."""
    z, r, neck_z = _blob_profile(blobs, neck)
    vertices, faces = _revolve_profile(z, r, n_around, ring_z=neck_z)
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
    :func:`bend` near-isometric on it.

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
}
"""Composite shapes with ground-truth parts: name -> zero-argument constructor."""


def bend(shape: Shape, angle: float = 0.6) -> Shape:
    """Bend a shape about the y axis so that its z axis becomes a circular arc.

    The segment of the z axis spanned by the shape (length ``L``) maps onto an arc of the
    same length turning by ``angle`` in the xz-plane, centred on the middle of the
    z-range; each point keeps its y and its offset x along the arc's normal.  Lengths on
    the axis are preserved exactly; along z at offset x they scale by ``1 - x angle / L``
    and across z not at all, so the bend is near-isometric for slender shapes (relative
    edge length change at most ``angle * max|x| / L``).

    Parameters
    ----------
    shape : Shape
    angle : float
        Total turning angle of the axis (radians); 0 leaves the shape unchanged.

    Returns
    -------
    Shape
        New shape with bent vertices and copies of the faces and part labels.
    """
    x, y, z = shape.vertices.T
    lo, hi = z.min(), z.max()
    s = z - (lo + hi) / 2                       # arc length from the middle
    theta = angle * s / (hi - lo)
    # With bending radius R = s / theta:  x' = x cos(theta) + R (1 - cos(theta)) and
    # z' = z_mid + R sin(theta) - x sin(theta); sinc forms stay finite as theta -> 0.
    sin_over_theta = np.sinc(theta / np.pi)
    one_minus_cos_over_theta = theta / 2 * np.sinc(theta / (2 * np.pi)) ** 2
    vertices = np.column_stack([x * np.cos(theta) + s * one_minus_cos_over_theta, y,
                                (lo + hi) / 2 + s * sin_over_theta - x * np.sin(theta)])
    labels = None if shape.part_labels is None else shape.part_labels.copy()
    return Shape(f"{shape.name}_bent", vertices, shape.faces.copy(), labels, shape.n_parts)
