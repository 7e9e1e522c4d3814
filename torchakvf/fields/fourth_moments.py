"""Y's fourth moments: Horst's gradient Yᵀ (Y A)^3 of the untangling without a pass over the
edges per step (:class:`FourthMoments`), and the size rule that says when it pays
(:func:`fourth_moments_pay`).
"""
from __future__ import annotations

import torch

#: Float64 Horst steps per restart assumed by :func:`fourth_moments_pay` where nothing better is
#: known (after a float32 phase its own step count is the estimate).
STEPS_PER_RESTART = 20


def side_by_side(m: torch.Tensor) -> torch.Tensor:
    """[b, q, n, n] rotations -> [b, n, q·n], side by side."""
    n = m.shape[-1]
    return m.permute(0, 2, 1, 3).reshape(len(m), n, m.shape[1] * n)


class FourthMoments:
    """G(A) = Yᵀ (Y A)^3 of each mesh (y [m, E, n] float64) from Y's fourth moments, in float64.

    Expanding the cube, G_ij = Σ_{k,l,m} M_iklm A_kj A_lj A_mj with M_iklm = Σ_e y_ei y_ek y_el
    y_em, which does not depend on A: computed once (the entries of ``Qᵀ Q`` at sorted
    quadruples, for Q [E, P] the products of column pairs, P = n(n+1)/2), each step then costs
    a product of n x C by C x q·n per mesh (C = n(n+1)(n+2)/6 sorted triples k <= l <= m),
    whatever E is. Where E is large against n (:func:`fourth_moments_pay`) that is far cheaper than
    two float64 GEMMs over E per step, which dominate the untangling of a large mesh. Both ways
    sum the same products in another order: they agree to round-off. Zero rows (padding) add
    nothing.

    moments : [m, n, C] M_iklm of every mesh, i and sorted triple (k, l, m), times the triple's
    count of distinct orderings; triple_k, triple_l, triple_m : [C] the triples' indices.
    """

    def __init__(self, y: torch.Tensor, gather: bool | None = None):
        """gather: form the pair products by two index gathers per pass (default: on devices
        other than the CPU) rather than by 2n broadcast products; the same values either way."""
        nb, e, n = y.shape
        dev = y.device
        self.n = n
        p = n * (n + 1) // 2
        # Every moment is one entry of Qᵀ Q: M_abcd for sorted a <= b <= c <= d is the product
        # of pair (a, b)'s column with pair (c, d)'s, and only those entries, b <= c, are
        # needed: n^4/24 of the P^2 (0.34 of them at n = 32). Rows of the product are the pairs
        # ordered by their second index b, columns the pairs in triu order (by first index c),
        # so the rows of one b need a suffix of the columns (c >= b). Rows are taken in 4 groups
        # of b, each times its suffix: one GEMM per group, 0.46 of Qᵀ Q's entries at n = 32,
        # and large enough blocks to run near the full GEMM's rate (PSB-21-sized forms,
        # E = 45594, n = 32: 0.6x the time of Qᵀ Q's upper block triangle).
        row_start = [b * (b + 1) // 2 for b in range(n + 1)]            # pairs (a <= b) by b
        col_start = [c * n - c * (c - 1) // 2 for c in range(n + 1)]    # pairs (c <= d) by c
        groups = sorted({round(n * g / 4) for g in range(5)})
        # Rows per pass: 2048 for one mesh (its [2048, P] pair products, 8.6 MB at n = 32, stay
        # in cache), fewer for a large batch so that [m, rows, P] stays near 16 MB.
        chunk = max(1, min(2048, max(16, 2 ** 21 // (nb * p)), e))
        gram = y.new_zeros(nb, p, p)
        cols = y.new_empty(nb, chunk, p)
        rows_t = y.new_empty(nb, p, chunk)
        gather = dev.type != "cpu" if gather is None else gather
        if gather:
            # One gather per pass on other devices, where 2n small products would be 2n kernel
            # launches per pass (and a large batch makes many short passes).
            first, second = torch.triu_indices(n, n)           # the pairs by first index: columns
            by_second = torch.argsort(second * n + first)       # the same by second index: rows
            c_first, c_second = first.to(dev), second.to(dev)
            r_first, r_second = first[by_second].to(dev), second[by_second].to(dev)
        for s in range(0, e, chunk):
            yc = y[:, s:s + chunk]
            h = yc.shape[1]
            yt = yc.transpose(1, 2).contiguous()                            # [m, n, h]
            qc, qr = cols[:, :h], rows_t[:, :, :h]
            if not gather:
                # Each pair block is one broadcast product (6.7x faster than gathering the P
                # columns twice by index: n = 32, 2048 rows, 0.9 against 5.9 ms).
                for i in range(n):
                    torch.mul(yc[:, :, i:i + 1], yc[:, :, i:], out=qc[:, :, col_start[i]:col_start[i + 1]])
                    torch.mul(yt[:, :i + 1], yt[:, i:i + 1], out=qr[:, row_start[i]:row_start[i + 1]])
            else:
                torch.mul(yc[:, :, c_first], yc[:, :, c_second], out=qc)
                torch.mul(yt[:, r_first], yt[:, r_second], out=qr)
            for b0, b1 in zip(groups[:-1], groups[1:]):
                r0, r1, c0 = row_start[b0], row_start[b1], col_start[b0]
                gram[:, r0:r1, c0:].baddbmm_(qr[:, r0:r1], qc[:, :, c0:])
        k, l, m = torch.combinations(torch.arange(n, device=dev), 3, with_replacement=True).T
        self.triple_k, self.triple_l, self.triple_m = k.contiguous(), l.contiguous(), m.contiguous()
        # A sorted triple stands for its distinct orderings: 1, 3 or 6 of the n³ terms.
        mult = torch.where((k == l) & (l == m), 1.0,
                           torch.where((k == l) | (l == m), 3.0, 6.0)).to(y.dtype)
        # M_iklm for every i and sorted triple k <= l <= m, read at its sorted quadruple.
        i = torch.arange(n, device=dev)[:, None].expand(-1, len(k))
        quad = torch.stack([i, k.expand_as(i), l.expand_as(i), m.expand_as(i)], -1).sort(-1).values
        a, b, c, d = quad.unbind(-1)
        row = torch.tensor(row_start, device=dev)[b] + a
        col = torch.tensor(col_start, device=dev)[c] + (d - c)
        self.moments = gram[:, row, col] * mult                              # [m, n, C]

    def select(self, meshes: torch.Tensor) -> "FourthMoments":
        """The same for a subset of the meshes (indices into this one's)."""
        out = object.__new__(FourthMoments)
        out.n, out.triple_k, out.triple_l, out.triple_m = self.n, self.triple_k, self.triple_l, self.triple_m
        out.moments = self.moments[meshes]
        return out

    def __call__(self, al: torch.Tensor) -> torch.Tensor:
        """G [m, q, n, n] (float64) of rotations al [m, q, n, n]."""
        nb, q, n = al.shape[0], al.shape[1], self.n
        a = side_by_side(al)                                                       # [m, n, q·n]
        cubes = a[:, self.triple_k] * a[:, self.triple_l]
        cubes.mul_(a[:, self.triple_m])                                           # [m, C, q·n]
        return torch.bmm(self.moments, cubes).reshape(nb, n, q, n).permute(0, 2, 1, 3)


def fourth_moments_pay(e: int, n: int, steps: int) -> bool:
    """Whether ``steps`` float64 Horst steps of single rotations (summed over the restarts) of a
    mesh with e edges (rows) and n fields are faster from :class:`FourthMoments` than by the
    products.

    A time model in flops weighted by measured rates (one thread; see docs/design.md): the
    moments' one-time Qᵀ Q (2 P² E flops) runs at
    about twice the products' rate per flop, their steps (a gather and an n x C by C x n
    product per rotation) at about half; the products cost 4 E n² flops per rotation and step."""
    pairs, triples = n * (n + 1) // 2, n * (n + 1) * (n + 2) // 6
    moments = 0.5 * (2.0 * pairs * pairs * e) + 2.0 * steps * (2.0 * n * n * triples + 4.0 * n * triples)
    return moments < steps * 4.0 * e * n * n


__all__ = ["FourthMoments", "fourth_moments_pay", "side_by_side", "STEPS_PER_RESTART"]
