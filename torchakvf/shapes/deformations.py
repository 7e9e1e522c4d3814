"""Deformations of a shape that keep its faces and labels (near-isometric bends)."""
from __future__ import annotations

import numpy as np

from .shape import Shape


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
