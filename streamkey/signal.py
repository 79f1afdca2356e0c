"""Shared signal tools used by the offline and online methods alike.

Pure functions over numpy arrays; no I/O. Derivatives are with respect to the frame index.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solveh_banded

from .errors import UsageError

__all__ = ["hp_lambda", "hp_filter", "hp_banded", "unwrap_degrees", "local_minima",
           "local_maxima"]


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


def unwrap_degrees(angles: np.ndarray) -> np.ndarray:
    """Euler angle channels (frames along axis 0) without ±180° jumps."""
    return np.unwrap(np.asarray(angles, dtype=np.float64), period=360.0, axis=0)


def local_minima(v: np.ndarray) -> np.ndarray:
    """Indices i (0 < i < n-1) with v[i-1] > v[i] <= v[i+1]: first frame of a flat bottom."""
    v = np.asarray(v)
    if v.shape[0] < 3:
        return np.empty(0, dtype=int)
    return np.flatnonzero((v[1:-1] < v[:-2]) & (v[1:-1] <= v[2:])) + 1


def local_maxima(v: np.ndarray) -> np.ndarray:
    """Indices i (0 < i < n-1) with v[i-1] < v[i] >= v[i+1]: first frame of a flat top."""
    return local_minima(-np.asarray(v))
