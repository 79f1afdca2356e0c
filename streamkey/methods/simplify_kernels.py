"""Compiled inner loops of curve simplification (`simplify.py`): the chord distance, the
split grid, the farthest-row search with its near-tie rule, and the split recursion shared
by the offline method and the online keyframer."""

from __future__ import annotations

import numpy as np

from ..jit import kernel, warmer

__all__ = ["chord_sq"]


@kernel
def chord_sq(x: np.ndarray, a: int, b: int, i: int) -> float:
    """Squared distance of row a + i of x to the time-parametrised chord from row a to row b
    (coordinates summed in column order; shared by the split search and decimation)."""
    t = i / (b - a)
    s = 0.0
    for j in range(x.shape[1]):
        xa = x[a, j]
        r = (x[a + i, j] - xa) - t * (x[b, j] - xa)
        s += r * r
    return s


@kernel
def _grid_level(offset: int, rate: float) -> int:
    """How coarse a dyadic grid in seconds the frame `offset` frames after the grid's anchor
    lies on: the largest L such that it is the frame nearest to a multiple of 2^L ticks of
    1/120 s at `rate` = fps / 120 frames a tick (ties: the later frame). At 120 Hz: the
    trailing zero bits of `offset` (the anchor itself: the coarsest level, 62)."""
    level = 0
    while level < 62:
        period = rate * 2.0 ** (level + 1)  # frames between grid times of the next level
        if period > 1.0:
            m = np.floor(offset / period + 0.5)
            d = m * period - offset
            if not (-0.5 <= d < 0.5):
                break
        level += 1
    return level


@kernel
def _anchor(anchors: np.ndarray, row: int) -> int:
    """The grid's anchor for `row`: the last of the sorted `anchors` at or before it (rows
    before the first: the first)."""
    k = anchors.shape[0] - 1
    while k > 0 and anchors[k] > row:
        k -= 1
    return int(anchors[k])


@kernel
def _farthest_rows(x: np.ndarray, a: int, b: int, anchors: np.ndarray, rate: float,
                   near: float, scratch: np.ndarray) -> tuple[int, float]:
    """(split row, largest squared distance) of x[a..b] from its time-parametrised chord, every
    distance computed directly; (a, -1.0) without interior rows. Split row: the farthest (ties:
    the earliest), or with `near` > 0 the grid frame (module docstring; the grid in seconds
    from `anchors`, rows of x, at `rate` frames a tick). `scratch` holds at least b - a
    distances."""
    m = b - a
    best, arg = -1.0, a
    for i in range(1, m):
        s = chord_sq(x, a, b, i)
        scratch[i] = s
        if s > best:
            best, arg = s, a + i
    if near > 0.0 and best > 0.0:
        floor = best * (1.0 - near) * (1.0 - near)
        level, dist = -1, -1.0
        for i in range(1, m):
            if scratch[i] >= floor:
                g = _grid_level(a + i - _anchor(anchors, a + i), rate)
                if g > level or (g == level and scratch[i] > dist):
                    level, dist, arg = g, scratch[i], a + i
    return arg, best


@kernel
def _splits(x: np.ndarray, a: int, b: int, limit: float, use_ratio: bool, anchors: np.ndarray,
            rate: float, near: float, scratch: np.ndarray) -> tuple[int, float]:
    """(split row, largest distance) of x[a..b] if the stopping rule splits the segment, else
    (-1, largest distance)."""
    k, sq = _farthest_rows(x, a, b, anchors, rate, near, scratch)
    dist = np.sqrt(sq) if sq > 0.0 else 0.0
    if use_ratio:
        c = 0.0
        for j in range(x.shape[1]):
            r = x[b, j] - x[a, j]
            c += r * r
        split = dist > 0.0 and dist > limit * np.sqrt(c)  # Önder §3.2 step 3
    else:
        split = dist > limit
    return (k if split else -1), dist


@kernel
def _split_all(x: np.ndarray, lo: int, hi: int, limit: float, use_ratio: bool, skip: int,
               anchors: np.ndarray, rate: float, near: float, rows: np.ndarray,
               dists: np.ndarray) -> int:
    """`split_keys` into `rows` / `dists` (room for hi - lo rows); returns the key count."""
    stack = np.empty((hi - lo + 2, 2), dtype=np.int64)
    scratch = np.empty(hi - lo + 1)
    stack[0, 0], stack[0, 1] = lo, hi
    top, n = 1, 0
    while top > 0:
        top -= 1
        a, b = stack[top, 0], stack[top, 1]
        if b - a < 2 or b <= skip:
            continue
        k, dist = _splits(x, a, b, limit, use_ratio, anchors, rate, near, scratch)
        if k >= 0:
            rows[n], dists[n] = k, dist
            n += 1
            stack[top, 0], stack[top, 1] = k, b
            stack[top + 1, 0], stack[top + 1, 1] = a, k
            top += 2
    return n


@kernel
def _first(x: np.ndarray, lo: int, hi: int, limit: float, use_ratio: bool,
           anchors: np.ndarray, rate: float, near: float) -> tuple[int, float]:
    """`first_key`: left halves only."""
    b, score = hi, 0.0
    scratch = np.empty(max(hi - lo + 1, 1))
    while b - lo >= 2:
        k, dist = _splits(x, lo, b, limit, use_ratio, anchors, rate, near, scratch)
        if k < 0:
            break
        b, score = k, dist
    return b, score


@warmer
def _warm() -> None:
    x = np.arange(12.0).reshape(4, 3) ** 2
    rows, dists = np.empty(4, dtype=np.int64), np.empty(4)
    origin = np.zeros(1, dtype=np.int64)
    for use_ratio in (False, True):
        _split_all(x, 0, 3, 0.0, use_ratio, -1, origin, 1.0, 0.3, rows, dists)
        _first(x, 0, 3, 0.0, use_ratio, origin, 1.0, 0.3)
        _splits(x, 0, 3, 0.0, use_ratio, origin, 1.0, 0.0, dists)  # alone: `Online._meets`
