"""Shared signal tools used by the offline and online methods alike.

Pure functions over numpy arrays; no I/O. Derivatives are with respect to the frame index.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from scipy.linalg import cholesky_banded, solveh_banded

from .errors import UsageError

__all__ = ["hp_lambda", "hp_filter", "hp_banded", "hp_settle", "hp_factor", "unwrap_degrees",
           "unwrap_step", "local_minima", "local_maxima"]


def hp_lambda(cutoff_hz: float, frame_time: float) -> float:
    """Hodrick–Prescott lambda whose gain is 50 % at `cutoff_hz` (Miura eq. 3)."""
    if cutoff_hz <= 0 or frame_time <= 0:
        raise UsageError("cutoff and frame time must be positive")
    return 1.0 / (4.0 * (1.0 - np.cos(2.0 * np.pi * cutoff_hz * frame_time)) ** 2)


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
    return solveh_banded(hp_banded(n, lam), y, check_finite=False)


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
    got = cholesky_banded(hp_banded(k + 2, lam), check_finite=False)[:, :k].copy()
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
        return cholesky_banded(hp_banded(n, lam), check_finite=False)
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


def unwrap_step(raw: np.ndarray, prev_raw: np.ndarray | None,
                offset: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unwrap a block of angle rows (degrees) continuing from the previous block's state.

    State is `(prev_raw, offset)`: the last raw row and the correction (a multiple of 360)
    applied to it. Returns `(unwrapped, prev_raw, offset)`. Same arithmetic as `np.unwrap`,
    accumulated in one sequence, so any split of a stream into blocks gives identical bits.
    """
    raw = np.asarray(raw, dtype=np.float64)
    if len(raw) == 0:
        return raw.copy(), prev_raw, offset  # type: ignore[return-value]
    if prev_raw is None or offset is None:
        prev_raw, offset = raw[0], np.zeros(raw.shape[1:])
    dd = np.empty(raw.shape)
    np.subtract(raw[:1], prev_raw, out=dd[:1])
    np.subtract(raw[1:], raw[:-1], out=dd[1:])
    jumps = np.flatnonzero(np.abs(dd) >= 180.0)
    if len(jumps) == 0:  # every correction is zero
        return raw + offset, raw[-1].copy(), offset
    # Corrections only where a jump is (x + 0 == x: the running sum is the dense one's).
    d = dd.reshape(-1)[jumps]
    dmod = np.mod(d + 180.0, 360.0) - 180.0
    np.copyto(dmod, 180.0, where=(dmod == -180.0) & (d > 0))
    acc = np.zeros(raw.shape)
    acc.reshape(-1)[jumps] = dmod - d
    acc[0] += offset
    np.add.accumulate(acc, axis=0, out=acc)
    return raw + acc, raw[-1].copy(), acc[-1].copy()


def unwrap_degrees(angles: np.ndarray) -> np.ndarray:
    """Euler angle channels (frames along axis 0) without ±180° jumps (as `np.unwrap`)."""
    return unwrap_step(angles, None, None)[0]


def local_minima(v: np.ndarray) -> np.ndarray:
    """Indices i (0 < i < n-1) with v[i-1] > v[i] <= v[i+1]: first frame of a flat bottom."""
    v = np.asarray(v)
    if v.shape[0] < 3:
        return np.empty(0, dtype=int)
    return np.flatnonzero((v[1:-1] < v[:-2]) & (v[1:-1] <= v[2:])) + 1


def local_maxima(v: np.ndarray) -> np.ndarray:
    """Indices i (0 < i < n-1) with v[i-1] < v[i] >= v[i+1]: first frame of a flat top."""
    return local_minima(-np.asarray(v))
