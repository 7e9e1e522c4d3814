"""Alpha-expansion for Potts energies on a general graph, with exact minimum cuts from
:func:`scipy.sparse.csgraph.maximum_flow` (BSD).

    E(L) = Σ_f unary[f, L_f] + Σ_p weights[p] [L_a ≠ L_b]        (p = (a, b) = pairs[p])

The moves are those of Boykov, Veksler & Zabih (2001), in the conventions of the field's
reference implementation (gco), so that on the same integer terms the labels are the same
(``tests/test_alpha_expansion.py`` compares the two where gco is installed):

* every site starts at the first label (or at the labels given, gco's ``init_label_at_site``);
  a cycle tries the labels in order, and the cycles stop early when one leaves the energy as it
  was (``cycles = -1``: gco's adaptive schedule, where the labels whose expansion succeeded are
  retried first, until no expansion lowers the energy);
* an expansion on α is a binary problem over the sites not labelled α (x = 0: take α, x = 1:
  keep); its minimum cut is exact, and among several minimizers the one where the most sites
  take α is chosen (the union of every minimizer's α sites: minimum cuts form a lattice): the
  sites that cannot reach the sink in the residual graph of a maximum flow take α;
* the move is kept only if it lowers the energy strictly.

Sites are split into groups that share no pair (connected components), each with its own ordered
list of labels; the groups' moves are independent, so the k-th expansion of every group is solved
in one maximum flow. Terms are integers (int64 sums; each capacity must fit in int32, which the
callers' scaling to at most 10⁶ per term keeps), so equal energies compare exactly.

What makes it fast without changing a label (each rule exact, see :func:`_cycles` and
:func:`expansion_step`): an expansion is skipped where it cannot move anything; consecutive
expansions that read no site an earlier one may move share one maximum flow; sites whose data
term outweighs all their pairs are decided before the flow; the graph is built straight into CSR
with every reverse arc present, so the residual and its reachability are array operations on the
flow's own layout.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

_INT32_MAX = int(np.iinfo(np.int32).max)


def potts_energy(labels: np.ndarray, unary: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> int:
    """E(L) = Σ_f unary[f, L_f] + Σ_p weights[p] [L_a ≠ L_b], exact for integer terms.

    labels : [F] int; unary : [F, k]; pairs : [P, 2]; weights : [P]."""
    labels = np.asarray(labels)
    data = unary[np.arange(len(labels)), labels].sum()
    if not len(pairs):
        return data.item()
    return (data + weights[labels[pairs[:, 0]] != labels[pairs[:, 1]]].sum()).item()


def potts_alpha_expansion(unary: np.ndarray, pairs: np.ndarray, weights: np.ndarray, cycles: int = 2,
                          groups: np.ndarray | None = None, group_labels: list | None = None,
                          initial: np.ndarray | None = None) -> np.ndarray:
    """Labels [F] int64 that minimize the Potts energy locally, by alpha-expansion.

    unary : [F, k] integers >= 0; pairs : [P, 2] site pairs, pairs[:, 0] < pairs[:, 1], each
        unordered pair once; weights : [P] integers >= 0; cycles : passes over the labels
        (>= 1), or -1 for the adaptive schedule until no expansion lowers the energy.
    groups, group_labels : optional [F] group of each site (no pair joins two groups) and, per
        group, the labels it may take in the order they are tried (int arrays; a group with none
        gets label 0). Default: one group over every label 0..k-1.
    initial : optional [F] labels to start from (each among its group's labels; gco's
        ``init_label_at_site``); default: every site at its group's first label.
    """
    unary = np.asarray(unary, dtype=np.int64)
    n, k = unary.shape
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(weights, dtype=np.int64)
    if groups is None:
        # independent sites, as gco: each its cheapest label, the first on ties, whatever the start
        if not len(pairs):
            return np.argmin(unary, axis=1).astype(np.int64) if n else np.zeros(0, dtype=np.int64)
        groups, group_labels = np.zeros(n, dtype=np.int64), [np.arange(k)]
    groups = np.asarray(groups, dtype=np.int64)
    table = _label_table(group_labels)
    labels = np.where(table[groups, 0] >= 0, table[groups, 0], 0)
    if initial is not None:
        labels = np.asarray(initial, dtype=np.int64).copy()
    if n == 0 or table.shape[1] <= 1:
        return labels
    _lonely_groups(labels, unary, pairs, groups, table)
    if cycles == -1:
        return _adaptive_by_group(labels, unary, pairs, weights, groups, group_labels)
    return _cycles(labels, unary, pairs, weights, groups, table, int(cycles), initial is None)


def _cycles(labels, unary, pairs, weights, groups, table, cycles: int, from_first: bool) -> np.ndarray:
    """``cycles`` passes over each group's labels (table [G, L]), in place, as gco makes them,
    in fewer maximum flows (each rule exact):

    * an expansion on α from a state where no α-move lowers the energy (the state an
      α-expansion produced or rejected) moves nothing; it stays so while no site changes that
      could move to α now or neighbours one that could (the α-moves' energy changes read those
      sites' labels alone), so a group's α is retried only once such a site changed since;
    * every site starting at the first label is as if expanded on it; and with two labels,
      the first expansion on the second from there is the group's exact optimum;
    * consecutive expansions share one flow while none reads a site an earlier one may move
      (its sites that could take its label, and their neighbours, and the sites that could
      take it once an earlier one moved them): solved together, each sees the state it would
      see in turn (parts far apart on a band; groups never share a pair)."""
    n = len(labels)
    rows = np.arange(n)
    a, b = pairs[:, 0], pairs[:, 1]
    n_groups, width = table.shape
    n_labels = (table >= 0).sum(axis=1)
    changed_at = np.full(n, -1, dtype=np.int64)          # the step each site last changed
    last_tried = np.full((n_groups, width), -2, dtype=np.int64)
    if from_first:
        last_tried[:, 0] = 0
    w_f = weights.astype(np.float64)
    incident = _site_sum(a, w_f, n) + _site_sum(b, w_f, n)
    # neighbours of a set of sites in one sparse product: [n, n] adjacency, both directions
    adjacency = csr_matrix((np.ones(2 * len(a), dtype=np.int32), (np.r_[a, b], np.r_[b, a])), shape=(n, n))
    cur = unary[rows, labels]                            # each site's data term now
    positions = [q for _ in range(cycles) for q in range(width)]
    i = 0
    while i < len(positions):
        alpha = np.full(n, -1, dtype=np.int64)            # the batch: each site's label, its step
        step_of = np.zeros(n, dtype=np.int64)
        writes = np.zeros(n, dtype=bool)
        j = i
        while j < len(positions):
            q, step = positions[j], j + 1
            has = table[:, q] >= 0
            if from_first:
                has &= ~((n_labels == 2) & (last_tried[:, 1] > 0))
            alpha_q = np.where(has[groups], table[groups, q], -1)
            could = (alpha_q >= 0) & (labels != alpha_q) & \
                (unary[rows, np.maximum(alpha_q, 0)] - cur <= incident)
            near = could | (adjacency @ could.astype(np.int32) > 0)
            if j > i and _reads_a_write(writes, near, alpha, alpha_q, unary, incident):
                break
            dirty = near & (changed_at > last_tried[groups, q])
            live = has & (np.bincount(groups[dirty], minlength=n_groups) > 0)
            last_tried[has, q] = step
            take = could & live[groups]
            alpha[take] = alpha_q[take]
            step_of[take] = step
            writes |= take
            j += 1
        if writes.any():
            before = labels.copy()
            move = groups * len(positions) + step_of      # each group's expansion accepted alone
            expansion_step(labels, alpha, unary, pairs, weights, move, incident)
            changed = np.flatnonzero(labels != before)
            changed_at[changed] = step_of[changed]
            cur[changed] = unary[changed, labels[changed]]
        i = j
    return labels


def _reads_a_write(writes, near, alpha, alpha_q, unary, incident) -> bool:
    """Whether the expansion on alpha_q [F] reads a site that the batch's earlier expansions
    (alpha [F] at the sites ``writes``) may move: a site it reads now (``near``), or one that
    could take alpha_q once it took its batch label."""
    if (writes & near).any():
        return True
    f = np.flatnonzero(writes & (alpha_q >= 0) & (alpha_q != alpha))
    return bool((unary[f, alpha_q[f]] - unary[f, alpha[f]] <= incident[f]).any())


def _lonely_groups(labels, unary, pairs, groups, table) -> None:
    """In place: the sites of a group without pairs take their cheapest label, the first in
    the group's order on ties, whatever the start (as gco solves a problem without pairs)."""
    paired = np.zeros(len(table), dtype=bool)
    paired[groups[pairs[:, 0]]] = True
    sites = np.flatnonzero(~paired[groups])
    if not len(sites):
        return
    options = table[groups[sites]]                      # [m, L], -1 past a group's last
    cost = np.where(options >= 0, unary[sites[:, None], np.maximum(options, 0)], np.iinfo(np.int64).max)
    best = options[np.arange(len(sites)), np.argmin(cost, axis=1)]
    labels[sites] = np.where(best >= 0, best, labels[sites])


def _label_table(group_labels: list) -> np.ndarray:
    """[G, L] labels of each group in order, -1 past a group's last."""
    width = max([len(g) for g in group_labels] + [1])
    table = np.full((len(group_labels), width), -1, dtype=np.int64)
    for g, labs in enumerate(group_labels):
        table[g, :len(labs)] = labs
    return table


def _site_sum(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """[n] int64 sums of integer values by index (bincount's float64 is exact below 2⁵³)."""
    return np.rint(np.bincount(index, weights=values, minlength=n)).astype(np.int64)


def expansion_step(labels: np.ndarray, alpha: np.ndarray, unary: np.ndarray, pairs: np.ndarray,
                   weights: np.ndarray, groups: np.ndarray, incident: np.ndarray | None = None) -> np.ndarray:
    """One expansion in every group at once, in place: site f's group expands on alpha[f]
    (-1: that group sits this step out). A group's move is kept where it lowers its energy
    strictly. Returns the groups whose labels changed ([G'] int).

    incident : [F] sum of each site's pair weights (computed if not given).

    Before the flow, a site whose data term for α against its own differs by at least the sum
    of its pairs' weights in the binary problem is decided: it keeps its label when α costs
    more (strictly: on a tie some minimizer takes α), it takes α when α costs that much less
    (the largest minimizer does: flipping it to α never raises the energy). Deciding sites turns
    their pairs into data terms of their neighbours, so this repeats (:data:`DECIDE_ROUNDS`).
    The work is on the sites that may take α and their pairs alone."""
    n = len(labels)
    a, b = pairs[:, 0], pairs[:, 1]
    if incident is None:
        incident = _site_sum(a, weights.astype(np.float64), n) + _site_sum(b, weights.astype(np.float64), n)
    sites = np.flatnonzero((alpha >= 0) & (labels != alpha))
    al = alpha[sites]
    diff = unary[sites, al] - unary[sites, labels[sites]]  # data cost of taking α
    keep = diff > incident[sites]
    sites, al, diff = sites[~keep], al[~keep], diff[~keep]
    r = len(sites)
    if r == 0:
        return np.zeros(0, dtype=np.int64)
    loc = np.full(n, -1, dtype=np.int64)
    loc[sites] = np.arange(r)
    ia, ib = loc[a], loc[b]
    touch = (ia >= 0) | (ib >= 0)
    ia, ib, w = ia[touch], ib[touch], weights[touch]
    la, lb = labels[a[touch]], labels[b[touch]]
    alpha_pair = np.where(ia >= 0, al[np.maximum(ia, 0)], al[np.maximum(ib, 0)])   # one group per pair
    state, u0, u1 = _decide(ia, ib, w, la, lb, alpha_pair, diff, r)
    free = np.flatnonzero(state == 0)
    if len(free):
        both = (ia >= 0) & (ib >= 0)
        both &= (state[np.maximum(ia, 0)] == 0) & (state[np.maximum(ib, 0)] == 0)
        x = _binary_cut(free, u0, u1, ia[both], ib[both], w[both], la[both] == lb[both], r)
        state[free[~x]] = 2
    takes = state == 2
    if not takes.any():
        return np.zeros(0, dtype=np.int64)
    # the move's energy change per group: data terms of the sites taking α, and the pairs
    # around them (before: their labels; after: α at the sites that take it)
    na = np.where((ia >= 0) & takes[np.maximum(ia, 0)], alpha_pair, la)
    nb = np.where((ib >= 0) & takes[np.maximum(ib, 0)], alpha_pair, lb)
    n_groups = int(groups.max()) + 1
    g_site = groups[sites]
    g_pair = np.where(ia >= 0, g_site[np.maximum(ia, 0)], g_site[np.maximum(ib, 0)])
    change = (np.bincount(g_site[takes], weights=diff[takes], minlength=n_groups)
              + np.bincount(g_pair, weights=w * ((na != nb).astype(np.int64) - (la != lb)), minlength=n_groups))
    better = np.rint(change) < 0
    move = takes & better[g_site]
    labels[sites[move]] = al[move]
    return np.flatnonzero(better & (np.bincount(g_site[move], minlength=n_groups) > 0))


def _pair_state(state, ia, ib):
    """State of each pair's two sites (0 free, 1 keeps, 2 takes α; a site outside keeps)."""
    sa = np.where(ia >= 0, state[np.maximum(ia, 0)], 1)
    sb = np.where(ib >= 0, state[np.maximum(ib, 0)], 1)
    return sa, sb


def _data_terms(ia, ib, w, la, lb, alpha_pair, diff, state, r):
    """[r] u0 (take α), u1 (keep) of the free sites: the data cost of α over its own (diff),
    plus each pair to a decided site as a data term."""
    sa, sb = _pair_state(state, ia, ib)
    w_f = w.astype(np.float64)
    nb_lab = np.where(sb == 2, alpha_pair, lb)             # the decided neighbour's label
    na_lab = np.where(sa == 2, alpha_pair, la)
    fa = (sa == 0) & (sb != 0)
    fb = (sb == 0) & (sa != 0)
    u0 = diff + _site_sum(ia[fa], w_f[fa] * (nb_lab[fa] != alpha_pair[fa]), r) \
        + _site_sum(ib[fb], w_f[fb] * (na_lab[fb] != alpha_pair[fb]), r)
    u1 = _site_sum(ia[fa], w_f[fa] * (nb_lab[fa] != la[fa]), r) \
        + _site_sum(ib[fb], w_f[fb] * (na_lab[fb] != lb[fb]), r)
    return u0, u1


#: rounds of deciding sites before the flow: each round frees the pairs of the sites it
#: decided; past the second, few more are decided on the graph cut's bands (the flow decides
#: the rest exactly, so the count changes time only)
DECIDE_ROUNDS = 2


def _decide(ia, ib, w, la, lb, alpha_pair, diff, r):
    """State [r] int8 of the sites that may take α (0 free, to the flow; 1 keeps; 2 takes α),
    decided where the data terms outweigh every pair between free sites (see expansion_step),
    and the free sites' data terms u0, u1 [r] given the decided ones."""
    state = np.zeros(r, dtype=np.int8)
    w_f = w.astype(np.float64)
    for _ in range(DECIDE_ROUNDS):
        u0, u1 = _data_terms(ia, ib, w, la, lb, alpha_pair, diff, state, r)
        sa, sb = _pair_state(state, ia, ib)
        both = (sa == 0) & (sb == 0)
        inc = _site_sum(ia[both], w_f[both], r) + _site_sum(ib[both], w_f[both], r)
        free = state == 0
        keeps = free & (u0 - u1 > inc)
        takes = free & (u1 - u0 >= inc)
        if not (keeps.any() or takes.any()):
            return state, u0, u1
        state[keeps] = 1
        state[takes] = 2
    return state, *_data_terms(ia, ib, w, la, lb, alpha_pair, diff, state, r)


def _binary_cut(free, u0, u1, i_loc, j_loc, w, same, r) -> np.ndarray:
    """[m] bool, x of the free sites (True: keep) in the largest-α minimizer of
    Σ_v u[v, x_v] + Σ_(i,j) V(x_i, x_j), V(0, 0) = 0, V(0, 1) = V(1, 0) = w, V(1, 1) = w [L_i ≠ L_j]
    (both take α: no cut; one takes α: cut; both keep: cut where their labels differ)."""
    m = len(free)
    var = np.full(r, -1, dtype=np.int64)
    var[free] = np.arange(m)
    i, j = var[i_loc], var[j_loc]
    d11 = np.where(same, 0, w)
    u0v, u1v = u0[free].copy(), u1[free].copy()
    # V(x_i, x_j) = A + (C-A) x_i + (D-C) x_j + (B+C-A-D)(1-x_i) x_j with A = 0, B = C = w, D = d11.
    u1v += _site_sum(i, w.astype(np.float64), m) + _site_sum(j, (d11 - w).astype(np.float64), m)
    low = np.minimum(u0v, u1v)
    return min_cut_sink_side(m, u1v - low, u0v - low, i, j, 2 * w - d11)


def min_cut_sink_side(m: int, src_cap: np.ndarray, sink_cap: np.ndarray, i: np.ndarray, j: np.ndarray,
                      edge_cap: np.ndarray) -> np.ndarray:
    """[m] bool: the nodes that can reach the sink in the residual graph of a maximum flow (the
    smallest sink side among the minimum cuts) of the graph on nodes 0..m-1 with arcs s -> v
    (src_cap [m]), v -> t (sink_cap [m]) and i -> j (edge_cap [P], at most one arc per node
    pair and no j -> i); integer capacities.

    The graph goes to maximum_flow with every reverse arc already present (capacity 0), sorted:
    the flow comes back on the same layout, so the residual is an array difference."""
    s, t = m, m + 1
    v = np.arange(m)
    on_s, on_t, on_e = src_cap > 0, sink_cap > 0, edge_cap > 0
    tails = np.concatenate([np.full(on_s.sum(), s), v[on_t], i[on_e]])
    heads = np.concatenate([v[on_s], np.full(on_t.sum(), t), j[on_e]])
    caps = np.concatenate([src_cap[on_s], sink_cap[on_t], edge_cap[on_e]])
    if len(caps) and int(caps.max()) > _INT32_MAX:
        raise OverflowError("a graph-cut capacity exceeds int32; scale the terms down")
    n_arcs = len(caps)
    tail2 = np.concatenate([tails, heads])               # arc e and its reverse e + n_arcs
    head2 = np.concatenate([heads, tails])
    order = np.argsort(tail2 * (m + 2) + head2)             # keys are distinct
    indices = head2[order].astype(np.int32)
    indptr = np.zeros(m + 3, dtype=np.int32)
    np.cumsum(np.bincount(tail2, minlength=m + 2), out=indptr[1:])
    cap2 = np.concatenate([caps, np.zeros(n_arcs, dtype=caps.dtype)])[order].astype(np.int32)
    graph = csr_matrix((cap2, indices, indptr), shape=(m + 2, m + 2))
    graph.has_sorted_indices = True
    flow = maximum_flow(graph, s, t, method="dinic").flow
    if flow.nnz != len(cap2) or not np.array_equal(flow.indices, indices):
        return _sink_side_general(graph, flow, m, t)
    residual = cap2.astype(np.int64) - flow.data
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    reverse = position[(order + n_arcs) % (2 * n_arcs)]  # where each arc's reverse sits
    # u -> v lies in the reversed residual graph where v -> u has residual capacity
    open_arc = residual[reverse] > 0
    rows = np.repeat(np.arange(m + 2), np.diff(indptr))[open_arc]
    back_ptr = np.zeros(m + 3, dtype=np.int32)
    np.cumsum(np.bincount(rows, minlength=m + 2), out=back_ptr[1:])
    # float64 data: the dtype breadth_first_order works in (no converted copy)
    back = csr_matrix((np.ones(len(rows)), indices[open_arc], back_ptr), shape=(m + 2, m + 2))
    reaches_sink = breadth_first_order(back, t, directed=True, return_predecessors=False)
    x = np.zeros(m + 2, dtype=bool)
    x[reaches_sink] = True
    return x[:m]


def _sink_side_general(graph: csr_matrix, flow: csr_matrix, m: int, t: int) -> np.ndarray:
    """:func:`min_cut_sink_side` by sparse algebra, for a flow on another layout."""
    residual = (graph.astype(np.int64) - csr_matrix(flow, dtype=np.int64)).tocsr()
    residual.data[residual.data < 0] = 0
    residual.eliminate_zeros()
    reaches_sink = breadth_first_order(residual.T.tocsr(), t, directed=True, return_predecessors=False)
    x = np.zeros(m + 2, dtype=bool)
    x[reaches_sink] = True
    return x[:m]


def _adaptive_by_group(labels, unary, pairs, weights, groups, group_labels) -> np.ndarray:
    """``cycles = -1``: gco's adaptive schedule, group by group (its queues differ per group),
    from the labels given."""
    for g, labs in enumerate(group_labels):
        sites = np.flatnonzero(groups == g)
        if len(labs) <= 1 or not len(sites):
            continue
        local = np.full(len(labels), -1, dtype=np.int64)
        local[sites] = np.arange(len(sites))
        inside = (groups[pairs[:, 0]] == g)
        sub_pairs, sub_w = local[pairs[inside]], weights[inside]
        sub_unary = unary[np.ix_(sites, np.asarray(labs))]
        position = np.zeros(unary.shape[1], dtype=np.int64)
        position[np.asarray(labs)] = np.arange(len(labs))
        sub = position[labels[sites]]
        one = np.zeros(len(sites), dtype=np.int64)
        w_f = sub_w.astype(np.float64)
        incident = _site_sum(sub_pairs[:, 0], w_f, len(sites)) + _site_sum(sub_pairs[:, 1], w_f, len(sites))

        def move(q):
            return len(expansion_step(sub, np.full(len(sites), q), sub_unary, sub_pairs, sub_w, one, incident)) > 0
        _adaptive_queue(move, len(labs))
        labels[sites] = np.asarray(labs)[sub]
    return labels


def _adaptive_queue(move, k: int) -> None:
    """Expansions until none lowers E: a pass over a queue of labels keeps, at its front, the
    labels whose expansion succeeded; the next pass retries those alone when they are fewer than
    half of the queue, and a pass where none succeeds returns to the previous (larger) queue."""
    table = list(range(k))
    queues = [k]
    nxt = 0
    while queues:
        size = queues[-1]
        start = nxt
        while True:
            if move(table[nxt]):
                nxt += 1
            else:
                size -= 1
                table[nxt], table[size] = table[size], table[nxt]
            if nxt >= size:
                break
        if nxt == start:
            nxt = queues.pop()
        elif size < queues[-1] // 2:
            nxt = 0
            queues.append(size)
        else:
            nxt = 0
