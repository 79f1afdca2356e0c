"""Offline baselines the papers compare against: uniform sampling and frame decimation
(Togawa & Okuda; Li, Okuda & Takahashi 2005, cited by Halit 2010, ch. 4).

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
- Each step removes the keyframe of least cost (ties: the earliest frame). A heap holds one
  (cost, frame) entry per interior keyframe, re-keyed in place when a removal re-prices one of
  its two neighbours (two new segment SSEs), so the whole run costs O(n log n + sum of
  re-priced segment lengths) instead of O(n^2) rescans. The loop is one numba kernel
  (`streamkey.jit`); its segment SSE sums squares in frame then column order (numpy's einsum
  and pairwise sum differ in the last bits), and the removal order is the one of the former
  heapq + numpy loop on every shared clip in both spaces, counts down to 2
  (tests/decimation_reference.py). Past the caches (100,000 frames: a 74 MB curve) the loop
  waits on memory: the heap is 4-ary (a node's children in one or two cache lines), the rows
  a removal re-prices are prefetched while the heap sifts, and the curve is built block by
  block without curve-sized temporaries. 100,000 frames: 0.44 s CPU in all (curve 0.22,
  loop 0.20) against 2.8 s for the heapq form.
- Removal order is nested: the keyframes for K are those for K + 1 minus one frame, so one run
  (`decimation_order`) serves every K.
"""

from __future__ import annotations

import numpy as np

from ..errors import UsageError
from ..features import Features, compute_features, filtered_motion
from ..jit import kernel, prefetch, warmer
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
    """`segment_sse`, compiled: rows summed in order, each row's squares in column order
    (`chord_sq`'s arithmetic), four rows at a time (four independent sums in flight)."""
    m = b - a
    total = 0.0
    i = 1
    while i + 3 < m:
        t0, t1, t2, t3 = i / m, (i + 1) / m, (i + 2) / m, (i + 3) / m
        s0 = s1 = s2 = s3 = 0.0
        for j in range(x.shape[1]):
            xa = x[a, j]
            db = x[b, j] - xa
            r0 = (x[a + i, j] - xa) - t0 * db
            r1 = (x[a + i + 1, j] - xa) - t1 * db
            r2 = (x[a + i + 2, j] - xa) - t2 * db
            r3 = (x[a + i + 3, j] - xa) - t3 * db
            s0 += r0 * r0
            s1 += r1 * r1
            s2 += r2 * r2
            s3 += r3 * r3
        total += s0
        total += s1
        total += s2
        total += s3
        i += 4
    for k in range(i, m):
        total += chord_sq(x, a, b, k)
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
def _before(c1: float, f1: float, c2: float, f2: float) -> bool:
    """Heap order: (cost, frame) lexicographic."""
    return c1 < c2 or (c1 == c2 and f1 < f2)


@kernel
def _place(h: np.ndarray, pos: np.ndarray, i: int, cost: float, frame: float) -> None:
    """Write entry (cost, frame) at heap slot `i` and record the slot."""
    h[i, 0] = cost
    h[i, 1] = frame
    pos[int(frame)] = i


@kernel
def _sift_down(h: np.ndarray, pos: np.ndarray, i: int, size: int) -> None:
    """Move heap entry `i` below its smaller children (4-ary heap of `size` entries, ordered
    by (cost, frame))."""
    c, f = h[i, 0], h[i, 1]
    while True:
        lo = 4 * i + 1
        if lo >= size:
            break
        best = lo
        for ch in range(lo + 1, min(lo + 4, size)):
            if _before(h[ch, 0], h[ch, 1], h[best, 0], h[best, 1]):
                best = ch
        if not _before(h[best, 0], h[best, 1], c, f):
            break
        _place(h, pos, i, h[best, 0], h[best, 1])
        i = best
    _place(h, pos, i, c, f)


@kernel
def _sift_up(h: np.ndarray, pos: np.ndarray, i: int) -> None:
    """Move heap entry `i` above its larger ancestors."""
    c, f = h[i, 0], h[i, 1]
    while i > 0:
        up = (i - 1) // 4
        if not _before(c, f, h[up, 0], h[up, 1]):
            break
        _place(h, pos, i, h[up, 0], h[up, 1])
        i = up
    _place(h, pos, i, c, f)


@kernel
def _decimation_order(x: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`decimation_order` in one compiled loop, plus `right`: the SSE of the segment from
    each kept row to the next (the last row's 0). An indexed 4-ary heap holds one
    (cost, frame) entry per interior frame, re-keyed in place when the frame is re-priced:
    its pops are those of a heap with lazily invalidated entries (the least valid entry,
    ties by frame) with n entries instead of up to 3 n, a quarter of the levels, and a
    node's children in one or two cache lines (x and the heap exceed the caches at 100k
    frames)."""
    n, d = x.shape
    flat = x.reshape(-1)
    h = np.empty((max(n - 2, 1), 2))  # (cost, frame)
    pos = np.empty(n, dtype=np.int64)  # heap slot of each interior frame
    span = np.empty(n)  # SSE(prev, next) of each interior frame: its cost's first term
    prev = np.arange(-1, n - 1)
    nxt = np.arange(1, n + 1)
    right = np.zeros(n)
    removed = np.empty(max(n - count, 0), dtype=np.int64)
    costs = np.empty(max(n - count, 0))
    size = 0
    for k in range(1, n - 1):
        span[k] = _segment_sse(x, k - 1, k + 1)
        _place(h, pos, size, span[k], float(k))
        size += 1
    for start in range((size - 2) // 4, -1, -1):  # heapify
        _sift_down(h, pos, start, size)
    left, done = n, 0
    while left > count and size > 0:
        cost, k = h[0, 0], int(h[0, 1])
        p, q = prev[k], nxt[k]
        # the rows the two re-pricings read: fetched while the heap sifts
        for e in range(max(prev[p], 0) * d, (min(nxt[q], n - 1) + 1) * d, 8):
            prefetch(flat, e)
        size -= 1  # pop: the last entry sifts down from the root
        if size > 0:
            h[0, 0], h[0, 1] = h[size, 0], h[size, 1]
            _sift_down(h, pos, 0, size)
        removed[done] = k
        costs[done] = cost
        done += 1
        left -= 1
        right[p] = span[k]  # SSE(p, q), computed when k was priced
        nxt[p] = q
        prev[q] = p
        for j in (p, q):
            if 0 < j < n - 1:
                span[j] = _segment_sse(x, prev[j], nxt[j])
                c = span[j] - right[prev[j]] - right[j]
                i = pos[j]
                old = h[i, 0]
                h[i, 0] = c
                if c < old:
                    _sift_up(h, pos, i)
                elif c > old:
                    _sift_down(h, pos, i, size)
    return removed[:done].copy(), costs[:done].copy(), right


@warmer
def _warm() -> None:
    """Compile (or load) the decimation kernels on a tiny curve."""
    _decimation_order(np.arange(12.0).reshape(6, 2) ** 2, 2)


def decimation_order(x: np.ndarray, count: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Greedy least-cost removal down to `count` rows: (removed rows in order, their costs)."""
    removed, costs, _ = _decimation_order(np.ascontiguousarray(x, dtype=np.float64), int(count))
    return removed, costs


def _curve(motion: Motion, space: str, features: Features | None,
           chunk: int = 1024) -> np.ndarray:
    """`simplify.curve` behind the default noise filter when no `features` are given (the
    curve `extract` gives decimate); in positions space without `features`, FK alone on the captured
    (noise-filtered) frames (the same rows: FK frames are independent, and the unwrapped
    rotations and the pelvis frame of `compute_features` are not needed), `chunk` frames at
    a time written into the curve (the same bits; the FK points and root-relative
    temporaries of a block stay in cache instead of three more curve-sized arrays)."""
    if space == "channels" and features is None:  # the filtered channels, as extract's
        features = compute_features(motion)
    if space == "positions" and features is None:
        motion = filtered_motion(motion)[0]  # behind the default noise filter, as `curve`
        channels = motion.channels[motion.first_frame :]
        skeleton = motion.skeleton
        nj, height = skeleton.n_joints, body_height(skeleton)
        x = np.empty((len(channels), 3 * nj))
        for lo in range(0, len(channels), chunk):
            fk = forward_kinematics(skeleton, channels[lo : lo + chunk])
            x[lo : lo + chunk] = position_rows(fk.positions, nj, height)
        return x
    return curve(motion, space, features)


def decimate(motion: Motion, count: int, *, space: str = DEFAULT_SPACE,
             features: Features | None = None) -> Keyframes:
    """Frame decimation to exactly `count` keyframes (see the module docstring)."""
    if space not in SPACES:
        raise UsageError(f"space must be one of {SPACES}, got {space!r}")
    x = _curve(motion, space, features)
    count = _check_count(count, len(x))
    removed, costs, right = _decimation_order(np.ascontiguousarray(x, dtype=np.float64), count)
    keep = np.ones(len(x), dtype=bool)
    keep[removed] = False
    rows = np.flatnonzero(keep)
    # `reconstruction_sse(x, rows)`: the same segment sums, added in the same order
    info = {"sse": float(sum(right[rows[:-1]].tolist())), "last_cost": float(costs[-1])
            if len(costs) else 0.0}
    return Keyframes("decimation", rows + motion.first_frame, np.zeros(len(rows)),
                     {"count": count, "space": space}, motion.n_frames, info)
