"""Optimal keys: segment costs, the DP, offline modes, online keyframer,
--max-gap, all on the shared CMU clips."""

from __future__ import annotations

import itertools
import pickle
from functools import cache

import numpy as np
import pytest
from cmu import DATA, clips
from optimal_pricing_reference import reference_band_costs

from streamkey.amc import read_motion
from streamkey.cli import main
from streamkey.errors import UsageError
from streamkey.evaluate import Evaluator, reconstruct
from streamkey.features import compute_features
from streamkey.keyframes import KeyframeEvent, SegmentEvent
from streamkey.kinematics import forward_kinematics
from streamkey.methods import baselines, optimal, optimal_offline, saliency
from streamkey.methods import optimal_math as om
from streamkey.motion import Frame
from streamkey.online import Pipeline

CLIPS = clips()
FAST = ["07_01.bvh", "09_06.amc", "05_02.bvh"]
LOOKAHEAD = 120  # the default lookahead (1 s) in frames at the clips' 120 Hz


@cache
def load(name: str):
    return read_motion(DATA / name)


def run(kf, frames) -> list[KeyframeEvent]:
    return [e for e in kf.push_block(frames) + kf.flush() if isinstance(e, KeyframeEvent)]


def e_joints(motion, frames) -> float:
    """E as Salient Poses states its anchor rows: the skeleton's joints (ROOT and
    JOINT), root-relative, slerp reconstruction, first and last captured frames keys."""
    first = motion.first_frame
    keys = np.union1d(np.asarray(frames), [first, motion.n_frames - 1])
    rec = reconstruct(motion, keys)
    j = motion.skeleton.n_joints

    def rel(ch):
        p = forward_kinematics(motion.skeleton, ch[first:]).positions[:, :j]
        return p - p[:, :1]

    d = rel(rec) - rel(motion.channels)
    return float(np.mean(np.sum(d * d, axis=-1)))


# --- segment costs and the DP ---------------------------------------------------------------

def test_prefix_sum_costs_equal_direct_sums_across_epochs():
    m = load("01_01.bvh")  # 2751 frames: five re-based epochs
    x = optimal.curve(m)
    band = om.band_costs(x, 240)
    rng = np.random.default_rng(3)
    for b in [*rng.integers(1, len(x), 60), 2047, 2048, 2049, 2063, 2064, 2559, len(x) - 1]:
        for j in rng.integers(0, 240, 8):
            a = b - 240 + int(j)
            if a < 0:
                assert np.isinf(band[b, j])
                continue
            direct = baselines.segment_sse(x, a, int(b))
            assert band[b, j] == pytest.approx(direct, rel=1e-6, abs=1e-11), (a, b)
    a = rng.integers(0, len(x) - 300, 50)
    b = a + rng.integers(1, 300, 50)
    direct = [baselines.segment_sse(x, int(p), int(q)) for p, q in zip(a, b, strict=True)]
    np.testing.assert_allclose(om.pair_costs(x, a, b), direct, rtol=1e-6, atol=1e-11)


@pytest.mark.numeric
def test_pricing_frame_by_frame_is_bit_identical_to_chunks_and_to_the_whole_take():
    """The online solver prices each frame as it arrives; offline prices a chunk or the whole
    take at once: the same bits, across re-based epochs (also when L > EPOCH re-bases at
    origin 0), from a buffer holding the stream from any base."""
    x = optimal.curve(load("01_01.bvh"))  # 2751 frames: five epochs
    rng = np.random.default_rng(7)
    for max_len in (240, 700):
        whole = om.band_costs(x, max_len)
        frames = om.Pricer(max_len)
        assert np.array_equal(np.concatenate([frames.price(x, 0, b, b + 1)
                                              for b in range(len(x))]), whole)
        cuts = np.unique(np.concatenate([[0, len(x)], np.cumsum(rng.integers(1, 40, 200))]))
        cuts = cuts[cuts <= len(x)]
        split, out = om.Pricer(max_len), np.empty_like(whole)
        for b0, b1 in itertools.pairwise(cuts):
            base = max(0, b0 - max_len)  # only the rows from b0 - L on are held
            split.price(x[base:], base, b0, b1, out[b0:b1])
        assert np.array_equal(out, whole)
    m = load("01_01.bvh")
    kf = optimal.Online(m.skeleton, m.fps)  # default lookahead: its buffer slides
    kf.push_block(m.frames())  # the noise filter still holds the last `delay` frames
    s = kf.solver
    assert s.base > 0 and s.n == len(x) - kf.features.delay
    assert np.array_equal(s.rows.costs[: s.n - s.base], om.band_costs(x, 240)[s.base : s.n])


@pytest.mark.numeric
@pytest.mark.parametrize("name", ["01_01.bvh", *FAST])
def test_compiled_pricing_agrees_with_the_blas_formulation_to_rounding(name):
    """The old pricing (four window x chunk matrix products, tests/optimal_pricing_reference)
    and the compiled column-by-column sums round differently; the costs are differences of
    prefix-sum terms up to u·(w_a·Q0_b) ~ U²·|w|² (U = EPOCH + L local frames, |w| at most the
    curve's diameter), so both sit within a few roundings of that term of each other (measured
    on the 35 shared clips: at most 2.9 of them; allowed: 16)."""
    x = optimal.curve(load(name))
    new, ref = om.band_costs(x, 240), reference_band_costs(x, 240)
    assert np.array_equal(np.isinf(new), np.isinf(ref))
    u = min(len(x), om.EPOCH + 240)
    diameter2 = 4.0 * np.max(np.sum((x - x.mean(axis=0)) ** 2, axis=1))
    ok = np.isfinite(ref)
    assert np.max(np.abs(new[ok] - ref[ok])) <= 16 * np.finfo(float).eps * u * u * diameter2


def _dp_numpy(band: np.ndarray, lam: float, floor: int) -> tuple[np.ndarray, np.ndarray]:
    """The penalised DP row by row in numpy (the code the compiled loop replaced)."""
    n, max_len = band.shape
    f, bp = np.full(n, np.inf), np.full(n, -1, dtype=np.int64)
    f[: floor + 1] = 0.0
    for b in range(floor + 1, n):
        lo = max(b - max_len, floor)
        vals = f[lo:b] + band[b, max_len - (b - lo):]
        i = int(np.argmin(vals))
        f[b], bp[b] = vals[i] + lam, lo + i
    return f, bp


@pytest.mark.numeric
@pytest.mark.parametrize("floor", [0, 37])
def test_compiled_dp_is_bit_identical_to_the_numpy_rows_on_a_shared_clip(floor):
    x = optimal.curve(load("05_02.bvh"))
    band = om.band_costs(x, 240)
    ref_f, ref_bp = _dp_numpy(band, 3.5e-3, floor)
    f, bp = np.full(len(x), np.inf), np.full(len(x), -1, dtype=np.int64)
    f[: floor + 1] = 0.0
    keys = np.zeros(len(x), dtype=np.int64)
    om.dp_rows(band, f, bp, keys, floor + 1, len(x), 3.5e-3, floor)
    assert np.array_equal(f, ref_f) and np.array_equal(bp[floor + 1 :], ref_bp[floor + 1 :])
    rows = np.array(om.chain(bp, len(x) - 1, floor - 1), dtype=np.int64)
    np.testing.assert_allclose(om.chain_costs(x, rows)[1:],
                               om.pair_costs(x, rows[:-1], rows[1:]), rtol=1e-9, atol=1e-15)


def test_hold_edge_costs_are_the_direct_sums_and_the_same_bits_in_any_split():
    """The segment over 49_18's closing still stretch (from frame 500), priced from running
    sums: the direct frame sums to rounding, and the same bits whatever the chunks."""
    m = load("49_18.amc")
    x = optimal.curve(m)
    edge = np.full(len(x), -1, dtype=np.int64)
    edge[501:] = 500
    whole = np.full(len(x), np.nan)
    om.edge_costs(x, edge, whole, 0, len(x), 240)
    parts = np.full(len(x), np.nan)
    for b0 in range(0, len(x), 16):
        om.edge_costs(x, edge, parts, b0, min(len(x), b0 + 16), 240)
    assert np.array_equal(whole, parts, equal_nan=True)
    assert np.isnan(whole[:741]).all() and not np.isnan(whole[741:]).any()
    direct = [om.chain_costs(x, np.array([500, b]))[1] for b in range(741, len(x), 37)]
    assert np.allclose(whole[741::37], direct, rtol=1e-9, atol=1e-15)


def test_count_mode_is_the_exact_k_key_optimum_on_a_small_curve():
    x = optimal.curve(load("07_01.bvh"))[::20]  # 16 rows
    n = len(x)
    for k in (3, 4, 5):
        best = min(baselines.reconstruction_sse(x, np.array([0, *c, n - 1]))
                   for c in itertools.combinations(range(1, n - 1), k - 2))
        keys, info = optimal_offline.count_keys(x, k, n)
        assert info["solver"] == "exact" and len(keys) == k
        assert baselines.reconstruction_sse(x, keys) == pytest.approx(best, rel=1e-9)


def test_lambda_search_lands_on_the_count_of_a_long_take():
    m = load("01_06.bvh")
    keys = optimal.extract(m, count=257)
    assert len(keys) == 257 and keys.info["solver"].startswith("lambda")
    assert keys.frames[0] == m.first_frame and keys.frames[-1] == m.n_frames - 1


def test_tolerance_mode_meets_its_tolerance_with_fewer_keys_than_uniform():
    m = load("05_02.bvh")
    x = optimal.curve(m)
    tol = 2e-4
    keys = optimal.extract(m, tolerance=tol)
    rows = keys.frames - m.first_frame
    seg = om.pair_costs(x, rows[:-1], rows[1:])
    assert np.all(seg <= tol * np.diff(rows) * (1 + 1e-9))  # every stretch meets it
    assert keys.info["error"] <= tol
    # uniform needs more keys to meet the same mean error
    uni = baselines.uniform(m, len(keys)).frames - m.first_frame
    assert baselines.reconstruction_sse(x, uni) / len(x) > tol


def test_modes_are_checked():
    m = load("07_01.bvh")
    for bad in ({"count": 1}, {"count": 10_000}, {"rate": -1.0}, {"tolerance": float("nan")},
                {"count": 5, "rate": 2.0}, {"max_segment": 0.0}):
        with pytest.raises(UsageError):
            optimal.extract(m, **bad)
    base = optimal.extract(m, count=16).frames
    same = optimal.extract(m, count=16, weights=np.full(m.skeleton.n_joints, 4.0)).frames
    assert np.array_equal(base, same)  # a common factor changes nothing
    hands = np.zeros(m.skeleton.n_joints)
    hands[[m.skeleton.index("LeftHand"), m.skeleton.index("RightHand")]] = 1.0
    assert not np.array_equal(base, optimal.extract(m, count=16, weights=hands).frames)
    assert len(optimal.extract(m, count=16, root_translation=True)) == 16
    with pytest.raises(UsageError):
        optimal.Online(m.skeleton, m.fps, lookahead=om.CHUNK - 1)
    with pytest.raises(UsageError):
        optimal.Online(m.skeleton, m.fps, count=10)


# --- offline against uniform and Salient Poses --------------------------------------------

def test_07_01_beats_salient_poses_anchor_rows():
    m = load("07_01.bvh")
    for k, salient_poses in ((16, 0.1227), (32, 0.00904)):
        keys = optimal.extract(m, count=k)
        assert len(keys) == k
        assert e_joints(m, keys.frames) <= salient_poses
        assert e_joints(m, keys.frames) < e_joints(m, baselines.uniform(m, k).frames)


@cache
def uniform_ratios() -> np.ndarray:
    """E of count mode's keys over E of uniform keys, 5 % and 10 % of frames, every clip."""
    ratios = []
    for name in CLIPS:
        m = load(name)
        ev = Evaluator(m)
        n = m.n_frames - m.first_frame
        for share in (0.05, 0.10):
            k = int(round(share * n))
            keys = optimal.extract(m, count=k)
            assert len(keys) == k
            ratios.append(ev.score(keys).error / ev.score(baselines.uniform(m, k)).error)
    return np.array(ratios)


@pytest.mark.slow
def test_count_mode_beats_uniform_on_the_shared_clips():
    ratios = uniform_ratios()
    assert len(ratios) == 70
    assert (ratios < 1).sum() >= 68


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured with the sensor-noise front end on by "
                   "default: geometric mean 0.689 (0.608 without the filter), worst 06_06 at 5 % "
                   "(20 keys) 1.051 (1.019 without): the keys fit the 5 Hz low-passed curve, E "
                   "is of the raw take")
def test_count_mode_beats_uniform_by_a_third_and_never_loses_3_percent():
    ratios = uniform_ratios()
    assert ratios.max() <= 1.03
    assert np.exp(np.mean(np.log(ratios))) <= 0.65


# --- online -------------------------------------------------------------------------------

def online_keys(name: str, lookahead: int | None = None, **mode) -> tuple[np.ndarray, int]:
    m = load(name)
    kf = optimal.Online(m.skeleton, m.fps, lookahead=lookahead or m.n_frames, **mode)
    events = run(kf, m.frames())
    frames = np.array([e.frame for e in events])
    assert np.all(np.diff(frames) > 0)
    return frames, max((e.latency_frames for e in events if e.decided_at < m.n_frames - 1),
                       default=0)


@pytest.mark.parametrize("name", FAST)
@pytest.mark.parametrize("mode", [{"rate": 6.0}, {"lam": 2e-3}, {"tolerance": 1e-4}])
def test_online_with_unbounded_lookahead_equals_offline(name, mode):
    m = load(name)
    frames, _ = online_keys(name, None, **mode)
    assert np.array_equal(frames, optimal.extract(m, **mode).frames)


@pytest.mark.slow
def test_online_rate_with_unbounded_lookahead_equals_offline_on_every_clip():
    for name in CLIPS:
        frames, _ = online_keys(name, None, rate=6.0)
        assert np.array_equal(frames, optimal.extract(load(name), rate=6.0).frames), name


@cache
def online_default(name: str, fixed_lambda: bool = False) -> tuple[np.ndarray, int, float]:
    """Online at the default lookahead and 5 % of frames: (frames, max latency, E / E of the
    offline optimum with as many keys)."""
    m = load(name)
    rate = 0.05 * m.fps
    mode = {"lam": optimal.extract(m, rate=rate).info["lambda"]} if fixed_lambda else {
        "rate": rate}
    frames, latency = online_keys(name, LOOKAHEAD, **mode)
    ev = Evaluator(m)
    ratio = ev.score(frames).error / ev.score(optimal.extract(m, count=len(frames))).error
    return frames, latency, ratio


@pytest.mark.slow
def test_online_latency_on_every_clip():
    for name in CLIPS:
        m = load(name)
        delay = optimal.Online(m.skeleton, m.fps).features.delay  # the noise filter's
        for fixed in (False, True):
            frames, latency, _ = online_default(name, fixed)
            assert latency <= LOOKAHEAD + delay, name
            assert frames[0] == m.first_frame and frames[-1] == m.n_frames - 1


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured with the noise front end on: with the "
                   "take's lambda, median 1.000, worst 05_13 1.087, 49_18 1.055, 05_02 1.052; "
                   "earlier, without the filter: 05_02 1.119, not smooth in lambda (0.995, "
                   "1.03, 1.119, 1.022, 0.992 at 0.8, 0.9, 1.0, 1.1, 1.25 x that lambda)")
def test_online_fixed_lambda_quality_on_every_clip():
    """The bounded-lookahead DP itself loses almost nothing."""
    for name in CLIPS:
        _, _, ratio = online_default(name, True)
        assert ratio <= 1.05, (name, ratio)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured (rate controller, lookahead 120, noise "
                   "front end on; no key inside calibration holds): E / E of the offline "
                   "count-mode optimum at the same count median 1.000, worst 07_01 1.131, "
                   "02_10 1.121, 05_18 1.087, 49_18 1.061 (131_01 was 1.447 before deadline "
                   "decisions stayed final through a lambda re-solve)")
def test_online_rate_is_within_5_percent_of_offline_on_every_clip():
    assert max(online_default(name)[2] for name in CLIPS) <= 1.05


@pytest.mark.parametrize("name", ["07_01.bvh", "05_02.bvh"])
def test_no_key_falls_inside_a_calibration_hold_offline_or_online(name):
    """A calibration hold (the take recorded after a 2 s T-pose, `variants.with_calibration`)
    gets no key strictly inside, offline and online (default lookahead), unless `hold_keys`
    asks; still stretches may get keys (`optimal.KEYLESS`): 49_18's closing one (501-1101,
    balancing on one leg) keeps three keys inside (586, 806 and 878)."""
    from streamkey.variants import with_calibration

    m = with_calibration(load(name)).motion
    spans = optimal.holds(m, compute_features(m), optimal.KEYLESS)
    assert spans and any(e - s > optimal.chunk_frames(m.fps) for s, e in spans)

    def inside(frames) -> list[int]:
        rows = np.asarray(frames) - m.first_frame
        return [int(r) for r in rows for s, e in spans if s < r < e]

    assert inside(optimal.extract(m).frames) == []
    kf = optimal.Online(m.skeleton, m.fps, lookahead=LOOKAHEAD)
    assert inside([e.frame for e in kf.push_block(m.frames()) + kf.flush()]) == []
    still = load("49_18.amc")
    spans = optimal.holds(still, compute_features(still))
    assert (501, 1101) in spans and optimal.holds(still, compute_features(still),
                                                  optimal.KEYLESS) == []
    rows = optimal.extract(still).frames - still.first_frame
    assert len([r for r in rows if 501 < r < 1101]) >= 3


def test_online_count_follows_offline_on_a_take_that_holds_still():
    """49_18 (balance on one leg) holds still for more than half its frames; those frames stay
    out of λ online and offline (`streamkey.segments`), so the online count at the default
    lookahead is the offline one (before: 16 keys for 21, 0.76x, E 1.20x at the same count)."""
    frames, _, ratio = online_default("49_18.amc")
    count = len(frames) / len(optimal.extract(load("49_18.amc"), rate=6.0))
    assert 0.8 <= count <= 1.25 and ratio <= 1.10, (count, ratio)


@pytest.mark.parametrize("name", ["49_18.amc", "05_02.bvh"])
def test_online_keys_are_the_same_through_a_pipeline_with_its_segment_detector(name):
    """Alone, the keyframer runs its own segment detector; in a pipeline it takes the
    pipeline's segment events (`note_segment`) and its own detector stops: same keys, same
    decision frames, on clips with a calibration hold / still stretches."""
    m = load(name)
    alone = optimal.Online(m.skeleton, m.fps)
    inside = optimal.Online(m.skeleton, m.fps)
    pipe = Pipeline([inside])
    events = pipe.push_block(m.frames()) + pipe.flush()
    assert inside.segments is None and any(isinstance(e, SegmentEvent) for e in events)
    got = [(e.frame, e.decided_at) for e in events if isinstance(e, KeyframeEvent)]
    assert got == [(e.frame, e.decided_at) for e in run(alone, m.frames())]
    assert alone.segments is not None


def test_online_memory_stays_bounded_on_a_long_stream():
    m = load("02_10.bvh")
    kf = optimal.Online(m.skeleton, m.fps, lam=2e-3)
    rows = m.channels[m.first_frame :]
    bound = kf.lookahead + 2 * kf.max_len + om.EPOCH
    peak, events = 0, 0
    for seq in range(4 * len(rows)):  # ~10,600 frames, 5 epochs
        out = kf.push(Frame(seq, seq / m.fps, rows[seq % len(rows)]))
        events += sum(isinstance(e, KeyframeEvent) for e in out)
        peak = max(peak, kf.solver.n - kf.solver.base, kf.solver.pricer.n - kf.solver.pricer.o)
        assert all(e.latency_frames <= e.lookahead == kf.lookahead + kf.features.delay
                   for e in out if isinstance(e, KeyframeEvent))  # the filter's delay too
    assert peak <= 2 * bound and len(kf.frames) <= 2 * bound and events > 100


# --- --max-gap ------------------------------------------------------------------------------

def test_max_gap_fills_the_long_stretch_saliency_leaves_on_05_02():
    m = load("05_02.bvh")
    keys = saliency.extract(m)
    ends = [m.first_frame, m.n_frames - 1]
    # the still start: no key before 333 (session segments get none)
    assert np.diff(np.union1d(keys.frames, ends)).max() >= 200
    filled = optimal.max_gap(m, keys, 1.0)
    rows = np.union1d(filled.frames, [m.first_frame, m.n_frames - 1])
    assert np.diff(rows).max() <= 120
    assert set(keys.frames) <= set(filled.frames)
    assert set(filled.info["max_gap_added"]) == set(filled.frames) - set(keys.frames)
    ev = Evaluator(m)
    assert ev.score(filled).error < ev.score(keys).error


def test_max_gap_online_wraps_any_keyframer():
    m = load("05_02.bvh")
    inner = run(saliency.Online(m.skeleton, m.fps), m.frames())
    kf = optimal.MaxGap(saliency.Online(m.skeleton, m.fps), 1.0)
    events = run(kf, m.frames())
    frames = [e.frame for e in events]
    assert frames == sorted(set(frames)) and set(e.frame for e in inner) <= set(frames)
    rows = np.union1d(frames, [m.first_frame, m.n_frames - 1])
    assert np.diff(rows).max() <= 120
    assert all(0 <= e.latency_frames <= kf.lookahead for e in events)
    assert kf.lookahead == saliency.Online(m.skeleton, m.fps).lookahead + 120
    again = optimal.MaxGap(saliency.Online(m.skeleton, m.fps), 1.0)
    frames_in = m.frames()
    head = [e for f in frames_in[:500] for e in again.push(f)]
    clone = pickle.loads(pickle.dumps(again))
    assert head + run(clone, frames_in[500:]) == events  # pickled mid-stream, resumed


def test_max_gap_keeps_the_inner_re_analysis_off_the_due_path():
    """Speed's window re-analysis waits for `idle` under `--max-gap` as it does without it,
    and the events equal those of the wrapper run with idle right after every frame."""
    from streamkey.methods import speed
    from streamkey.online import Pipeline

    m = load("07_01.bvh")
    kf = optimal.MaxGap(speed.Online(m.skeleton, m.fps), 0.5)
    pipeline = Pipeline([kf])
    deferred, events = 0, []
    for f in m.frames():
        events += pipeline.push(f)
        deferred += kf.inner._analysis_due
        events += pipeline.idle()
        assert not kf.inner._analysis_due
    events += pipeline.flush()
    assert deferred > 0
    keys = [(e.frame, e.decided_at) for e in events if isinstance(e, KeyframeEvent)]
    block = Pipeline([optimal.MaxGap(speed.Online(m.skeleton, m.fps), 0.5)])
    same = block.push_block(m.frames()) + block.flush()
    assert keys == [(e.frame, e.decided_at) for e in same if isinstance(e, KeyframeEvent)]


def test_cli_optimal_and_max_gap(tmp_path, capsys):
    out = tmp_path / "keys.csv"
    clip = str(DATA / "07_01.bvh")
    assert main(["extract", clip, "--method", "optimal", "--count", "16", "--format", "csv",
                 "-o", str(out)]) == 0
    assert len(out.read_text().splitlines()) == 17
    assert main(["extract", clip, "--method", "speed", "--max-gap", "0.25", "--online",
                 "--format", "csv", "-o", str(out)]) == 0
    frames = [int(line.split(",")[2]) for line in out.read_text().splitlines()[1:]]
    assert np.diff(np.union1d(frames, [1, 316])).max() <= 30
    for bad in (["--rate", "-2"], ["--max-gap", "0"], ["--max-segment", "nan"],
                ["--online", "--count", "5"], ["--online", "--lookahead", "3"]):
        assert main(["extract", clip, "--method", "optimal", *bad]) == 2, bad
        assert capsys.readouterr().err.startswith("error: ")
