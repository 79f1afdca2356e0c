"""Compiled loops of multiscale motion saliency: the online keyframer's frame-by-frame rows,
running map statistics, classification and clustering, and the clustering's keyframe choice.

Each loop is the sequential twin of a vectorised function of `saliency_math` (named in its
docstring), with the same arithmetic in the same order, so that offline and online results
agree to the bit. No state, no I/O.
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import kernel as compiled
from ..jit import warmer

__all__ = ["Clusterer", "pick_keyframe", "cuts", "itti_factors", "classify_terms",
           "classify_block", "ring_curves", "ring_maps_of", "smooth_rows"]

_TIE = 1e-9  # keyframe distances within this are ties (the earlier frame wins)

@compiled
def cuts(row: int, length: float) -> bool:
    """Whether `row` (frames from the stream's first) starts a new slot of the cluster grid
    of `length` frames: floor(row / length) > floor((row - 1) / length) (`row % length == 0`
    for a whole length)."""
    return math.floor(row / length) > math.floor((row - 1) / length)


def pick_keyframe(rows: list[int], wrow: list[float], foot: list[bool]) -> int:
    """Halit sec. 3.1.4 / sec. 3.3 choice in one cluster (sequential twin of `cluster_keyframes`,
    summing in row order as its `bincount` does; `_pick`, compiled)."""
    return int(_pick(np.asarray(rows, dtype=np.int64), np.asarray(wrow, dtype=np.float64),
                     np.asarray(foot, dtype=np.bool_), len(rows)))


class Clusterer:
    """Sequential clustering of classified frames: runs cut on the stream's grid of `cmax`
    frames (sec. 3.1.4, `cuts`); the open cluster's state, which `classify_block` advances
    over a block of rows.

    `close()` may also be called early (an online decision deadline); the run then goes on
    in a new cluster that still ends on the `cmax` grid, as offline.
    """

    def __init__(self, cmax: float) -> None:
        self.cmax = cmax
        self.rows: list[int] = []
        self.wrow: list[float] = []
        self.foot: list[bool] = []
        self.score = 0.0
        self.last = -2  # last candidate row
        self.run = 0  # candidate rows of the current run so far

    def close(self) -> tuple[int, float]:
        """Close the open cluster: (keyframe row, score)."""
        out = (pick_keyframe(self.rows, self.wrow, self.foot), self.score)
        self.rows, self.wrow, self.foot, self.score = [], [], [], 0.0
        return out


@compiled
def itti_factors(top: np.ndarray, hmax: np.ndarray, h3: np.ndarray, total: np.ndarray, n: int,
                 lm_n: np.ndarray, lm_sum: np.ndarray, lm_top: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """`normalisation` of the `MapStats` fields in one compiled loop, given `h3` (k,) =
    `top.max(axis=1, keepdims=True) ** 3` computed by numpy (its `power` is not libm's) for
    the row maxima `hmax`: the same operations in the same order, so the same bits. Returns
    (a, thr, thr with its zeros as 1, True), or False last when a row maximum of `top` is
    not `hmax` (`h3` is stale: compute it again)."""
    k = top.shape[0]
    a = np.empty((k, 4))
    thr = np.empty(k)
    safe_thr = np.empty(k)
    for j in range(k):
        h = top[j, 0]
        for i in range(1, 4):
            h = max(h, top[j, i])
        if h != hmax[j] and (h == h or hmax[j] == hmax[j]):  # (NaN matches NaN)
            return a, thr, safe_thr, False
    nn = max(n, 1)
    for j in range(k):
        acc = 0.0
        for i in range(4):
            t = top[j, i]
            safe = t if t > 0 else 1.0
            has = lm_top[j, i] == t
            m = (lm_sum[j, i] - (t if has else 0.0)) / max(lm_n[j, i] - (1 if has else 0), 1)
            r = 1.0 - m / safe
            a[j, i] = h3[j] / safe * (r * r) * (1.0 if t > 0 else 0.0)
            term = total[j, i] / nn * a[j, i]
            acc = term if i == 0 else acc + term
        thr[j] = acc
        safe_thr[j] = acc if acc > 0 else 1.0
    return a, thr, safe_thr, True


@compiled
def classify_terms(s: np.ndarray, a: np.ndarray, thr: np.ndarray, thr_safe: np.ndarray,
                   weights: np.ndarray, footmask: np.ndarray, wsum: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per row of maps `s` (n, k, 4) in one compiled loop: the clustering terms of
    `combine(s, a) > thr` (any candidate, weight, foot flag, score term) and the trace level
    (the weighted mean of S_j / mean(S_j), over `wsum`). The saliency and the flags have the
    bits of `combine`; the sums over curves go in curve order."""
    n, k = s.shape[0], s.shape[1]
    hit = np.zeros(n, dtype=np.bool_)
    foot = np.zeros(n, dtype=np.bool_)
    wrow = np.zeros(n)
    term = np.zeros(n)
    level = np.zeros(n)
    wtotal = 0.0
    for j in range(k):
        wtotal += weights[j]
    for f in range(n):
        w_acc, t_acc, l_acc = 0.0, 0.0, 0.0
        for j in range(k):
            sal = ((s[f, j, 0] * a[j, 0] + s[f, j, 1] * a[j, 1]) + s[f, j, 2] * a[j, 2]) + (
                s[f, j, 3] * a[j, 3])
            rel = sal / thr_safe[j]
            l_acc += rel * weights[j]
            if sal > thr[j]:
                hit[f] = True
                w_acc += weights[j]
                t_acc += rel * weights[j]
                if footmask[j]:
                    foot[f] = True
        wrow[f] = w_acc
        term[f] = t_acc / wtotal
        level[f] = l_acc / wsum
    return hit, wrow, foot, term, level


@compiled
def _pick(rows: np.ndarray, wrow: np.ndarray, foot: np.ndarray, n: int) -> int:
    """`pick_keyframe` of the first n rows (the same operations, so the same choice)."""
    num, den, any_foot = 0.0, 0.0, False
    for i in range(n):
        num += wrow[i] * rows[i]
        den += wrow[i]
        any_foot = any_foot or foot[i]
    mean = num / den
    best = np.inf
    for i in range(n):
        if foot[i] or not any_foot:
            best = min(best, abs(rows[i] - mean))
    for i in range(n):
        if (foot[i] or not any_foot) and abs(rows[i] - mean) <= best + _TIE:
            key: int = rows[i]
            return key
    first: int = rows[0]
    return first


@compiled
def classify_block(s: np.ndarray, a: np.ndarray, thr: np.ndarray, thr_safe: np.ndarray,
                   weights: np.ndarray, footmask: np.ndarray, wsum: float, g0: int,
                   stop: int, cmax: float, rows: np.ndarray, wrow: np.ndarray,
                   foot: np.ndarray, n_open: int, score: float, last: int, run: int,
                   moving: np.ndarray
                   ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, int, int, float, int,
                              int]:
    """`classify_terms` of the rows g0.. of maps `s`, fed to the clusterer in the same loop
    (row by row, runs cut on the stream's grid of `cmax` rows (`cuts`), stopping before the
    first row
    whose cluster would start after `stop`): the open cluster's rows / weights / foot flags
    in the buffers `rows`, `wrow`, `foot` (at least ceil(cmax) + 1 long, updated in place; its
    first n_open rows), its score, the last candidate row and the run length. Returns (rows
    classified, their trace levels, the keyframe rows and scores of the clusters closed, how
    many, n_open, score, last, run). `moving`: per row, whether it is motion (in a take)."""
    hit, wr, ft, term, level = classify_terms(s, a, thr, thr_safe, weights, footmask, wsum)
    n = len(hit)
    keys = np.empty(n + 1, dtype=np.int64)
    kscore = np.empty(n + 1)
    nk = 0
    for i in range(n):
        row = g0 + i
        if (rows[0] if n_open > 0 else row) > stop:
            return i, level, keys, kscore, nk, n_open, score, last, run
        h = hit[i] and moving[i]  # a calibration hold or still stretch has no candidate
        if n_open > 0 and (not h or row != rows[n_open - 1] + 1):
            keys[nk], kscore[nk] = _pick(rows, wrow, foot, n_open), score
            nk, n_open, score = nk + 1, 0, 0.0
        if h:
            run = run + 1 if row == last + 1 else 1
            last = row
            rows[n_open], wrow[n_open], foot[n_open] = row, wr[i], ft[i]
            n_open += 1
            score += term[i]
            if cuts(row + 1, cmax):  # the next row starts a new slot of the grid
                keys[nk], kscore[nk] = _pick(rows, wrow, foot, n_open), score
                nk, n_open, score = nk + 1, 0, 0.0
    return n, level, keys, kscore, nk, n_open, score, last, run


# --------------------------------------------------------------------------- online ring rows

@compiled
def smooth_rows(x: np.ndarray, y: np.ndarray, r0: int, r1: int, start: int, b: np.ndarray,
                a: np.ndarray) -> None:
    """Rows r0..r1-1 of `y`: the causal low-pass (b, a) (a[0] = 1) of the rows of `x`, row by
    row in direct form, `start` the first row of the recursion (rows before it taken as
    x[start], the steady state of a constant signal). The filter of
    `saliency_math.smooth_curves`.

    The recursion runs on the departure from x[start], so a signal that stays at its first
    value comes out exactly as it went in: in direct form a 6th-order low-pass turns a
    constant into one that wobbles by ~1e-9, which the curvature maps would normalise into
    keys on a still pose."""
    order = len(a) - 1
    for r in range(r0, r1):
        for j in range(x.shape[1]):
            base = x[start, j]
            acc = b[0] * (x[r, j] - base)
            for i in range(1, order + 1):
                p = r - i
                if p >= start:
                    acc += b[i] * (x[p, j] - base)
                    acc -= a[i] * (y[p, j] - base)
            y[r, j] = base + acc


@compiled
def ring_curves(xs: np.ndarray, ft: np.ndarray, keep: np.ndarray, mean: np.ndarray,
                sd: np.ndarray, vec: np.ndarray, contact: bool, d: np.ndarray, c: np.ndarray,
                a0: int, a1: int, step: float) -> None:
    """Online rows between basis updates, one compiled loop: curve rows a0..a1-1 of the ring
    (projection of the kept columns, the foot heights last with contact) and the interior
    curvatures (eq. 3.4, `step` as `curvature`'s) of rows a0-1..a1-2. Row by row, so any
    block split gives the same bits."""
    npca = vec.shape[1]
    h2, hh = 2.0 * step, step * step
    for r in range(a0, a1):
        for j in range(npca):
            acc = 0.0
            for q in range(len(keep)):
                acc += (xs[r, keep[q]] - mean[q]) / sd[q] * vec[q, j]
            d[r, j] = acc
        if contact:
            d[r, d.shape[1] - 2] = ft[r, 0]
            d[r, d.shape[1] - 1] = ft[r, 1]
    for r in range(a0 - 1, a1 - 1):
        for j in range(d.shape[1]):
            d1 = (d[r + 1, j] - d[r - 1, j]) / h2
            num = ((d[r + 1, j] - 2.0 * d[r, j]) + d[r - 1, j]) / hh
            c[r, j] = abs(num) / (1.0 + d1 * d1) ** 1.5


@compiled
def ring_maps_of(c: np.ndarray, s: np.ndarray, lm: np.ndarray, f0: int, f1: int,
                 bank: np.ndarray, col: np.ndarray, total: np.ndarray, top: np.ndarray,
                 lm_n: np.ndarray, lm_sum: np.ndarray, lm_top: np.ndarray,
                 moving: np.ndarray) -> None:
    """Maps S of ring rows f0..f1 from their curvatures `c`, and the running statistics in
    place (`MapStats` fields, frame by frame): S_i of curve j = |sum over the window of the
    curvatures times column col[j] + i of `bank`| ((2 R + 1, columns): the differences of
    the normalised Gaussian kernels of each sigma, summed in window order; the curves
    sharing a sigma share columns), row f - 1's local-maximum flags once row f exists. Only
    the rows that are motion (`moving`, in a take) enter the statistics."""
    k = c.shape[1]
    acc = np.empty((k, 4))
    for f in range(f0, f1 + 1):
        acc[:] = 0.0
        for q in range(bank.shape[0]):
            r = f - (bank.shape[0] - 1) // 2 + q
            for j in range(k):
                cj = c[r, j]
                for i in range(4):
                    acc[j, i] += cj * bank[q, col[j] + i]
        for j in range(k):
            for i in range(4):
                v = abs(acc[j, i])
                s[f, j, i] = v
                if moving[f]:
                    total[j, i] += v
                    if v > top[j, i]:
                        top[j, i] = v
                mid = s[f - 1, j, i]
                flag = mid > s[f - 2, j, i] and mid >= v
                lm[f - 1, j, i] = flag
                if flag and moving[f - 1]:
                    lm_n[j, i] += 1
                    lm_sum[j, i] += mid
                    if mid > lm_top[j, i]:
                        lm_top[j, i] = mid


@warmer
def _warm() -> None:
    xs, ft = np.zeros((8, 3)), np.zeros((8, 2))
    d, c = np.zeros((8, 3)), np.zeros((8, 3))
    keep = np.arange(3, dtype=np.int64)
    ring_curves(xs, ft, keep, np.zeros(3), np.ones(3), np.ones((3, 1)), True, d, c, 2, 8, 1.0)
    ba = np.array([1.0, 0.0, 0.0])
    smooth_rows(xs, d, 0, 8, 0, ba, ba)
    z = np.zeros((3, 4))
    ring_maps_of(c, np.zeros((8, 3, 4)), np.zeros((8, 3, 4), dtype=bool), 3, 4,
                 np.ones((3, 12)), 4 * np.arange(3), z, z.copy(),
                 np.zeros((3, 4), dtype=np.int64), z.copy(), z.copy(), np.ones(8, dtype=bool))
    pick_keyframe([4, 5], [1.0, 1.0], [False, True])
    a, thr, safe, _ = itti_factors(z, np.zeros(3), np.ones(3), z, 1,
                                   np.zeros((3, 4), dtype=np.int64), z, z)
    classify_terms(np.ones((2, 3, 4)), a, thr, safe, np.ones(3), np.ones(3, dtype=bool), 1.0)
    classify_block(np.ones((2, 3, 4)), a, thr, safe, np.ones(3), np.ones(3, dtype=bool), 1.0,
                   0, 1, 2.0, np.zeros(3, dtype=np.int64), np.zeros(3), np.zeros(3, dtype=bool),
                   0, 0.0, -2, 0, np.ones(2, dtype=bool))
