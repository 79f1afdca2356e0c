"""The heapq + numpy form of frame decimation as it was before the numba kernel
(`streamkey.methods.baselines._decimation_order`): kept here, verbatim, as the reference
whose removal order the kernel must reproduce (tests/test_baselines.py)."""

from __future__ import annotations

import heapq

import numpy as np

_STEPS: dict[int, np.ndarray] = {}  # m -> (1 .. m-1) / m as a column


def _steps(m: int) -> np.ndarray:
    t = _STEPS.get(m)
    if t is None:
        t = np.arange(1, m, dtype=np.float64)[:, None] / m
        if m <= 4096:
            _STEPS[m] = t
    return t


def segment_sse(x: np.ndarray, a: int, b: int) -> float:
    """Sum of squared distances of rows a < i < b to the linear interpolation of rows a, b."""
    m = b - a
    if m < 2:
        return 0.0
    xa = x[a]
    resid = x[a + 1 : b] - xa
    resid -= _steps(m) * (x[b] - xa)
    return float(np.add.reduce(np.einsum("ij,ij->i", resid, resid)))


def decimation_order(x: np.ndarray, count: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Greedy least-cost removal down to `count` rows: (removed rows in order, their costs)."""
    n = len(x)
    # Plain lists: the loop reads and writes single entries, which lists do several times
    # faster than numpy arrays.
    prev = list(range(-1, n - 1))
    nxt = list(range(1, n + 1))
    right = [0.0] * n  # right[k] = SSE of the segment from keyframe k to the next one
    version = [0] * n
    # removing k from the full set: SSE(k-1, k+1) (segment_sse's arithmetic, vectorised)
    resid = x[1:-1] - x[:-2] - 0.5 * (x[2:] - x[:-2])
    first = np.einsum("ij,ij->i", resid, resid)
    heap = [(c, k, 0, c) for k, c in enumerate(first.tolist(), 1)]
    heapq.heapify(heap)
    removed: list[int] = []
    costs: list[float] = []
    pop, push = heapq.heappop, heapq.heappush
    left = n
    while left > count and heap:
        cost, k, ver, span = pop(heap)
        if ver != version[k]:
            continue  # stale entry (lazy invalidation)
        p, q = prev[k], nxt[k]
        removed.append(k)
        costs.append(cost)
        left -= 1
        right[p] = span  # SSE(p, q), computed when k was priced
        nxt[p], prev[q] = q, p
        for j in (p, q):
            if 0 < j < n - 1:
                version[j] += 1
                span_j = segment_sse(x, prev[j], nxt[j])
                push(heap, (span_j - right[prev[j]] - right[j], j, version[j], span_j))
    return np.array(removed, dtype=np.int64), np.array(costs)
