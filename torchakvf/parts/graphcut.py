"""Boundaries on the creases: a multi-label graph cut on the dual graph (faces = sites).

After the parts are chosen (k-means, merging), each face's part is re-decided by minimizing

    E(L) = Σ_f (a_f / ā) D[f, L_f]  +  λ Σ_{(f, g) dual edges} (ℓ_fg / ℓ̄) c_fg [L_f ≠ L_g]

* data term D [F, k]: the face's distance to each part (the mean over its corners of the
  per-vertex distance fields the isolines are cut from), weighted by face area a_f;
* smoothness: a cut across a dual edge costs its length ℓ_fg, less where the surface bends
  concavely (the minima rule): c_fg = 1 / (1 + β w_fg), w_fg = min(θ_fg / crease_angle, 1)
  on concave creases (θ > 0), 0 elsewhere (:func:`~torchakvf.parts.concavity.crease_weights`);
* a band: a face may only take a part present within ``band`` dual rings of it, so the cut
  moves boundaries and never relabels a far-away region with look-alike features (which
  would make a part disconnected). Faces with one part in reach are fixed and only the band
  around the boundaries goes to the solver (their edges to it become data terms).

The minimization is alpha-expansion (Boykov, Veksler & Zabih 2001) from the parts: each
expansion's exact minimum cut by scipy.sparse.csgraph.maximum_flow (BSD,
:mod:`~torchakvf.parts.alpha_expansion`), in the conventions of the field's reference solver,
gco (Veksler & Delong), which ``GraphCut(engine="gco")`` uses instead where gco-wrapper is
installed (licensed for research use only; the same labels).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..errors import ParameterError
from ..options import EXPANSION_CYCLES, GraphCut
from ..options import GRAPHCUT_ENGINES as ENGINES
from .alpha_expansion import potts_alpha_expansion
from .boundaries import barycenter_values
from .concavity import DualEdges, crease_weights


@dataclass(frozen=True)
class CornerMeans:
    """[F, k] values per face as the mean over its corners of per-vertex values [V, k]
    (:func:`~torchakvf.parts.boundaries.barycenter_values`), made only for the rows read:
    ``cm[rows]`` is ``barycenter_values(faces, vertex_values)[rows]``, bitwise (row by row the
    same sums). The graph cut reads the band's rows alone."""

    faces: np.ndarray
    vertex_values: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.faces), self.vertex_values.shape[1]

    def __getitem__(self, rows) -> np.ndarray:
        return barycenter_values(self.faces[rows], self.vertex_values)


def _gco():
    try:
        import gco
    except ImportError as e:   # imported here so the rest of the package works without it
        raise ParameterError("the graph cut's engine 'gco' needs gco-wrapper (research use only): "
                             "pip install 'torchakvf[gco]', or use GraphCut(engine='scipy')") from e
    return gco


def edge_weights(dual: DualEdges, opts: GraphCut) -> np.ndarray:
    """[P] cost of cutting each dual edge: (ℓ / ℓ̄) / (1 + β w_concave) (see the module notes)."""
    cav, _ = crease_weights(dual.dihedral, opts.crease_angle)
    scale = max(float(dual.length.mean()), 1e-300) if len(dual.length) else 1.0
    return (dual.length / scale) / (1.0 + opts.beta * cav)


def _reach_bits(labels: np.ndarray, pairs: np.ndarray, k: int, band: int) -> np.ndarray:
    """[ceil(k / 64), F] uint64: bit l of face f's words set where part l occurs within
    ``band`` dual rings of f (:func:`allowed_labels` as bit sets)."""
    labels = np.asarray(labels)
    n = len(labels)
    words = max((k + 63) // 64, 1)
    ok = labels >= 0
    lab = labels[ok].astype(np.int64)
    bits = np.zeros((words, n), dtype=np.uint64)
    bits[lab // 64, np.flatnonzero(ok)] = np.left_shift(np.uint64(1), (lab % 64).astype(np.uint64))
    if band > 0 and len(pairs):
        a = np.ascontiguousarray(pairs[:, 0], dtype=np.intp)
        b = np.ascontiguousarray(pairs[:, 1], dtype=np.intp)
        for row in bits:                  # a view: updated in place, word by word
            for _ in range(band):
                ra, rb = row[a], row[b]   # the sets before this ring
                diff = np.flatnonzero(ra != rb)
                if not len(diff):
                    break
                np.bitwise_or.at(row, a[diff], rb[diff])
                np.bitwise_or.at(row, b[diff], ra[diff])
    return bits


def _unpack(bits: np.ndarray, k: int) -> np.ndarray:
    """[F, k] bool from [words, F] uint64 bit sets (bit l of word l // 64)."""
    n = bits.shape[1]
    as_bytes = np.ascontiguousarray(bits.T, dtype="<u8").view(np.uint8).reshape(n, 8 * bits.shape[0])
    return np.unpackbits(as_bytes, axis=1, bitorder="little")[:, :k].view(bool)


def _several(bits: np.ndarray) -> np.ndarray:
    """[F] bool: more than one bit set in face f's words."""
    one_word = (bits & (bits - np.uint64(1))) != 0          # a word with two bits or more
    return one_word.any(axis=0) | ((bits != 0).sum(axis=0) > 1)


def allowed_labels(labels: np.ndarray, pairs: np.ndarray, k: int, band: int) -> np.ndarray:
    """[F, k] bool: part l occurs within ``band`` dual rings of face f (its own part always).

    Each face's reachable parts are a bit set (ceil(k / 64) uint64 words); a ring ORs into
    each face the sets its dual neighbours had before the ring, which is what ``band``
    products with (adjacency + identity), clipped to 1, compute as counts. Only the edges
    whose two sets differ change anything, and they are few (the boundaries' bands)."""
    return _unpack(_reach_bits(labels, pairs, k, band), k)


def energy(labels: np.ndarray, unary: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> float:
    """E(L) = Σ_f unary[f, L_f] + Σ_p weights[p] [L_a ≠ L_b] (p = (a, b) = pairs[p])."""
    labels = np.asarray(labels)
    return float(unary[np.arange(len(labels)), labels].sum()
                 + weights[labels[pairs[:, 0]] != labels[pairs[:, 1]]].sum())


#: Energies go to the solver as integers: the largest term maps to this many units (sums in
#: 64 bits, equal energies compare exactly; gco's own float mode keeps only 3 digits of the
#: largest term for edge weights).
INTEGER_UNITS = 1_000_000


def potts_expansion(unary: np.ndarray, pairs: np.ndarray, weights: np.ndarray,
                    cycles: int = EXPANSION_CYCLES, allowed: np.ndarray | None = None,
                    engine: str = "scipy", initial: np.ndarray | None = None) -> np.ndarray:
    """argmin-ish of Σ_f unary[f, L_f] + Σ_p weights[p] [L_a ≠ L_b] by alpha-expansion,
    ``cycles`` cycles over the labels (-1: until converged).

    unary : [F, k] float >= 0; pairs : [P, 2] site pairs; weights : [P] >= 0. Returns [F] int64.
    Terms are rounded to integers with :data:`INTEGER_UNITS` for the largest one.
    allowed : optional [F, k] bool, the labels each site may take (the others must cost more
        than any site can gain, as :func:`graphcut_labels` makes them). Given it, each connected
        component of the sites is solved alone over the labels allowed somewhere in it (the
        energy is a sum over components, and a component's moves on its own labels are those
        of the whole problem restricted to it): an expansion builds a graph of every site, so
        k labels over all sites cost k times the sites per cycle, a band's boundary two or three.
    engine : "scipy" (:mod:`~torchakvf.parts.alpha_expansion`, minimum cuts from
        scipy.sparse.csgraph.maximum_flow, BSD) or "gco" (the gco library through gco-wrapper,
        licensed for research use only; ``pip install torchakvf[gco]``). On the same integer
        terms the two give the same labels.
    initial : optional [F] labels to start from (each allowed at its site); default: every
        site at label 0, or at its component's first label given ``allowed`` (gco's start,
        which gives the labels of the whole problem solved at once).
    """
    if engine not in ENGINES:
        raise ParameterError(f"graph cut engine must be one of {ENGINES}, got {engine!r}")
    unary = np.asarray(unary, dtype=np.float64)
    n, k = unary.shape
    if k == 1 or n == 0:
        return np.zeros(n, dtype=np.int64)
    e = np.sort(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), axis=1)
    keep = e[:, 0] != e[:, 1]
    e, w = e[keep], np.asarray(weights, dtype=np.float64)[keep]
    top = max(float(unary.max(initial=0.0)), float(w.max(initial=0.0)), 1e-300)
    scale = INTEGER_UNITS / top
    int_unary = np.rint(unary * scale)
    int_w = np.rint(w * scale)
    if engine == "scipy":
        e, int_w = _merge_duplicates(e, int_w, n)
        if allowed is None:
            return potts_alpha_expansion(int_unary, e, int_w, cycles, initial=initial)
        groups, group_labels = _components(e, n, allowed)
        return potts_alpha_expansion(int_unary, e, int_w, cycles, groups=groups, group_labels=group_labels,
                                     initial=initial)
    return _gco_by_component(int_unary, e, int_w, cycles, allowed, initial)


def _gco_by_component(unary, e, w, cycles, allowed, initial) -> np.ndarray:
    """:func:`potts_expansion` with gco on integer terms, one gco problem per component."""
    n = len(unary)
    if allowed is None:
        return gco_expansion(unary, e, w, cycles, initial)
    n_comp, comp = connected_components(
        coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    out = np.zeros(n, dtype=np.int64)
    by_comp = np.argsort(comp, kind="stable")                      # sites, ascending in each
    site_ptr = np.r_[0, np.cumsum(np.bincount(comp, minlength=n_comp))]
    edge_order = np.argsort(comp[e[:, 0]], kind="stable")
    edge_ptr = np.r_[0, np.cumsum(np.bincount(comp[e[:, 0]], minlength=n_comp))]
    local = np.empty(n, dtype=np.int64)
    for c in range(n_comp):
        sites = by_comp[site_ptr[c]:site_ptr[c + 1]]
        labels = np.flatnonzero(allowed[sites].any(axis=0))
        if len(labels) <= 1:
            out[sites] = labels[0] if len(labels) else 0
            continue
        local[sites] = np.arange(len(sites))
        ce = edge_order[edge_ptr[c]:edge_ptr[c + 1]]
        start = None if initial is None else np.searchsorted(labels, initial[sites])
        got = gco_expansion(unary[np.ix_(sites, labels)], local[e[ce]], w[ce], cycles, start)
        out[sites] = labels[got]
    return out


def _merge_duplicates(e: np.ndarray, w: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs [P', 2] listed once, their weights summed (a Potts term per pair is additive)."""
    if not len(e):
        return e, w
    key = e[:, 0] * n + e[:, 1]
    uniq, inv = np.unique(key, return_inverse=True)
    if len(uniq) == len(key):
        return e, w
    return np.stack([uniq // n, uniq % n], axis=1), np.bincount(inv, weights=w)


def _components(e: np.ndarray, n: int, allowed: np.ndarray) -> tuple[np.ndarray, list]:
    """[F] connected component of each site and, per component, the labels allowed in it
    (ascending): the groups of :func:`~torchakvf.parts.alpha_expansion.potts_alpha_expansion`."""
    n_comp, comp = connected_components(
        coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)), directed=False)
    anywhere = np.zeros((n_comp, allowed.shape[1]), dtype=bool)
    np.logical_or.at(anywhere, comp, allowed)
    return comp.astype(np.int64), [np.flatnonzero(row) for row in anywhere]


def gco_expansion(unary: np.ndarray, e: np.ndarray, w: np.ndarray, cycles: int,
                  initial: np.ndarray | None = None) -> np.ndarray:
    """gco's alpha-expansion on integer terms (unary [F, k], pairs e [P, 2], weights w [P]),
    from the labels ``initial`` [F] if given: the ``engine="gco"`` solver, and the reference the
    default engine's labels are tested against."""
    n, k = unary.shape
    gco = _gco()
    g = gco.GCO()
    g.create_general_graph(n, k, energy_is_float=False)
    try:
        g.set_data_cost(np.ascontiguousarray(unary, dtype=np.intc))
        if len(e):
            g.set_all_neighbors(np.ascontiguousarray(e[:, 0], dtype=np.intc),
                                np.ascontiguousarray(e[:, 1], dtype=np.intc),
                                np.ascontiguousarray(w, dtype=np.intc))
        g.set_smooth_cost(np.ascontiguousarray(1 - np.eye(k), dtype=np.intc))
        if initial is not None:
            for site, label in enumerate(np.asarray(initial).tolist()):
                g.init_label_at_site(site, label)
        g.expansion(int(cycles))
        return np.asarray(g.get_labels(), dtype=np.int64)
    finally:
        g.destroy_graph()


def graphcut_labels(labels: np.ndarray, distances: np.ndarray, dual: DualEdges, face_area: np.ndarray,
                    opts: GraphCut | None = None, cut_cost: np.ndarray | None = None,
                    min_fraction: float = 0.0) -> np.ndarray:
    """Face labels [F] re-decided by the graph cut (see the module notes).

    labels : [F] parts 0..k-1 (faces < 0 are left as they are and out of the cut);
    distances : [F, k] each face's distance to each part (inf where a part is absent): an
        array, or anything with ``shape`` and row indexing such as :class:`CornerMeans`;
    dual : the mesh's :func:`~torchakvf.parts.concavity.dual_edges`; face_area : [F];
    cut_cost : [P] ``edge_weights(dual, opts)`` if at hand (it depends on the mesh alone).
    min_fraction : a part the cut would leave below this fraction of the labelled faces' area
        (having had at least that before) keeps its faces, as does a part the cut would empty
        (the segmentation passes its part floor, :func:`~torchakvf.parts.cut.part_floor`).
    """
    opts = GraphCut() if opts is None else opts
    labels = np.asarray(labels)
    k = distances.shape[1]
    if k <= 1:
        return labels.copy()
    sites = np.flatnonzero(labels >= 0)
    index = np.full(len(labels), -1, dtype=np.int64)
    index[sites] = np.arange(len(sites))
    pa, pb = index[dual.pairs[:, 0]], index[dual.pairs[:, 1]]
    inside = (pa >= 0) & (pb >= 0)
    pairs = np.stack([pa[inside], pb[inside]], axis=1)
    if cut_cost is None:
        cut_cost = edge_weights(dual, opts)
    w = opts.smoothness * cut_cost[inside]
    area = np.asarray(face_area, dtype=np.float64)[sites]
    own = labels[sites]
    # Faces with one allowed part (beyond the band of every boundary) keep it: they leave the
    # graph, and each of their edges to a free face becomes that face's cost of taking any
    # other part (exact: the energy differs by a constant). Only the band is solved, so the
    # allowed parts and data terms are built for its faces alone (row by row the same numbers):
    # a face reaching one part is fixed whatever its distances.
    bits = _reach_bits(own, pairs, k, opts.band)
    cand = np.flatnonzero(_several(bits))
    d_cand = np.asarray(distances[sites[cand]], dtype=np.float64)
    finite_cand = np.isfinite(d_cand)
    allowed_cand = _unpack(bits[:, cand], k) & finite_cand
    free_cand = allowed_cand.sum(axis=1) > 1
    idx = cand[free_cand]
    free = np.zeros(len(sites), dtype=bool)
    free[idx] = True
    local = np.full(len(sites), -1, dtype=np.int64)
    local[idx] = np.arange(len(idx))
    sub_unary = (np.where(finite_cand[free_cand], d_cand[free_cand], 0.0)
                 * (area[idx] / max(float(area.mean()), 1e-300))[:, None])
    fa, fb = free[pairs[:, 0]], free[pairs[:, 1]]
    for side, other in ((0, 1), (1, 0)):
        edge = free[pairs[:, side]] & ~free[pairs[:, other]]
        f_free, f_fixed = local[pairs[edge, side]], pairs[edge, other]
        np.add.at(sub_unary, f_free, w[edge][:, None])                   # w for every label...
        np.add.at(sub_unary, (f_free, own[f_fixed]), -w[edge])           # ...but the fixed one's
    both = fa & fb
    sub_pairs = local[pairs[both]]
    sub_w = w[both]
    incident = np.bincount(sub_pairs.ravel(), weights=np.r_[sub_w, sub_w], minlength=len(idx))
    # A forbidden label costs more than any face could gain by taking it (its own data term
    # plus every cut edge around it), so it is never chosen; kept finite for gco's integers.
    big = float(np.abs(sub_unary).max(initial=0.0) + incident.max(initial=0.0)) + 1.0
    sub_unary = np.where(allowed_cand[free_cand], sub_unary, big)
    new = own.copy()
    if len(idx):
        # the expansion starts from the parts (a labelling of low energy; a face whose own part
        # is not allowed, at an infinite distance, from its first allowed one), so each
        # expansion on a part only involves the band around it
        allowed_free = allowed_cand[free_cand]
        start = own[idx]
        start = np.where(allowed_free[np.arange(len(idx)), start], start, np.argmax(allowed_free, axis=1))
        new[idx] = potts_expansion(sub_unary, sub_pairs, sub_w, opts.cycles, allowed=allowed_free,
                                   engine=opts.engine, initial=start)
    new = _restore_parts(own, new, area, k, min_fraction)
    out = labels.copy()
    out[sites] = new
    return out


def _restore_parts(own: np.ndarray, new: np.ndarray, area: np.ndarray, k: int, min_fraction: float) -> np.ndarray:
    """The cut's labels new [S] of the sites (own [S] before it, area [S]), with the faces of
    every part the cut emptied or left under ``min_fraction`` of the area given back."""
    # A part the cut emptied (a small part inside the band of its boundary, outweighed by its
    # cut length), or left below ``min_fraction`` of the area when it had that much, gets its
    # faces back: the cut moves boundaries, it does not change k (a dumbbell's handle, 8% of its
    # area after the merge at k = 3, was cut down to 4 faces). Faces given back can leave a part
    # that had grown into them under the floor in turn (its own faces taken by a third part), so
    # this repeats until no part is; each round gives parts back their own faces only, which no
    # other part given back claims, so it ends within k rounds.
    before = np.bincount(own, minlength=k)
    floor = min_fraction * float(area.sum())
    area_before = np.bincount(own, weights=area, minlength=k)
    restored = np.zeros(k, dtype=bool)
    while True:
        after = np.bincount(new, minlength=k)
        area_after = np.bincount(new, weights=area, minlength=k)
        gone = ~restored & (before > 0) & ((after == 0) | ((area_after < floor) & (area_before >= floor)))
        if not gone.any():
            break
        restored |= gone
        back = gone[own]
        new[back] = own[back]
    return new


__all__ = ["GraphCut", "CornerMeans", "INTEGER_UNITS", "graphcut_labels", "potts_expansion", "energy", "edge_weights",
           "allowed_labels", "gco_expansion"]
