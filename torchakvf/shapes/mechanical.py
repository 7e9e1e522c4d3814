"""Mechanical families of procedural shapes (:mod:`.procedural`): plain unions of boxes,
cylinders, frusta and prisms, so that parts meet at sharp creases (sometimes a small fillet),
with holes cut through. Where the symmetry fields cannot tell parts apart (coaxial cylinders,
coplanar slabs) only the crease can, which is what these families exercise.

Each generator draws every choice from its ``rng`` and returns a :class:`~.design.Design`
(z up, sizes of order 1: the mesher rotates and scales).
"""
from __future__ import annotations

import numpy as np

from .design import Design, Family, uniform
from .sdf import Box, Difference, Ellipsoid, Extrusion, Revolved, Torus, Union, cylinder, frame, rotation

#: The local frame that extrudes a local-xy polygon along world y (local z = -y, local y = z).
_XZ_PLANE = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _hexagon(inradius: float) -> tuple:
    c = inradius / np.cos(np.pi / 6)
    return tuple((c * np.cos(a), c * np.sin(a)) for a in np.arange(6) * np.pi / 3)


def _turned(z0: float, z1: float, r0: float, r1: float, c0: float, c1: float) -> Revolved:
    """A section of a turned part about z: radius r0 at z0 to r1 at z1, its outer corners
    chamfered by c0 and c1 (0: sharp)."""
    prof = [(0.0, z0)] + ([(r0 - c0, z0), (r0, z0 + c0)] if c0 > 0 else [(r0, z0)])
    prof += ([(r1, z1 - c1), (r1 - c1, z1)] if c1 > 0 else [(r1, z1)]) + [(0.0, z1)]
    return Revolved(profile=tuple(prof))


def _step_radii(rng, n: int, r0: float, lo: float, hi: float) -> list:
    """n radii from r0, each a step of 1.25-1.9x up or down from the last, kept in [lo, hi]."""
    radii = [r0]
    for _ in range(n - 1):
        step = float(np.exp(rng.uniform(np.log(1.25), np.log(1.9))))
        up = rng.random() < 0.5
        r = radii[-1] * step if up else radii[-1] / step
        if not lo <= r <= hi:
            r = radii[-1] / step if up else radii[-1] * step
        radii.append(r)
    return radii


def shaft(rng) -> Design:
    """A turned part: 2-5 coaxial sections stepping up or down in radius, the end sections
    sometimes tapered, exposed corners sometimes chamfered, sometimes a fillet at the steps
    and blind centre bores in the ends; a part per section (people cut at each step)."""
    n = int(rng.integers(2, 6))
    radii = _step_radii(rng, n, uniform(rng, 0.2, 0.6), 0.12, 0.75)
    lengths = [uniform(rng, 0.2, 0.9) for _ in range(n)]
    z = np.concatenate([[0.0], np.cumsum(lengths)]) - sum(lengths) / 2
    chamfer = rng.random() < 0.5
    parts, free = [], {}
    for i in range(n):
        r = radii[i]
        below = radii[i - 1] if i > 0 else 0.0
        above = radii[i + 1] if i < n - 1 else 0.0
        # A smaller section reaches half-way into its larger neighbours (no coplanar end discs).
        z0 = z[i] - (0.5 * lengths[i - 1] if below > r else 0.0)
        z1 = z[i + 1] + (0.5 * lengths[i + 1] if above > r else 0.0)
        taper = uniform(rng, 0.7, 0.9) if (i in (0, n - 1) and rng.random() < 0.3) else 1.0
        r0 = r * taper if i == 0 else r
        r1 = r * taper if i == n - 1 and i > 0 else r
        c0 = uniform(rng, 0.1, 0.3) * min(r0 - below if below < r else 0.0, lengths[i] / 2) if chamfer else 0.0
        c1 = uniform(rng, 0.1, 0.3) * min(r1 - above if above < r else 0.0, lengths[i] / 2) if chamfer else 0.0
        parts.append((f"section {i + 1}", _turned(z0, z1, r0, r1, c0, c1)))
        if i in (0, n - 1):
            free[i] = (r0 - c0) if i == 0 else (r1 - c1)        # the end face's radius
    holes, thin = [], min(min(lengths), 2 * min(radii))
    for end in (0, n - 1) if rng.random() < 0.3 else ():
        # A blind centre bore in an end section (one through every section would leave a middle
        # section's bore wall apart from its outside), where the end face is wide enough.
        if free[end] < 0.25:
            continue
        rb, depth = uniform(rng, 0.2, 0.4) * free[end], uniform(rng, 0.3, 0.8) * lengths[end]
        top = z[-1] if end else z[0]
        holes.append(cylinder((0, 0, top - (depth if end else -depth)), (0, 0, top + (1 if end else -1)), rb))
        thin = min(thin, free[end] - rb)
    blend = uniform(rng, 0.03, 0.08) * min(radii) if rng.random() < 0.4 else 0.0
    return Design(parts, thin, blend, holes, params={"sections": n, "radii": radii, "lengths": lengths,
                                                      "bore": bool(holes), "chamfer": chamfer, "fillet": blend})


def flanged_hub(rng) -> Design:
    """A thin disc (thickness 0.08-0.25 of its radius) and a hub on one side or a hub on each
    side (two parts), sometimes bolt holes on a pitch circle, a bore, a fillet."""
    t, rh = uniform(rng, 0.08, 0.25), uniform(rng, 0.22, 0.5)
    both = rng.random() < 0.4
    L1 = uniform(rng, 0.25, 1.0)
    parts = [("disc", cylinder((0, 0, -t / 2), (0, 0, t / 2), 1.0))]
    cham = uniform(rng, 0.05, 0.2) * rh if rng.random() < 0.5 else 0.0
    parts.append(("hub" if not both else "front hub", _turned(0.0, t / 2 + L1, rh, rh, 0.0, cham)))
    L2 = 0.0
    if both:
        L2 = uniform(rng, 0.2, 0.8)
        parts.append(("back hub", _turned(-t / 2 - L2, 0.0, rh, rh, cham, 0.0)))
    holes, thin = [], min(t, L1)
    if rng.random() < 0.6:
        n, rb = int(rng.integers(3, 9)), uniform(rng, 0.04, 0.08)
        pitch = uniform(rng, rh + rb + 0.08, 1.0 - rb - 0.08)
        phase = uniform(rng, 0, 2 * np.pi)
        for a in phase + 2 * np.pi * np.arange(n) / n:
            c = (pitch * np.cos(a), pitch * np.sin(a))
            holes.append(cylinder((*c, -t), (*c, t), rb))
        thin = min(thin, 2 * rb)
    if rng.random() < 0.5:
        rbore = uniform(rng, 0.35, 0.7) * rh
        holes.append(cylinder((0, 0, -t / 2 - L2 - 1), (0, 0, t / 2 + L1 + 1), rbore))
        thin = min(thin, rh - rbore)
    blend = uniform(rng, 0.02, 0.05) if rng.random() < 0.3 else 0.0
    return Design(parts, thin, blend, holes, params={"thickness": t, "hub_radius": rh, "hubs": 1 + both,
                                                      "hub_lengths": [L1, L2], "holes": len(holes), "fillet": blend})


def _plate_holes(rng, n: int, axis: int, span, across, depth, radius: float) -> list:
    """n holes along ``axis``-normal through a plate: centres spread over ``span`` (the plate's
    free length along its own direction) at y in ``across``; ``depth`` the plate's extent."""
    holes = []
    for s in np.linspace(span[0], span[1], n + 2)[1:-1]:
        y = float(rng.choice(across))
        a, b = [s, y, depth[0] - 0.1], [s, y, depth[1] + 0.1]
        if axis == 0:       # a hole through an upright plate (normal along x): s is its height
            a, b = [depth[0] - 0.1, y, s], [depth[1] + 0.1, y, s]
        holes.append(cylinder(a, b, radius))
    return holes


def bracket(rng) -> Design:
    """Plates at right angles: an L (base and upright, sometimes one or two gussets), a U
    channel or a Z; holes through the plates. A part per plate and per gusset."""
    t, w, b = uniform(rng, 0.06, 0.14), uniform(rng, 0.4, 1.0), uniform(rng, 0.5, 1.2)
    style = str(rng.choice(["L", "L", "U", "Z"]))
    parts = [("base", Box(center=(0.5, 0, t / 2), half=(0.5, w / 2, t / 2)))]
    top = b - t / 2 if style == "Z" else b
    parts.append(("upright", Box(center=(t / 2, 0, (t / 2 + top) / 2), half=(t / 2, w / 2, (top - t / 2) / 2))))
    if style == "U":
        b2 = uniform(rng, 0.6, 1.0) * b
        parts.append(("second upright", Box(center=(1 - t / 2, 0, (t / 2 + b2) / 2),
                                            half=(t / 2, w / 2, (b2 - t / 2) / 2))))
    elif style == "Z":
        c = uniform(rng, 0.3, 0.8)
        parts.append(("flange", Box(center=((t - c) / 2, 0, b - t / 2), half=((t + c) / 2, w / 2, t / 2))))
    g, tg, ng = 0.0, t, 0
    if style == "L" and rng.random() < 0.6:
        ng, g, tg = int(rng.integers(1, 3)), uniform(rng, 0.25, 0.5) * min(1.0, b), uniform(rng, 0.5, 1.0) * t
        tri = ((t / 2, t / 2), (t + g, t / 2), (t / 2, t + g))
        for i, y in enumerate([0.0] if ng == 1 else [-(w / 2 - tg / 2), w / 2 - tg / 2]):
            parts.append((f"gusset {i + 1}", Extrusion(center=(0, y, 0), rotation=_XZ_PLANE, polygon=tri,
                                                       half_height=tg / 2)))
    rh = uniform(rng, 0.04, 0.09) * min(1.0, w / 0.6)
    across = [0.0] if ng != 1 else [-w / 4, w / 4]
    holes = _plate_holes(rng, int(rng.integers(0, 3)), 2, (t + g + rh + 0.05, 0.95), across, (0, t), rh)
    holes += _plate_holes(rng, int(rng.integers(0, 3)), 0, (t + g + rh + 0.05, top - 0.05), across, (0, t), rh)
    thin = min(t, tg, 2 * rh)
    blend = uniform(rng, 0.01, 0.03) if rng.random() < 0.3 else 0.0
    return Design(parts, thin, blend, holes, params={"style": style, "thickness": t, "width": w, "height": b,
                                                      "gussets": ng, "holes": len(holes), "fillet": blend})


def table(rng) -> Design:
    """A table: a rectangular or round top (thickness varied) on 3-4 legs (square, round or
    tapered, sometimes splayed), or a round top on a pedestal and foot. A part per leg."""
    W, H = uniform(rng, 1.0, 1.8), uniform(rng, 0.5, 1.0)
    tt = uniform(rng, 0.035, 0.08) * W
    round_top = rng.random() < 0.35
    top_z = H - tt / 2
    if round_top:
        R = W / 2
        parts = [("top", _turned(H - tt, H, R, R, 0.0, uniform(rng, 0.0, 0.4) * tt))]
    else:
        D = uniform(rng, 0.5, 1.0) * W
        parts = [("top", Box(center=(0, 0, top_z), half=(W / 2, D / 2, tt / 2), rounding=uniform(rng, 0, 0.45) * tt))]
    lw = uniform(rng, 0.025, 0.07) * (W / 1.2)
    if round_top and rng.random() < 0.35:
        rc, ft = uniform(rng, 0.04, 0.1), uniform(rng, 0.03, 0.08)
        parts.append(("column", cylinder((0, 0, ft / 2), (0, 0, top_z), rc)))
        parts.append(("foot", _turned(0.0, ft, uniform(rng, 0.5, 0.8) * R, uniform(rng, 0.5, 0.8) * R * 0.9, 0.0, 0.0)))
        return Design(parts, min(tt, ft, 2 * rc), 0.0, params={"top": "round", "legs": "pedestal", "height": H,
                                                                "top_thickness": tt})
    n = 4 if not round_top else int(rng.integers(3, 5))
    style = str(rng.choice(["square", "round", "tapered"]))
    inset = uniform(rng, 0.02, 0.15) * W / 2
    splay = np.radians(uniform(rng, 3, 10)) if (style != "square" and rng.random() < 0.3) else 0.0
    for i in range(n):
        if round_top:
            a = 2 * np.pi * i / n + np.pi / 4
            xy = (R - inset - lw) * np.array([np.cos(a), np.sin(a)])
        else:
            xy = np.array([(W / 2 - inset - lw) * (1 if i in (0, 3) else -1),
                           (D / 2 - inset - lw) * (1 if i < 2 else -1)])
        foot = xy + np.tan(splay) * top_z * xy / np.linalg.norm(xy)
        length = np.hypot(top_z, np.linalg.norm(foot - xy))
        if style == "square":
            leg = Box(center=(*xy, top_z / 2), half=(lw, lw, top_z / 2))
        else:
            leg = Revolved(center=(*foot, 0.0), rotation=_tilt(foot, xy, top_z),
                           profile=((0, 0), (lw * (0.6 if style == "tapered" else 1.0), 0), (lw, length), (0, length)))
        parts.append((f"leg {i + 1}", leg))
    return Design(parts, min(tt, 2 * lw), 0.0, params={"top": "round" if round_top else "rect", "legs": n,
                                                        "leg_style": style, "height": H, "top_thickness": tt,
                                                        "splay_deg": np.degrees(splay)})


def _tilt(foot, top_xy, top_z) -> np.ndarray:
    """The frame whose local z runs from a leg's foot (z = 0) to its top (top_xy, top_z)."""
    return frame(np.array([top_xy[0] - foot[0], top_xy[1] - foot[1], top_z]))


def chair(rng) -> Design:
    """A chair (seat, back panel, four legs, sometimes two arms) or a stool (round seat, 3-4
    legs, sometimes splayed). A part per leg, arm and the back."""
    if rng.random() < 0.35:
        R, st, sh = uniform(rng, 0.16, 0.3), uniform(rng, 0.04, 0.1), uniform(rng, 0.45, 0.8)
        parts = [("seat", _turned(sh - st, sh, R, R, uniform(rng, 0, 0.3) * st, uniform(rng, 0, 0.4) * st))]
        n, lw = int(rng.integers(3, 5)), uniform(rng, 0.02, 0.04)
        splay, top = np.radians(uniform(rng, 0, 12)), sh - st / 2
        for i in range(n):
            a = 2 * np.pi * i / n
            xy = (R - 1.5 * lw) * np.array([np.cos(a), np.sin(a)])
            foot = xy * (1 + np.tan(splay) * top / np.linalg.norm(xy))
            length = np.hypot(top, np.linalg.norm(foot - xy))
            parts.append((f"leg {i + 1}", Revolved(center=(*foot, 0.0), rotation=_tilt(foot, xy, top),
                                                   profile=((0, 0), (lw, 0), (lw, length), (0, length)))))
        return Design(parts, min(st, 2 * lw), 0.0, params={"style": "stool", "legs": n, "seat_height": sh})
    sw, sd, st, sh = uniform(rng, 0.4, 0.6), uniform(rng, 0.4, 0.6), uniform(rng, 0.04, 0.1), uniform(rng, 0.4, 0.55)
    lw, inset = uniform(rng, 0.018, 0.045), uniform(rng, 0.0, 0.05)
    parts = [("seat", Box(center=(0, 0, sh - st / 2), half=(sw / 2, sd / 2, st / 2),
                          rounding=uniform(rng, 0, 0.4) * st))]
    bh, bt, tilt = uniform(rng, 0.3, 0.6), uniform(rng, 0.03, 0.07), np.radians(uniform(rng, 0, 15))
    bw = sw - uniform(rng, 0, 0.12)
    tilt_rot = rotation((1, 0, 0), tilt)
    base = np.array([0, -sd / 2 + bt / 2, sh - st / 2])
    parts.append(("back", Box(center=tuple(base + tilt_rot @ [0, 0, bh / 2 + st / 4]), rotation=tilt_rot,
                              half=(bw / 2, bt / 2, bh / 2 + st / 4))))
    round_legs = rng.random() < 0.5
    for i in range(4):
        x, y = (sw / 2 - inset - lw) * (1 if i in (0, 3) else -1), (sd / 2 - inset - lw) * (1 if i < 2 else -1)
        top = sh - st / 2
        if round_legs:
            leg = cylinder((x, y, 0), (x, y, top), lw)
        else:
            leg = Box(center=(x, y, top / 2), half=(lw, lw, top / 2))
        parts.append((f"leg {i + 1}", leg))
    arms = rng.random() < 0.3
    if arms:
        ah, aw = uniform(rng, 0.18, 0.28), uniform(rng, 0.02, 0.035)
        for s, name in ((1, "right arm"), (-1, "left arm")):
            x = s * (sw / 2 - aw)
            post = Box(center=(x, sd / 2 - 3 * aw, sh + ah / 2 - st / 4), half=(aw, aw, ah / 2 + st / 4))
            y0 = -sd / 2 + bt + 0.02 + np.tan(tilt) * ah          # clear of the tilted back
            bar = Box(center=(x, (y0 + sd / 2) / 2, sh + ah), half=(aw * 1.2, (sd / 2 - y0) / 2, aw))
            parts.append((name, Union((post, bar))))
    thin = min(st, 2 * lw, bt) if not arms else min(st, 2 * lw, bt, 2 * aw)
    return Design(parts, thin, 0.0, params={"style": "chair", "arms": arms, "back_height": bh,
                                             "tilt_deg": np.degrees(tilt), "seat_height": sh})


def bolt(rng) -> Design:
    """A bolt or pin: a head (hexagonal, round with a hex socket, or a dome) on a shank with a
    chamfered tip; sometimes a washer under the head, a nut (bolts) or a cross hole (pins)."""
    rs, Ls = uniform(rng, 0.07, 0.15), uniform(rng, 0.6, 1.4)
    head = str(rng.choice(["hex", "socket", "dome"]))
    holes, socket = [], 1.0
    if head == "hex":
        hh = uniform(rng, 0.6, 0.9) * 2 * rs
        solid = Extrusion(center=(0, 0, hh / 2), polygon=_hexagon(uniform(rng, 1.5, 1.9) * rs), half_height=hh / 2)
    elif head == "socket":
        hr, hh = uniform(rng, 1.4, 1.8) * rs, uniform(rng, 0.8, 1.2) * 2 * rs
        solid = _turned(0.0, hh, hr, hr, 0.0, uniform(rng, 0.05, 0.15) * hr)
        if rng.random() < 0.6:
            holes.append(Extrusion(center=(0, 0, hh), polygon=_hexagon(0.55 * rs), half_height=0.5 * hh))
            socket = 1.1 * rs
    else:
        hr, hh = uniform(rng, 1.5, 2.0) * rs, uniform(rng, 0.5, 0.9) * 1.6 * rs
        solid = Difference(Ellipsoid(axes=(hr, hr, hh)), Box(center=(0, 0, -hh), half=(2 * hr, 2 * hr, hh)))
    parts = [("head", solid)]
    washer = rng.random() < 0.3
    wt = uniform(rng, 0.3, 0.5) * rs
    if washer:
        parts.append(("washer", cylinder((0, 0, -wt), (0, 0, 0.2 * wt), uniform(rng, 1.8, 2.3) * rs)))
    nut = head != "dome" and rng.random() < 0.5
    c = uniform(rng, 0.1, 0.25) * rs
    parts.insert(1, ("shank", _turned(-Ls, hh / 2, rs, rs, 0.0 if nut else c, 0.0)))
    thin = min(2 * rs, hh, wt if washer else 1.0, socket)
    if nut:
        nh = uniform(rng, 0.7, 1.0) * 2 * rs
        parts.append(("nut", Extrusion(center=(0, 0, -Ls + 0.25 * nh), polygon=_hexagon(uniform(rng, 1.5, 1.8) * rs),
                                       half_height=nh / 2)))
    elif rng.random() < 0.5:
        rc, zc = uniform(rng, 0.25, 0.4) * rs, -Ls + uniform(rng, 2.0, 4.0) * rs
        holes.append(cylinder((-2 * rs, 0, zc), (2 * rs, 0, zc), rc))
        thin = min(thin, 2 * rc)
    return Design(parts, thin, 0.0, holes, params={"head": head, "shank_radius": rs, "shank_length": Ls,
                                                    "washer": washer, "nut": nut, "holes": len(holes)})


def wheel(rng) -> Design:
    """A wheel or pulley: a rim (a flat ring, grooved on pulleys, or a round tyre), a hub
    (sometimes bored) and 3-8 spokes, or a web disc with lightening holes and a hub on one
    side or one on each (two parts). A part per spoke."""
    rh, hl = uniform(rng, 0.1, 0.22), uniform(rng, 0.2, 0.5)
    web = rng.random() < 0.3
    if rng.random() < 0.6:
        W, rw = uniform(rng, 0.12, 0.35), uniform(rng, 0.07, 0.14)
        rim = Difference(cylinder((0, 0, -W / 2), (0, 0, W / 2), 1.0), cylinder((0, 0, -W), (0, 0, W), 1.0 - rw))
        if web and rng.random() < 0.5:
            g = min(uniform(rng, 0.25, 0.4) * W, rw)
            rim = Difference(rim, Torus(major=1.0 + 0.4 * g, minor=g))
        # Spokes and the web reach 0.3 of the way into the rim: clear of a pulley's groove.
        mid, thin, fit = 1.0 - 0.7 * rw, min(rw, W), 0.4 * W
    else:
        rt = uniform(rng, 0.06, 0.12)
        rim, mid, thin, fit = Torus(major=1.0 - rt, minor=rt), 1.0 - rt, 2 * rt, 0.8 * rt
    parts, holes = [("rim", rim)], []
    if web:
        wt = uniform(rng, 0.05, 0.12)
        parts.append(("web", cylinder((0, 0, -wt / 2), (0, 0, wt / 2), mid)))
        parts.append(("hub", cylinder((0, 0, 0), (0, 0, hl), rh)))
        if rng.random() < 0.5:
            parts.append(("back hub", cylinder((0, 0, -uniform(rng, 0.5, 1.0) * hl), (0, 0, 0), rh)))
        # Lightening holes, apart from each other: they join the web's two faces (whose edges
        # are buried in the hub and the rim), so the web is one region.
        nh = int(rng.integers(3, 7))
        rl = min(uniform(rng, 0.3, 0.42) * (mid - rh), 0.75 * 0.5 * (mid + rh) * np.sin(np.pi / nh))
        for a in 2 * np.pi * np.arange(nh) / nh:
            c = (0.5 * (mid + rh) * np.cos(a), 0.5 * (mid + rh) * np.sin(a))
            holes.append(cylinder((*c, -wt), (*c, wt), rl))
        thin, n = min(thin, wt), 0
    else:
        n, sr = int(rng.integers(3, 9)), min(uniform(rng, 0.025, 0.06), fit)   # a spoke's end fits in the rim
        # Spokes take at most 0.7 of the hub's girth: a closed ring of them would cut the hub in two.
        rh = max(rh, n * sr / (0.7 * np.pi))
        parts.append(("hub", cylinder((0, 0, -hl / 2), (0, 0, hl / 2), rh)))
        phase = uniform(rng, 0, 2 * np.pi)
        for i, a in enumerate(phase + 2 * np.pi * np.arange(n) / n):
            parts.append((f"spoke {i + 1}", cylinder((0, 0, 0), (mid * np.cos(a), mid * np.sin(a), 0), sr)))
        thin = min(thin, 2 * sr)
    if rng.random() < 0.5:
        rb = uniform(rng, 0.3, 0.6) * rh
        holes.append(cylinder((0, 0, -2), (0, 0, 2), rb))
        thin = min(thin, rh - rb)
    return Design(parts, thin, 0.0, holes, params={"web": web, "spokes": n, "hub_radius": rh, "holes": len(holes)})


def pipe_fitting(rng) -> Design:
    """A pipe fitting: an elbow (a bend and two straight ends), a tee, a wye or a cross (four
    arms), a blind socket bored into each end; sometimes a collar on each end (a part each).
    The sockets are blind: a bore through would leave each part's outside and inside joined
    only at the open ends, so a part between two others would be two regions."""
    w, va = uniform(rng, 0.25, 0.45), uniform(rng, 0.5, 1.2)            # wall; an arm's length beyond the joint
    style = str(rng.choice(["elbow", "tee", "wye", "cross"]))
    collar = rng.random() < 0.5
    wc, lc = uniform(rng, 0.15, 0.35), (uniform(rng, 0.5, 1.0) if collar else 0.0)
    # Where the arms (radius 1) leave the joint: 1 from the centre, 2.42 for a 45-degree branch.
    joint = {"elbow": 0.0, "tee": 1.0, "wye": 2.42, "cross": 1.0}[style]
    length = joint + va + lc
    ends, parts, holes, fillers = [], [], [], []
    if style == "elbow":
        Rb, arc = uniform(rng, 1.3, 2.2), float(np.radians(rng.choice([45, 60, 90])))
        parts.append(("bend", Torus(major=Rb, minor=1.0, arc=arc, flat_ends=True)))
        for a, sign in ((0.0, -1), (arc, 1)):
            ends.append((Rb * np.array([np.cos(a), np.sin(a), 0]), sign * np.array([-np.sin(a), np.cos(a), 0])))
            fillers.append(Ellipsoid(center=tuple(ends[-1][0]), axes=(0.95, 0.95, 0.95)))   # the flat joint
    else:
        dirs = {"tee": [(1, 0, 0), (-1, 0, 0), (0, 1, 0)], "wye": [(1, 0, 0), (-1, 0, 0), (0.7071, 0.7071, 0)],
                "cross": [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]}[style]
        ends = [(np.zeros(3), np.array(d, dtype=np.float64)) for d in dirs]
        if style == "cross":      # four arms only touch at the centre: fill it
            fillers.append(Ellipsoid(axes=(0.95, 0.95, 0.95)))
    stop = length - 0.5 * lc          # an arm ends inside its collar
    for i, (p, d) in enumerate(ends):
        if style in ("tee", "wye") and i < 2:          # the run: one cylinder through
            if i == 0:
                parts.append(("run", cylinder(ends[1][1] * stop, d * stop, 1.0)))
        else:
            name = "branch" if style in ("tee", "wye") else (f"end {i + 1}" if style == "elbow" else f"arm {i + 1}")
            parts.append((name, cylinder(p, p + d * stop, 1.0)))
        # A socket stays in its collar beyond the arm's buried end, or in the arm beyond the joint.
        depth = uniform(rng, 0.3, 0.8) * (0.5 * lc if collar else va)
        holes.append(cylinder(p + d * (length - depth), p + d * (length + 1), 1.0 - w))
        if collar:
            parts.append((f"collar {i + 1}", cylinder(p + d * (length - lc), p + d * length, 1.0 + wc)))
    thin = min(w, wc) if collar else w
    return Design(parts, thin, 0.0, holes, fillers, params={"style": style, "wall": w, "arm": va, "collars": collar})


#: The mechanical families (name -> Family).
FAMILIES = {
    "shaft": Family("mechanical", shaft, "turned part with steps in radius (the PSB's bearings)"),
    "flanged_hub": Family("mechanical", flanged_hub, "thin disc and hub: a thin part decimation can erase"),
    "bracket": Family("mechanical", bracket, "coplanar and perpendicular plates meeting at creases, holes"),
    "table": Family("mechanical", table, "flat top and legs: flat regions k-means cuts into stripes"),
    "chair": Family("mechanical", chair, "seat, back, legs, arms: furniture of many thin parts"),
    "bolt": Family("mechanical", bolt, "coaxial head, shank, washer and nut"),
    "wheel": Family("mechanical", wheel, "rotational symmetry: rim, hub and identical spokes"),
    "pipe_fitting": Family("mechanical", pipe_fitting, "tubes meeting at concave creases, bored through"),
}
