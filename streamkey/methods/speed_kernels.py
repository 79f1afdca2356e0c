"""Compiled inner loops of the speed method (`streamkey.jit` kernels).

- `hp_advance` / `hp_tail`: every HP scale of an online analysis at once. The forward
  substitution (U'y = v with the factor of `signal.hp_factor`) runs over the stream since its
  start and is carried from one analysis to the next over the speeds that are final; an
  analysis only adds the fresh speeds, the factor's bottom corner and the back substitution
  over its region. Rows are frames, columns lambdas (independent recursions side by side).
- `tail_minima`: local minima of each scale's trend (the comparisons of
  `signal.local_minima`) at or above a rest speed, and the speed descent u there.
- `chain_totals`: the candidates' chains of matched minima (`speed.Chain`: mutual nearest
  minima, `mutual_nearest`, same ties): the same intensities, bit for bit.
- `band_offsets`: the band DP of `speed.match_minima` (the order-preserving matching).
- `ward_levels`: `speed.ward_1d`'s greedy merging of sorted neighbours with an array heap.
  Merges pop in the order of the (level, left, right, size) tuples, like the heapq version,
  so the hierarchy and the levels are the same.
- `ward_labels`, `dropped_threshold`: the rest of `speed.mojena_threshold` (clusters of the
  cut, the dropped cluster and its largest intensity): integer work, comparisons and
  sums in numpy's order, so the same numbers.
"""

from __future__ import annotations

import numpy as np

from ..jit import kernel, warmer

__all__ = ["hp_advance", "hp_tail", "hp_tail_part", "tail_minima", "chain_totals", "band_offsets",
           "mutual_nearest", "ward_levels", "ward_labels", "dropped_threshold"]


@kernel
def _column(pre: np.ndarray, off: np.ndarray, lam: int, j: int
            ) -> tuple[float, float, float]:
    """Interior column j of lambda lam's factor: its first columns, then the converged one."""
    k = off[lam + 1] - off[lam]
    c = off[lam] + min(j, k - 1)
    return pre[0, c], pre[1, c], pre[2, c]


@kernel
def _forward_row(x: float, g: int, y: np.ndarray, y1: np.ndarray, y2: np.ndarray,
                 pre: np.ndarray, off: np.ndarray, conv: np.ndarray, lam0: int, lam1: int
                 ) -> None:
    """Forward row g of lambdas lam0..lam1-1 (y1, y2: rows g-1, g-2), factors not all
    converged."""
    for lam in range(lam0, lam1):
        if g >= off[lam + 1] - off[lam]:  # converged: the constant column
            y[lam] = ((x - conv[0, lam] * y2[lam]) - conv[1, lam] * y1[lam]) * conv[3, lam]
        else:
            c = off[lam] + g
            t = x
            if g >= 2:
                t = t - pre[0, c] * y2[lam]
            if g >= 1:
                t = t - pre[1, c] * y1[lam]
            y[lam] = t / pre[2, c]


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
            y, y1, y2 = ys[r], ys[r1], ys[r2]
            for lam in range(n_lam):
                y[lam] = ((x - conv[0, lam] * y2[lam]) - conv[1, lam] * y1[lam]) * conv[3, lam]
        else:
            _forward_row(x, g, ys[r], ys[r1], ys[r2], pre, off, conv, 0, n_lam)
    return upto


@kernel
def hp_tail(v: np.ndarray, g0: int, lo: int, done: int, ys: np.ndarray, pre: np.ndarray,
            off: np.ndarray, conv: np.ndarray, lams: np.ndarray, scratch: np.ndarray
            ) -> np.ndarray:
    """HP trends of every lambda at stream rows g0+lo .. N-1 (N = g0 + len(v) >= 5: the
    system since the stream's start), rows x lambdas. Forward values before row `done` come
    from the ring `ys` (`hp_advance`); rows done..N-1 are solved here, the last two with the
    factor's bottom corner (the arithmetic of `signal.hp_factor`), then the back
    substitution (U x = y, bottom up) down to row g0 + lo. The result is a view of
    `scratch` (at least N - min(g0 + lo, done) rows, reused: no page faults per call)."""
    out: np.ndarray = hp_tail_part(v, g0, lo, done, ys, pre, off, conv, lams, scratch, 0,
                                   ys.shape[1])
    return out


@kernel
def hp_tail_part(v: np.ndarray, g0: int, lo: int, done: int, ys: np.ndarray, pre: np.ndarray,
                 off: np.ndarray, conv: np.ndarray, lams: np.ndarray, scratch: np.ndarray,
                 lam0: int, lam1: int) -> np.ndarray:
    """`hp_tail` for the lambdas lam0..lam1-1 only (their columns of the result; the others
    are left as they are): each lambda's recursion is its own, so a call per part gives the
    same numbers as one call for all."""
    n_ring = ys.shape[0]
    big_n = g0 + len(v)
    lo_g = g0 + lo
    e0 = min(lo_g, done)  # rows before `done` are read from the ring (no copy)
    out = scratch[: big_n - e0]
    k_max = 0
    for lam in range(lam0, lam1):
        k_max = max(k_max, off[lam + 1] - off[lam])
    for g in range(done, big_n):  # forward rows (the last two: the corner, below)
        y = out[g - e0]
        y1 = ys[(g - 1) % n_ring] if g - 1 < done else out[g - 1 - e0]
        y2 = ys[(g - 2) % n_ring] if g - 2 < done else out[g - 2 - e0]
        x = v[g - g0]
        if g >= big_n - 2:
            for lam in range(lam0, lam1):  # the bottom corner
                u0, u1, _ = _column(pre, off, lam, big_n - 2)
                v0 = _column(pre, off, lam, big_n - 1)[0]
                d2 = np.sqrt((1.0 + 5.0 * lams[lam]) - u0 * u0 - u1 * u1)
                if g == big_n - 2:
                    y[lam] = ((x - u0 * y2[lam]) - u1 * y1[lam]) / d2
                else:
                    e = ((-2.0 * lams[lam]) - u1 * v0) / d2
                    last = np.sqrt((1.0 + lams[lam]) - v0 * v0 - e * e)
                    y[lam] = ((x - v0 * y2[lam]) - e * y1[lam]) / last
        elif g >= k_max:
            for lam in range(lam0, lam1):
                y[lam] = ((x - conv[0, lam] * y2[lam]) - conv[1, lam] * y1[lam]) * conv[3, lam]
        else:
            _forward_row(x, g, y, y1, y2, pre, off, conv, lam0, lam1)
    i = big_n - 2 - e0
    for lam in range(lam0, lam1):  # the corner, back
        u0, u1, _ = _column(pre, off, lam, big_n - 2)
        v0 = _column(pre, off, lam, big_n - 1)[0]
        d2 = np.sqrt((1.0 + 5.0 * lams[lam]) - u0 * u0 - u1 * u1)
        e = ((-2.0 * lams[lam]) - u1 * v0) / d2
        last = np.sqrt((1.0 + lams[lam]) - v0 * v0 - e * e)
        out[i + 1, lam] = out[i + 1, lam] / last
        out[i, lam] = (out[i, lam] - out[i + 1, lam] * e) / d2
    for g in range(big_n - 3, lo_g - 1, -1):
        i = g - e0
        x0, x1, x2 = out[i], out[i + 1], out[i + 2]
        y = ys[g % n_ring] if g < done else x0
        if g >= k_max:
            for lam in range(lam0, lam1):
                x0[lam] = ((y[lam] - x2[lam] * conv[0, lam]) - x1[lam] * conv[1, lam]
                           ) * conv[3, lam]
        else:
            for lam in range(lam0, lam1):
                if g + 1 >= off[lam + 1] - off[lam]:  # columns g..g+2 have converged
                    x0[lam] = ((y[lam] - x2[lam] * conv[0, lam]) - x1[lam] * conv[1, lam]
                               ) * conv[3, lam]
                else:
                    c2 = _column(pre, off, lam, g)[2]
                    c1 = _column(pre, off, lam, g + 1)[1]
                    c0 = _column(pre, off, lam, g + 2)[0]
                    x0[lam] = ((y[lam] - x2[lam] * c0) - x1[lam] * c1) / c2
    return out[lo_g - e0 :]


@kernel
def tail_minima(trends: np.ndarray, n_scales: int, lo: int, start: int, floor: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scale s: local minima m >= start of column s of `trends` (rows from frame lo)
    whose value is at least `floor`, u = |trend_s - trend_(S+s)| there. Flat (m, u) and
    per-scale counts."""
    rows = trends.shape[0]
    first = max(1, start - lo)
    found = np.empty((n_scales, max(rows // 2, 1)), dtype=np.int64)  # rows of each's minima
    counts = np.zeros(n_scales, dtype=np.int64)
    for i in range(first, rows - 1):  # row by row: the trends' memory order
        before, here, after = trends[i - 1], trends[i], trends[i + 1]
        for s in range(n_scales):
            if (here[s] < before[s]) & (here[s] <= after[s]) & (here[s] >= floor):
                found[s, counts[s]] = i
                counts[s] += 1
    ms = np.empty(counts.sum(), dtype=np.int64)
    us = np.empty(len(ms))
    k = 0
    for s in range(n_scales):
        for j in range(counts[s]):
            i = found[s, j]
            ms[k] = i + lo
            us[k] = abs(trends[i, s] - trends[i, n_scales + s])
            k += 1
    return ms, us, counts


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
def _nearest(x: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Index of the element of sorted `x` nearest each of sorted `q` (a tie: the earlier)."""
    out = np.empty(len(q), dtype=np.int64)
    j = 0  # the first element of x at or after q[i] (len(x): none)
    for i in range(len(q)):
        while j < len(x) and x[j] < q[i]:
            j += 1
        if j == 0:
            out[i] = 0
        elif j == len(x) or q[i] - x[j - 1] <= x[j] - q[i]:
            out[i] = j - 1
        else:
            out[i] = j
    return out


@kernel
def mutual_nearest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`speed.nearest_pairs`: per element of sorted `a`, the index of its partner in sorted
    `b` when each is the other's nearest (ties: the earlier), else -1."""
    partner = np.full(len(a), -1, dtype=np.int64)
    if len(a) == 0 or len(b) == 0:
        return partner
    near_b = _nearest(b, a)
    near_a = _nearest(a, b)
    for i in range(len(a)):
        if near_a[near_b[i]] == i:
            partner[i] = near_b[i]
    return partner


@kernel
def chain_totals(candidates: np.ndarray, minima: np.ndarray, u: np.ndarray,
                 counts: np.ndarray) -> np.ndarray:
    """`speed.intensities` over flat per-scale minima: u summed along each candidate's chain
    of mutual nearest minima (`mutual_nearest`), bit for bit."""
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
        partner = mutual_nearest(prev, cur)
        for c in range(n):
            chain[c] = partner[chain[c]] if alive[c] and len(prev) else -1
            alive[c] = chain[c] >= 0
        for c in range(n):
            if alive[c]:
                total[c] += cu[chain[c]]
        prev = cur
    return total


@kernel
def _before(level: np.ndarray, x: int, y: int) -> bool:
    """Pair x pops before pair y: (level, left cluster) compared as a tuple (a current pair
    is named by its left cluster, which fixes its right one and its size)."""
    return level[x] < level[y] or (level[x] == level[y] and x < y)


@kernel
def _sift(heap: np.ndarray, pos: np.ndarray, level: np.ndarray, at: int, size: int,
          up: bool) -> None:
    """Restore the heap order around position `at` (up if `up`, then down)."""
    x = heap[at]
    while up and at > 0:
        parent = (at - 1) // 2
        if not _before(level, x, heap[parent]):
            break
        heap[at] = heap[parent]
        pos[heap[at]] = at
        at = parent
    while True:
        child = 2 * at + 1
        if child >= size:
            break
        if child + 1 < size and _before(level, heap[child + 1], heap[child]):
            child += 1
        if not _before(level, heap[child], x):
            break
        heap[at] = heap[child]
        pos[heap[at]] = at
        at = child
    heap[at] = x
    pos[x] = at


@kernel
def ward_levels(v: np.ndarray, two: float) -> tuple[np.ndarray, np.ndarray]:
    """`speed.ward_1d` on sorted values v: fusion levels in merge order, and per merge the
    sorted position where its right cluster starts. `two` = 2.0, passed at run time: the
    first levels are 0.5 d ** two through libm's pow, as Python's `d ** 2` (x * x differs in
    the last bit for ~1 d in 1,000).

    The heapq version pushed a (level, left, right, size) tuple per new neighbour pair and
    skipped stale ones; its pops are the least tuple among the current pairs. Here each
    current pair has one entry, keyed (level, left) and updated in place: the same pops."""
    n = len(v)
    size = np.ones(n)
    total = v.copy()
    left = np.arange(-1, n - 1)
    right = np.arange(1, n + 1)
    level = np.empty(max(n - 1, 1))
    for i in range(n - 1):
        d = v[i + 1] - v[i]
        level[i] = 0.5 * d**two
    alpha = np.empty(max(n - 1, 0))
    bounds = np.empty(max(n - 1, 0), dtype=np.int64)
    # Leading zeros (most intensities, online): their pairs are the least keys, (0, 0) first,
    # and cluster 0 keeps level 0 while it takes them in turn; merged here, same arithmetic.
    zeros = 0
    while zeros < n and v[zeros] == 0:
        zeros += 1
    for b in range(1, zeros):
        alpha[b - 1], bounds[b - 1] = 2.0 * level[0], b
        size[0] += size[b]
        total[0] += total[b]
        right[0] = right[b]
        if right[0] < n:
            y = right[0]
            left[y] = 0
            diff = total[0] / size[0] - total[y] / size[y]
            level[0] = size[0] * size[y] / (size[0] + size[y]) * diff * diff
    merged = max(zeros - 1, 0)
    heap = np.empty(max(n - 1, 0), dtype=np.int64)
    pos = np.empty(max(n - 1, 0), dtype=np.int64)
    h = 0
    for i in range(n - 1):  # the pairs left: 0's, then those right of the zeros
        if right[i] < n and (i == 0 or i > merged):
            heap[h], pos[i] = i, h
            h += 1
    for at in range(h // 2 - 1, -1, -1):
        _sift(heap, pos, level, at, h, False)
    for done in range(merged, n - 1):
        a = heap[0]
        b = right[a]
        alpha[done], bounds[done] = 2.0 * level[a], b
        h -= 1  # a leaves the heap ...
        if h > 0:
            heap[0] = heap[h]
            _sift(heap, pos, level, 0, h, False)
        if right[b] < n:  # ... and so does b's pair with its right neighbour
            at = pos[b]
            h -= 1
            if at < h:
                heap[at] = heap[h]
                _sift(heap, pos, level, at, h, True)
        size[a] += size[b]
        total[a] += total[b]
        right[a] = right[b]
        if right[a] < n:
            left[right[a]] = a
            y = right[a]  # a's new pair: back in the heap
            diff = total[a] / size[a] - total[y] / size[y]
            level[a] = size[a] * size[y] / (size[a] + size[y]) * diff * diff
            heap[h] = a
            h += 1
            _sift(heap, pos, level, h - 1, h, True)
        x = left[a]
        if x >= 0:  # the left neighbour's pair: new level, in place
            diff = total[x] / size[x] - total[a] / size[a]
            level[x] = size[x] * size[a] / (size[x] + size[a]) * diff * diff
            _sift(heap, pos, level, pos[x], h, True)
    return alpha, bounds


@kernel
def ward_labels(order: np.ndarray, alpha: np.ndarray, bounds: np.ndarray, n_clusters: int
                ) -> np.ndarray:
    """Cluster label of each value (in `u`'s order) when `ward_levels`' hierarchy is cut
    into `n_clusters`: just above the last level kept (Ward is monotone)."""
    n = len(order)
    merged = np.zeros(n, dtype=np.bool_)  # boundary before sorted position i merged
    cut = alpha[n - 1 - n_clusters]
    for j in range(len(alpha)):
        if alpha[j] <= cut:
            merged[bounds[j]] = True
    labels = np.empty(n, dtype=np.int64)
    label = -1
    for i in range(n):
        if not merged[i]:
            label += 1
        labels[order[i]] = label
    return labels


@kernel
def dropped_threshold(u: np.ndarray, labels: np.ndarray) -> tuple[float, bool]:
    """The dropped cluster (the one holding the first zero intensity, else the lowest mean:
    sums in index order, as `np.bincount`) -> (its largest intensity, whether the clusters
    are intervals of intensity)."""
    n = len(u)
    drop = -1
    for i in range(n):
        if u[i] == 0:
            drop = labels[i]
            break
    if drop < 0:
        sums = np.zeros(labels.max() + 1)
        counts = np.zeros(len(sums), dtype=np.int64)
        for i in range(n):
            sums[labels[i]] += u[i]
            counts[labels[i]] += 1
        best = np.inf
        for label in range(len(sums)):
            mean = sums[label] / counts[label]
            if mean < best:
                best, drop = mean, label
    threshold = -np.inf
    for i in range(n):
        if labels[i] == drop:
            threshold = max(threshold, u[i])
    contiguous = True
    for i in range(n):
        contiguous = contiguous and (u[i] > threshold) == (labels[i] != drop)
    return threshold, contiguous


@warmer
def _warm() -> None:
    """Compile (or load) every kernel of this module on tiny inputs."""
    lams = np.array([2.0, 30.0])
    pre, conv = np.ones((3, 4)), np.ones((4, 2))
    off = np.array([0, 2, 4], dtype=np.int64)
    ys = np.zeros((8, 2))
    v = np.linspace(0.0, 1.0, 7)
    done = hp_advance(v, 0, 0, 3, ys, pre, off, conv)
    trends = hp_tail(v, 0, 0, done, ys, pre, off, conv, lams, np.empty((9, 2)))
    hp_tail_part(v, 0, 0, done, ys, pre, off, conv, lams, np.empty((9, 2)), 0, 1)  # stages
    m, u, c = tail_minima(trends, 1, 0, 1, 0.0)
    tail_minima(np.ascontiguousarray(trends), 1, 0, 1, 0.0)
    chain_totals(np.array([1, 3], dtype=np.int64), m, u, c)
    mutual_nearest(np.array([1, 3], dtype=np.int64), np.array([2], dtype=np.int64))
    band_offsets(np.array([1, 2, 3], dtype=np.int64), np.array([2], dtype=np.int64))
    alpha, bounds = ward_levels(np.array([0.0, 1.0, 3.0]), 2.0)
    labels = ward_labels(np.array([2, 0, 1], dtype=np.int64), alpha, bounds, 2)
    dropped_threshold(np.array([1.0, 0.0, 3.0]), labels)
