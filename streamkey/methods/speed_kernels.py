"""Compiled inner loops of the speed method (`streamkey.jit` kernels; issue 13).

- `hp_advance` / `hp_tail`: every HP scale of an online analysis at once. The forward
  substitution (U'y = v with the factor of `signal.hp_factor`) runs over the stream since its
  start and is carried from one analysis to the next over the speeds that are final; an
  analysis only adds the fresh speeds, the factor's bottom corner and the back substitution
  over its region. Rows are frames, columns lambdas (independent recursions side by side).
- `tail_minima`: local minima of each scale's trend (the comparisons of
  `signal.local_minima`) and the speed descent u there.
- `chain_totals`: the candidates' chains of matched minima (`speed.Chain`, the band DP of
  `speed._band_dp`, same ties): the same intensities, bit for bit.
- `ward_levels`: `speed.ward_1d`'s greedy merging of sorted neighbours with an array heap.
  Merges pop in the order of the (level, left, right, size) tuples, like the heapq version,
  so the hierarchy and the levels are the same.
"""

from __future__ import annotations

import numpy as np

from ..jit import kernel, warmer

__all__ = ["hp_advance", "hp_tail", "tail_minima", "chain_totals", "band_offsets",
           "ward_levels"]


@kernel
def _column(pre: np.ndarray, off: np.ndarray, lam: int, j: int
            ) -> tuple[float, float, float]:
    """Interior column j of lambda lam's factor: its first columns, then the converged one."""
    k = off[lam + 1] - off[lam]
    c = off[lam] + min(j, k - 1)
    return pre[0, c], pre[1, c], pre[2, c]


@kernel
def hp_advance(v: np.ndarray, g0: int, done: int, upto: int, ys: np.ndarray, pre: np.ndarray,
               off: np.ndarray, conv: np.ndarray) -> int:
    """Forward substitution of every lambda over stream rows done..upto-1 (speed g is
    v[g - g0]; interior factor columns) into the ring `ys` (row g at g % len(ys)).
    Returns upto."""
    n_ring, n_lam = ys.shape
    k_max = 0
    for lam in range(n_lam):
        k_max = max(k_max, off[lam + 1] - off[lam])
    for g in range(done, upto):
        x = v[g - g0]
        r, r1, r2 = g % n_ring, (g - 1) % n_ring, (g - 2) % n_ring
        if g >= k_max:  # every factor has converged: constant columns
            for lam in range(n_lam):
                ys[r, lam] = ((x - conv[0, lam] * ys[r2, lam]) - conv[1, lam] * ys[r1, lam]
                              ) / conv[2, lam]
        else:
            for lam in range(n_lam):
                c0, c1, c2 = _column(pre, off, lam, g)
                t = x
                if g >= 2:
                    t = t - c0 * ys[r2, lam]
                if g >= 1:
                    t = t - c1 * ys[r1, lam]
                ys[r, lam] = t / c2
    return upto


@kernel
def hp_tail(v: np.ndarray, g0: int, lo: int, done: int, ys: np.ndarray, pre: np.ndarray,
            off: np.ndarray, conv: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """HP trends of every lambda at stream rows g0+lo .. N-1 (N = g0 + len(v) >= 5: the
    system since the stream's start), rows x lambdas. Forward values before row `done` come
    from the ring `ys` (`hp_advance`); rows done..N-1 are solved here, the last two with the
    factor's bottom corner (the arithmetic of `signal.hp_factor`), then the back
    substitution (U x = y, bottom up) down to row g0 + lo."""
    n_ring, n_lam = ys.shape
    big_n = g0 + len(v)
    lo_g = g0 + lo
    e0 = max(0, min(lo_g, done - 2))
    out = np.empty((big_n - e0, n_lam))
    for g in range(e0, done):
        out[g - e0] = ys[g % n_ring]
    k_max = 0
    for lam in range(n_lam):
        k_max = max(k_max, off[lam + 1] - off[lam])
    for g in range(done, big_n - 2):  # interior rows
        x = v[g - g0]
        i = g - e0
        if g >= k_max:
            for lam in range(n_lam):
                out[i, lam] = ((x - conv[0, lam] * out[i - 2, lam])
                               - conv[1, lam] * out[i - 1, lam]) / conv[2, lam]
        else:
            for lam in range(n_lam):
                c0, c1, c2 = _column(pre, off, lam, g)
                t = x
                if g >= 2:
                    t = t - c0 * out[i - 2, lam]
                if g >= 1:
                    t = t - c1 * out[i - 1, lam]
                out[i, lam] = t / c2
    i = big_n - 2 - e0
    for lam in range(n_lam):  # the bottom corner, forward and back
        u0, u1, _ = _column(pre, off, lam, big_n - 2)
        v0 = _column(pre, off, lam, big_n - 1)[0]
        d2 = np.sqrt((1.0 + 5.0 * lams[lam]) - u0 * u0 - u1 * u1)
        e = ((-2.0 * lams[lam]) - u1 * v0) / d2
        last = np.sqrt((1.0 + lams[lam]) - v0 * v0 - e * e)
        y2 = ((v[big_n - 2 - g0] - u0 * out[i - 2, lam]) - u1 * out[i - 1, lam]) / d2
        y1 = ((v[big_n - 1 - g0] - v0 * out[i - 1, lam]) - e * y2) / last
        out[i + 1, lam] = y1 / last
        out[i, lam] = (y2 - out[i + 1, lam] * e) / d2
    for g in range(big_n - 3, lo_g - 1, -1):
        i = g - e0
        if g >= k_max:
            for lam in range(n_lam):
                out[i, lam] = ((out[i, lam] - out[i + 2, lam] * conv[0, lam])
                               - out[i + 1, lam] * conv[1, lam]) / conv[2, lam]
        else:
            for lam in range(n_lam):
                c2 = _column(pre, off, lam, g)[2]
                c1 = _column(pre, off, lam, g + 1)[1]
                c0 = _column(pre, off, lam, g + 2)[0]
                out[i, lam] = ((out[i, lam] - out[i + 2, lam] * c0) - out[i + 1, lam] * c1) / c2
    return out[lo_g - e0 :]


@kernel
def tail_minima(trends: np.ndarray, n_scales: int, lo: int, start: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scale s: local minima m >= start of column s of `trends` (rows from frame lo),
    u = |trend_s - trend_(S+s)| there. Flat (m, u) and per-scale counts."""
    rows = trends.shape[0]
    ms = np.empty(n_scales * max(rows // 2, 1), dtype=np.int64)
    us = np.empty(len(ms))
    counts = np.zeros(n_scales, dtype=np.int64)
    k = 0
    first = max(1, start - lo)
    for s in range(n_scales):
        for i in range(first, rows - 1):
            x = trends[i, s]
            if x < trends[i - 1, s] and x <= trends[i + 1, s]:
                ms[k] = i + lo
                us[k] = abs(x - trends[i, n_scales + s])
                k += 1
                counts[s] += 1
    return ms[:k], us[:k], counts


@kernel
def band_offsets(long_: np.ndarray, short: np.ndarray) -> np.ndarray:
    """`speed._band_dp`: offsets d_j (short[j] pairs with long_[j + d_j]), nondecreasing in
    [0, k], minimum total |difference|; ties keep the smaller offset (same integer sums)."""
    p, k = len(short), len(long_) - len(short)
    arg = np.empty((k + 1, p), dtype=np.int64)
    m_prev = np.full(p, np.inf)
    arg_prev = np.zeros(p, dtype=np.int64)
    for d in range(k + 1):
        x = 0.0
        below = np.inf  # m_prev[j - 1] before this column's update
        for j in range(p):
            c = float(abs(long_[d + j] - short[j]))
            x = c if j == 0 else c + min(below, x)
            below = m_prev[j]
            if x < m_prev[j]:
                arg_prev[j] = d
                m_prev[j] = x
            arg[d, j] = arg_prev[j]
    offsets = np.empty(p, dtype=np.int64)
    hi = k
    for j in range(p - 1, -1, -1):
        hi = arg[hi, j]
        offsets[j] = hi
    return offsets


@kernel
def chain_totals(candidates: np.ndarray, minima: np.ndarray, u: np.ndarray,
                 counts: np.ndarray) -> np.ndarray:
    """`speed.intensities` over flat per-scale minima: u summed along each candidate's chain
    (band DP matching only: the caller checks `speed.BAND_BUDGET`)."""
    n = len(candidates)
    total = np.zeros(n)
    chain = np.arange(n)
    alive = np.ones(n, dtype=np.bool_)
    prev = candidates
    at = 0
    for s in range(len(counts)):
        cur = minima[at : at + counts[s]]
        cu = u[at : at + counts[s]]
        at += counts[s]
        if len(cur) != len(prev):
            partner = np.full(len(prev), -1, dtype=np.int64)
            if len(prev) and len(cur):
                if len(cur) > len(prev):
                    partner[:] = np.arange(len(prev)) + band_offsets(cur, prev)
                else:
                    idx = np.arange(len(cur)) + band_offsets(prev, cur)
                    partner[idx] = np.arange(len(cur))
            for c in range(n):
                chain[c] = partner[chain[c]] if alive[c] and len(prev) else -1
                alive[c] = chain[c] >= 0
        for c in range(n):
            if alive[c]:
                total[c] += cu[chain[c]]
        prev = cur
    return total


@kernel
def _heap_less(hd: np.ndarray, hi: np.ndarray, hs: np.ndarray, x: int, y: int) -> bool:
    """Entry x before entry y: (level, left, right, size) compared as tuples."""
    if hd[x] != hd[y]:
        return hd[x] < hd[y]
    if hi[x, 0] != hi[y, 0]:
        return hi[x, 0] < hi[y, 0]
    if hi[x, 1] != hi[y, 1]:
        return hi[x, 1] < hi[y, 1]
    return hs[x] < hs[y]


@kernel
def _heap_swap(hd: np.ndarray, hi: np.ndarray, hs: np.ndarray, x: int, y: int) -> None:
    hd[x], hd[y] = hd[y], hd[x]
    hi[x, 0], hi[y, 0] = hi[y, 0], hi[x, 0]
    hi[x, 1], hi[y, 1] = hi[y, 1], hi[x, 1]
    hs[x], hs[y] = hs[y], hs[x]


@kernel
def _sift_down(hd: np.ndarray, hi: np.ndarray, hs: np.ndarray, pos: int, size: int) -> None:
    while True:
        a = 2 * pos + 1
        if a >= size:
            return
        if a + 1 < size and _heap_less(hd, hi, hs, a + 1, a):
            a += 1
        if not _heap_less(hd, hi, hs, a, pos):
            return
        _heap_swap(hd, hi, hs, a, pos)
        pos = a


@kernel
def ward_levels(v: np.ndarray, two: float) -> tuple[np.ndarray, np.ndarray]:
    """`speed.ward_1d` on sorted values v: fusion levels in merge order, and per merge the
    sorted position where its right cluster starts. `two` = 2.0, passed at run time: the
    first levels are 0.5 d ** two through libm's pow, as Python's `d ** 2` (x * x differs in
    the last bit for ~1 d in 1,000)."""
    n = len(v)
    cap = max(3 * n, 1)
    hd = np.empty(cap)
    hi = np.empty((cap, 2), dtype=np.int64)
    hs = np.empty(cap)
    size = np.ones(n)
    total = v.copy()
    left = np.arange(-1, n - 1)
    right = np.arange(1, n + 1)
    alive = np.ones(n, dtype=np.bool_)
    for i in range(n - 1):
        d = v[i + 1] - v[i]
        hd[i], hi[i, 0], hi[i, 1], hs[i] = 0.5 * d**two, i, i + 1, 2.0
    h = max(n - 1, 0)
    for pos in range(h // 2 - 1, -1, -1):
        _sift_down(hd, hi, hs, pos, h)
    alpha = np.empty(max(n - 1, 0))
    bounds = np.empty(max(n - 1, 0), dtype=np.int64)
    done = 0
    while done < n - 1:
        d, a, b, both = hd[0], hi[0, 0], hi[0, 1], hs[0]
        h -= 1
        _heap_swap(hd, hi, hs, 0, h)
        _sift_down(hd, hi, hs, 0, h)
        if not (alive[a] and alive[b]) or right[a] != b or size[a] + size[b] != both:
            continue  # stale: one side has grown since
        alpha[done], bounds[done] = 2.0 * d, b
        done += 1
        alive[b] = False
        size[a] += size[b]
        total[a] += total[b]
        right[a] = right[b]
        if right[a] < n:
            left[right[a]] = a
        for x, y in ((left[a], a), (a, right[a])):
            if 0 <= x and y < n:
                nx, ny = size[x], size[y]
                diff = total[x] / nx - total[y] / ny
                hd[h], hi[h, 0], hi[h, 1], hs[h] = nx * ny / (nx + ny) * diff * diff, x, y, nx + ny
                pos = h
                h += 1
                while pos > 0:  # sift up
                    parent = (pos - 1) // 2
                    if not _heap_less(hd, hi, hs, pos, parent):
                        break
                    _heap_swap(hd, hi, hs, pos, parent)
                    pos = parent
    return alpha, bounds


@warmer
def _warm() -> None:
    """Compile (or load) every kernel of this module on tiny inputs."""
    lams = np.array([2.0, 30.0])
    pre, conv = np.ones((3, 4)), np.ones((3, 2))
    off = np.array([0, 2, 4], dtype=np.int64)
    ys = np.zeros((8, 2))
    v = np.linspace(0.0, 1.0, 7)
    done = hp_advance(v, 0, 0, 3, ys, pre, off, conv)
    trends = hp_tail(v, 0, 0, done, ys, pre, off, conv, lams)
    m, u, c = tail_minima(trends, 1, 0, 1)
    tail_minima(np.ascontiguousarray(trends), 1, 0, 1)
    chain_totals(np.array([1, 3], dtype=np.int64), m, u, c)
    band_offsets(np.array([1, 2, 3], dtype=np.int64), np.array([2], dtype=np.int64))
    ward_levels(np.array([0.0, 1.0, 3.0]), 2.0)
