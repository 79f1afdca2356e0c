"""The speed signal of Miura et al. 2014 and its scales: positions -> speed v (eq. 2-3), the
HP trends of v at every scale and their minima (eq. 4), the candidates (local minima of v),
shared by the offline and the online keyframer (`streamkey.methods.speed`).

HP solves go through the factors of `signal.hp_factor` (O(n), no factorisation of length n):
offline through LAPACK (`HPBank`), online through the packed interior columns
(`packed_factors`) read by the compiled kernels of `speed_kernels`.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import get_blas_funcs, get_lapack_funcs

from ..errors import UsageError
from ..signal import HP_SETTLE, hp_factor, hp_filter, hp_lambda, hp_prefix, hp_settle, local_minima

__all__ = ["METHOD", "check_params", "scale_frequencies", "speed_signal", "WorkRows",
           "packed_factors", "speed_tail", "HPBank", "scale_lambdas", "scale_minima",
           "scale_minimum", "SETTLE", "REST_SPEED", "candidates_of", "settle_frames"]

METHOD = "speed"
_PBTRS = get_lapack_funcs("pbtrs", (np.empty(1),))
_TBSV = get_blas_funcs("tbsv", (np.empty(1),))


def check_params(f_c: float, f_max: float, f_min: float, r: float, mojena_k: float) -> None:
    """Refuse parameters the method has no meaning for, with a clear message."""
    if not (f_c > 0 and f_max > 0 and 0 < f_min <= f_max):
        raise UsageError("speed: need f_c > 0 and 0 < f_min <= f_max")
    if not 0 < r < 1:
        raise UsageError("speed: the scale ratio r must lie in (0, 1)")
    if not np.isfinite(mojena_k):
        raise UsageError("speed: mojena_k must be finite")


def scale_frequencies(f_max: float = 8.0, f_min: float = 0.2, r: float = 0.95) -> np.ndarray:
    """Cut-offs f_i = f_max r^(i-1), i = 1..i_max, the last one >= f_min (Miura section 3.2 (3))."""
    i_max = int(np.floor(np.log(f_min / f_max) / np.log(r) + 1e-9)) + 1
    return f_max * r ** np.arange(i_max)


def speed_signal(positions: np.ndarray, frame_time: float, f_c: float = 10.0) -> np.ndarray:
    """Miura eq. 2-3: HP low-pass of (n, 48) positions at f_c, then the norm of the step / dt."""
    pf = hp_filter(positions, hp_lambda(f_c, frame_time))
    speed: np.ndarray = np.linalg.norm(np.diff(pf, axis=0), axis=1) / frame_time
    return speed


_PACKED: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # lambdas -> tables
# No locks (algorithm modules import no threading): the engine drives every keyframer from
# one thread, and a race between threads could at worst build a table twice.


class WorkRows:
    """A keyframer's reused `hp_tail` work rows (no page faults per analysis; per keyframer,
    as the kernels release the GIL). Derived: pickled empty."""

    def __init__(self) -> None:
        self.rows = np.empty((0, 0))

    def __reduce__(self) -> tuple[type, tuple[()]]:
        return (WorkRows, ())

    def get(self, n: int, width: int) -> np.ndarray:
        """At least n rows of `width` values (contents undefined). Grown by doubling: while
        a stream's window fills, a new block per analysis meant fresh pages (page faults)
        on every early analysis."""
        if len(self.rows) < n or self.rows.shape[1] != width:
            grow = 2 * len(self.rows) if self.rows.shape[1:] == (width,) else 0
            self.rows = np.empty((max(n, grow), width))
        return self.rows


def packed_factors(lams: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The interior columns of every lambda's HP factor (`signal.hp_factor`) side by side for
    `speed_kernels.hp_tail`: LAPACK's first columns of lambda i at `off[i]:off[i + 1]` of
    `pre` (3, total), and the converged columns `conv` (4, len(lams): the fourth row holds the
    reciprocals of the diagonal; the kernels multiply where the columns are constant).
    Derived data shared by every stream with the same lambdas (2.4 MB at 120 fps with the
    defaults), never pickled.
    """
    key = np.asarray(lams, dtype=np.float64).tobytes()
    got = _PACKED.get(key)
    if got is None:
        cols = [hp_prefix(float(lam)) for lam in lams]
        off = np.concatenate([[0], np.cumsum([c.shape[1] for c in cols])]).astype(np.int64)
        pre = np.ascontiguousarray(np.concatenate(cols, axis=1))
        conv = np.stack([c[:, -1] for c in cols], axis=1)
        conv = np.ascontiguousarray(np.vstack([conv, 1.0 / conv[2:]]))
        if len(_PACKED) >= 16:
            _PACKED.clear()
        got = _PACKED[key] = (pre, off, conv)
    return got


_TAILS: dict[tuple[float, int, int], np.ndarray] = {}  # (lambda, n, k) -> step operator


def speed_tail(positions: np.ndarray, frame_time: float, f_c: float, k: int) -> np.ndarray:
    """The last k values of `speed_signal(positions)` through one cached matrix product:
    the HP smoother's last k + 1 rows, differenced ((k, n), shared like the HP factors)."""
    n = len(positions)
    key = (hp_lambda(f_c, frame_time), n, k)
    op = _TAILS.get(key)
    if op is None:
        rows = hp_filter(np.eye(n), key[0])[n - k - 1 :]
        op = rows[1:] - rows[:-1]
        if len(_TAILS) >= 64:
            _TAILS.clear()
        _TAILS[key] = op
    speed: np.ndarray = np.linalg.norm(op @ positions, axis=1) / frame_time
    return speed


class HPBank:
    """HP solves for several lambdas at any length (factors from `signal.hp_factor`, O(n),
    no factorisation). A bank holds its lambdas only (a snapshot carries nothing else)."""

    def __init__(self, lams: np.ndarray) -> None:
        self.lams = np.asarray(lams, dtype=np.float64)

    def __reduce__(self) -> tuple[type, tuple[np.ndarray]]:
        return (HPBank, (self.lams,))

    def factor(self, n: int, i: int) -> np.ndarray:
        """Upper banded Cholesky factor (3, n) of the length-n HP system for lambda i."""
        return hp_factor(int(n), float(self.lams[i]))

    def solve(self, v: np.ndarray, i: int, tail: int | None = None) -> np.ndarray:
        """HP trend of the 1-D signal `v` for the i-th lambda (its last `tail` values only:
        the back substitution stops there; the same numbers as the whole solve's)."""
        v = np.asarray(v, dtype=np.float64)
        n = len(v)
        if n < 3:
            return v[n - (n if tail is None else min(tail, n)) :].copy()
        c = self.factor(n, i)
        if tail is not None and tail < n:  # dpbtrs is these two dtbsv calls, on all rows
            y = _TBSV(2, c, v, trans=1)
            return np.asarray(_TBSV(2, c[:, n - tail :], y[n - tail :], trans=0,
                                    overwrite_x=1))
        x, info = _PBTRS(c, v, lower=0)  # less overhead than scipy's
        if info != 0:
            raise UsageError(f"HP solve failed (LAPACK info {info})")
        return np.asarray(x)


def scale_lambdas(freqs: np.ndarray, frame_time: float) -> np.ndarray:
    """HP lambdas for every scale f followed by those for f/2 (Miura eq. 4), shape (2 S,)."""
    return np.array([hp_lambda(f, frame_time) for f in np.concatenate([freqs, freqs / 2])])


def scale_minima(v: np.ndarray, bank: HPBank) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per scale: local minima of HP(v, f) and the speed descent u there (Miura eq. 4).

    `bank` holds the lambdas of `scale_lambdas`: f_i at i, f_i / 2 at S + i.
    """
    return [scale_minimum(v, bank, i) for i in range(len(bank.lams) // 2)]


def scale_minimum(v: np.ndarray, bank: HPBank, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Scale i of `scale_minima`: minima of HP(v, f_i) (rest left out), and u there."""
    trend = bank.solve(v, i)
    m = local_minima(trend)
    m = m[trend[m] >= REST_SPEED]
    if len(m) == 0:  # no minimum: the f/2 trend is not needed
        return m, np.zeros(0)
    return m, np.abs(trend[m] - bank.solve(v, len(bank.lams) // 2 + i)[m])


SETTLE = HP_SETTLE

# Speeds below this (body heights per second, the norm over the 16 joints) are rest: no
# candidate and no scale minimum lies there. An exact hold (a calibration pose, a take that
# stops) leaves only rounding noise and the HP filters' ringing, whose minima are not motion:
# 3 s of stillness added ~140 candidates (nearly all of zero intensity) to every shared clip
# at 120 Hz, and their count moved Mojena's cut-off; the HP trends' ringing minima there took
# over the chains of real candidates (06_02 at 30 Hz: every key moved by a step). The slowest
# candidate of a captured take on the shared clips moves at 0.042 (49_18).
REST_SPEED = 0.02


def candidates_of(v: np.ndarray) -> np.ndarray:
    """Keypose candidates: local minima of the speed `v`, rest (`REST_SPEED`) left out."""
    m = local_minima(v)
    kept: np.ndarray = m[v[m] >= REST_SPEED]
    return kept


def settle_frames(lams: np.ndarray) -> np.ndarray:
    """Frames after which an HP filter forgets a boundary to ~1e-6 (`signal.hp_settle`)."""
    return hp_settle(lams)
