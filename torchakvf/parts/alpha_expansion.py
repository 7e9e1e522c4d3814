"""Alpha-expansion for Potts energies on a general graph, with exact minimum cuts from
:func:`scipy.sparse.csgraph.maximum_flow` (BSD).

    E(L) = Σ_f unary[f, L_f] + Σ_p weights[p] [L_a ≠ L_b]        (p = (a, b) = pairs[p])

The moves are those of Boykov, Veksler & Zabih (2001), in the conventions of the field's
reference implementation (gco), so that on the same integer terms the labels are the same
(``tests/test_alpha_expansion.py`` compares the two where gco is installed):

* every site starts at the first label; a cycle tries the labels in order, and the cycles stop
  early when one leaves the energy as it was (``cycles = -1``: gco's adaptive schedule, where the
  labels whose expansion succeeded are retried first, until no expansion lowers the energy);
* an expansion on α is a binary problem over the sites not labelled α (x = 0: take α, x = 1:
  keep); its minimum cut is exact, and among several minimizers the one where the most sites
  take α is chosen: the sites that cannot reach the sink in the residual graph of a maximum flow
  take α (that set is the same for every maximum flow and every graph of the same binary energy);
* the move is kept only if it lowers the energy strictly.

Sites are split into groups that share no pair (connected components), each with its own ordered
list of labels; the groups' moves are independent, so the k-th expansion of every group is solved
in one maximum flow. Terms are integers (int64 sums; each capacity must fit in int32, which the
callers' scaling to at most 10⁶ per term keeps), so equal energies compare exactly.
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
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
                          groups: np.ndarray | None = None, group_labels: list | None = None) -> np.ndarray:
    """Labels [F] int64 that minimize the Potts energy locally, by alpha-expansion.

    unary : [F, k] integers >= 0; pairs : [P, 2] site pairs, pairs[:, 0] < pairs[:, 1], each
        unordered pair once; weights : [P] integers >= 0; cycles : passes over the labels
        (>= 1), or -1 for the adaptive schedule until no expansion lowers the energy.
    groups, group_labels : optional [F] group of each site (no pair joins two groups) and, per
        group, the labels it may take in the order they are tried (int arrays; a group with none
        gets label 0). Default: one group over every label 0..k-1.
    """
    unary = np.asarray(unary, dtype=np.int64)
    n, k = unary.shape
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(weights, dtype=np.int64)
    if groups is None:
        if not len(pairs):   # independent sites: each its cheapest label, the first on ties
            return np.argmin(unary, axis=1).astype(np.int64) if n else np.zeros(0, dtype=np.int64)
        groups, group_labels = np.zeros(n, dtype=np.int64), [np.arange(k)]
    groups = np.asarray(groups, dtype=np.int64)
    table = _label_table(group_labels)
    labels = np.where(table[groups, 0] >= 0, table[groups, 0], 0)
    if n == 0 or table.shape[1] <= 1:
        return labels
    if cycles == -1:
        return _adaptive_by_group(labels, unary, pairs, weights, groups, group_labels)
    incident = _incident_weights(pairs, weights, n)
    for _ in range(int(cycles)):
        changed = False
        for q in range(table.shape[1]):
            changed |= expansion_step(labels, table[groups, q], unary, pairs, weights, groups, incident)
        if not changed:   # the same state again: every later cycle would leave it as it is
            break
    return labels


def _label_table(group_labels: list) -> np.ndarray:
    """[G, L] labels of each group in order, -1 past a group's last."""
    width = max([len(g) for g in group_labels] + [1])
    table = np.full((len(group_labels), width), -1, dtype=np.int64)
    for g, labs in enumerate(group_labels):
        table[g, :len(labs)] = labs
    return table


def _incident_weights(pairs: np.ndarray, weights: np.ndarray, n: int) -> np.ndarray:
    """[F] int64 sum of the weights of each site's pairs."""
    out = np.zeros(n, dtype=np.int64)
    np.add.at(out, pairs[:, 0], weights)
    np.add.at(out, pairs[:, 1], weights)
    return out


def expansion_step(labels: np.ndarray, alpha: np.ndarray, unary: np.ndarray, pairs: np.ndarray,
                   weights: np.ndarray, groups: np.ndarray, incident: np.ndarray) -> bool:
    """One expansion in every group at once, in place: site f's group expands on alpha[f]
    (-1: that group sits this step out). A group's move is kept where it lowers its energy
    strictly. Returns whether any group's labels changed.

    A site whose data term rises by more than ``incident[f]`` (the sum of its pairs' weights)
    when it takes α keeps its label in every minimizer, since no pair can pay that back; it stays
    out of the graph as a fixed neighbour (on the graph cut's bands, most sites)."""
    rows = np.arange(len(labels))
    cur = unary[rows, labels]
    take = unary[rows, np.maximum(alpha, 0)]
    movable = (alpha >= 0) & (labels != alpha) & (take - cur <= incident)
    sites = np.flatnonzero(movable)
    m = len(sites)
    if m == 0:
        return False
    var = np.full(len(labels), -1, dtype=np.int64)
    var[sites] = np.arange(m)
    u0, u1 = take[sites].copy(), cur[sites].copy()        # x = 0: take α; x = 1: keep
    a, b = pairs[:, 0], pairs[:, 1]
    la, lb = labels[a], labels[b]
    mov_a, mov_b = movable[a], movable[b]
    for mine, lmine, lother, one in ((a, la, lb, mov_a & ~mov_b), (b, lb, la, mov_b & ~mov_a)):
        v, w = var[mine[one]], weights[one]               # a pair with a fixed site: unary terms
        np.add.at(u0, v, np.where(lother[one] != alpha[mine[one]], w, 0))
        np.add.at(u1, v, np.where(lother[one] != lmine[one], w, 0))
    both = mov_a & mov_b
    i, j, w = var[a[both]], var[b[both]], weights[both]
    d11 = np.where(la[both] == lb[both], 0, w)            # both keep
    g_site, g_pair = groups[sites], groups[a[both]]
    n_groups = int(groups.max()) + 1
    before = _group_sum(g_site, u1, n_groups) + _group_sum(g_pair, d11, n_groups)
    # E(x_i, x_j) = A + (C-A) x_i + (D-C) x_j + (B+C-A-D)(1-x_i) x_j with A = 0, B = C = w.
    np.add.at(u1, i, w)
    np.add.at(u1, j, d11 - w)
    low = np.minimum(u0, u1)
    src_cap, sink_cap = u1 - low, u0 - low                # s -> v cut when x_v = 1, v -> t when 0
    edge_cap = 2 * w - d11                                # i -> j cut when x_i = 0, x_j = 1
    x = min_cut_sink_side(m, src_cap, sink_cap, i, j, edge_cap)
    after = (_group_sum(g_site, low + np.where(x, src_cap, sink_cap), n_groups)
             + _group_sum(g_pair, np.where(~x[i] & x[j], edge_cap, 0), n_groups))
    better = after < before
    move = ~x & better[g_site]
    labels[sites[move]] = alpha[sites[move]]
    return bool(move.any())


def _group_sum(group: np.ndarray, values: np.ndarray, n_groups: int) -> np.ndarray:
    out = np.zeros(n_groups, dtype=np.int64)
    np.add.at(out, group, values)
    return out


def min_cut_sink_side(m: int, src_cap: np.ndarray, sink_cap: np.ndarray, i: np.ndarray, j: np.ndarray,
                      edge_cap: np.ndarray) -> np.ndarray:
    """[m] bool: the nodes that can reach the sink in the residual graph of a maximum flow (the
    smallest sink side among the minimum cuts) of the graph on nodes 0..m-1 with arcs s -> v
    (src_cap [m]), v -> t (sink_cap [m]) and i -> j (edge_cap [P]); integer capacities."""
    s, t = m, m + 1
    rows = np.concatenate([np.full(m, s), np.arange(m), i])
    cols = np.concatenate([np.arange(m), np.full(m, t), j])
    caps = np.concatenate([src_cap, sink_cap, edge_cap])
    nz = caps > 0
    if nz.any() and int(caps.max()) > _INT32_MAX:
        raise OverflowError("a graph-cut capacity exceeds int32; scale the terms down")
    graph = coo_matrix((caps[nz].astype(np.int32), (rows[nz], cols[nz])), shape=(m + 2, m + 2)).tocsr()
    graph.sum_duplicates()
    flow = maximum_flow(graph, s, t, method="dinic").flow
    residual = (graph.astype(np.int64) - csr_matrix(flow, dtype=np.int64)).tocsr()
    residual.data[residual.data < 0] = 0
    residual.eliminate_zeros()
    reaches_sink = breadth_first_order(residual.T.tocsr(), t, directed=True, return_predecessors=False)
    x = np.zeros(m + 2, dtype=bool)
    x[reaches_sink] = True
    return x[:m]


def _adaptive_by_group(labels, unary, pairs, weights, groups, group_labels) -> np.ndarray:
    """``cycles = -1``: gco's adaptive schedule, group by group (its queues differ per group)."""
    for g, labs in enumerate(group_labels):
        sites = np.flatnonzero(groups == g)
        if len(labs) <= 1 or not len(sites):
            continue
        local = np.full(len(labels), -1, dtype=np.int64)
        local[sites] = np.arange(len(sites))
        inside = (groups[pairs[:, 0]] == g)
        sub_pairs, sub_w = local[pairs[inside]], weights[inside]
        sub_unary = unary[np.ix_(sites, np.asarray(labs))]
        sub = np.zeros(len(sites), dtype=np.int64)
        one = np.zeros(len(sites), dtype=np.int64)
        incident = _incident_weights(sub_pairs, sub_w, len(sites))

        def move(q):
            return expansion_step(sub, np.full(len(sites), q), sub_unary, sub_pairs, sub_w, one, incident)
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
