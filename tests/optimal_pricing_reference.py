"""The BLAS formulation of optimal's segment pricing that `optimal_math.Pricer` replaced
(four window × chunk matrix products a chunk), kept as a test reference only: the compiled
column-by-column pricing must agree with it to rounding (tests/test_optimal.py)."""

from __future__ import annotations

import numpy as np

from streamkey.methods.optimal_math import CHUNK, EPOCH


def _rowdot(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", p, q)


class ReferencePricer:
    """Segment costs chunk by chunk from four matrix products over the window (the old
    `Pricer`: same prefix sums, re-base every `EPOCH` frames, re-centring)."""

    def __init__(self, max_len: int) -> None:
        self.max_len = int(max_len)
        self.o = 0
        self.n = 0
        self.c = np.empty(0)
        self.w = np.empty((0, 0))

    def _alloc(self, d: int) -> None:
        size = EPOCH + self.max_len + CHUNK + 1
        self.w = np.zeros((size, d))
        self.q0 = np.zeros((size + 1, d))
        self.q1 = np.zeros((size + 1, d))
        self.q2 = np.zeros(size + 1)
        self.na = np.zeros(size)
        self.h1 = np.zeros(size)
        self.h3 = np.zeros(size)
        self.mr = np.zeros((size, d))

    def _append(self, rows: np.ndarray) -> None:
        lo = self.n - self.o
        hi = lo + len(rows)
        wc = rows - self.c
        u = np.arange(lo, hi, dtype=np.float64)[:, None]
        self.w[lo:hi] = wc
        self.q0[lo + 1 : hi + 1] = self.q0[lo] + np.cumsum(wc, axis=0)
        self.q1[lo + 1 : hi + 1] = self.q1[lo] + np.cumsum(u * wc, axis=0)
        na = _rowdot(wc, wc)
        self.q2[lo + 1 : hi + 1] = self.q2[lo] + np.cumsum(na)
        q0, q1 = self.q0[lo + 1 : hi + 1], self.q1[lo + 1 : hi + 1]
        self.na[lo:hi] = na
        self.h1[lo:hi] = _rowdot(wc, q0)
        self.h3[lo:hi] = _rowdot(wc, q1)
        self.mr[lo:hi] = u * q0 - q1
        self.n += len(rows)

    def price(self, x: np.ndarray, xbase: int, b0: int, b1: int) -> np.ndarray:
        """Costs C[i, j] of the segments (a, b), b = b0 + i < b1, a = b − L + j."""
        L = self.max_len
        if len(self.w) == 0:
            self._alloc(x.shape[1])
            self.c = x[0 - xbase].copy()
        if b0 > 0 and b0 % EPOCH == 0:
            self.o = self.n = max(0, b0 - L)
            self.c = x[self.o - xbase].copy()
            self._append(x[self.o - xbase : b0 - xbase])
        self._append(x[b0 - xbase : b1 - xbase])
        o = self.o
        ls, lb0, lb1 = max(o, b0 - L) - o, b0 - o, b1 - o
        nb = lb1 - lb0
        win = self.w[ls:lb1]
        pb, q0b, q1b = self.w[lb0:lb1], self.q0[lb0:lb1], self.q1[lb0:lb1]
        u = np.arange(ls, lb1, dtype=np.float64)[:, None]
        ub = np.arange(lb0, lb1, dtype=np.float64)
        x1, x2, x3 = win @ pb.T, win @ q0b.T, win @ q1b.T
        x4 = self.mr[ls:lb1] @ pb.T
        g0, g1 = _rowdot(pb, q0b), _rowdot(pb, q1b)
        s2, cx1, two_m = (t[L + nb - len(win) :] for t in _tables(L, nb))
        na = self.na[ls:lb1, None]
        cost = (cx1 * x1 - 2.0 * x2 - self.q2[ls + 1 : lb1 + 1, None]
                + s2 * (na + self.na[lb0:lb1]) + (self.q2[lb0:lb1] - 2.0 * g0)
                + two_m * ((ub * g0 - g1) + ub * self.h1[ls:lb1, None] - self.h3[ls:lb1, None]
                           - u * x2 + x3 - x4))
        np.maximum(cost, 0.0, out=cost)
        if len(win) < L + nb:
            cost = np.concatenate([np.full((L + nb - len(win), nb), np.inf), cost])
        step, col = cost.strides
        band = np.lib.stride_tricks.as_strided(cost, (nb, L), (step + col, step)).copy()
        band[:, -1] = 0.0
        return band


def _tables(max_len: int, nb: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    m = (max_len + np.arange(nb))[None, :] - np.arange(max_len + nb)[:, None]
    m = m.astype(np.float64)
    ok = m >= 1.0
    mm = np.where(ok, m, 1.0)
    s2 = np.where(ok, (mm - 1.0) * (2.0 * mm - 1.0) / (6.0 * mm), 0.0)
    return s2, np.where(ok, (mm - 1.0) - 2.0 * s2, 0.0), np.where(ok, 2.0 / mm, 0.0)


def reference_band_costs(x: np.ndarray, max_len: int) -> np.ndarray:
    """Every frame's band of segment costs (n, max_len), chunk by chunk (the old way)."""
    n = len(x)
    out = np.empty((n, max_len))
    pricer = ReferencePricer(max_len)
    for b0 in range(0, n, CHUNK):
        b1 = min(n, b0 + CHUNK)
        out[b0:b1] = pricer.price(x, 0, b0, b1)
    return out
