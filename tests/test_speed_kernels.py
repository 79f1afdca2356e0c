"""Speed's compiled kernels against the numpy / heapq / LAPACK code they replace."""

from __future__ import annotations

import heapq

import numpy as np
import pytest
from cmu import DATA

from streamkey.bench import long_motion
from streamkey.bvh import read_bvh
from streamkey.features import compute_features
from streamkey.methods import speed
from streamkey.methods import speed_kernels as kern
from streamkey.roles import MIURA_ROLES
from streamkey.signal import local_minima


def heapq_ward(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pure-Python 1-D Ward of the previous `speed.Ward1D` (levels, bounds)."""
    v = np.sort(np.asarray(u, dtype=np.float64), kind="stable").tolist()
    n = len(v)
    size, total = [1.0] * n, list(v)
    left, right = list(range(-1, n - 1)), list(range(1, n + 1))
    alive = [True] * n
    heap = [(0.5 * (v[i + 1] - v[i]) ** 2, i, i + 1, 2.0) for i in range(n - 1)]
    heapq.heapify(heap)
    alpha, bounds = [], []
    while len(alpha) < n - 1:
        d, a, b, both = heapq.heappop(heap)
        if not (alive[a] and alive[b]) or right[a] != b or size[a] + size[b] != both:
            continue
        alpha.append(2.0 * d)
        bounds.append(b)
        alive[b] = False
        size[a] += size[b]
        total[a] += total[b]
        right[a] = right[b]
        if right[a] < n:
            left[right[a]] = a
        for x, y in ((left[a], a), (a, right[a])):
            if 0 <= x and y < n:
                nx, ny = size[x], size[y]
                diff = total[x] / nx - total[y] / ny
                heapq.heappush(heap, (nx * ny / (nx + ny) * diff * diff, x, y, nx + ny))
    return np.array(alpha), np.array(bounds, dtype=np.int64)


def numpy_band_dp(long_: np.ndarray, short: np.ndarray) -> np.ndarray:
    """The vectorised band DP of the previous `speed._band_dp` (closed-form columns)."""
    p, k = len(short), len(long_) - len(short)
    arg = np.empty((k + 1, p), dtype=np.int64)
    m_prev = np.full(p, np.inf)
    arg_prev = np.zeros(p, dtype=np.int64)
    b = np.empty(p)
    for d in range(k + 1):
        c = np.abs(long_[d : d + p] - short).astype(np.float64)
        b[0] = 0.0
        b[1:] = m_prev[:-1]
        s = np.cumsum(c)
        x = s + np.minimum.accumulate(b - (s - c))
        better = x < m_prev
        arg_prev = np.where(better, d, arg_prev)
        m_prev = np.where(better, x, m_prev)
        arg[d] = arg_prev
    offsets = np.empty(p, dtype=np.int64)
    hi = k
    for j in range(p - 1, -1, -1):
        hi = int(arg[hi, j])
        offsets[j] = hi
    return offsets


def clip_speed(name: str = "07_01.bvh", frames: int = 0) -> np.ndarray:
    """Speed signal of a shared clip (or of `frames` frames of the clips looped)."""
    m = long_motion(frames, DATA)[0] if frames else read_bvh(DATA / name)
    feats = compute_features(m)
    p = feats.role_positions(MIURA_ROLES)[m.first_frame :]
    return speed.speed_signal(p.reshape(len(p), -1) / feats.body_height, m.frame_time)


@pytest.mark.numeric
def test_ward_levels_equal_the_heapq_merging_bit_for_bit() -> None:
    rng = np.random.default_rng(15)
    values = np.array([0.0, 0.3, 1.7, 2.25, 9.5, 40.125])
    cases = [speed.extract(read_bvh(DATA / "07_01.bvh")).info["intensities"],
             np.zeros(5), np.array([0.0, 0.0]), np.array([0.0, 1.0]), np.array([0.0, 2.0, 2.0]),
             np.array([0.0, 0.0, 0.0, 3.0, 3.0, 0.5]), np.array([-0.0, 0.0, 0.0, 1e-300])]
    for _ in range(300):  # exact duplicates (ties in the heap) plus spread values
        cases.append(np.concatenate([rng.choice(values, int(rng.integers(2, 80))),
                                     np.abs(rng.standard_cauchy(int(rng.integers(0, 600))))]))
    for case, u in enumerate(cases):
        alpha, order, bounds = speed.ward_1d(u)
        ref_alpha, ref_bounds = heapq_ward(u)
        assert np.array_equal(order, np.argsort(u, kind="stable"))
        assert np.array_equal(alpha, ref_alpha), case
        assert np.array_equal(bounds, ref_bounds), case


@pytest.mark.numeric
def test_band_offsets_equal_the_numpy_band_dp() -> None:
    rng = np.random.default_rng(16)
    for case in range(400):
        n_long = int(rng.integers(2, 60))
        n_short = int(rng.integers(1, n_long))
        long_ = np.sort(rng.choice(300, n_long, replace=False)).astype(np.int64)
        short = np.sort(rng.choice(300, n_short, replace=False)).astype(np.int64)
        assert np.array_equal(kern.band_offsets(long_, short), numpy_band_dp(long_, short)), case


def brute_mutual_nearest(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mutual nearest neighbours by full distance tables (ties: the earlier index)."""
    if len(a) == 0 or len(b) == 0:
        return np.full(len(a), -1)
    d = np.abs(a[:, None] - b[None, :])
    near_b, near_a = np.argmin(d, axis=1), np.argmin(d, axis=0)  # argmin: the first of ties
    return np.where(near_a[near_b] == np.arange(len(a)), near_b, -1)


@pytest.mark.numeric
def test_mutual_nearest_equals_brute_force() -> None:
    rng = np.random.default_rng(19)
    for case in range(2000):
        a = np.sort(rng.choice(80, int(rng.integers(0, 12)), replace=False)).astype(np.int64)
        b = np.sort(rng.choice(80, int(rng.integers(0, 12)), replace=False)).astype(np.int64)
        assert np.array_equal(kern.mutual_nearest(a, b), brute_mutual_nearest(a, b)), case


@pytest.mark.numeric
def test_chain_totals_equal_the_numpy_chains_on_a_clip() -> None:
    v = clip_speed()
    bank = speed.HPBank(speed.scale_lambdas(speed.scale_frequencies(), 1.0 / 120.0))
    cand = local_minima(v)
    per_scale = speed.scale_minima(v, bank)
    minima = np.concatenate([m for m, _ in per_scale]).astype(np.int64)
    u = np.concatenate([x for _, x in per_scale])
    counts = np.array([len(m) for m, _ in per_scale], dtype=np.int64)
    got = kern.chain_totals(cand, minima, u, counts)
    assert np.array_equal(got, speed.intensities(cand, per_scale))
    assert np.count_nonzero(got) > len(got) // 2


@pytest.mark.numeric
def test_tail_minima_equal_local_minima_of_each_trend() -> None:
    rng = np.random.default_rng(17)
    trends = np.round(rng.normal(size=(300, 8)), 1)  # flat bottoms too
    lo, start = 40, 47
    ms, us, counts = kern.tail_minima(trends, 4, lo, start, -np.inf)
    at = 0
    for s in range(4):
        m = local_minima(trends[:, s]) + lo
        m = m[m >= start]
        assert np.array_equal(ms[at : at + counts[s]], m)
        assert np.array_equal(us[at : at + counts[s]],
                              np.abs(trends[m - lo, s] - trends[m - lo, 4 + s]))
        at += counts[s]
    assert at == len(ms) > 0


def test_tail_minima_leave_out_minima_below_the_rest_speed() -> None:
    rng = np.random.default_rng(19)
    trends = np.round(rng.normal(size=(300, 8)), 1)
    ms, _, counts = kern.tail_minima(trends, 4, 0, 1, 0.3)
    every, _, all_counts = kern.tail_minima(trends, 4, 0, 1, -np.inf)
    at = 0
    for s in range(4):
        m = every[at : at + all_counts[s]]
        at += all_counts[s]
        assert np.array_equal(ms[counts[:s].sum() : counts[: s + 1].sum()],
                              m[trends[m, s] >= 0.3])
    assert 0 < len(ms) < len(every)


@pytest.mark.numeric
@pytest.mark.parametrize("window", [300, 5000])
def test_carried_hp_passes_equal_lapack_solves_of_the_stream_so_far(window: int) -> None:
    """Analyses every 24 speeds over a sliding window (rows older than it carried): every
    scale's trend over the region equals LAPACK's solve of all speeds so far (`HPBank`, the
    same factor) to 1e-10 of its range: the same arithmetic in another order (measured
    < 5e-13; the coarsest half-scale's system has condition ~2e10)."""
    v_all = clip_speed(frames=4200)
    lams = speed.scale_lambdas(speed.scale_frequencies(), 1.0 / 120.0)
    bank = speed.HPBank(lams)
    pre, off, conv = speed.packed_factors(lams)
    region, fresh = 150, 72
    ys = np.zeros((region + 4, len(lams)))
    scratch = np.full((window + 2, len(lams)), np.nan)
    done, checked = 0, 0
    for end in range(100, len(v_all) + 1, 24):
        g0 = max(0, end - window)
        v = v_all[g0:end]
        upto = g0 + len(v) - fresh
        if upto > done:
            done = kern.hp_advance(v, g0, done, upto, ys, pre, off, conv)
        lo = max(0, len(v) - region - 1)
        trends = kern.hp_tail(v, g0, lo, done, ys, pre, off, conv, lams, scratch)
        if end % 480 == 4 or end + 24 > len(v_all):
            for i in range(len(lams)):
                ref = bank.solve(v_all[:end], i)[g0 + lo :]
                err = np.max(np.abs(trends[:, i] - ref)) / np.ptp(v_all[:end])
                assert err < 1e-10, (end, i, err)
            checked += 1
    assert checked >= 8 and done > 3836  # past every factor's first columns


def test_the_warmer_compiles_every_kernel() -> None:
    kern._warm()
    for fn in (kern.hp_advance, kern.hp_tail, kern.tail_minima, kern.chain_totals,
               kern.mutual_nearest, kern.band_offsets, kern.ward_levels, kern.ward_labels,
               kern.dropped_threshold):
        assert fn.compiled is not None and fn.compiled.signatures


@pytest.mark.numeric
def test_ward_labels_and_dropped_threshold_equal_the_numpy_steps() -> None:
    rng = np.random.default_rng(18)
    values = np.array([0.0, 0.5, 2.0, 7.25])
    for case in range(200):
        u = np.concatenate([rng.choice(values, int(rng.integers(0, 30))),
                            np.abs(rng.standard_cauchy(int(rng.integers(3, 300))))])
        rng.shuffle(u)
        alpha, order, bounds = speed.ward_1d(u)
        n_clusters = int(rng.integers(2, min(len(u), 12)))
        merged = np.zeros(len(u), dtype=bool)  # the numpy steps of the previous version
        merged[bounds[alpha <= alpha[len(u) - 1 - n_clusters]]] = True
        labels = np.empty(len(u), dtype=np.int64)
        labels[order] = np.cumsum(~merged) - 1
        assert np.array_equal(kern.ward_labels(order, alpha, bounds, n_clusters), labels)
        zero = np.flatnonzero(u == 0)
        if len(zero):
            drop = labels[zero[0]]
        else:
            drop = int(np.argmin(np.bincount(labels, weights=u) / np.bincount(labels)))
        threshold = float(u[labels == drop].max())
        contiguous = bool(np.all((u > threshold) == (labels != drop)))
        assert kern.dropped_threshold(u, labels) == (threshold, contiguous), case
