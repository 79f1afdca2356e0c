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
  O(n log n + sum of re-priced segment lengths) instead of O(n^2) rescans. The loop is one
  numba kernel (`streamkey.jit`); its segment SSE sums squares in frame then column order
  (numpy's einsum and pairwise sum differ in the last bits), and the removal order is the one
  of the former heapq + numpy loop on every shared clip in both spaces, counts down to 2
  (tests/decimation_reference.py); 100,000 frames: 0.36 s CPU against 2.8 s.
- Removal order is nested: the keyframes for K are those for K + 1 minus one frame, so one run
  (`decimation_order`) serves every K.
"""

from __future__ import annotations

import numpy as np

from ..errors import UsageError
from ..features import Features
from ..jit import kernel, warmer
from ..keyframes import Keyframes
from ..kinematics import body_height, forward_kinematics
from ..motion import Motion
from .simplify import DEFAULT_SPACE, SPACES, chord_sq, curve, position_rows

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


@kernel
def _segment_sse(x: np.ndarray, a: int, b: int) -> float:
    """`segment_sse`, compiled: rows summed in order, each row's squares in column order."""
    total = 0.0
    for i in range(1, b - a):
        total += chord_sq(x, a, b, i)
    return total


def segment_sse(x: np.ndarray, a: int, b: int) -> float:
    """Sum of squared distances of rows a < i < b to the linear interpolation of rows a, b."""
    return float(_segment_sse(np.ascontiguousarray(x, dtype=np.float64), int(a), int(b)))


def reconstruction_sse(x: np.ndarray, keys: np.ndarray) -> float:
    """Total SSE of linearly interpolating `x` between sorted `keys` (first and last row in)."""
    keys = np.asarray(keys, dtype=np.int64)
    x = np.ascontiguousarray(x, dtype=np.float64)
    return float(sum(_segment_sse(x, int(a), int(b))
                     for a, b in zip(keys[:-1], keys[1:], strict=True)))


@kernel
def _before(c1: float, k1: int, v1: int, c2: float, k2: int, v2: int) -> bool:
    """Heap order: (cost, frame, version) lexicographic, as heapq's tuples."""
    if c1 != c2:
        return c1 < c2
    if k1 != k2:
        return k1 < k2
    return v1 < v2


@kernel
def _sift_down(hc: np.ndarray, hk: np.ndarray, hv: np.ndarray, hs: np.ndarray, i: int,
               size: int) -> None:
    """Move heap entry `i` down below its smaller children (heap of `size` entries)."""
    while True:
        lo = 2 * i + 1
        if lo >= size:
            break
        if lo + 1 < size and _before(hc[lo + 1], hk[lo + 1], hv[lo + 1], hc[lo], hk[lo],
                                     hv[lo]):
            lo += 1
        if not _before(hc[lo], hk[lo], hv[lo], hc[i], hk[i], hv[i]):
            break
        hc[i], hc[lo] = hc[lo], hc[i]
        hk[i], hk[lo] = hk[lo], hk[i]
        hv[i], hv[lo] = hv[lo], hv[i]
        hs[i], hs[lo] = hs[lo], hs[i]
        i = lo


@kernel
def _decimation_order(x: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """`decimation_order` in one compiled loop: a binary heap of (cost, frame, version, span)
    with lazy invalidation."""
    n = len(x)
    cap = 3 * n + 1
    hc = np.empty(cap)  # cost
    hk = np.empty(cap, dtype=np.int64)  # frame
    hv = np.empty(cap, dtype=np.int64)  # version
    hs = np.empty(cap)  # span: SSE(prev, next), the cost's first term
    prev = np.arange(-1, n - 1)
    nxt = np.arange(1, n + 1)
    right = np.zeros(n)
    version = np.zeros(n, dtype=np.int64)
    size = 0
    removed = np.empty(max(n - count, 0), dtype=np.int64)
    costs = np.empty(max(n - count, 0))
    for k in range(1, n - 1):
        c = _segment_sse(x, k - 1, k + 1)
        hc[size], hk[size], hv[size], hs[size] = c, k, 0, c
        size += 1
    for start in range(size // 2 - 1, -1, -1):  # heapify
        _sift_down(hc, hk, hv, hs, start, size)
    left, done = n, 0
    while left > count and size > 0:
        cost, k, ver, span = hc[0], hk[0], hv[0], hs[0]
        size -= 1  # pop: the last entry sifts down from the root
        hc[0], hk[0], hv[0], hs[0] = hc[size], hk[size], hv[size], hs[size]
        _sift_down(hc, hk, hv, hs, 0, size)
        if ver != version[k]:
            continue  # stale entry (lazy invalidation)
        p, q = prev[k], nxt[k]
        removed[done] = k
        costs[done] = cost
        done += 1
        left -= 1
        right[p] = span  # SSE(p, q), computed when k was priced
        nxt[p] = q
        prev[q] = p
        for j in (p, q):
            if 0 < j < n - 1:
                version[j] += 1
                span_j = _segment_sse(x, prev[j], nxt[j])
                c = span_j - right[prev[j]] - right[j]
                i = size  # push: sift up
                size += 1
                while i > 0:
                    up = (i - 1) // 2
                    if not _before(c, j, version[j], hc[up], hk[up], hv[up]):
                        break
                    hc[i], hk[i], hv[i], hs[i] = hc[up], hk[up], hv[up], hs[up]
                    i = up
                hc[i], hk[i], hv[i], hs[i] = c, j, version[j], span_j
    return removed[:done].copy(), costs[:done].copy()


@warmer
def _warm() -> None:
    """Compile (or load) the decimation kernels on a tiny curve."""
    _decimation_order(np.arange(12.0).reshape(6, 2) ** 2, 2)


def decimation_order(x: np.ndarray, count: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Greedy least-cost removal down to `count` rows: (removed rows in order, their costs)."""
    return _decimation_order(np.ascontiguousarray(x, dtype=np.float64), int(count))


def _curve(motion: Motion, space: str, features: Features | None) -> np.ndarray:
    """`simplify.curve`; in positions space without `features`, FK alone on the captured
    frames (the same rows: FK frames are independent, and the unwrapped rotations and the
    pelvis frame of `compute_features` are not needed)."""
    if space == "positions" and features is None:
        fk = forward_kinematics(motion.skeleton, motion.channels[motion.first_frame :])
        return position_rows(fk.positions, motion.skeleton.n_joints, body_height(motion.skeleton))
    return curve(motion, space, features)


def decimate(motion: Motion, count: int, *, space: str = DEFAULT_SPACE,
             features: Features | None = None) -> Keyframes:
    """Frame decimation to exactly `count` keyframes (see the module docstring)."""
    if space not in SPACES:
        raise UsageError(f"space must be one of {SPACES}, got {space!r}")
    x = _curve(motion, space, features)
    count = _check_count(count, len(x))
    removed, costs = decimation_order(x, count)
    keep = np.ones(len(x), dtype=bool)
    keep[removed] = False
    rows = np.flatnonzero(keep)
    info = {"sse": reconstruction_sse(x, rows), "last_cost": float(costs[-1]) if len(costs)
            else 0.0}
    return Keyframes("decimation", rows + motion.first_frame, np.zeros(len(rows)),
                     {"count": count, "space": space}, motion.n_frames, info)
