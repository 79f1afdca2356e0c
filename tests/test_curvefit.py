"""Hermite curve fitting with dynamic programming (Önder et al. 2008, "Keyframe reduction
techniques for motion capture data", §3.1)."""

from __future__ import annotations

from functools import cache

import curvefit_reference as reference
import numpy as np
import pytest
from cmu import DATA, ROOT, clips

from streamkey.amc import read_motion
from streamkey.errors import UsageError
from streamkey.evaluate import Evaluator, reconstruct
from streamkey.features import compute_features
from streamkey.keyframes import Keyframes
from streamkey.methods import curvefit, simplify
from streamkey.motion import Motion

CLIPS = clips()
MORE_KEYS = curvefit.DEFAULT_SMOOTH / 2  # less smoothing keeps more derivative sign changes


@cache
def load(name: str) -> Motion:
    return read_motion(DATA / name)


@cache
def fitted(name: str, smooth: float = curvefit.DEFAULT_SMOOTH) -> Keyframes:
    return curvefit.extract(load(name), smooth=smooth)


@cache
def evaluator(name: str) -> Evaluator:
    return Evaluator(load(name))


@cache
def own_error(name: str, smooth: float = curvefit.DEFAULT_SMOOTH) -> float:
    """Thesis eq. 4.1 (/ body height^2) of the method's own per-channel Hermite rebuild."""
    rebuilt = curvefit.reconstruct(load(name), fitted(name, smooth))
    return evaluator(name).error_e(rebuilt, True)


def hermite_curve(bounds: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A curve made of Hermite segments with zero tangents at `bounds` (C1, not C2)."""
    f = np.arange(bounds[-1] + 1)
    y = np.zeros(len(f))
    for i in range(len(bounds) - 1):
        a, b = bounds[i], bounds[i + 1]
        t = (f[a : b + 1] - a) / (b - a)
        y[a : b + 1] = curvefit.hermite(t, values[i], values[i + 1], 0.0, 0.0)
    return y


# --- building blocks -------------------------------------------------------------------------

def test_hermite_is_oenders_matrix_form() -> None:
    basis = np.array([[2, -2, 1, 1], [-3, 3, -2, -1], [0, 0, 1, 0], [1, 0, 0, 0]], float)
    p = np.array([1.5, -2.0, 0.7, 3.0])  # p_i, p_i+1, r_i, r_i+1
    for t in np.linspace(0, 1, 7):
        expected = np.array([t**3, t**2, t, 1.0]) @ basis @ p
        assert curvefit.hermite(np.array(t), p[0], p[1], p[2], p[3]) == pytest.approx(expected)


def test_segment_costs_from_moments_equal_direct_evaluation() -> None:
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(0, 1, (2, 120)), axis=1) * 5 + 100  # channels x frames
    m = np.ascontiguousarray(curvefit.tangents(x.T).T)
    a = np.array([[10, 11, 12, 13, 14, 15, 16, 17, 18], [40] * 9])
    ends = np.array([[30 + j for j in range(9)] + [70], [41 + 3 * j for j in range(9)] + [90]])
    got = curvefit._block_costs(x, m, np.array([0, 1]), a, ends, curvefit._gram(120))
    for r in range(2):
        for i in range(9):
            for e in range(10):
                lo, hi = a[r, i], ends[r, e]
                if e == 9 and i != curvefit.SEARCH:
                    assert got[r, i, e] == np.inf
                    continue
                keys = [np.array([lo, hi])]
                seg = x[r, lo : hi + 1][:, None]
                direct = seg[:, 0] - curvefit.hermite_curves(seg, m[r, lo : hi + 1][:, None],
                                                             [keys[0] - lo])[:, 0]
                assert got[r, i, e] == pytest.approx(float(direct @ direct), rel=1e-7, abs=1e-7)


def test_tangents_are_right_at_a_junction_where_the_curvature_jumps() -> None:
    y = hermite_curve(np.array([0, 30, 80]), np.array([0.0, 30.0, -10.0]))
    m = curvefit.tangents(y[:, None])[:, 0]
    # the true tangent is 0: one-sided differences are off by h^2 x'''/3 (~0.002), the central
    # difference by a quarter of the curvature jump (~0.026)
    assert abs(m[30]) < 0.005
    assert abs((y[31] - y[29]) / 2) > 0.02


def test_initial_keys_are_the_sign_changes_of_the_first_and_second_derivative() -> None:
    f = np.arange(400)
    y = np.sin(2 * np.pi * f / 200)[:, None] * 30
    keys = np.flatnonzero(curvefit.initial_keys(y, 0.0)[:, 0])
    # ends, extrema at 50, 150, 250, 350 and inflections at 100, 200, 300 (within a frame)
    expected = np.array([0, 50, 100, 150, 200, 250, 300, 350, 399])
    assert len(keys) == len(expected)
    assert np.all(np.abs(keys - expected) <= 1)


@pytest.mark.parametrize("seed", range(5))
def test_curvefit_recovers_known_hermite_boundaries_within_2_frames(seed: int) -> None:
    bounds = np.array([0, 37, 80, 118, 165, 205, 251, 299])
    y = hermite_curve(bounds, np.array([0.0, 30, -10, 25, -20, 15, -20, 20]))
    x = (y + np.random.default_rng(seed).normal(0, 0.001, len(y)))[:, None]
    init = [np.flatnonzero(curvefit.initial_keys(x, curvefit.DEFAULT_SMOOTH)[:, 0])]
    assert len(init[0]) > len(bounds)  # the inflections in the middle of the segments too
    keys, _, _ = curvefit.fit_channels(x, curvefit.tangents(x), init, curvefit.DEFAULT_KEY_COST,
                                       100, curvefit.DEFAULT_TOL)
    assert len(keys[0]) == len(bounds)
    assert np.max(np.abs(keys[0] - bounds)) <= 2


def test_a_constant_channel_keeps_only_its_two_end_keys() -> None:
    x = np.column_stack([np.full(50, 3.0), np.sin(np.arange(50) / 5.0)])
    init = [np.flatnonzero(curvefit.initial_keys(x, 2.0)[:, c]) for c in range(2)]
    keys, cost, _ = curvefit.fit_channels(x, curvefit.tangents(x), init, 1.0, 10, 0.0)
    assert keys[0].tolist() == [0, 49]
    assert cost[0] == pytest.approx(2.0)


# --- the method on real data -----------------------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("name", CLIPS)
def test_curvefit_returns_sorted_unique_captured_keys_on_every_clip(name: str) -> None:
    motion = load(name)
    k = fitted(name)
    first, n = motion.first_frame, motion.n_frames
    assert np.all(np.diff(k.frames) > 0) and k.frames[0] >= first and k.frames[-1] < n
    per_channel = k.info["per_channel"]
    assert len(per_channel) == motion.skeleton.n_channels
    for keys in per_channel:
        assert keys[0] == first and keys[-1] == n - 1 and np.all(np.diff(keys) > 0)
    assert set(np.concatenate(per_channel).tolist()) == set(k.frames.tolist())
    assert k.info["mean_keys_per_channel"] < k.info["mean_initial_keys_per_channel"]


@pytest.mark.slow
@pytest.mark.parametrize("name", CLIPS)
def test_curvefit_error_falls_when_less_smoothing_asks_for_more_keys(name: str) -> None:
    few, many = fitted(name), fitted(name, MORE_KEYS)
    assert many.info["mean_keys_per_channel"] > few.info["mean_keys_per_channel"]
    assert many.info["mse"] < few.info["mse"]
    assert own_error(name, MORE_KEYS) < own_error(name)


def _per_channel_simplification(x: np.ndarray, counts: list[int]) -> tuple[np.ndarray, int]:
    """Lowe's split per channel (worst segment first) to the given key counts, linear:
    the rebuilt channels and the number of frames keyed in some channel."""
    out = np.empty_like(x)
    frames = np.arange(len(x))
    keyed = np.zeros(len(x), dtype=bool)
    for c, count in enumerate(counts):
        rows = np.sort(simplify.split_order(x[:, [c]], count)[0])
        out[:, c] = np.interp(frames, rows, x[rows, c])
        keyed[rows] = True
    return out, int(keyed.sum())


def _row(label: str, keys_per_channel: float, n: int, poses: int, ev: Evaluator,
         channels: np.ndarray) -> str:
    return (f"| {label} | {keys_per_channel:.1f} | {100 * keys_per_channel / n:.1f} % | {poses} "
            f"| {ev.euler_mse(channels):.4f} | {ev.error_e(channels, True):.3e} |")


def test_curvefit_reduces_keys_on_07_01_and_writes_table_2() -> None:
    """Önder Table 2 on CMU 07_01: Hermite DP next to curve simplification at equal counts."""
    name = "07_01.bvh"
    motion, k = load(name), fitted(name)
    info = k.info
    assert info["mean_keys_per_channel"] < 0.9 * info["mean_initial_keys_per_channel"]
    first, n = motion.first_frame, motion.n_frames - motion.first_frame
    ev = evaluator(name)
    x = simplify.curve(motion, "channels")
    counts = info["keys_per_channel"]
    per_pose = int(round(info["mean_keys_per_channel"]))
    lowe = motion.channels.copy()
    lowe[first:], lowe_poses = _per_channel_simplification(x, counts)
    simp = simplify.extract(motion, count=per_pose)
    simp_union = simplify.extract(motion, count=len(k))
    init = info["mean_initial_keys_per_channel"]
    lines = [
        f"# Önder et al. Table 2 on CMU {name} ({n} frames, {motion.skeleton.n_channels} "
        "channels)", "",
        f"Curve fitting: smooth={curvefit.DEFAULT_SMOOTH}, key_cost={curvefit.DEFAULT_KEY_COST}, "
        f"tol={curvefit.DEFAULT_TOL}; initial sign-change keys {init:.1f} per channel, "
        f"{info['passes']} passes. Euler MSE: wrapped rotation channels (deg^2); "
        "E: thesis eq. 4.1 / body height^2.", "",
        "| method | keys / channel | reduction ratio | pose keyframes | Euler MSE | E / h^2 |",
        "| --- | ---: | ---: | ---: | ---: | ---: |",
        _row("curve fitting & DP (Hermite per channel)", info["mean_keys_per_channel"], n,
             len(k), ev, curvefit.reconstruct(motion, k)),
        _row("curve simplification per channel (Lowe, same counts, linear)",
             float(np.mean(counts)), n, lowe_poses, ev, lowe),
        _row(f"curve simplification, {per_pose} poses (count mode, slerp)", per_pose, n,
             per_pose, ev, reconstruct(motion, simp)),
        _row("curve fitting keys as poses (union, slerp)", len(k), n, len(k), ev,
             reconstruct(motion, k)),
        _row(f"curve simplification, {len(k)} poses (count mode, slerp)", len(k), n, len(k),
             ev, reconstruct(motion, simp_union)),
    ]
    out = ROOT / "results"
    out.mkdir(exist_ok=True)
    (out / "curvefit_table2.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert np.isfinite(own_error(name))


def test_a_lower_key_cost_keeps_more_keys_and_fits_the_channels_closer() -> None:
    motion = load("07_01.bvh")
    few, many = fitted("07_01.bvh"), curvefit.extract(motion, key_cost=0.1)
    assert many.info["mean_keys_per_channel"] > few.info["mean_keys_per_channel"]
    assert many.info["mse"] < few.info["mse"]


def test_curvefit_info_lists_the_keys_of_every_channel_in_file_numbering() -> None:
    motion = load("07_01.bvh")
    k = fitted("07_01.bvh")
    assert motion.first_frame == 1
    assert all(keys[0] == 1 for keys in k.info["per_channel"])
    assert len(k.info["channels"]) == len(k.info["per_channel"])
    np.testing.assert_array_equal(k.scores, [sum(f in keys for keys in k.info["per_channel"])
                                             for f in k.frames])


def test_reconstruct_rejects_a_result_of_another_method() -> None:
    motion = load("07_01.bvh")
    with pytest.raises(UsageError):
        curvefit.reconstruct(motion, simplify.extract(motion, count=10))


@pytest.mark.parametrize("bad", [{"smooth": -1.0}, {"key_cost": float("inf")}, {"tol": 1.0},
                                 {"max_passes": -1}])
def test_curvefit_rejects_bad_parameters(bad: dict[str, float]) -> None:
    with pytest.raises(UsageError):
        curvefit.extract(load("07_01.bvh"), **bad)  # type: ignore[arg-type]


# --- the compiled search against the numpy form it replaced (tests/curvefit_reference.py) -----

def _search_inputs(x: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    mask = curvefit.initial_keys(x, curvefit.DEFAULT_SMOOTH)
    return curvefit.tangents(x), [np.flatnonzero(mask[:, c]) for c in range(x.shape[1])]


@pytest.mark.numeric
def test_block_kernel_prices_segments_bit_for_bit_as_the_numpy_form() -> None:
    rng = np.random.default_rng(7)
    x = np.cumsum(rng.normal(0, 1, (3, 400)), axis=1) * 7 + 50  # channels x frames
    m = np.ascontiguousarray(curvefit.tangents(x.T).T)
    gaps = rng.integers(1, 40, (60, 3))  # some keys so close that their candidates cross
    keys = np.cumsum(gaps, axis=1) + rng.integers(5, 250, (60, 1))
    a = np.clip(keys[:, :1] + np.arange(-4, 5), 0, 399)
    ends = np.concatenate([np.clip(keys[:, 1:2] + np.arange(-4, 5), 0, 399), keys[:, 2:]], 1)
    ch = rng.integers(0, 3, 60)
    got = curvefit._block_costs(x, m, ch, a, ends, curvefit._gram(400))
    want = reference._block_costs(x, m, ch, a, ends, curvefit._gram(400))
    assert np.isinf(want).any() and (want == 0).any() and np.isfinite(want).sum() > 1000
    np.testing.assert_array_equal(got, want)


@pytest.mark.numeric
@pytest.mark.parametrize("name", ["07_01.bvh", "09_06.amc", "02_03.bvh"])
def test_search_kernel_gives_the_numpy_searchs_keys_costs_and_history(name: str) -> None:
    x = simplify.curve(load(name), "channels")
    m, init = _search_inputs(x)
    args = (x, m, init, curvefit.DEFAULT_KEY_COST, 100, curvefit.DEFAULT_TOL)
    keys, cost, history = curvefit.fit_channels(*args)
    ref_keys, ref_cost, ref_history = reference.fit_channels(*args)
    assert len(history) > 2  # several passes
    assert all(np.array_equal(k, r) for k, r in zip(keys, ref_keys, strict=True))
    np.testing.assert_array_equal(cost, ref_cost)
    assert history == ref_history


@pytest.mark.numeric
@pytest.mark.parametrize(("key_cost", "passes", "tol"), [(0.0, 3, 0.0), (5.0, 100, 0.0),
                                                        (1.0, 0, 1e-3), (0.3, 100, 0.5)])
def test_search_kernel_matches_the_numpy_search_for_other_parameters(
        key_cost: float, passes: int, tol: float) -> None:
    x = simplify.curve(load("06_08.bvh"), "channels")[:, ::7]
    m, init = _search_inputs(x)
    keys, cost, history = curvefit.fit_channels(x, m, init, key_cost, passes, tol)
    ref_keys, ref_cost, ref_history = reference.fit_channels(x, m, init, key_cost, passes, tol)
    assert all(np.array_equal(k, r) for k, r in zip(keys, ref_keys, strict=True))
    np.testing.assert_array_equal(cost, ref_cost)
    assert history == ref_history


@pytest.mark.slow
@pytest.mark.numeric
@pytest.mark.parametrize("name", CLIPS)
def test_curvefit_gives_the_numpy_searchs_result_on_every_shared_clip(
        name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Per-channel keys, cost history and MSE bit for bit as the whole method gives them with
    the numpy search in place of the kernels, both run here: numbers recorded on another
    machine would not do (numba's code and numpy's SIMD paths round differently on another
    CPU); the two forms on one machine must agree to the last bit on any CPU."""
    compiled = fitted(name)
    monkeypatch.setattr(curvefit, "fit_channels", reference.fit_channels)
    numpy_form = curvefit.extract(load(name))
    assert compiled.info == numpy_form.info
    np.testing.assert_array_equal(compiled.frames, numpy_form.frames)
    np.testing.assert_array_equal(compiled.scores, numpy_form.scores)


@pytest.mark.numeric
@pytest.mark.parametrize("name", ["07_01.bvh", "05_11.amc"])
def test_curvefit_with_the_features_rotations_equals_curvefit_without(name: str) -> None:
    motion = load(name)
    with_features = curvefit.extract(motion, features=compute_features(motion))
    assert with_features.info == fitted(name).info
    np.testing.assert_array_equal(with_features.frames, fitted(name).frames)


@pytest.mark.numeric
@pytest.mark.parametrize("name", ["07_01.bvh", "49_18.amc"])
def test_hermite_kernel_rebuilds_channels_bit_for_bit_as_the_numpy_form(name: str) -> None:
    motion = load(name)
    x = simplify.curve(motion, "channels")
    m = curvefit.tangents(x)
    keys = [np.asarray(k) - motion.first_frame for k in fitted(name).info["per_channel"]]
    keys[0] = keys[0][1:-1]  # a channel whose keys leave frames outside: extrapolated
    keys[1] = keys[1][:1]  # a single key: the data kept
    np.testing.assert_array_equal(curvefit.hermite_curves(x, m, keys),
                                  reference.hermite_curves(x, m, keys))
    np.testing.assert_array_equal(curvefit._cost(x, m, keys, 1.0),
                                  reference._cost(x, m, keys, 1.0))
