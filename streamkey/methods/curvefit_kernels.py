"""Compiled inner loops of `curvefit` (numba kernels, `streamkey.jit`): the whole search of
one channel (Önder steps 2-6) in one call.

The arithmetic is the one of the vectorised numpy form it replaced (kept in the tests as the
reference): the same running sums (one window per key, summed in frame order), the same
moment and Gram-matrix expressions term by term, the same predecessor order in the DP (the
first of equal costs wins, a dropped key only when strictly cheaper), so keys and costs are
bit-identical. What changes is where the time goes: numpy paid ~15 calls per key per pass on
vectors of a few channels; a long clip has thousands of keys per channel and a few channels
still searching, so that overhead grew with the clip (~1 ms per frame at 10k frames, 1.6 ms at
100k). Here one pass costs ~0.1 µs per key whose neighbourhood did not move (its 9 x 10 block
of segment costs is reused from the last pass, the DP step is 81 additions) and a few µs per
key that moved (its block is priced again).
"""

from __future__ import annotations

import numpy as np

from ..jit import kernel, warmer

__all__ = ["candidates", "block_costs", "search_pass", "fit_channel", "hermite_fill",
           "work_size", "SEARCH"]

SEARCH = 4  # nine candidates: key - 4 .. key + 4 (Önder §3.1 step 2)
_ACCEPT = 1 - 1e-12  # a pass's result is kept when it lowers the cost by more than this


@kernel
def candidates(keys: np.ndarray, count: int, n: int, out: np.ndarray) -> None:
    """out[k] = the nine candidate frames of key k (count x 9); the endpoints stay put."""
    for k in range(count):
        for j in range(9):
            if k == 0 or k >= count - 1:
                out[k, j] = keys[k]
            else:
                out[k, j] = min(max(keys[k] + j - SEARCH, 0), n - 1)


@kernel
def block_costs(xc: np.ndarray, mc: np.ndarray, a: np.ndarray, ends: np.ndarray,
                gram: np.ndarray, run: np.ndarray, out: np.ndarray) -> None:
    """Segment SSE of channel `xc` (tangents `mc`) from each of the 9 candidates `a` of a key
    to each of 10 `ends` (the next key's 9 candidates, then the key after it, reached from the
    middle candidate only) into `out` (9 x 10): +inf where the keys would not stay strictly
    ordered, 0 for adjacent frames. `run` (5 x window) is scratch for the running sums."""
    n = len(xc)
    o = a[0]
    width = 0
    for i in range(9):
        for e in range(10):
            end = ends[e] if (e < 9 or i == SEARCH) else a[i]
            if end - a[i] >= 2:
                width = max(width, end - 1 - o)
    x0 = xc[o]
    s0 = s1 = s2 = s3 = s4 = 0.0
    for i in range(width + 1):
        v = xc[min(o + i, n - 1)] - x0
        fi = float(i)
        q1 = v * fi
        q2 = q1 * fi
        q3 = q2 * fi
        q4 = v * v
        if i == 0:
            s0, s1, s2, s3, s4 = v, q1, q2, q3, q4
        else:
            s0 += v
            s1 += q1
            s2 += q2
            s3 += q3
            s4 += q4
        run[0, i] = s0
        run[1, i] = s1
        run[2, i] = s2
        run[3, i] = s3
        run[4, i] = s4
    for i in range(9):
        ai = a[i]
        for e in range(10):
            end = ends[e] if (e < 9 or i == SEARCH) else ai
            length = end - ai
            if length < 2:
                out[i, e] = 0.0 if length == 1 else np.inf
                continue
            d = ai - o
            hi = d + length - 1
            a0 = run[0, hi] - run[0, d]
            a1 = run[1, hi] - run[1, d]
            a2 = run[2, hi] - run[2, d]
            a3 = run[3, hi] - run[3, d]
            a4 = run[4, hi] - run[4, d]
            vd = xc[ai] - x0
            fd = float(d)
            fj = float(length - 1)
            p1 = fj * (fj + 1) / 2
            m1 = a1 - fd * a0 - vd * p1
            m2 = a2 - 2 * fd * a1 + (fd * fd) * a0 - vd * (p1 * (2 * fj + 1) / 3)
            m3 = (a3 - 3 * fd * a2 + 3 * (fd * fd) * a1 - (fd * fd * fd) * a0
                  - vd * (p1 * p1))
            m4 = a4 - 2 * vd * a0 + fj * (vd * vd)
            # _sse: Hermite fit of the segment from its moments
            lf = float(length)
            b1 = m1 / lf
            b2 = m2 / (lf * lf)
            b3 = m3 / (lf * lf * lf)
            xa = xc[ai]
            delta = xc[end] - xa
            bound = 3 * abs(delta)
            ra = min(max(mc[ai] * lf, -bound), bound)
            rb = min(max(mc[end] * lf, -bound), bound)
            cross = delta * (3 * b2 - 2 * b3) + ra * (b1 - 2 * b2 + b3) + rb * (b3 - b2)
            quad = (gram[0, length] * (delta * delta) + gram[1, length] * (ra * ra)
                    + gram[2, length] * (rb * rb)
                    + 2 * (gram[3, length] * delta * ra + gram[4, length] * delta * rb
                           + gram[5, length] * ra * rb))
            sse = m4 - 2 * cross + quad
            out[i, e] = sse if not sse < 0.0 else 0.0


@kernel
def search_pass(xc: np.ndarray, mc: np.ndarray, kp: np.ndarray, count: int, key_cost: float,
                gram: np.ndarray, old_kp: np.ndarray, old_count: int, blocks: np.ndarray,
                cand: np.ndarray, value: np.ndarray, back: np.ndarray,
                run: np.ndarray, found: np.ndarray) -> tuple[int, float]:
    """One pass (Önder steps 2-5) over one channel's keys `kp[:count]` (padded by two n - 1):
    its new keys into `found`, returns (their count, their cost). `blocks` holds the last
    pass's blocks (of keys `old_kp`) and receives this pass's, in place: a key whose frame
    and next two keys' frames are those of a key of the last pass at the same or a later
    index keeps or moves that block down, the others are priced. `value` and `back`
    hold the last pass's DP: its rows before the first key that moved are this pass's too
    (the same blocks, summed in the same order), so the DP restarts there."""
    n = len(xc)
    first = 0  # first key index whose frame differs from the last pass's
    while first < count and first < old_count and kp[first] == old_kp[first]:
        first += 1
    candidates(kp, count, n, cand)
    for j in range(9):
        cand[count, j] = n - 1  # the padding key after the last
    ends = np.empty(10, dtype=np.int64)
    i_old = 0
    for k in range(count - 1):
        f = kp[k]
        while i_old < old_count and old_kp[i_old] < f:
            i_old += 1
        if (k <= i_old <= old_count - 2 and old_kp[i_old] == f
                and old_kp[i_old + 1] == kp[k + 1] and old_kp[i_old + 2] == kp[k + 2]):
            if i_old != k:  # slots below k are this pass's, slots from k on the last's
                blocks[k] = blocks[i_old]
        else:
            for j in range(9):
                ends[j] = cand[k + 1, j]
            ends[9] = kp[k + 2]
            block_costs(xc, mc, cand[k], ends, gram, run, blocks[k])
    for j in range(9):
        value[0, j] = key_cost
    for k in range(max(1, first - 1), count):
        for j in range(9):
            best = value[k - 1, 0] + blocks[k - 1, 0, j]
            arg = 0
            for jp in range(1, 9):
                t = value[k - 1, jp] + blocks[k - 1, jp, j]
                if t < best:
                    best = t
                    arg = jp
            step = 1
            if k >= 2 and j == SEARCH:  # or drop key k - 1 while k - 2 and k keep their frames
                b2 = value[k - 2, SEARCH] + blocks[k - 2, SEARCH, 9]
                if b2 < best:
                    best = b2
                    arg = SEARCH
                    step = 2
            value[k, j] = best + key_cost
            back[k, j, 0] = step
            back[k, j, 1] = arg
    # trace back from the last key (middle candidate), then reverse into frame order
    k, j, m = count - 1, SEARCH, 0
    found[m] = cand[k, j]
    m += 1
    while k > 0:
        step, arg = back[k, j, 0], back[k, j, 1]
        k -= step
        j = arg
        found[m] = cand[k, j]
        m += 1
    found[:m] = found[:m][::-1].copy()
    return m, value[count - 1, SEARCH]


@kernel
def fit_channel(xc: np.ndarray, mc: np.ndarray, keys: np.ndarray, cost: float,
                key_cost: float, tol: float, max_passes: int, gram: np.ndarray,
                work: np.ndarray, run: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Önder steps 2-6 on one channel: passes until one lowers the cost by less than `tol`
    (relative) or `max_passes`: (final keys, cost after each pass run). `work` (at least
    `work_size(len(keys))` floats) and `run` (5 x (n + 1)) are scratch, reused between
    channels so that long clips do not touch fresh memory per channel."""
    n = len(xc)
    size = len(keys) + 2
    blocks = work[: size * 90].reshape(size, 9, 10)
    value = work[size * 90 : size * 99].reshape(size, 9)
    back = np.empty((size, 9, 2), dtype=np.int64)
    cand = np.empty((size, 9), dtype=np.int64)
    found = np.empty(size, dtype=np.int64)
    kp = np.full(size, n - 1, dtype=np.int64)
    kp[: len(keys)] = keys
    count = len(keys)
    old_kp = np.full(size, n - 1, dtype=np.int64)
    old_count = 0
    history = np.empty(max(max_passes, 0))
    passes = 0
    while passes < max_passes:
        m, new = search_pass(xc, mc, kp, count, key_cost, gram, old_kp, old_count, blocks,
                             cand, value, back, run, found)
        old_kp[:] = kp
        old_count = count
        accept = new < cost * _ACCEPT
        going = accept and new < cost * (1 - tol)
        if accept:
            kp[:] = n - 1
            kp[:m] = found[:m]
            count = m
            cost = new
        history[passes] = cost
        passes += 1
        if not going:
            break
    return kp[:count].copy(), history[:passes].copy()


@kernel
def hermite_fill(xc: np.ndarray, mc: np.ndarray, keys: np.ndarray, out: np.ndarray) -> None:
    """Channel `xc` rebuilt from its sorted `keys` (at least 2) by Hermite segments (tangents
    `mc`, limited as in the search) into `out`; frames outside the keys extrapolate the first
    or last segment; the keys keep their data values. `curvefit.hermite`'s arithmetic."""
    s = 0
    for f in range(len(xc)):
        while s < len(keys) - 2 and keys[s + 1] <= f:
            s += 1
        a, b = keys[s], keys[s + 1]
        length = float(b - a)
        t = (f - a) / length
        bound = 3 * abs(xc[b] - xc[a])
        ra = min(max(mc[a] * length, -bound), bound)
        rb = min(max(mc[b] * length, -bound), bound)
        t2 = t * t
        t3 = t2 * t
        out[f] = ((2 * t3 - 3 * t2 + 1) * xc[a] + (t3 - 2 * t2 + t) * ra
                  + (-2 * t3 + 3 * t2) * xc[b] + (t3 - t2) * rb)
    for k in keys:
        out[k] = xc[k]


def work_size(keys: int) -> int:
    """Floats of `fit_channel`'s scratch buffer for a channel of `keys` initial keys."""
    return 99 * (keys + 2)


@warmer
def _warm() -> None:
    """Compile (or load) the kernels on a tiny channel."""
    x = np.sin(np.arange(40) / 4.0)
    m = np.gradient(x)
    gram = np.zeros((6, 41))
    keys = np.array([0, 10, 20, 39])
    hermite_fill(x, m, keys, np.empty(len(x)))
    fit_channel(x, m, keys, 1e9, 1.0, 0.0, 1, gram, np.empty(work_size(len(keys))),
                np.empty((5, len(x) + 1)))
