"""Baselines of the thesis comparison: uniform sampling and frame decimation (Togawa & Okuda)."""

from __future__ import annotations

from functools import cache

import decimation_reference as reference
import numpy as np
import pytest
from cmu import DATA, clips
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from streamkey.amc import read_motion
from streamkey.errors import UsageError
from streamkey.features import compute_features
from streamkey.methods import baselines, simplify
from streamkey.motion import Motion

CLIPS = clips()


@cache
def load(name: str) -> Motion:
    """A shared clip, BVH or AMC."""
    return read_motion(DATA / name)


def brute_force_decimation(x: np.ndarray, count: int) -> list[int]:
    """Greedy decimation re-pricing every keyframe from scratch at every step (O(n^2) a step).

    Uses the module's segment SSE so prices are bit-identical; what it checks is the heap,
    the lazy invalidation and the local updates.
    """
    keys = list(range(len(x)))
    sse = baselines.segment_sse
    while len(keys) > count:
        costs = [sse(x, keys[i - 1], keys[i + 1]) - sse(x, keys[i - 1], keys[i])
                 - sse(x, keys[i], keys[i + 1]) for i in range(1, len(keys) - 1)]
        keys.pop(1 + int(np.argmin(costs)))  # ties: earliest frame
    return keys


def loop_sse(x: np.ndarray, keys: list[int]) -> float:
    """Reconstruction SSE with a plain loop over frames."""
    total = 0.0
    for a, b in zip(keys[:-1], keys[1:], strict=True):
        for i in range(a + 1, b):
            t = (i - a) / (b - a)
            total += float(np.sum((x[i] - ((1 - t) * x[a] + t * x[b])) ** 2))
    return total


curves = st.integers(2, 30).flatmap(lambda n: st.integers(1, 3).flatmap(
    lambda d: arrays(np.float64, (n, d), elements=st.floats(-50, 50, width=32))))


@settings(max_examples=200, deadline=None)
@given(x=curves, data=st.data())
def test_decimation_equals_brute_force_greedy_on_random_curves(x, data):
    count = data.draw(st.integers(2, len(x)))
    removed, costs = baselines.decimation_order(x, count)
    kept = sorted(set(range(len(x))) - set(removed.tolist()))
    assert len(kept) == count
    assert kept == brute_force_decimation(x, count)
    assert baselines.reconstruction_sse(x, np.array(kept)) == pytest.approx(
        loop_sse(x, kept), rel=1e-9, abs=1e-6)


@settings(max_examples=100, deadline=None)
@given(x=curves)
def test_removal_costs_add_up_to_the_final_reconstruction_error(x):
    removed, costs = baselines.decimation_order(x, 2)
    assert float(np.sum(costs)) == pytest.approx(loop_sse(x, [0, len(x) - 1]), rel=1e-9,
                                                 abs=1e-6)


def test_decimation_and_uniform_give_exactly_k_on_every_shared_clip():
    for name in CLIPS:
        m = load(name)
        n = m.n_frames - m.first_frame
        for k in (2, 16, n // 20):
            for keys in (baselines.decimate(m, k), baselines.uniform(m, k)):
                assert len(keys) == k, (name, keys.method)
                assert keys.frames[0] == m.first_frame, name
                assert keys.frames[-1] == m.n_frames - 1, name


def test_decimation_beats_uniform_on_its_own_objective_at_the_largest_count_on_every_clip():
    # Greedy decimation is not optimal: at small K uniform spacing sometimes wins on periodic
    # walks (e.g. 02_01 at K = 8, 16, 32; measured 15 of 194 (clip, K) pairs); from the largest
    # power of two <= n/2 it wins on every shared clip.
    # On the raw curve (the noise filter off).
    _decimation_beats_uniform_at_the_largest_count(None)


@pytest.mark.xfail(strict=True, reason="measured: behind the default 5 Hz noise filter the "
                   "smoother 02_01 walk curve at K = 128 gives decimation SSE 1.64e-5 against "
                   "uniform's 1.25e-5 (uniform lower on 15 of 35 clips, all at K <= 512)")
def test_decimation_beats_uniform_at_the_largest_count_behind_the_noise_filter():
    from streamkey.filters import DEFAULT_NOISE_CUTOFF_HZ

    _decimation_beats_uniform_at_the_largest_count(DEFAULT_NOISE_CUTOFF_HZ)


def _decimation_beats_uniform_at_the_largest_count(cutoff: float | None) -> None:
    from streamkey.features import compute_features

    for name in CLIPS:
        m = load(name)
        feats = compute_features(m, noise_cutoff_hz=cutoff)
        x = simplify.curve(m, features=feats)
        k = 2 ** int(np.log2(len(x) // 2))
        dec = baselines.decimate(m, k, features=feats).frames - m.first_frame
        uni = baselines.uniform(m, k).frames - m.first_frame
        assert baselines.reconstruction_sse(x, dec) < baselines.reconstruction_sse(x, uni), name


def test_uniform_spacing_differs_by_at_most_one_frame():
    m = load("07_01.bvh")
    for k in range(2, m.n_frames - m.first_frame + 1):
        gaps = np.diff(baselines.uniform(m, k).frames)
        assert gaps.min() >= 1 and gaps.max() - gaps.min() <= 1, k


def test_decimation_in_positions_space_keeps_both_ends():
    m = load("09_06.amc")
    keys = baselines.decimate(m, 12, space="positions")
    assert len(keys) == 12 and keys.frames[0] == 0 and keys.frames[-1] == m.n_frames - 1


def test_bad_counts_raise_usage_error():
    m = load("07_01.bvh")
    for bad in (1, 0, m.n_frames, 2.5, True):
        with pytest.raises(UsageError):
            baselines.decimate(m, bad)
        with pytest.raises(UsageError):
            baselines.uniform(m, bad)
    with pytest.raises(UsageError):
        baselines.decimate(m, 5, space="euler")


@pytest.mark.numeric
@pytest.mark.slow
def test_decimation_kernel_removes_in_the_heapq_forms_order_on_every_shared_clip():
    """The compiled loop sums a segment's squares in another order than numpy (costs differ
    in the last bits), yet the whole removal order down to 2 keys is the one of the heapq +
    numpy form it replaced (tests/decimation_reference.py), in both spaces (whose curves
    are the same rows whether decimate computes them or is given the features)."""
    for name in CLIPS:
        m = load(name)
        feats = compute_features(m)
        for space in simplify.SPACES:
            x = simplify.curve(m, space, feats)
            # without features, positions come from FK alone: the same rows
            np.testing.assert_array_equal(baselines._curve(m, space, None), x)
            removed, costs = baselines.decimation_order(x, 2)
            ref_removed, ref_costs = reference.decimation_order(x, 2)
            np.testing.assert_array_equal(removed, ref_removed, err_msg=f"{name} {space}")
            np.testing.assert_allclose(costs, ref_costs, rtol=1e-9, atol=1e-12)


@pytest.mark.numeric
def test_segment_sse_kernel_equals_the_numpy_form():
    m = load("07_01.bvh")
    x = simplify.curve(m, "positions")
    for a, b in ((0, 1), (0, 2), (10, 60), (5, len(x) - 1)):
        assert baselines.segment_sse(x, a, b) == pytest.approx(
            reference.segment_sse(x, a, b), rel=1e-12, abs=1e-15)


@pytest.mark.numeric
def test_segment_sse_sums_the_chord_distances_of_its_rows_bit_for_bit():
    """Four rows at a time, yet each row's squares in column order and the rows in frame
    order: the same bits as adding `simplify.chord_sq` row by row (the removal order and
    keys of decimate do not move)."""
    x = simplify.curve(load("07_01.bvh"), "positions")
    for a, b in [(0, m) for m in range(1, 14)] + [(37, 140), (3, len(x) - 1)]:
        total = 0.0
        for i in range(1, b - a):
            total += simplify.chord_sq(x, a, b, i)
        assert baselines.segment_sse(x, a, b) == total, (a, b)
