"""What a procedural family draws (:class:`Design`), the family record, and the helpers the
generators of :mod:`.mechanical` and :mod:`.organic` share (limbs as chains of round cones)."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .sdf import RoundCone, Union, rotation


@dataclass
class Design:
    """A solid made of named parts.

    parts : [(name, solid)], solids callable on points [N, 3] -> [N] with ``bounds()``; a part
        is one solid (a leg of two round cones is one :class:`~.sdf.Union`).
    thin : the thinnest dimension (length units) the mesh must resolve (a disc's thickness).
    blend : smooth-union radius between parts (0: a plain union, parts meet at creases).
    holes : solids cut from the whole (bores, bolt holes); never parts.
    fillers : solids added to the whole, never labelled, that must lie inside it (they close
        the planes where parts only touch, so no sample of the distance is exactly zero there).
    params : the main parameters drawn (JSON-ready after rounding), for the corpus index.
    """
    parts: list
    thin: float
    blend: float = 0.0
    holes: list = field(default_factory=list)
    fillers: list = field(default_factory=list)
    params: dict = field(default_factory=dict)


@dataclass
class Family:
    """A family of shapes: ``kind`` "organic" or "mechanical", ``generator`` rng -> Design,
    ``about`` what varies and why the family is there."""
    kind: str
    generator: Callable[[np.random.Generator], Design]
    about: str = ""


def limb(start, direction, lengths, radii, bends, bend_axis, blend: float = 0.0) -> Union:
    """A chain of round cones from ``start``: segment i has length lengths[i], radii[i] to
    radii[i + 1] at its ends, and turns by bends[i] radians about ``bend_axis`` (at its
    start) from the previous direction; a leg, an arm, a finger, a tentacle."""
    p = np.asarray(start, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    cones = []
    for i, (length, bend) in enumerate(zip(lengths, bends)):
        d = rotation(bend_axis, bend) @ d
        q = p + length * d
        cones.append(RoundCone(tuple(p), tuple(q), float(radii[i]), float(radii[i + 1])))
        p = q
    return Union(tuple(cones), blend)


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One draw from U(lo, hi) as a Python float (a design parameter)."""
    return float(rng.uniform(lo, hi))


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _samples(solid, n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Points [M, 3] along the axes of a limb's round cones and the radius [M] at each (its
other solids, a hand or a foot, are left out)."""
    cones = [c for c in (solid.parts if isinstance(solid, Union) else (solid,)) if isinstance(c, RoundCone)]
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = [np.asarray(c.a) + t * (np.asarray(c.b) - np.asarray(c.a)) for c in cones]
    rad = [c.ra + t[:, 0] * (c.rb - c.ra) for c in cones]
    return np.concatenate(pts), np.concatenate(rad)


def apart(limbs, gap: float, body=None) -> bool:
    """Whether every two of ``limbs`` (round cones or unions of them) keep ``gap`` between
    their surfaces (sampled along their axes): limbs that touch would merge their parts.
    body : a solid the limbs grow from; where a limb is buried in it, it may touch others."""
    samples = [_samples(s) for s in limbs]
    if body is not None:
        samples = [(p[body(p) + r > 0], r[body(p) + r > 0]) for p, r in samples]
        samples = [(p, r) for p, r in samples if len(p)]
    for i in range(len(samples)):
        for j in range(i):
            (p, r), (q, s) = samples[i], samples[j]
            d = np.linalg.norm(p[:, None] - q[None], axis=2) - r[:, None] - s[None]
            if d.min() < gap:
                return False
    return True


def clear_of(solid, limb, gap: float, skip: int = 1) -> bool:
    """Whether ``limb`` beyond its first ``skip`` cones stays ``gap`` outside ``solid`` (a limb
    that curls back into the body it grows from would cut its part in two)."""
    cones = limb.parts if isinstance(limb, Union) else (limb,)
    if len(cones) <= skip:
        return True
    p, r = _samples(Union(tuple(cones[skip:])))
    return bool(np.all(solid(p) - r >= gap))
