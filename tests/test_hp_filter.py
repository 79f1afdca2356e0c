"""The Hodrick–Prescott filter against statsmodels' `hpfilter` (an independent oracle).

Accuracy note: the HP system I + lambda D'D has a condition number of about 16 lambda. From
10 Hz down to 1 Hz at 120 fps (lambda <= 1.4e5) both solvers agree to 1e-8 relative. At Miura's
coarsest half-scale, 0.1 Hz (lambda = 1.3e9), the exact rational solution shows both solvers
err by ~2e-7 relative: the 1e-8 target is below what double precision can give there.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from cmu import DATA
from scipy.linalg import cholesky_banded
from statsmodels.tsa.filters.hp_filter import hpfilter

from streamkey.bvh import read_bvh
from streamkey.methods.speed import HPBank
from streamkey.signal import hp_banded, hp_factor, hp_filter, hp_lambda, hp_settle, unwrap_degrees

DT = 1.0 / 120.0
EPS = float(np.finfo(float).eps)
WELL_CONDITIONED_HZ = (10.0, 8.0, 4.0, 2.0, 1.0)


def _rel_err(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))


def _exact_trend(y: np.ndarray, lam: float) -> np.ndarray:
    """HP trend by Gaussian elimination in exact rational arithmetic (small n only)."""
    n, lam_q = len(y), Fraction(lam)
    a = [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]
    for k in range(n - 2):
        d = {k: 1, k + 1: -2, k + 2: 1}
        for i, di in d.items():
            for j, dj in d.items():
                a[i][j] += lam_q * di * dj
    b = [Fraction(float(v)) for v in y]
    for c in range(n):
        for r in range(c + 1, n):
            f = a[r][c] / a[c][c]
            a[r] = [x - f * z for x, z in zip(a[r], a[c], strict=True)]
            b[r] -= f * b[c]
    x = [Fraction(0)] * n
    for r in range(n - 1, -1, -1):
        x[r] = (b[r] - sum(a[r][k] * x[k] for k in range(r + 1, n))) / a[r][r]
    return np.array([float(v) for v in x])


@pytest.mark.parametrize("n", [3, 4, 5, 6, 17, 250, 3000])
@pytest.mark.parametrize("cutoff", WELL_CONDITIONED_HZ)
def test_hp_filter_equals_statsmodels_on_random_signals(n: int, cutoff: float) -> None:
    rng = np.random.default_rng(n * 1000 + int(cutoff * 10))
    y = rng.normal(size=n).cumsum() + 3.0
    lam = hp_lambda(cutoff, DT)
    assert _rel_err(hp_filter(y, lam), hpfilter(y, lam)[1]) < 1e-8


@pytest.mark.parametrize("n", [3, 4, 5, 40, 3000])
@pytest.mark.xfail(strict=True, reason="measured 6e-8 to 3e-7 relative at lambda = 1.3e9: "
                   "condition number ~2e10, both solvers err ~2e-7 against the exact solution")
def test_hp_filter_equals_statsmodels_to_1e_8_at_the_coarsest_half_scale(n: int) -> None:
    rng = np.random.default_rng(n)
    y = rng.normal(size=n).cumsum() + 3.0
    lam = hp_lambda(0.1, DT)
    assert _rel_err(hp_filter(y, lam), hpfilter(y, lam)[1]) < 1e-8


@pytest.mark.parametrize("n", [3, 4, 5, 8, 13])
@pytest.mark.parametrize("cutoff", [10.0, 1.0, 0.1])
def test_hp_filter_is_as_accurate_as_statsmodels_against_the_exact_solution(
        n: int, cutoff: float) -> None:
    rng = np.random.default_rng(7 * n)
    y = rng.normal(size=n).cumsum()
    lam = hp_lambda(cutoff, DT)
    exact = _exact_trend(y, lam)
    bound = max(1e-12, 16 * lam * np.finfo(float).eps)  # condition number x unit roundoff
    assert _rel_err(hp_filter(y, lam), exact) < bound
    assert _rel_err(hpfilter(y, lam)[1], exact) < bound


@pytest.mark.parametrize("cutoff", WELL_CONDITIONED_HZ)
def test_hp_filter_equals_statsmodels_on_a_cmu_joint_channel(cutoff: float) -> None:
    motion = read_bvh(DATA / "07_01.bvh")
    col = motion.skeleton.channel_index(motion.skeleton.index("LeftUpLeg"), "Xrotation")
    y = unwrap_degrees(motion.channels[motion.first_frame :, col])
    lam = hp_lambda(cutoff, motion.frame_time)
    assert _rel_err(hp_filter(y, lam), hpfilter(y, lam)[1]) < 1e-8


def test_hp_filter_filters_each_column_of_a_2d_signal_on_its_own() -> None:
    motion = read_bvh(DATA / "07_01.bvh")
    y = unwrap_degrees(motion.channels[1:, motion.skeleton.rotation_columns()])
    y = y[:, y.std(axis=0) > 1.0][:, :8]
    lam = hp_lambda(10.0, motion.frame_time)
    both = hp_filter(y, lam)
    for j in range(y.shape[1]):
        assert _rel_err(both[:, j], hpfilter(y[:, j], lam)[1]) < 1e-8


@pytest.mark.numeric
def test_hp_bank_gives_the_same_trends_as_hp_filter() -> None:
    rng = np.random.default_rng(3)
    v = np.abs(rng.normal(size=500)).cumsum()
    lams = np.array([hp_lambda(f, DT) for f in (8.0, 2.0, 0.5)])
    bank = HPBank(lams)
    for i, lam in enumerate(lams):
        np.testing.assert_allclose(bank.solve(v, i), hp_filter(v, lam), rtol=1e-9)
        for n in (3, 4, 5, 6, 100, 499):  # every length: the same factor
            np.testing.assert_allclose(bank.solve(v[:n], i), hp_filter(v[:n], lam), rtol=1e-9)
            assert np.array_equal(bank.solve(v[:n], i), HPBank(lams).solve(v[:n], i))


@pytest.mark.numeric
@pytest.mark.parametrize("cutoff", [8.0, 1.0, 0.1])
def test_hp_factor_equals_lapacks_factorisation_at_every_length(cutoff: float) -> None:
    lam = hp_lambda(cutoff, DT)
    k = int(hp_settle(lam))  # columns taken from LAPACK; the converged one repeated after
    for n in (3, 4, 5, 6, 40, k - 1, k, k + 1, k + 2, k + 3, 3 * k):
        ref = cholesky_banded(hp_banded(n, lam), check_finite=False)
        got = hp_factor(n, lam)
        np.testing.assert_allclose(got[:, :-2], ref[:, :-2], rtol=1e-9, err_msg=f"n = {n}")
        # The bottom corner, (1 + 5 lam) - u0^2 - u1^2 ~ 1, cancels ~eps lam in any order.
        np.testing.assert_allclose(got[:, -2:], ref[:, -2:], rtol=max(1e-9, 8 * EPS * lam),
                                   err_msg=f"n = {n}")
