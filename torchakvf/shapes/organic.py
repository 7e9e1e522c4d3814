"""Organic families of procedural shapes (:mod:`.procedural`): smooth unions (blend radius
varied) of ellipsoids and chains of round cones, creatures of varied proportions, poses and
part counts, thin fins and wings, handles. People cut protrusions (legs, fins, tentacles) off
a body where they join it, which is where these families put the part boundaries.

Each generator draws every choice from its ``rng`` and returns a :class:`~.design.Design`
(z up, sizes of order 1: the mesher rotates and scales). Poses are redrawn until limbs keep
clear of each other and of the body they grow from (limbs that touch would merge parts).
"""
from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from .design import Design, Family, apart, clear_of, limb, uniform, unit
from .sdf import Box, Ellipsoid, Revolved, RoundCone, Union, capsule, frame, rotation

#: Redraws of a pose before a generator settles for its last one.
_POSE_TRIES = 60


def _posed(rng, draw, ok):
    """``draw(rng)`` until ``ok(result)``, at most _POSE_TRIES times (the last draw otherwise)."""
    for _ in range(_POSE_TRIES):
        out = draw(rng)
        if ok(out):
            return out
    return out


def _flat(center, span_dir, chord_dir, axes) -> Ellipsoid:
    """A thin ellipsoid (a fin, a wing): semi-axes (chord, span, thickness) along chord_dir,
    span_dir and their normal."""
    s = unit(span_dir)
    c = unit(np.asarray(chord_dir) - (np.asarray(chord_dir) @ s) * s)
    return Ellipsoid(center=tuple(center), rotation=np.stack([c, s, np.cross(c, s)], axis=1), axes=tuple(axes))


def quadruped(rng) -> Design:
    """A four-legged animal: an ellipsoidal body (sometimes chest and hips), a head on a neck,
    four legs of two or three round cones (length, thickness, stride, splay and knee bend
    drawn per leg), sometimes a tail and ears."""
    a, b, c = uniform(rng, 0.7, 1.2), uniform(rng, 0.25, 0.45), uniform(rng, 0.25, 0.45)
    if rng.random() < 0.5:
        hips = (0.65 * a, uniform(rng, 0.8, 1.1) * b, uniform(rng, 0.8, 1.1) * c)
        body = Union((Ellipsoid(center=(0.35 * a, 0, 0.05 * c), axes=(0.65 * a, b, c)),
                      Ellipsoid(center=(-0.35 * a, 0, 0), axes=hips)), 0.2 * b)
    else:
        body = Ellipsoid(axes=(a, b, c))
    ll, lr = c * uniform(rng, 1.8, 3.5), uniform(rng, 0.06, 0.13)
    segs = int(rng.integers(2, 4))
    blend = uniform(rng, 0.04, 0.1)      # limbs closer than the blend radius would be webbed together

    def draw(rng):
        legs = []
        for front in (True, False):
            for side in (1, -1):
                hip = (0.62 * a * (1 if front else -1), side * 0.55 * b, -0.3 * c)
                swing = uniform(rng, -0.45, 0.45)
                d = (np.sin(swing), side * uniform(rng, 0.0, 0.25), -np.cos(swing))
                knee = uniform(rng, 0.0, 0.7) * (1 if front else -1)
                parts = np.array([0.5, 0.5] if segs == 2 else [0.4, 0.4, 0.2]) * ll * uniform(rng, 0.9, 1.1)
                legs.append(limb(hip, d, parts, lr * np.linspace(1.0, 0.7, segs + 1),
                                 [0.0, knee, -knee][:segs], (0, 1, 0)))
        el, nl = uniform(rng, 0.2, 1.1), uniform(rng, 0.25, 0.7)
        neck0 = np.array([0.75 * a, 0, 0.3 * c])
        neck1 = neck0 + nl * np.array([np.cos(el), 0, np.sin(el)])
        hd = unit([np.cos(uniform(rng, -0.8, 0.3)), 0, np.sin(uniform(rng, -0.8, 0.3))])
        hs = uniform(rng, 0.16, 0.32)
        nr = uniform(rng, 0.45, 0.7) * min(b, c)
        neck = RoundCone(tuple(neck0), tuple(neck1), nr, 0.8 * nr)
        return legs, neck, neck1 + 0.5 * hs * hd, hd, hs

    def ok(o):
        legs, neck, hc, hd, hs = o
        head = RoundCone(tuple(neck.b), tuple(hc + hs * hd), 0.7 * hs, 0.5 * hs)     # the head, roughly
        return (apart(legs + [Union((neck, head))], max(0.25 * lr, blend), body)
                and all(clear_of(body, g, max(0.2 * lr, blend)) for g in legs))

    legs, neck, hc, hd, hs = _posed(rng, draw, ok)
    head = [neck, Ellipsoid(center=tuple(hc), rotation=frame(hd, (0, 0, 1)),
                            axes=(hs * uniform(rng, 0.55, 0.8), hs * uniform(rng, 0.5, 0.75), hs))]
    ears = rng.random() < 0.4
    if ears:
        for side in (1, -1):
            e0 = hc + np.array([-0.3 * hs, side * 0.3 * hs, 0.4 * hs])
            head.append(capsule(e0, e0 + uniform(rng, 0.15, 0.3) * np.array([-0.3, side * 0.3, 1.0]), 0.12 * hs))
    parts = [("body", body), ("head", Union(tuple(head), 0.05))]
    parts += [(f"{('front', 'hind')[i // 2]} {('left', 'right')[i % 2]} leg", g) for i, g in enumerate(legs)]
    thin = 2 * 0.7 * lr
    if rng.random() < 0.65:
        tr = uniform(rng, 0.045, 0.08)
        tail = _posed(rng, lambda r: limb((-0.85 * a, 0, 0.2 * c), (-1, 0, uniform(r, -0.8, 0.8)),
                                          [uniform(r, 0.15, 0.3)] * 3, [tr, 0.8 * tr, 0.65 * tr, 0.5 * tr],
                                          [0, uniform(r, -0.5, 0.5), uniform(r, -0.5, 0.5)], (0, 1, 0)),
                      lambda t: apart([t] + legs, max(0.5 * tr, blend)) and clear_of(body, t, max(0.3 * tr, blend)))
        parts.append(("tail", tail))
        thin = min(thin, 2 * 0.65 * tr)        # the last cone's start; its tip may thin out
    return Design(parts, thin, blend, params={"body": [a, b, c], "leg_length": ll, "leg_radius": lr,
                                                            "leg_segments": segs, "ears": ears})


def fish(rng) -> Design:
    """A fish: an ellipsoidal body (sometimes bent), a tail fin (rounded or forked), one or two
    dorsal fins, two pectoral fins, sometimes an anal fin; fins 0.035-0.1 of the body's length
    thick, drooping and swept at random."""
    b, c = uniform(rng, 0.15, 0.32), uniform(rng, 0.25, 0.5)
    ft = uniform(rng, 0.035, 0.1)                       # half the fins' thickness (body length 2)
    bend = uniform(rng, -0.35, 0.35) if rng.random() < 0.5 else 0.0
    if bend:
        back = rotation((0, 0, 1), bend)
        body = Union((Ellipsoid(center=(0.3, 0, 0), axes=(0.75, b, c)),
                      Ellipsoid(center=tuple(back @ [-0.45, 0, 0]), rotation=back, axes=(0.6, 0.85 * b, 0.85 * c))),
                     0.3 * b)
        tail_at, tail_dir = back @ np.array([-1.0, 0, 0]), back @ np.array([-1.0, 0, 0])
    else:
        body = Ellipsoid(axes=(1.0, b, c))
        tail_at, tail_dir = np.array([-0.95, 0, 0]), np.array([-1.0, 0, 0])
    lt, ht = uniform(rng, 0.22, 0.4), uniform(rng, 0.25, 0.55)
    if rng.random() < 0.5:
        lobes = []
        for s in (1, -1):
            d = unit(tail_dir * np.cos(0.6) + np.array([0, 0, s * np.sin(0.6)]) * uniform(rng, 0.6, 1.3))
            lobes.append(_flat(tail_at + 0.8 * ht * d, np.cross(d, [0, 1, 0]), d,
                               (0.9 * ht, 0.25 * ht, ft)))
        tail = Union((_flat(tail_at + 0.3 * lt * tail_dir, [0, 0, 1], tail_dir, (0.45 * lt, 0.4 * ht, ft)), *lobes))
    else:
        tail = _flat(tail_at + 0.6 * lt * tail_dir, [0, 0, 1], tail_dir, (lt, ht, ft))
    parts = [("body", body), ("tail fin", tail)]
    sweep = uniform(rng, 0.0, 0.6)
    dx = uniform(rng, -0.3, 0.3)
    dz = c * np.sqrt(max(1 - dx * dx, 0.2))
    parts.append(("dorsal fin", _flat((dx, 0, 0.9 * dz), [np.sin(-sweep), 0, np.cos(sweep)], [1, 0, 0],
                                      (uniform(rng, 0.2, 0.45), uniform(rng, 0.18, 0.35), ft))))
    droop, pl = uniform(rng, 0.1, 0.7), uniform(rng, 0.12, 0.28)
    psweep = uniform(rng, 0.2, 0.8)
    for s, name in ((1, "left pectoral fin"), (-1, "right pectoral fin")):
        span = rotation((0, 0, 1), s * psweep) @ rotation((1, 0, 0), -s * droop) @ np.array([0, s, 0])
        root = np.array([0.45, s * 0.75 * b, -0.3 * c])
        parts.append((name, _flat(root + 0.75 * pl * span, span, [1, 0, 0], (uniform(rng, 0.12, 0.25), pl, ft))))
    if rng.random() < 0.4:
        parts.append(("anal fin", _flat((-0.45, 0, -0.85 * c * 0.9), [0.3, 0, -1], [1, 0, 0],
                                         (uniform(rng, 0.12, 0.25), uniform(rng, 0.08, 0.18) + 0.1 * c, ft))))
    return Design(parts, 2 * ft, uniform(rng, 0.03, 0.07), params={"body": [1.0, b, c], "fin_half_thickness": ft,
                                                              "bend": bend, "fins": len(parts) - 1})


def bird(rng) -> Design:
    """A bird: an ellipsoidal body, a head with a beak on a short neck, two thin wings (span,
    chord, sweep and dihedral drawn: folded to spread, raised or lowered), a tail fan,
    sometimes two legs."""
    a, b, c = uniform(rng, 0.45, 0.7), uniform(rng, 0.18, 0.3), uniform(rng, 0.2, 0.32)
    body = Ellipsoid(axes=(a, b, c))
    el, nl, hr = uniform(rng, 0.3, 1.0), uniform(rng, 0.05, 0.25), uniform(rng, 0.11, 0.2)
    n0 = np.array([0.75 * a, 0, 0.35 * c])
    hc = n0 + (nl + 0.5 * hr) * np.array([np.cos(el), 0, np.sin(el)])
    pitch, bl = uniform(rng, -0.5, 0.2), uniform(rng, 0.6, 2.0) * hr
    tip = hc + (0.6 * hr + bl) * np.array([np.cos(pitch), 0, np.sin(pitch)])
    head = Union((RoundCone(tuple(n0), tuple(hc), 0.7 * hr, 0.8 * hr),
                  Ellipsoid(center=tuple(hc), axes=(hr, 0.9 * hr, hr)),
                  RoundCone(tuple(hc), tuple(tip), 0.45 * hr, 0.06 * hr)), 0.03)
    parts = [("body", body), ("head", head)]
    span, chord, wt = uniform(rng, 0.5, 1.1), uniform(rng, 0.15, 0.3), uniform(rng, 0.035, 0.06)
    dihedral, sweep = uniform(rng, -0.4, 0.9), uniform(rng, -0.2, 0.6)
    wx = uniform(rng, -0.2, 0.25) * a
    for s, name in ((1, "left wing"), (-1, "right wing")):
        d = rotation((0, 0, 1), s * sweep) @ rotation((1, 0, 0), s * dihedral) @ np.array([0, s, 0])
        root = np.array([wx, s * 0.5 * b, uniform(rng, 0.0, 0.4) * c])
        parts.append((name, _flat(root + 0.92 * span * d, d, [1, 0, 0], (chord, span, wt))))
    tl, tt = uniform(rng, 0.2, 0.4), uniform(rng, 0.025, 0.05)
    tilt = uniform(rng, -0.4, 0.3)
    td = np.array([-np.cos(tilt), 0, np.sin(tilt)])
    parts.append(("tail", _flat(np.array([-0.85 * a, 0, 0.1 * c]) + 0.8 * tl * td, [0, 1, 0], td,
                                (tl, uniform(rng, 0.1, 0.22), tt))))
    thin = 2 * min(wt, tt)
    if rng.random() < 0.5:
        lr, ll, knee = uniform(rng, 0.04, 0.06), uniform(rng, 0.12, 0.25), uniform(rng, 0.0, 0.8)
        for s, name in ((1, "left leg"), (-1, "right leg")):
            parts.append((name, limb((0.1 * a, s * 0.4 * b, -0.6 * c), (0, s * 0.15, -1), [ll, ll],
                                     [lr, lr, 0.8 * lr], [0.0, -knee], (0, 1, 0))))
        thin = min(thin, 1.6 * lr)
    return Design(parts, thin, uniform(rng, 0.03, 0.06), params={"body": [a, b, c], "span": span, "chord": chord,
                                                            "wing_half_thickness": wt, "dihedral": dihedral,
                                                            "sweep": sweep, "legs": len(parts) > 5})


def humanoid(rng) -> Design:
    """A humanoid or a teddy bear: a torso, a head (on a neck; a teddy's larger, sometimes
    with ears, each a part), two arms and two legs of two round cones with a hand or a foot
    (shoulder, elbow, hip and knee angles drawn: standing, waving, sitting)."""
    teddy = rng.random() < 0.4
    tw, td, th = uniform(rng, 0.25, 0.4), uniform(rng, 0.15, 0.25), uniform(rng, 0.35, 0.55)
    torso = Ellipsoid(axes=(tw, td, th))
    hr = uniform(rng, 0.2, 0.32) if teddy else uniform(rng, 0.13, 0.2)
    hc = np.array([0, 0, th + (0.7 if teddy else 1.15) * hr])
    head = [Ellipsoid(center=tuple(hc), axes=(hr, 0.92 * hr, 1.08 * hr))]
    if not teddy:
        head.append(RoundCone((0, 0, 0.8 * th), tuple(hc), 0.35 * hr, 0.3 * hr))
    scale = 0.7 if teddy else 1.0
    ar = (uniform(rng, 0.08, 0.12) if teddy else uniform(rng, 0.04, 0.065))
    lr = (uniform(rng, 0.1, 0.14) if teddy else uniform(rng, 0.055, 0.09))
    la, ll = scale * uniform(rng, 0.3, 0.42), scale * uniform(rng, 0.38, 0.55)
    blend = uniform(rng, 0.06, 0.12) if teddy else uniform(rng, 0.03, 0.06)

    def draw(rng):
        arms, legs = [], []
        for s in (1, -1):
            ab, fw = uniform(rng, 0.15, 1.5), uniform(rng, -0.5, 0.8)
            d = np.array([s * np.sin(ab), np.sin(fw) * np.cos(ab), -np.cos(ab) * np.cos(fw)])
            arm = limb((s * 0.8 * tw, 0, 0.6 * th), d, [la, la], [ar, 0.85 * ar, 0.8 * ar], [0, uniform(rng, 0, 1.3)],
                       np.cross(d, (0, 0, 1)) if abs(d[2]) < 0.99 else (1, 0, 0))
            hand = Ellipsoid(center=tuple(np.asarray(arm.parts[-1].b)), axes=(1.3 * ar, 1.3 * ar, 1.3 * ar))
            arms.append(Union((*arm.parts, hand), 0.3 * ar))
            sit = uniform(rng, 0.0, 1.5) if teddy else uniform(rng, -0.3, 0.6)
            d = np.array([s * uniform(rng, 0.0, 0.35), np.sin(sit), -np.cos(sit)])
            leg = limb((s * 0.45 * tw, 0, -0.75 * th), d, [ll, ll], [lr, 0.85 * lr, 0.75 * lr],
                       [0, -uniform(rng, 0.0, 0.9) * (not teddy)], (1, 0, 0))
            end = np.asarray(leg.parts[-1].b)
            foot = Ellipsoid(center=tuple(end + [0, 1.2 * lr, -0.3 * lr]), axes=(1.1 * lr, 2.0 * lr, 0.9 * lr))
            legs.append(Union((*leg.parts, foot), 0.3 * lr))
        return arms, legs

    def ok(o):
        limbs = o[0] + o[1]
        gap = max(0.3 * ar, blend)
        return apart(limbs, gap, torso) and all(clear_of(torso, g, gap) for g in limbs)

    arms, legs = _posed(rng, draw, ok)
    parts = [("torso", torso), ("head", Union(tuple(head), 0.05))]
    parts += [("left arm", arms[0]), ("right arm", arms[1]), ("left leg", legs[0]), ("right leg", legs[1])]
    ears = teddy and rng.random() < 0.8
    if ears:
        er = uniform(rng, 0.25, 0.4) * hr
        for s, name in ((1, "left ear"), (-1, "right ear")):
            parts.append((name, Ellipsoid(center=tuple(hc + hr * np.array([s * 0.72, 0, 0.72])),
                                          axes=(er, 0.5 * er, er))))
    thin = 2 * min(0.8 * ar, 0.75 * lr, 0.5 * er if ears else 1.0)
    return Design(parts, thin, blend, params={"teddy": teddy, "torso": [tw, td, th], "head_radius": hr,
                                              "arm_radius": ar, "leg_radius": lr, "ears": ears})


def octopus(rng) -> Design:
    """An octopus (a mantle over 4-8 curling tentacles) or a starfish (a flat disc and 4-7
    tapering arms curving in its plane); each tentacle or arm a part."""
    star = rng.random() < 0.35
    if star:
        r0, h0 = uniform(rng, 0.2, 0.35), uniform(rng, 0.08, 0.15)
        body, n, z0, out_r = Ellipsoid(axes=(r0, r0, h0)), int(rng.integers(4, 8)), 0.0, 0.5 * r0
        base_r, segs = uniform(rng, 0.45, 0.65) * h0 * 1.6, 4
    else:
        r0 = uniform(rng, 0.3, 0.5)
        body = Ellipsoid(center=(0, 0, 0.3), axes=(r0, uniform(rng, 0.8, 1.0) * r0, uniform(rng, 0.4, 0.7)))
        c = float(body.axes[2])
        # Tentacles grow from the mantle's lower rim, so the middle of its underside stays body.
        n, z0, out_r, base_r, segs = int(rng.integers(4, 9)), 0.3 - 0.5 * c, 0.6 * r0, uniform(rng, 0.06, 0.11), 5
    tip = max(0.3 * base_r, 0.03)
    length = uniform(rng, 0.7, 1.3)
    phase = uniform(rng, 0, 2 * np.pi)
    blend = uniform(rng, 0.05, 0.12)
    gap = max(0.3 * tip, blend)

    def draw(rng):
        arms = []
        for i in range(n):
            t = phase + 2 * np.pi * i / n + uniform(rng, -0.15, 0.15)
            out = np.array([np.cos(t), np.sin(t), 0.0])
            side = np.cross((0, 0, 1), out)
            if star:
                d, axis = out, (0, 0, 1)
                bends = [0] + [uniform(rng, -0.3, 0.3) for _ in range(segs - 1)]
            else:
                d, axis = unit(out - [0, 0, uniform(rng, 0.3, 1.0)]), side
                bends = [0] + [uniform(rng, -0.15, 0.5) for _ in range(segs - 1)]
            lens = length * np.linspace(1.2, 0.8, segs) / segs
            arms.append(limb(out_r * out + [0, 0, z0], d, lens, np.linspace(base_r, tip, segs + 1), bends, axis))
        return arms

    arms = _posed(rng, draw, lambda o: apart(o, gap, body) and all(clear_of(body, g, gap) for g in o))
    parts = [("body", body)] + [(f"{'arm' if star else 'tentacle'} {i + 1}", g) for i, g in enumerate(arms)]
    return Design(parts, 2 * tip, blend, params={"starfish": star, "arms": n, "arm_length": length,
                                                               "base_radius": base_r})


def _profile(z0: float, z1: float, radii) -> tuple:
    """A smooth profile of revolution through ``radii`` at evenly spaced heights (monotone
    cubic between them), closed along the axis: (((radius, z), ...), the radius function)."""
    rad = PchipInterpolator(np.linspace(z0, z1, len(radii)), radii)
    z = np.linspace(z0, z1, 16)
    return tuple([(0.0, z0)] + [(float(a), float(b)) for a, b in zip(rad(z), z)] + [(0.0, z1)]), rad


def vase(rng) -> Design:
    """A vase or a mug: a smooth body of revolution (or a near-cylinder), sometimes a neck and
    a foot (parts of their own), one or two handles bowed out from the body, sometimes a
    hollow at the mouth."""
    mug = rng.random() < 0.3
    if mug:
        r = uniform(rng, 0.3, 0.45)
        radii = [r * uniform(rng, 0.95, 1.05) for _ in range(3)]
    else:
        radii = [uniform(rng, 0.15, 0.3), uniform(rng, 0.3, 0.5), uniform(rng, 0.2, 0.45), uniform(rng, 0.12, 0.3)]
    H = uniform(rng, 0.8, 1.2) * (0.8 if mug else 1.0)
    prof, rad = _profile(0.0, H, radii)
    parts = [("body", Revolved(profile=prof))]
    top = H
    if not mug and rng.random() < 0.5:
        rn, nh = radii[-1] * uniform(rng, 0.6, 0.9), uniform(rng, 0.15, 0.4)
        flare = rn * uniform(rng, 1.0, 1.5)
        nprof, _ = _profile(H - 0.08, H + nh, [rn, 0.95 * rn, flare])
        parts.append(("neck", Revolved(profile=nprof)))
        top = H + nh
    if rng.random() < 0.4:
        fr, fh = radii[0] * uniform(rng, 0.7, 1.3), uniform(rng, 0.04, 0.1)
        parts.append(("foot", Revolved(profile=((0, -fh), (fr, -fh), (fr, 0.03), (0, 0.03)))))
    tr = uniform(rng, 0.03, 0.06)
    n_handles = 1 if mug else int(rng.integers(1, 3))
    z1 = uniform(rng, 0.55, 0.85) * H
    z2 = z1 - uniform(rng, 0.3, 0.5) * H
    ext = uniform(rng, 0.12, 0.3) * H + 2 * tr
    # A handle follows the body's outline, ext * cos(t) out from it: outside the body between
    # its ends, which sink into the body.
    t = np.linspace(-np.pi / 2, np.pi / 2, 7)
    zt = 0.5 * (z1 + z2) + 0.5 * (z1 - z2) * np.sin(t)
    xt = rad(zt) - tr + ext * np.cos(t)
    for i in range(n_handles):
        s = 1 if i == 0 else -1
        pts = [(s * x, 0.0, z) for x, z in zip(xt, zt)]
        caps = tuple(capsule(pts[j], pts[j + 1], tr) for j in range(len(pts) - 1))
        parts.append((f"handle {i + 1}", Union(caps)))
    holes = []
    if rng.random() < 0.5:
        rm = float(rad(H)) if len(parts) < 2 or parts[1][0] != "neck" else 0.0
        rm = rm or radii[-1] * 0.6
        holes.append(Ellipsoid(center=(0, 0, top), axes=(0.7 * rm, 0.7 * rm, uniform(rng, 0.1, 0.35))))
    return Design(parts, 2 * tr, uniform(rng, 0.01, 0.05), holes,
                  params={"mug": mug, "radii": radii, "height": H, "handles": n_handles, "hollow": bool(holes)})


def hand(rng) -> Design:
    """A hand: a palm (a rounded slab), four fingers and a thumb of two or three round cones,
    each a part; spread and curl drawn per finger (open hand to fist-like)."""
    pw, pt, ph = uniform(rng, 0.32, 0.42), uniform(rng, 0.1, 0.15), uniform(rng, 0.32, 0.45)
    palm = Box(half=(pw / 2, pt / 2, ph / 2), rounding=0.45 * pt)
    r = uniform(rng, 0.3, 0.38) * pw / 4           # fingers pw / 4 apart: gaps of a quarter their width or more
    base = uniform(rng, 0.14, 0.2)
    curl = uniform(rng, 0.0, 1.0)

    def draw(rng):
        fingers = []
        for i, (k, rk) in enumerate(zip([0.85, 1.0, 0.95, 0.75], [1.0, 1.0, 0.95, 0.85])):
            x = (-0.75 + 0.5 * i) * pw / 2
            sp = (i - 1.5) * uniform(rng, 0.0, 0.15)
            d = (np.sin(sp), 0, np.cos(sp))
            bends = [uniform(rng, 0, 0.6) * curl, uniform(rng, 0.3, 1.1) * curl, uniform(rng, 0.2, 0.8) * curl]
            fingers.append(limb((x, 0, ph / 2 - 1.2 * r), d, base * k * np.array([1.0, 0.65, 0.55]),
                                rk * r * np.array([1.0, 0.95, 0.9, 0.8]), bends, (1, 0, 0)))
        a = uniform(rng, 0.3, 1.0)
        d = (np.cos(a), -uniform(rng, 0.1, 0.6), np.sin(a))
        thumb = limb((0.42 * pw, -0.1 * pt, -0.05 * ph), d, base * np.array([0.8, 0.6]),
                     1.15 * r * np.array([1.0, 0.95, 0.85]), [0.0, uniform(rng, 0, 0.8) * curl], (0, 0, 1))
        return fingers, thumb

    def ok(o):
        limbs = o[0] + [o[1]]
        return apart(limbs, max(0.2 * r, 1.5 * blend), palm) and all(clear_of(palm, g, 0.2 * r) for g in limbs)

    blend = uniform(rng, 0.02, 0.04)
    fingers, thumb = _posed(rng, draw, ok)
    parts = [("palm", palm), ("thumb", thumb)]
    parts += [(n, g) for n, g in zip(["index finger", "middle finger", "ring finger", "little finger"], fingers)]
    return Design(parts, 2 * 0.85 * 0.8 * r, blend, params={"palm": [pw, pt, ph], "finger_radius": r,
                                                                          "curl": curl})


#: The organic families (name -> Family).
FAMILIES = {
    "quadruped": Family("organic", quadruped, "four legs, head and tail of varied proportions and poses (Fourleg)"),
    "fish": Family("organic", fish, "thin fins on a smooth body: thin parts that decimation can erase"),
    "bird": Family("organic", bird, "thin wings and tail of varied span, sweep and dihedral (Bird)"),
    "humanoid": Family("organic", humanoid, "limbs in varied poses, a teddy's large head and ears"),
    "octopus": Family("organic", octopus, "many identical curling limbs around a body (rotational repeats)"),
    "vase": Family("organic", vase, "a smooth body of revolution with handles, neck and foot"),
    "hand": Family("organic", hand, "parallel fingers close together, curled to varied degrees"),
}
