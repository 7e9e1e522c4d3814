"""Probe (issue 13): a sparse Cholesky factor written in torch, multifrontal over a geometric
nested dissection, with the dense fronts of each level of the elimination tree batched (one
padded batched ``cholesky_ex`` / ``solve_triangular`` / ``matmul`` per level, so the op count
is the tree's height, not its node count). A prototype, not part of the package: it measures
whether such a factor (which would also run on CUDA, and could factor a whole batch's forest at
once) can beat cholespy's simplicial CHOLMOD on full-resolution PSB meshes.

Ordering: each region is split at the median of its edge midpoints along its longest axis; the
separator is the smaller of the two sides' boundary sets; regions of <= ``leaf`` unknowns are
leaves. Solutions are checked against cholespy's.

What it found (experiments/results/factor_engines.md): the solves are exact (7e-14 against
cholespy), the batched dense kernels are fast, but this ordering's fill is about 2x METIS's
nnz(L) and 4x its flops (the boundary-set separators are two stencil layers thick), and fronts
padded to each level's largest cost more in memory traffic than the kernels. Next steps, if
anyone takes this up: minimal vertex separators (a vertex cover of the cut), size buckets within
a level, workspaces reused between factors.

Usage::

    python experiments/solver/factor_engines_multifrontal.py [--leaf 16 32 64]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def dissect(indptr, indices, coords, leaf=64):
    n = len(coords)
    rows = np.repeat(np.arange(n), np.diff(indptr))
    cols = indices
    off = rows != cols
    rows, cols = rows[off], cols[off]
    region = np.zeros(n, np.int64)          # -1: assigned
    reg_parent = np.array([-1])             # parent node of each region
    node_of = np.full(n, -1, np.int64)
    parents = []                            # per node
    owns = []
    while True:
        live = region >= 0
        if not live.any():
            break
        nreg = len(reg_parent)
        size = np.bincount(region[live], minlength=nreg)
        # leaves
        small = (size <= leaf) & (size > 0)
        idx = np.nonzero(live)[0]
        r_idx = region[idx]
        leafmask = small[r_idx]
        if leafmask.any():
            li = idx[leafmask]
            lr = region[li]
            order = np.argsort(lr, kind="stable")
            li, lr = li[order], lr[order]
            ur, starts = np.unique(lr, return_index=True)
            base = len(parents)
            for t, rr in enumerate(ur):
                owns.append(li[starts[t]: starts[t + 1] if t + 1 < len(ur) else len(li)])
                parents.append(reg_parent[rr])
            node_of[li] = base + np.searchsorted(ur, lr)
            region[li] = -1
        idx = idx[~leafmask]
        if len(idx) == 0:
            break
        r_idx = region[idx]
        # axis of largest extent per region
        lo = np.full((nreg, 3), np.inf)
        hi = np.full((nreg, 3), -np.inf)
        np.minimum.at(lo, r_idx, coords[idx])
        np.maximum.at(hi, r_idx, coords[idx])
        axis = np.argmax(hi - lo, axis=1)
        key = coords[idx, axis[r_idx]]
        order = np.lexsort((key, r_idx))
        idx_s, r_s = idx[order], r_idx[order]
        first = np.searchsorted(r_s, r_s, side="left")
        rank = np.arange(len(idx_s)) - first
        side = np.zeros(n, np.int8)
        side[idx_s] = (rank >= size[r_s] // 2).astype(np.int8)
        # boundary of each side
        same = (region[rows] == region[cols]) & (region[rows] >= 0)
        cross = same & (side[rows] != side[cols])
        bnd = np.zeros(n, bool)
        bnd[rows[cross]] = True
        nb0 = np.bincount(region[bnd & (side == 0)], minlength=nreg)
        nb1 = np.bincount(region[bnd & (side == 1)], minlength=nreg)
        sepside = (nb1 < nb0).astype(np.int8)
        in_sep = np.zeros(n, bool)
        in_sep[idx] = bnd[idx] & (side[idx] == sepside[region[idx]])
        # new separator nodes (one per split region, even if empty)
        split = np.unique(r_idx)
        base = len(parents)
        sep_node = np.full(nreg, -1, np.int64)
        sep_node[split] = base + np.arange(len(split))
        si = np.nonzero(in_sep)[0]
        sr = region[si]
        order = np.argsort(sr, kind="stable")
        si, sr = si[order], sr[order]
        bounds = np.searchsorted(sr, split), np.searchsorted(sr, split, side="right")
        for t, rr in enumerate(split):
            owns.append(si[bounds[0][t]:bounds[1][t]])
            parents.append(reg_parent[rr])
        node_of[si] = sep_node[sr]
        region[si] = -1
        # children regions: (old region, side) -> new id
        rest = idx[~in_sep[idx]]
        newkey = region[rest] * 2 + side[rest]
        uk, inv = np.unique(newkey, return_inverse=True)
        region[rest] = inv
        reg_parent = sep_node[uk // 2]
    return node_of, np.array(parents), owns

class Multifrontal:
    def __init__(self, indptr, indices, coords, leaf=64):
        t0 = time.perf_counter()
        n = len(coords)
        self.n = n
        node_of, parent, owns = dissect(indptr, indices, coords, leaf)
        t1 = time.perf_counter()
        nn = len(parent)
        children = [[] for _ in range(nn)]
        for c in range(nn):
            if parent[c] >= 0:
                children[parent[c]].append(c)
        # heights (nodes created top-down: children have larger ids)
        height = np.zeros(nn, np.int64)
        for c in range(nn - 1, -1, -1):
            if parent[c] >= 0:
                height[parent[c]] = max(height[parent[c]], height[c] + 1)
        self.t_order = t1 - t0
        # symbolic: struct per node, in increasing-height processing
        nh = height[node_of]     # height of each var's node
        structs = [None] * nn
        for h in range(height.max() + 1):
            for N in np.nonzero(height == h)[0]:
                own = owns[N]
                adj = (indices[np.concatenate([np.arange(indptr[i], indptr[i + 1]) for i in own])] if len(own)
                       else np.zeros(0, np.int64))
                cand = [adj] + [structs[c] for c in children[N]]
                cand = np.unique(np.concatenate(cand))
                structs[N] = cand[(nh[cand] > h)]
        self.t_sym = time.perf_counter() - t1
        self.owns, self.structs, self.height, self.parent, self.children = owns, structs, height, parent, children
        self.node_of = node_of
        self._plan(indptr, indices)

    def _plan(self, indptr, indices):
        """Per height level: padded index arrays, entry scatter maps, extend-add maps."""
        n = self.n
        levels = []
        slot_of = {}  # node -> (level, slot)
        for h in range(self.height.max() + 1):
            nodes = np.nonzero(self.height == h)[0]
            K = max(1, max(len(self.owns[N]) for N in nodes))
            S = max(len(self.structs[N]) for N in nodes)
            m = len(nodes)
            F = K + S
            own_idx = np.full((m, K), n, np.int64)
            st_idx = np.full((m, S), n, np.int64)
            for t, N in enumerate(nodes):
                own_idx[t, :len(self.owns[N])] = self.owns[N]
                st_idx[t, :len(self.structs[N])] = self.structs[N]
                slot_of[N] = (h, t)
            # entry map: rows in own; local position of col
            ent_src, ent_dst = [], []
            for t, N in enumerate(nodes):
                own, st = self.owns[N], self.structs[N]
                loc = {}
                for a, j in enumerate(own):
                    loc[j] = a
                for a, j in enumerate(st):
                    loc[j] = K + a
                for a, i in enumerate(own):
                    for p in range(indptr[i], indptr[i + 1]):
                        j = indices[p]
                        if j in loc:
                            lj = loc[j]
                            if lj < K:
                                ent_src.append(p)
                                ent_dst.append(t * F * F + a * F + lj)
                            else:
                                ent_src.append(p)
                                ent_dst.append(t * F * F + lj * F + a)
            pad_diag = []
            for t, N in enumerate(nodes):
                for a in range(len(self.owns[N]), K):
                    pad_diag.append(t * F * F + a * F + a)
            # extend-add from children: child's U (S_c x S_c in its level) -> this front
            ea = []
            for t, N in enumerate(nodes):
                own, st = self.owns[N], self.structs[N]
                loc = {j: a for a, j in enumerate(own)}
                loc.update({j: K + a for a, j in enumerate(st)})
                for c in self.children[N]:
                    hc, tc = slot_of[c]
                    sc = self.structs[c]
                    lc = np.array([loc[j] for j in sc], np.int64)
                    ea.append((hc, tc, len(sc), t * F * F + lc[:, None] * F + lc[None, :]))
            levels.append(dict(m=m, K=K, S=S, own=torch.from_numpy(own_idx), st=torch.from_numpy(st_idx),
                               src=torch.tensor(ent_src, dtype=torch.long), dst=torch.tensor(ent_dst, dtype=torch.long),
                               pad=torch.tensor(pad_diag, dtype=torch.long), ea=ea))
        # group extend-add by child level into flat gathers
        for h, L in enumerate(levels):
            by = {}
            for hc, tc, sc, dst in L["ea"]:
                Sc = levels[hc]["S"]
                src = tc * Sc * Sc + np.arange(sc)[:, None] * Sc + np.arange(sc)[None, :]
                by.setdefault(hc, ([], []))
                by[hc][0].append(src.ravel())
                by[hc][1].append(dst.ravel())
            L["ea"] = {hc: (torch.from_numpy(np.concatenate(a)), torch.from_numpy(np.concatenate(b)))
                       for hc, (a, b) in by.items()}
        self.levels = levels

    def factor(self, values):
        """values: CSR data of the (shifted) matrix. Returns False where not PD."""
        vals = torch.as_tensor(values, dtype=torch.float64)
        us = []
        self.L = []
        for h, L in enumerate(self.levels):
            m, K, S = L["m"], L["K"], L["S"]
            F = K + S
            front = torch.zeros(m * F * F, dtype=torch.float64)
            front[L["dst"]] = vals[L["src"]]
            front[L["pad"]] = 1.0
            for hc, (src, dst) in L["ea"].items():
                front.index_add_(0, dst, us[hc].reshape(-1)[src])
            front = front.view(m, F, F)
            l11, info = torch.linalg.cholesky_ex(front[:, :K, :K])
            if bool((info > 0).any()):
                return False
            if S:
                l21 = torch.linalg.solve_triangular(l11, front[:, K:, :K].transpose(1, 2), upper=False).transpose(1, 2)
                u = front[:, K:, K:] - l21 @ l21.transpose(1, 2)
            else:
                l21 = front.new_zeros(m, 0, K)
                u = front.new_zeros(m, 0, 0)
            us.append(u.contiguous())
            self.L.append((l11, l21.contiguous()))
        return True

    def solve(self, b):
        r = b.shape[1]
        y = torch.cat([b.to(torch.float64), b.new_zeros(1, r, dtype=torch.float64)])
        for L, (l11, l21) in zip(self.levels, self.L):
            yo = torch.linalg.solve_triangular(l11, y[L["own"]], upper=False)
            y[L["own"]] = yo
            y[-1] = 0
            if L["S"]:
                y.index_add_(0, L["st"].reshape(-1), -(l21 @ yo).reshape(-1, r))
                y[-1] = 0
        x = y
        for L, (l11, l21) in zip(reversed(self.levels), reversed(self.L)):
            rhs = x[L["own"]]
            if L["S"]:
                rhs = rhs - l21.transpose(1, 2) @ x[L["st"]]
            x[L["own"]] = torch.linalg.solve_triangular(l11.transpose(1, 2), rhs, upper=True)
            x[-1] = 0
        return x[:-1]


def main(argv=None) -> int:
    import scipy.sparse as sp

    import torchakvf as ta
    from torchakvf.evaluate.psb import default_psb_root
    from torchakvf.io import load_mesh
    from torchakvf.mesh import clean_mesh
    from torchakvf.operators import killing_operator
    from torchakvf.solvers.factor import ShiftedFactor
    p = argparse.ArgumentParser(description="multifrontal probe")
    p.add_argument("--leaf", type=int, nargs="+", default=[16, 64])
    p.add_argument("--ids", type=int, nargs="+", default=[21, 301])
    args = p.parse_args(argv)
    psb = default_psb_root()
    if psb is None:
        p.error("no PSB found: set TORCHAKVF_PSB")
    for i in args.ids:
        mesh = clean_mesh(load_mesh(psb / "meshes" / f"{i}.off.gz"))
        batch = ta.MeshBatch.from_meshes([mesh])
        system = killing_operator(batch, remedy="smooth")
        r, c, v, n = system.block(0)
        a = (sp.csr_matrix((v.numpy(), (r.numpy(), c.numpy())), shape=(n, n)) + sp.diags(system.mass.numpy())).tocsr()
        a.sort_indices()
        pts, e = batch.verts.numpy(), batch.edges.numpy()
        coords = 0.5 * (pts[e[:, 0]] + pts[e[:, 1]])
        t = time.perf_counter()
        chol = ShiftedFactor(r, c, v, system.mass)
        t_chol = time.perf_counter() - t
        rhs = torch.randn(n, 4, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        ref = chol.solve(rhs)
        t = time.perf_counter()
        for _ in range(10):
            chol.solve(rhs)
        t_cs = (time.perf_counter() - t) / 10
        for leaf in args.leaf:
            t = time.perf_counter()
            mf = Multifrontal(a.indptr, a.indices, coords, leaf)
            t_an = time.perf_counter() - t
            ks = np.array([len(o) for o in mf.owns])
            ss = np.array([len(x) for x in mf.structs])
            nnz_l = int((ks * (ks + 1) / 2 + ks * ss).sum())
            flops = float((ks ** 3 / 3 + ks ** 2 * ss + ks * ss ** 2).sum())
            mf.factor(a.data)
            t = time.perf_counter()
            ok = mf.factor(a.data)
            t_num = time.perf_counter() - t
            x = mf.solve(rhs)
            t = time.perf_counter()
            for _ in range(10):
                x = mf.solve(rhs)
            t_s = (time.perf_counter() - t) / 10
            padded = sum(int(l11.numel() + l21.numel()) for l11, l21 in mf.L)
            print(f"| {i} | {n} | {leaf} | {len(ks)} | {len(mf.levels)} | {nnz_l:,} | {padded:,} | {flops / 1e6:.0f} "
                  f"| {mf.t_order * 1e3:.0f} + {mf.t_sym * 1e3:.0f} + {(t_an - mf.t_order - mf.t_sym) * 1e3:.0f} "
                  f"| {t_num * 1e3:.0f} | {t_chol * 1e3:.0f} | {t_s * 1e3:.1f} | {t_cs * 1e3:.1f} "
                  f"| {float((x - ref).abs().max() / ref.abs().max()):.0e} | {ok} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
