"""Offline baselines the seeds compare against (DESIGN §4.4): uniform sampling and frame
decimation (Togawa & Okuda; Li, Okuda & Takahashi 2005, cited by the thesis, seed 000 ch. 4).

Both return exactly `count` keyframes, always including the first and the last captured frame,
in the file's numbering (frames before `motion.first_frame` are skipped).

Frame decimation, as settled here:

- The curve is the one of curve simplification (`simplify.curve`): body-frame (root-relative)
  joint positions in body heights (``space="positions"``, the default), or every channel with
  unwrapped rotations (``space="channels"``, which spends keys on Euler flips).
- Reconstruction error of a keyframe set = the sum over frames of the squared Euclidean distance
  between the frame and the linear interpolation of its enclosing keyframes (SSE). It is a sum
  over segments, so removing an interior keyframe k with neighbours p < k < q raises it by
  exactly ``cost(k) = SSE(p, q) - SSE(p, k) - SSE(k, q)``.
- Each step removes the keyframe of least cost (ties: the earliest frame). A heap holds
  (cost, frame); entries are invalidated lazily by a per-frame version number, and a removal
  only re-prices its two neighbours (two new segment SSEs), so the whole run costs
  O(n log n + sum of re-priced segment lengths) instead of O(n^2) rescans.
- Removal order is nested: the keyframes for K are those for K + 1 minus one frame, so one run
  (`decimation_order`) serves every K.
"""

from __future__ import annotations

import heapq

import numpy as np

from ..errors import UsageError
from ..features import Features
from ..keyframes import Keyframes
from ..motion import Motion
from .simplify import DEFAULT_SPACE, SPACES, curve

__all__ = ["uniform", "decimate", "decimation_order", "segment_sse", "reconstruction_sse"]


def _check_count(count: int, n: int) -> int:
    if isinstance(count, bool) or not isinstance(count, int | np.integer):
        raise UsageError(f"count must be an integer, got {count!r}")
    if not min(2, n) <= count <= n:
        raise UsageError(f"count must be in [2, {n}] (captured frames), got {count}")
    return int(count)


def uniform(motion: Motion, count: int) -> Keyframes:
    """`count` keyframes evenly spaced over the captured frames (first and last included)."""
    n = motion.n_frames - motion.first_frame
    count = _check_count(count, n)
    # floor(x + 0.5) is strictly increasing for spacing >= 1 (np.round's half-to-even is not)
    rows = np.floor(np.linspace(0.0, n - 1, count) + 0.5).astype(np.int64)
    return Keyframes("uniform", rows + motion.first_frame, np.zeros(count), {"count": count},
                     motion.n_frames)


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


def reconstruction_sse(x: np.ndarray, keys: np.ndarray) -> float:
    """Total SSE of linearly interpolating `x` between sorted `keys` (first and last row in)."""
    keys = np.asarray(keys, dtype=np.int64)
    return float(sum(segment_sse(x, int(a), int(b))
                     for a, b in zip(keys[:-1], keys[1:], strict=True)))


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


def decimate(motion: Motion, count: int, *, space: str = DEFAULT_SPACE,
             features: Features | None = None) -> Keyframes:
    """Frame decimation to exactly `count` keyframes (see the module docstring)."""
    if space not in SPACES:
        raise UsageError(f"space must be one of {SPACES}, got {space!r}")
    x = curve(motion, space, features)
    count = _check_count(count, len(x))
    removed, costs = decimation_order(x, count)
    keep = np.ones(len(x), dtype=bool)
    keep[removed] = False
    rows = np.flatnonzero(keep)
    info = {"sse": reconstruction_sse(x, rows), "last_cost": float(costs[-1]) if len(costs)
            else 0.0}
    return Keyframes("decimation", rows + motion.first_frame, np.zeros(len(rows)),
                     {"count": count, "space": space}, motion.n_frames, info)
