"""Shared signal tools used by the offline and online methods alike.

Pure functions over numpy arrays; no I/O. Derivatives are with respect to the frame index.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from scipy.linalg import cholesky_banded, solveh_banded

from .errors import UsageError
from .jit import kernel, warmer

__all__ = ["hp_lambda", "hp_filter", "hp_banded", "hp_settle", "hp_factor", "hp_prefix",
           "unwrap_degrees", "unwrap_step", "unwrap_state", "unwrap_columns", "unwrap_into",
           "local_minima", "local_maxima", "warm_unwrap"]


def hp_lambda(cutoff_hz: float, frame_time: float) -> float:
    """Hodrick–Prescott lambda whose gain is 50 % at `cutoff_hz` (Miura eq. 3)."""
    if cutoff_hz <= 0 or frame_time <= 0:
        raise UsageError("cutoff and frame time must be positive")
    lam: float = 1.0 / (4.0 * (1.0 - np.cos(2.0 * np.pi * cutoff_hz * frame_time)) ** 2)
    return lam


def hp_banded(n: int, lam: float) -> np.ndarray:
    """Upper banded form (3, n) of I + lam D'D, D the (n-2) x n second-difference matrix."""
    ab = np.zeros((3, n))
    diag = np.full(n, 6.0)
    off1 = np.full(n - 1, -4.0)
    if n >= 3:
        diag[[0, -1]] = 1.0
        diag[[1, -2]] = 5.0 if n > 3 else 4.0
        off1[[0, -1]] = -2.0
    else:
        diag[:] = 0.0
        off1[:] = 0.0
    ab[2] = 1.0 + lam * diag
    ab[1, 1:] = lam * off1
    if n >= 3:
        ab[0, 2:] = lam
    return ab


def hp_filter(y: np.ndarray, lam: float) -> np.ndarray:
    """HP trend of `y` along axis 0 (1-D, or 2-D with one signal per column); O(n)."""
    y = np.asarray(y, dtype=np.float64)
    n = y.shape[0]
    if n < 3:
        return y.copy()
    trend: np.ndarray = solveh_banded(hp_banded(n, lam), y, check_finite=False)
    return trend


HP_SETTLE = 20.0  # time constants an HP filter needs to forget a boundary (e^(-20/sqrt 2) ~ 7e-7)


def hp_settle(lams: np.ndarray | float) -> np.ndarray:
    """Frames after which an HP filter forgets a boundary to ~1e-6: HP_SETTLE time constants.

    The HP smoother's impulse response decays with time constant lambda^(1/4) frames; its
    banded Cholesky factor converges column by column at the same rate (to LAPACK's own
    rounding noise, ~1e-11 relative, within these frames).
    """
    return np.ceil(HP_SETTLE * np.asarray(lams, dtype=np.float64) ** 0.25).astype(int) + 8


_PREFIXES: OrderedDict[float, np.ndarray] = OrderedDict()  # lambda -> LAPACK's first columns
_PREFIX_LIMIT = 1024


def hp_prefix(lam: float) -> np.ndarray:
    """LAPACK's upper banded factor of I + lam D'D in its first `hp_settle(lam)` columns."""
    got = _PREFIXES.get(lam)
    if got is not None:
        _PREFIXES.move_to_end(lam)
        return got
    k = int(hp_settle(lam))
    factor: np.ndarray = cholesky_banded(hp_banded(k + 2, lam), check_finite=False)
    got = factor[:, :k].copy()
    got.setflags(write=False)
    _PREFIXES[lam] = got
    if len(_PREFIXES) > _PREFIX_LIMIT:
        _PREFIXES.popitem(last=False)
    return got


def hp_factor(n: int, lam: float) -> np.ndarray:
    """Upper banded Cholesky factor (3, n) of the length-n HP system I + lam D'D, O(n).

    Column j of the factor only looks back, so the first n - 2 columns of every length agree;
    they converge to a fixed column within `hp_settle` columns. Built here from LAPACK's first
    `hp_settle` columns (shared by every length and caller, cached per lambda), that converged
    column repeated, and the two bottom-corner columns (D'D has 5 and 1 there) finished by the
    same arithmetic every time: a deterministic function of (n, lam), without a factorisation
    of length n (which costs ~80 ns a column in LAPACK).
    """
    lam = float(lam)
    if n < 5:
        factor: np.ndarray = cholesky_banded(hp_banded(n, lam), check_finite=False)
        return factor
    pre = hp_prefix(lam)
    k = min(n, pre.shape[1])
    c = np.empty((3, n), order="F")  # LAPACK's layout: no copy per solve
    c[:, :k] = pre[:, :k]
    c[:, k:] = pre[:, k - 1 : k]  # converged: the last column, repeated
    # Bottom corner rows n-2, n-1 of I + lam D'D: 1 + 5 lam, -2 lam, 1 + lam.
    u0, u1 = c[0, n - 2], c[1, n - 2]          # U[n-4, n-2], U[n-3, n-2]
    v0 = c[0, n - 1]                            # U[n-3, n-1]
    d2 = np.sqrt((1.0 + 5.0 * lam) - u0 * u0 - u1 * u1)
    e = ((-2.0 * lam) - u1 * v0) / d2
    c[2, n - 2], c[1, n - 1] = d2, e
    c[2, n - 1] = np.sqrt((1.0 + lam) - v0 * v0 - e * e)
    return c


@kernel
def unwrap_into(channels: np.ndarray, cols: np.ndarray, prev: np.ndarray,
                   offset: np.ndarray, out: np.ndarray) -> None:
    """`np.unwrap` (period 360) of channels[:, cols] into `out`, continuing from the state
    `prev` (last raw row) and `offset` (its correction), both updated in place. np.unwrap's
    arithmetic: a correction where |step| >= 180, the corrections summed in stream order
    (zeros included), added to the raw value."""
    for f in range(channels.shape[0]):
        for c in range(cols.shape[0]):
            x = channels[f, cols[c]]
            d = x - prev[c]
            corr = 0.0
            if abs(d) >= 180.0:
                m = np.fmod(d + 180.0, 360.0)  # np.mod(d + 180, 360): the divisor's sign
                if m < 0.0:
                    m += 360.0
                elif m == 0.0:
                    m = 0.0
                m -= 180.0
                if m == -180.0 and d > 0.0:
                    m = 180.0
                corr = m - d
            offset[c] = offset[c] + corr
            out[f, c] = x + offset[c]
            prev[c] = x


def unwrap_step(raw: np.ndarray, prev_raw: np.ndarray | None,
                offset: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unwrap a block of angle rows (degrees) continuing from the previous block's state.

    State is `(prev_raw, offset)`: the last raw row and the correction (a multiple of 360)
    applied to it. Returns `(unwrapped, prev_raw, offset)` (new arrays). Same arithmetic as
    `np.unwrap`, accumulated in one sequence, so any split of a stream into blocks gives
    identical bits.
    """
    raw = np.asarray(raw, dtype=np.float64)
    if len(raw) == 0:
        return raw.copy(), prev_raw, offset  # type: ignore[return-value]
    shape = raw.shape
    rows = np.ascontiguousarray(raw.reshape(len(raw), -1))
    out = np.empty(rows.shape)
    prev, off = unwrap_state(rows[0], prev_raw, offset)
    unwrap_into(rows, np.arange(rows.shape[1]), prev, off, out)
    return out.reshape(shape), prev.reshape(shape[1:]), off.reshape(shape[1:])


def unwrap_state(first: np.ndarray, prev_raw: np.ndarray | None,
                 offset: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Fresh, writable copies of an unwrap state (`unwrap_into`); a stream's start (no
    state): its first raw row, no correction."""
    if prev_raw is None or offset is None:
        return np.array(first, dtype=np.float64).ravel(), np.zeros(np.size(first))
    return (np.array(prev_raw, dtype=np.float64).ravel(),
            np.array(offset, dtype=np.float64).ravel())


def unwrap_degrees(angles: np.ndarray) -> np.ndarray:
    """Euler angle channels (frames along axis 0) without ±180° jumps (as `np.unwrap`)."""
    return unwrap_step(angles, None, None)[0]


def unwrap_columns(channels: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """`unwrap_degrees(channels[:, cols])` without the copy of the columns (n, len(cols))."""
    channels = np.ascontiguousarray(channels, dtype=np.float64)
    cols = np.asarray(cols, dtype=np.int64)
    out = np.empty((len(channels), len(cols)))
    if len(channels):
        prev, off = unwrap_state(channels[0, cols], None, None)
        unwrap_into(channels, cols, prev, off, out)
    return out


@warmer
def warm_unwrap() -> None:
    """Compile (or load from the cache) the unwrap kernel."""
    unwrap_columns(np.array([[0.0, 170.0], [0.0, -170.0]]), np.array([1]))


def local_minima(v: np.ndarray) -> np.ndarray:
    """Indices i (0 < i < n-1) with v[i-1] > v[i] <= v[i+1]: first frame of a flat bottom."""
    v = np.asarray(v)
    if v.shape[0] < 3:
        return np.empty(0, dtype=int)
    return np.flatnonzero((v[1:-1] < v[:-2]) & (v[1:-1] <= v[2:])) + 1


def local_maxima(v: np.ndarray) -> np.ndarray:
    """Indices i (0 < i < n-1) with v[i-1] < v[i] >= v[i+1]: first frame of a flat top."""
    return local_minima(-np.asarray(v))
