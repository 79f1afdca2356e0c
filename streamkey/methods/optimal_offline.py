"""Offline optimal keys: the whole take's penalised or tolerance solve, the rate mode's one
pass with the take's λ, and the count mode (exact K-key DP, or a search over λ with greedy
adjustment). Definitions: the module docstring of `streamkey.methods.optimal`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from . import optimal_math as om
from .optimal_solver import Solver, mark_rows

__all__ = ["solve_all", "rate_keys", "count_keys"]

_GRID = 16  # lambdas per pass of the count search
_EXACT_BUDGET = 4e7  # frames x K x L below which count mode runs the exact K-key DP


def _segment_errors(f: np.ndarray, keys: np.ndarray, lam: float) -> np.ndarray:
    """Costs of the segments between consecutive keys from the DP's F (F(b) = F(a) +
    cost(a, b) + λ along a chain; λ = 0 in tolerance mode)."""
    errors: np.ndarray = np.maximum(np.diff(f[keys]) - lam, 0.0)
    return errors


def solve_all(x: np.ndarray, max_len: int, ticks: float,
               **mode: Any) -> tuple[np.ndarray, np.ndarray]:
    """Offline λ / tolerance: the online solver over every row, nothing forced; the keys and
    the costs of the segments between them (frame sums)."""
    solver = Solver(max_len, ticks=ticks, **mode)
    solver.add(x)
    keys = np.array(solver.finish(), dtype=np.int64)
    lam = 0.0 if solver.tolerance is not None else solver.lam
    return keys, _segment_errors(solver.rows.f, keys - solver.base, lam)


def rate_keys(x: np.ndarray, max_len: int, rate: float, ticks: float, chunk: int,
              holds: Sequence[tuple[int, int]] = (), hold_keys: bool = False,
              keyless: Sequence[tuple[int, int]] | None = None
              ) -> tuple[np.ndarray, np.ndarray, float]:
    """Offline rate: λ from every frame's cost (as the online controller ends up with), then
    one penalised pass (keys, segment costs as frame sums, λ in ticks x body heights²).
    `holds`: the calibration holds and still stretches (first, last row), out of λ and,
    `keyless` (default: `holds`) unless `hold_keys`, with no key strictly inside
    (`Solver.hold`). Same costs and chunks as `Solver`, so bit-identical to it."""
    solver = Solver(max_len, rate=rate, ticks=ticks, chunk=chunk)
    assert solver.rate is not None
    solver.rate.motion.known = len(x)
    for first, last in holds:
        solver.rate.motion.hold(first, last)
    band = np.empty((len(x), max_len))
    for b0 in range(0, len(x), chunk):
        b1 = min(len(x), b0 + chunk)
        band[b0:b1] = solver.pricer.price(x, 0, b0, b1)
        lam = solver.rate.observe(band[b0:b1], b0)
    marks = om.no_marks(len(x))
    keyless = holds if keyless is None else keyless
    if keyless and not hold_keys:
        marks = (*mark_rows(list(keyless), 0, len(x), 0), marks[2])
        om.edge_costs(np.ascontiguousarray(x, dtype=np.float64), marks[1], marks[2], 0,
                      len(x), max_len)
    keys, f = _penalised(band, lam, marks)
    return keys, _segment_errors(f, keys, lam), solver.rate.estimate()


def _penalised(band: np.ndarray, lam: float,
               marks: om.Marks | None = None) -> tuple[np.ndarray, np.ndarray]:
    n = len(band)
    f = np.full(n, np.inf)
    bp = np.full(n, -1, dtype=np.int64)
    keys = np.zeros(n, dtype=np.int64)
    f[0], keys[0] = 0.0, 1
    om.dp_rows(band, f, bp, keys, 1, n, lam, marks=marks)
    return np.array(om.chain(bp, n - 1), dtype=np.int64), f


def _exact_count(band: np.ndarray, count: int) -> np.ndarray:
    """The K-key optimum: G_j(b) = min_a G_{j−1}(a) + cost(a, b), j segments ending at b."""
    n, max_len = band.shape
    a = np.arange(n)[:, None] - max_len + np.arange(max_len)[None, :]
    a_ok = np.maximum(a, 0)
    g = np.full(n, np.inf)
    g[0] = 0.0
    back = np.empty((count - 1, n), dtype=np.int64)
    for j in range(count - 1):
        vals = g[a_ok] + band
        vals[a < 0] = np.inf
        arg = np.argmin(vals, axis=1)
        back[j] = a_ok[np.arange(n), arg]
        g = vals[np.arange(n), arg]
        g[0] = np.inf
    keys = [n - 1]
    for j in range(count - 2, -1, -1):
        keys.append(int(back[j, keys[-1]]))
    return np.array(keys[::-1], dtype=np.int64)


def _adjust(x: np.ndarray, rows: np.ndarray, count: int) -> np.ndarray:
    """Remove (least cost increase) or insert (largest decrease) keys until `count`; only
    the segments next to each change are priced again."""
    keys = [int(k) for k in rows]

    def removal(i: int) -> float:  # cost increase of removing keys[i]
        p, k, q = keys[i - 1], keys[i], keys[i + 1]
        return float(om.pair_costs(x, [p, p, k], [q, k, q]) @ [1.0, -1.0, -1.0])

    def split(a: int, b: int) -> tuple[float, int]:  # best inserted key in (a, b), its gain
        if b - a < 2:
            return -np.inf, a
        ks = np.arange(a + 1, b)
        gain = (om.pair_costs(x, [a], [b])[0] - om.pair_costs(x, np.full(len(ks), a), ks)
                - om.pair_costs(x, ks, np.full(len(ks), b)))
        i = int(np.argmax(gain))
        return float(gain[i]), int(ks[i])

    if len(keys) > count:
        up = [np.inf] + [removal(i) for i in range(1, len(keys) - 1)] + [np.inf]
        while len(keys) > count:
            i = int(np.argmin(up))
            del keys[i], up[i]
            for j in (i - 1, i):
                if 0 < j < len(keys) - 1:
                    up[j] = removal(j)
    if len(keys) < count:
        best = [split(a, b) for a, b in zip(keys[:-1], keys[1:], strict=True)]
        while len(keys) < count:
            i = int(np.argmax([g for g, _ in best]))
            k = best[i][1]
            keys.insert(i + 1, k)
            best[i : i + 1] = [split(keys[i], k), split(k, keys[i + 2])]
    return np.array(keys, dtype=np.int64)


def count_keys(x: np.ndarray, count: int, max_len: int) -> tuple[np.ndarray, dict[str, Any]]:
    """Exactly `count` keys minimising Σ cost (module docstring of `optimal`), and how they
    were found."""
    n = len(x)
    max_len = max(max_len, -(-(n - 1) // (count - 1)))  # K keys must be able to cover n
    band = om.band_costs(x, max_len)
    if n * count * max_len <= _EXACT_BUDGET:
        return _exact_count(band, count), {"solver": "exact", "max_segment_frames": max_len}
    band32 = band.astype(np.float32)
    del band
    lo, hi = math.log(1e-9), math.log(1e3)  # log lambda bracket: lo gives >= count keys
    best: dict[int, float] = {}
    for _ in range(4):
        grid = np.linspace(lo, hi, _GRID)
        counts = _penalised_counts(band32, np.exp(grid))
        for g, c in zip(grid, counts, strict=True):
            best.setdefault(int(c), float(g))
        if count in best:
            break
        above = np.flatnonzero(counts > count)
        below = np.flatnonzero(counts < count)
        lo = grid[above[-1]] if len(above) else lo - 4.0
        hi = grid[below[0]] if len(below) else hi + 4.0
    near = min(best, key=lambda k: (abs(k - count), k < count))
    keys = _adjust(x, _penalised(band32, math.exp(best[near]))[0], count)
    return keys, {"solver": "lambda" if near == count else "lambda+greedy",
                  "lambda_count": near, "max_segment_frames": max_len}


def _penalised_counts(band: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """Key counts of the penalised optimum for several λ at once (one pass over the band)."""
    n, max_len = band.shape
    width = len(lams)
    f = np.full((n, width), np.inf)
    keys = np.zeros((n, width), dtype=np.int64)
    f[0], keys[0] = 0.0, 1
    cols = np.arange(width)
    for b in range(1, n):
        lo = max(0, b - max_len)
        vals = f[lo:b] + band[b, max_len - (b - lo):, None]
        i = np.argmin(vals, axis=0)
        f[b] = vals[i, cols] + lams
        keys[b] = keys[lo + i, cols] + 1
    counts: np.ndarray = keys[n - 1]
    return counts


