"""Adaptive speed-minima keyposes (Miura et al. 2014): offline method and online keyframer."""

from __future__ import annotations

import itertools
import json
import pickle
from functools import cache

import numpy as np
import pytest
from cmu import DATA, ROOT, clips
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from streamkey.amc import read_motion
from streamkey.bvh import read_bvh
from streamkey.errors import UsageError
from streamkey.features import compute_features
from streamkey.keyframes import Event, GapEvent, KeyframeEvent
from streamkey.methods import speed, speed_chains
from streamkey.motion import Motion
from streamkey.roles import MIURA_ROLES
from streamkey.signal import hp_filter, hp_lambda

HEELSTRIKES = json.loads((DATA / "HEELSTRIKES.json").read_text(encoding="utf-8"))["clips"]
# 131_xx entries are hop landings, not heel strikes (HEELSTRIKES.json "about").
WALKS = sorted(c for c in HEELSTRIKES if not c.startswith("131_"))


@cache
def load(name: str) -> Motion:
    """A shared clip, BVH or AMC."""
    return read_bvh(DATA / name) if name.endswith(".bvh") else read_motion(DATA / name)


@cache
def offline(name: str) -> speed.Keyframes:
    return speed.extract(load(name))


def match_count(found: np.ndarray, truth: np.ndarray, tol: float) -> int:
    """Largest one-to-one matching of two sorted frame lists with |difference| <= tol."""
    used = np.zeros(len(truth), dtype=bool)
    n = 0
    for f in np.sort(found):
        free = np.flatnonzero(~used & (np.abs(truth - f) <= tol))
        if len(free):
            used[free[0]] = True
            n += 1
    return n


def prf(found: np.ndarray, truth: np.ndarray, tol: float) -> tuple[float, float, float]:
    """Precision, recall and F-measure (Miura §4.4) of `found` against `truth`."""
    n = match_count(np.asarray(found), np.asarray(truth), tol)
    p = n / len(found) if len(found) else float(len(truth) == 0)
    r = n / len(truth) if len(truth) else 1.0
    return p, r, (2 * p * r / (p + r) if p + r else 0.0)


def scored_walk(name: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Keyposes and heel strikes of a walk within the annotated part, and Miura's tolerance.

    Miura scores only the part of a clip the ground truth covers (§4.4); the heel-strike
    detector cannot see the strikes at the clip's edges, so the scored part runs from the
    first to the last heel strike, widened by the tolerance (1/4 of the median interval).
    """
    truth = np.array(HEELSTRIKES[name]["all"])
    tol = float(np.median(np.diff(truth))) / 4
    keys = offline(name).frames
    keys = keys[(keys >= truth[0] - tol) & (keys <= truth[-1] + tol)]
    return keys, truth, tol


# --- building blocks -------------------------------------------------------------------------

def test_scales_run_from_8_hz_down_to_the_last_one_above_0_2_hz() -> None:
    f = speed.scale_frequencies(8.0, 0.2, 0.95)
    assert f[0] == 8.0 and len(f) == 72
    assert f[-1] >= 0.2 > f[-1] * 0.95
    np.testing.assert_allclose(f[1:] / f[:-1], 0.95)


def test_speed_is_the_norm_of_the_stacked_48_vector_per_frame_step() -> None:
    motion = load("07_01.bvh")
    feats = compute_features(motion)
    p = feats.role_positions(MIURA_ROLES)[1:].reshape(motion.n_frames - 1, 48)
    p = p / feats.body_height
    v = speed.speed_signal(p, motion.frame_time, 10.0)
    pf = hp_filter(p, hp_lambda(10.0, motion.frame_time))
    n = 100  # v(n) lives at frame n: the step from n to n+1 (Miura eq. 3)
    assert len(v) == len(p) - 1
    assert v[n] == pytest.approx(np.sqrt(np.sum((pf[n + 1] - pf[n]) ** 2)) * 120.0)


def _brute_force_cost(a: np.ndarray, b: np.ndarray) -> int:
    short, long_ = (a, b) if len(a) <= len(b) else (b, a)
    return min(int(np.abs(long_[list(idx)] - short).sum())
               for idx in itertools.combinations(range(len(long_)), len(short)))


def test_dp_correspondence_equals_brute_force_on_small_inputs() -> None:
    rng = np.random.default_rng(11)
    for _ in range(400):
        a = np.sort(rng.choice(60, size=rng.integers(0, 8), replace=False))
        b = np.sort(rng.choice(60, size=rng.integers(0, 8), replace=False))
        if len(a) and len(b):
            assert _cost(a, b, speed.match_minima(a, b)) == _brute_force_cost(a, b)
        else:
            assert np.all(speed.match_minima(a, b) == -1)


def test_an_extra_minimum_does_not_shift_its_neighbours_chains() -> None:
    # One extra candidate (at 40) among steps whose minima match one to one: a matching that
    # pairs every minimum shifted every later pair by one step; mutual nearest minima do not.
    cand = np.array([10, 40, 60, 110, 160, 210])
    minima = np.array([11, 61, 111, 161, 209, 260])
    assert speed.nearest_pairs(cand, minima).tolist() == [0, -1, 1, 2, 3, 4]
    shifted = speed.match_minima(cand, minima)
    assert shifted.tolist() != [0, -1, 1, 2, 3, 4]


def test_a_candidate_whose_chain_breaks_gets_no_more_speed_descent() -> None:
    cand = np.array([10, 30, 50])
    per_scale = [(np.array([11, 31, 49]), np.array([1.0, 2.0, 3.0])),
                 (np.array([12, 48]), np.array([4.0, 5.0])),   # 31 loses its chain here
                 (np.array([14, 29, 47]), np.array([6.0, 7.0, 8.0]))]
    u = speed.intensities(cand, per_scale)
    np.testing.assert_allclose(u, [1 + 4 + 6, 2, 3 + 5 + 8])


def test_mojena_drops_the_cluster_holding_a_zero_intensity() -> None:
    u = np.array([0.0, 0.1, 0.2, 0.15, 0.05, 0.12, 9.0, 9.5, 10.0, 8.8, 0.3, 0.02])
    res = speed.mojena_threshold(u)
    assert res.n_clusters == 2 and res.threshold == pytest.approx(0.3)


def test_mojena_with_one_cluster_keeps_every_positive_intensity() -> None:
    u = np.array([0.0, 1.0, 1.1, 0.9, 1.05, 0.95])
    res = speed.mojena_threshold(u)
    assert res.n_clusters == 1 and res.threshold == 0.0


def test_mojena_without_zero_intensity_drops_the_lowest_mean_cluster() -> None:
    u = np.concatenate([np.linspace(0.9, 1.1, 20), [20.0, 21.0, 19.5]])
    res = speed.mojena_threshold(u)
    assert res.n_clusters == 2 and res.threshold == pytest.approx(1.1)


@pytest.mark.parametrize("bad", [{"r": 1.0}, {"f_min": 9.0}, {"f_c": 0.0}, {"mojena_k": np.nan},
                                 {"cut": "ward"}])
def test_bad_parameters_raise_usage_error(bad: dict[str, float]) -> None:
    with pytest.raises(UsageError):
        speed.extract(load("07_01.bvh"), **bad)


# --- offline on the CMU clips ----------------------------------------------------------------

def test_finds_3_to_5_keyposes_on_07_01_where_miura_counts_4() -> None:
    keys = offline("07_01.bvh")
    assert 3 <= len(keys) <= 5
    assert keys.frames.min() >= 1  # the cgspeed reference frame is skipped
    info = keys.info
    assert set(keys.frames) <= set(info["candidates"])
    assert info["cut"] == "quantile" and info["n_scales"] == 72
    assert info["threshold"] == speed.quantile_threshold(info["intensities"])
    assert speed.extract(load("07_01.bvh"), cut="mojena").info["n_clusters"] >= 1
    np.testing.assert_array_equal(keys.scores, info["intensities"][
        np.isin(info["candidates"], keys.frames)])


@pytest.mark.parametrize("name", [pytest.param(
    name, marks=pytest.mark.xfail(strict=True, reason="measured: 25 keys for 28 heel strikes "
                                  "with the sensor-noise front end on (6 Hz)"))
    if name == "09_12.bvh" else name for name in WALKS])
def test_walk_has_one_keypose_per_step_give_or_take_one(name: str) -> None:
    keys, truth, _ = scored_walk(name)
    assert abs(len(keys) - len(truth)) <= 1


@pytest.mark.parametrize("name", WALKS)
def test_walk_keyposes_fall_on_heel_strikes_within_miura_tolerance(name: str) -> None:
    keys, truth, tol = scored_walk(name)
    assert prf(keys, truth, tol)[2] >= 0.7


def test_walk_keyposes_have_mean_f_measure_of_at_least_0_9() -> None:
    assert np.mean([prf(*scored_walk(name))[2] for name in WALKS]) >= 0.9


@pytest.mark.parametrize("trial", [
    pytest.param("07_05", marks=pytest.mark.xfail(
        strict=True, reason="measured: behind the 5 Hz noise filter the AMC take's last "
        "minimum (U 5.50, cut 5.23) is a key and the BVH take's (U 5.53, cut 5.68) is not: "
        "5 keys against 4; the two skeletons' speeds differ by ~8 %")),
    "09_06", "05_11"])
def test_amc_and_bvh_of_one_trial_give_the_same_keyposes_in_file_numbering(trial: str) -> None:
    amc, bvh = offline(trial + ".amc"), offline(trial + ".bvh")
    assert len(amc) == len(bvh)
    # AMC frame i is cgspeed BVH frame i + 1 (the BVH has a reference frame)
    assert np.max(np.abs(amc.frames + 1 - bvh.frames)) <= 5


def _cost(a: np.ndarray, b: np.ndarray, partner: np.ndarray) -> int:
    matched = np.flatnonzero(partner >= 0)
    assert len(matched) == min(len(a), len(b))
    assert np.all(np.diff(partner[matched]) > 0)  # order-preserving, one-to-one
    return int(np.abs(a[matched] - b[partner[matched]]).sum())


def test_windowed_dp_correspondence_is_optimal_when_many_minima_vanish(
        monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(12)
    cases = [(np.sort(rng.choice(300, size=rng.integers(20, 90), replace=False)),
              np.sort(rng.choice(300, size=rng.integers(1, 12), replace=False)))
             for _ in range(200)]
    # lopsided: the short list sits past the long one, so pairs pile up over a few frames
    cases += [(np.sort(rng.choice(100, size=60, replace=False)),
               np.sort(rng.choice(np.arange(80, 160), size=n, replace=False)))
              for n in range(1, 30)]
    monkeypatch.setattr(speed_chains, "BAND_BUDGET", 10**12)  # the full band DP
    full = [_cost(b, a, speed.match_minima(b, a)) for a, b in cases]
    monkeypatch.setattr(speed_chains, "BAND_BUDGET", 0)  # now the windowed DP, certified
    for (a, b), reference in zip(cases, full, strict=True):
        assert _cost(a, b, speed.match_minima(a, b)) == reference
        if len(b) <= 2:
            assert reference == _brute_force_cost(a, b)


# --- online ----------------------------------------------------------------------------------

ALL_CLIPS = clips()
RESULTS = ROOT / "results"


def run_online(m: Motion, **kw: object) -> list[KeyframeEvent]:
    kf = speed.Online(m.skeleton, m.fps, **kw)  # type: ignore[arg-type]
    events = kf.push_block(m.frames()) + kf.flush()
    return [e for e in events if isinstance(e, KeyframeEvent)]


@cache
def online_default(name: str) -> tuple[KeyframeEvent, ...]:
    """Default online keyframer over the clip (one block; equal to frame by frame, see below)."""
    return tuple(run_online(load(name)))


@cache
def frame_by_frame(name: str) -> tuple[Event, ...]:
    m = load(name)
    kf = speed.Online(m.skeleton, m.fps)
    return tuple([e for f in m.frames() for e in kf.push(f)] + kf.flush())


@cache
def agreement() -> list[tuple[str, int, int, float, float, float]]:
    """Per clip: offline count, online count, P, R, F1 of online against offline."""
    rows = []
    for name in ALL_CLIPS:
        off = offline(name).frames
        on = np.array([e.frame for e in online_default(name)])
        tol = float(np.median(np.diff(off))) / 4 if len(off) > 1 else 30.0
        rows.append((name, len(off), len(on), *prf(on, off, tol)))
    return rows


@pytest.mark.slow
@pytest.mark.parametrize("name", ALL_CLIPS)
def test_online_with_unbounded_lookahead_equals_offline(name: str) -> None:
    m = load(name)
    events = run_online(m, lookahead=m.n_frames + 1)
    assert [e.frame for e in events] == offline(name).frames.tolist()
    assert [e.score for e in events] == offline(name).scores.tolist()
    assert all(e.decided_at == m.n_frames - 1 for e in events)
    # with --cut mojena, Ward's clusters are intensity intervals (the cut's premise)
    assert speed.extract(m, cut="mojena").info["contiguous_clusters"]


def test_the_default_lookahead_is_120_frames_and_bounds_every_latency() -> None:
    # The sensor-noise front end holds each frame `delay` frames (14 at 120 Hz); the events'
    # latency bound is the keyframer's lookahead plus that delay.
    for name in ("07_01.bvh", "05_06.bvh", "35_01.amc"):
        m = load(name)
        kf = speed.Online(m.skeleton, m.fps)
        assert kf.lookahead == 120 and kf.features.delay == 14
        events = online_default(name)
        assert events and all(0 <= e.latency_frames <= 120 + 14 for e in events)
        assert {e.lookahead for e in events} == {120 + 14}


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.integers(min_value=1, max_value=150), min_size=1, max_size=8))
def test_push_block_gives_the_same_events_as_pushing_frame_by_frame(sizes: list[int]) -> None:
    m = load("07_05.bvh")
    frames = m.frames()
    kf = speed.Online(m.skeleton, m.fps)
    got, i, j = [], 0, 0
    while i < len(frames):
        n = sizes[j % len(sizes)]
        got += kf.push_block(frames[i : i + n])
        i, j = i + n, j + 1
    got += kf.flush()
    assert tuple(got) == frame_by_frame("07_05.bvh") and len(got) > 0


@pytest.mark.slow
def test_online_agrees_with_offline_on_the_shared_clips_and_writes_the_table() -> None:
    rows = agreement()
    RESULTS.mkdir(exist_ok=True)
    lines = ["# Speed minima: online (default lookahead 120, hop 24) vs offline", "",
             "One-to-one matching within 1/4 of the median offline keypose interval "
             "(Miura's criterion).", "",
             "| clip | offline | online | P | R | F1 |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]
    lines += [f"| {n} | {a} | {b} | {p:.3f} | {r:.3f} | {f:.3f} |" for n, a, b, p, r, f in rows]
    f1 = np.array([row[5] for row in rows])
    lines += ["", f"Mean F1 {f1.mean():.3f}; lowest {f1.min():.3f} "
              f"({', '.join(row[0] for row in rows if row[5] < 0.6) or 'none below 0.6'})."]
    (RESULTS / "agreement_speed.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert f1.mean() >= 0.85


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="measured: lowest F1 0.556 (05_02: online 12 keys, "
                   "offline 6) with the sensor-noise front end on; a calm start gets a low cut")
def test_no_clip_agrees_below_f1_0_6() -> None:
    assert min(row[5] for row in agreement()) >= 0.6


def test_memory_stays_bounded_by_the_window_on_a_long_stream() -> None:
    m = load("01_01.bvh")
    kf = speed.Online(m.skeleton, m.fps, history=600, cutoff_history=900)
    frames = m.frames()[:1800]
    sizes = []
    for i in range(0, len(frames), 250):
        kf.push_block(frames[i : i + 250])
        sizes.append((len(kf._ring), len(kf._ring._rows), len(kf._speeds.v),
                      len(kf._cutoff.values)))
    cap = kf._ring.capacity
    assert cap == 600 + 120 + 24 + 2
    assert all(n <= cap and rows <= 2 * cap and v < cap for n, rows, v, _ in sizes)
    assert max(h for *_, h in sizes) <= 1200  # at most one candidate per frame of history


def test_online_keyframer_pickled_mid_stream_resumes_identically() -> None:
    m = load("06_15.bvh")
    frames = m.frames()
    kf = speed.Online(m.skeleton, m.fps)
    kf.push_block(frames[:300])
    clone = pickle.loads(pickle.dumps(kf))
    assert kf.push_block(frames[300:]) + kf.flush() == clone.push_block(frames[300:]) + \
        clone.flush()


def test_flush_restarts_the_stream_and_a_replay_gives_the_same_events() -> None:
    m = load("07_01.bvh")
    kf = speed.Online(m.skeleton, m.fps)
    first = kf.push_block(m.frames()) + kf.flush()
    assert first and kf.push_block(m.frames()) + kf.flush() == first


@pytest.mark.parametrize("bad", [{"lookahead": 5, "hop": 4}, {"hop": 0}, {"history": -1},
                                 {"lookahead": 12.5}, {"r": 2.0}, {"warmup_candidates": True}])
def test_bad_online_parameters_raise_usage_error(bad: dict[str, object]) -> None:
    m = load("07_01.bvh")
    with pytest.raises(UsageError):
        speed.Online(m.skeleton, m.fps, **bad)  # type: ignore[arg-type]


def test_a_long_gap_flushes_the_window_and_starts_a_new_stream() -> None:
    m = load("07_05.bvh")
    frames = m.frames()
    kf = speed.Online(m.skeleton, m.fps)
    events = kf.push_block(frames[:300]) + kf.push_block(frames[340:]) + kf.flush()
    gaps = [e for e in events if isinstance(e, GapEvent)]
    keys = [e for e in events if isinstance(e, KeyframeEvent)]
    assert len(gaps) == 1 and not gaps[0].bridged and (gaps[0].first, gaps[0].last) == (301, 340)
    before = [e for e in keys if e.frame <= 300]
    assert before and all(e.decided_at <= 300 for e in before)
    assert any(e.frame > 340 for e in keys)
    assert all(e.latency_frames <= kf.lookahead + kf.features.delay for e in keys)


def test_the_analysis_hop_defaults_to_a_fifth_of_the_lookahead() -> None:
    m = load("07_01.bvh")
    assert speed.Online(m.skeleton, m.fps).hop == 24
    assert speed.Online(m.skeleton, m.fps, lookahead=60).hop == 12
    assert speed.Online(m.skeleton, m.fps, lookahead=10).hop == 2
    events = run_online(load("05_06.bvh"), lookahead=60)
    assert events and all(e.latency_frames <= 60 + 14 for e in events)  # + the front end's


def test_1d_ward_gives_scipys_levels_and_mojena_verdict() -> None:
    from scipy.cluster.hierarchy import linkage

    rng = np.random.default_rng(13)
    levels_set = np.array([0.0, 0.3, 1.7, 2.25, 9.5, 40.125, 41.0, 300.5])
    for case in range(150):  # exact duplicates (zeros above all) plus spread values
        u = np.concatenate([rng.choice(levels_set, int(rng.integers(3, 60))),
                            np.abs(rng.standard_cauchy(int(rng.integers(0, 60))))])
        levels = np.sort(linkage(u.reshape(-1, 1), method="ward")[:, 2] ** 2)
        np.testing.assert_allclose(np.sort(speed.ward_1d(u)[0]), levels, rtol=1e-9,
                                   atol=1e-12, err_msg=f"case {case}")
        scipy_way = speed.mojena_threshold(u)
        old, speed_chains.WARD_1D_FROM = speed_chains.WARD_1D_FROM, 0
        try:
            ours = speed.mojena_threshold(u)
        finally:
            speed_chains.WARD_1D_FROM = old
        assert (ours.threshold, ours.n_clusters) == (scipy_way.threshold, scipy_way.n_clusters)


def test_1d_ward_keeps_the_offline_keyposes_on_the_shared_clips_concatenated() -> None:
    from streamkey.bench import long_motion

    motion, _ = long_motion(20_000, DATA)
    feats = compute_features(motion)
    ours = speed.extract(motion, features=feats, cut="mojena")
    assert len(ours.info["candidates"]) >= speed.WARD_1D_FROM  # the 1-D path ran
    old, speed_chains.WARD_1D_FROM = speed_chains.WARD_1D_FROM, 10**9
    try:
        scipy_way = speed.extract(motion, features=feats, cut="mojena")
    finally:
        speed_chains.WARD_1D_FROM = old
    np.testing.assert_array_equal(ours.frames, scipy_way.frames)


def test_the_regular_analysis_is_spread_over_the_frames_after_its_start() -> None:
    """No push runs a whole re-analysis: its six stages (speed and the carried HP forward
    passes; the HP trends of half the scales' lambdas; of the rest and their minima; the
    chains; Ward + Mojena; the warm-up rule and the decisions) run on six different frames of
    the `delay` after the analysis starts."""
    from streamkey.bench import long_motion

    motion, _ = long_motion(3400, DATA)
    kf = speed.Online(motion.skeleton, motion.fps)
    assert (kf.hop, kf.delay) == (24, 16)
    per_push = []
    for frame in motion.frames():
        job = kf._job
        before = job.done if job is not None else None
        kf.push(frame)
        if job is None:
            job = kf._job
            before = 0
        per_push.append(0 if job is None else job.done - before)
    steady = np.array(per_push[2592:3384])  # window full (2,546 frames), 33 whole hops
    assert steady.max() == 1
    stages = len(speed.Online.STAGES)
    assert stages == 6
    assert steady.sum() == 33 * stages
    busy = (steady > 0).reshape(-1, kf.hop).sum(axis=1)
    assert busy.min() == stages


def test_hp_tables_are_shared_between_streams_and_left_out_of_pickles() -> None:
    from streamkey.bench import long_motion

    motion, _ = long_motion(3624, DATA)  # 30 s: the window at full length
    frames = motion.frames()
    a = speed.Online(motion.skeleton, motion.fps)
    b = speed.Online(motion.skeleton, motion.fps, stream="other")
    a.push_block(frames[:3600])
    b.push_block(frames[:3600])
    tables = speed.packed_factors(a._carry.lams)
    assert all(x is y for x, y in zip(tables, speed.packed_factors(b._carry.lams), strict=True))
    clone = pickle.loads(pickle.dumps(a))
    sizes, events = [], []
    for frame in frames[3600:]:  # one hop: every stage of an analysis in flight
        events += a.push(frame)
        sizes.append(len(pickle.dumps(a)))
    # Measured 1.44-1.51 MB (the window's rows, the carried HP forward values); the tables
    # are 2.4 MB.
    assert max(sizes) < 2 * 2**20 and sum(t.nbytes for t in tables) > 2 * 2**20
    assert clone.push_block(frames[3600:]) + clone.flush() == events + a.flush()
    assert speed.packed_factors(clone._carry.lams)[0] is tables[0]


def test_a_keyframer_pickled_between_its_two_trend_stages_resumes_identically() -> None:
    """The first part of the trends lives in derived work rows (pickled empty): a keyframer
    restored between the two trend stages solves every lambda in the second."""
    from streamkey.bench import long_motion

    motion, _ = long_motion(3000, DATA)
    frames = motion.frames()
    kf = speed.Online(motion.skeleton, motion.fps)
    kf.push_block(frames[:2900])
    clones, events = [], []
    for frame in frames[2900:2924]:  # one hop: every stage of an analysis in flight
        events.append(kf.push(frame))
        job = kf._job
        if job is not None and job.done == 2:
            clones.append((len(events), pickle.loads(pickle.dumps(kf))))
    rest = sum(events, []) + [e for f in frames[2924:] for e in kf.push(f)] + kf.flush()
    assert clones
    for at, clone in clones:
        assert clone._job is not None and clone._job.rows.rows is None
        mine = [e for f in frames[2900 + at:] for e in clone.push(f)] + clone.flush()
        assert sum(events[:at], []) + mine == rest
