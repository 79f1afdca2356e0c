"""Multiscale motion saliency (Halit & Capin): offline on real CMU clips, then online."""

from __future__ import annotations

import copy
import pickle
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from streamkey.agreement import Agreement, agreement
from streamkey.amc import read_motion
from streamkey.errors import UsageError
from streamkey.features import Features, compute_features
from streamkey.keyframes import Event, GapEvent, KeyframeEvent, Keyframes
from streamkey.methods import saliency, saliency_math
from streamkey.motion import Frame, Motion
from streamkey.units import Duration
from streamkey.variants import resample

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "cmu"
RESULTS = ROOT / "results"
CLIPS = sorted(p.name for p in DATA.iterdir() if p.suffix in (".bvh", ".amc"))
LOW = {"sigma": 10.0, "k": 7}
FOOT = saliency.FOOT_SIGMA.to_frames(120.0)  # 3 frames at 120 Hz


@cache
def motion(name: str) -> Motion:
    return read_motion(DATA / name)


@cache
def features(name: str) -> Features:
    return compute_features(motion(name))


@cache
def offline(name: str, contact: bool = True) -> Keyframes:
    return saliency.extract(motion(name), contact=contact, features=features(name), **LOW)


def run_online(m: Motion, **kw: object) -> list[KeyframeEvent]:
    kf = saliency.Online(m.skeleton, m.fps, **kw)
    events = kf.push_block(m.frames()) + kf.flush()
    return [e for e in events if isinstance(e, KeyframeEvent)]


@cache
def online_default(name: str) -> tuple[KeyframeEvent, ...]:
    return tuple(run_online(motion(name), **LOW))


# ----------------------------------------------------------------------------- building blocks

def test_curvature_of_a_parabola_is_its_textbook_value() -> None:
    x = np.arange(-20.0, 21.0)
    d = (0.01 * x * x)[:, None]
    c = saliency.curvature(d)[:, 0]
    expected = 0.02 / (1 + (0.02 * x) ** 2) ** 1.5
    assert np.allclose(c[1:-1], expected[1:-1])
    # ends: one-sided first difference, second difference copied from the neighbour
    assert c[0] == pytest.approx(0.02 / (1 + (d[1, 0] - d[0, 0]) ** 2) ** 1.5)


def test_gaussian_means_of_a_constant_are_that_constant_up_to_the_clip_ends() -> None:
    c = np.full((50, 3), 2.5)
    g = saliency.gaussian_means(c, 3.0)
    assert g.shape == (50, 3, 8)
    assert np.allclose(g, 2.5)


def test_itti_normalisation_favours_a_map_with_one_strong_peak() -> None:
    n = 200
    flat = 1.0 + 0.5 * np.sin(np.arange(n) * 0.7)  # many equal peaks
    peaky = np.full(n, 0.1)
    peaky[100] = 1.5
    s = np.zeros((n, 1, 4))
    s[:, 0, 0], s[:, 0, 1], s[:, 0, 2], s[:, 0, 3] = flat, peaky, flat, flat
    a, thr = saliency.normalisation(saliency.map_stats(s))
    assert a[0, 1] * peaky.max() > 10 * a[0, 0] * flat.max()
    assert thr[0] == pytest.approx(float(saliency.combine(s, a).mean()))


def test_maps_cut_at_the_newest_frame_are_the_offline_maps_of_the_clip_ending_there() -> None:
    d = features("07_01.bvh").rotations[:, :7] / 30.0  # seven real curves, feet last
    t, radius = 180, saliency.support_radius(10.0, True, FOOT)
    c = saliency.curvature(d[: t + 1])  # the clip as if it ended at frame t
    assert np.allclose(saliency_math.end_curvature(d[t - 2 : t + 1]), c[-1], rtol=1e-12)
    bank = np.hstack([saliency.kernel_bank(10.0, radius),
                      saliency.kernel_bank(FOOT, radius)])
    foot = np.array([False] * 5 + [True] * 2)
    lo, frames = t - 2 * radius, np.arange(t - radius - 1, t + 1)
    got = saliency_math.truncated_maps(c[max(lo, 0) :], bank, frames - max(lo, 0), foot)
    assert np.allclose(got, saliency.maps_of(c, 10.0, True, FOOT)[frames], rtol=1e-9, atol=1e-15)


@pytest.mark.numeric
def test_compiled_ring_rows_match_the_batch_curves_maps_and_statistics() -> None:
    f = features("05_18.bvh")
    xs = f.rotations - f.rotations[0]
    feet = f.foot_heights / f.body_height
    basis = saliency_math.fit_k(saliency.pca_basis(saliency.moments(xs), 7, False), 7, True)
    d_ref = saliency.curves_of(basis, xs, feet, True)
    c_ref = saliency.curvature(d_ref)
    n, k, R = len(xs), d_ref.shape[1], saliency.support_radius(10.0, True, FOOT)
    d, c = np.zeros((n, k)), np.zeros((n, k))
    keep = basis.keep
    saliency_math.ring_curves(xs, feet, keep, basis.mean[keep], basis.sd[keep],
                              np.ascontiguousarray(basis.vectors[:, :-2]), True, d, c, 0, n,
                              1.0)
    assert np.allclose(d, d_ref, rtol=1e-12, atol=1e-12)
    # the interior rule; rounding in a cancellation near zero is absolute (05_18 at 5 Hz: one
    # curvature of 6.0e-7 off by 2.2e-15), so the floor is on the curves' scale, as for maps
    assert np.allclose(c[1:-1], c_ref[1:-1], rtol=1e-9, atol=1e-12 * np.abs(c_ref).max())
    bank = np.hstack([saliency.kernel_bank(10.0, R), saliency.kernel_bank(FOOT, R)])
    full = bank / bank.sum(axis=0)
    diff = np.hstack([full[:, 0:4] - full[:, 4:8], full[:, 8:12] - full[:, 12:16]])
    cols = np.arange(4)[None, :] + 4 * np.array([0] * (k - 2) + [1, 1])[:, None]
    s, lm = np.zeros((n, k, 4)), np.zeros((n, k, 4), dtype=bool)
    st = saliency.MapStats.empty(k)
    f0, f1 = R + 2, n - R - 1  # rows with whole Gaussian windows
    s[f0 - 2 : f0] = saliency.maps_of(c_ref, 10.0, True, FOOT)[f0 - 2 : f0]
    saliency_math.ring_maps_of(c_ref, s, lm, f0, f1, np.ascontiguousarray(diff),
                               np.ascontiguousarray(cols[:, 0]), st.total, st.top, st.lm_n,
                               st.lm_sum, st.lm_top, np.ones(len(c_ref), dtype=bool))
    ref = saliency.maps_of(c_ref, 10.0, True, FOOT)
    assert np.allclose(s[f0 : f1 + 1], ref[f0 : f1 + 1], rtol=1e-9, atol=1e-12 * ref.max())
    got = s[f0 - 2 : f1 + 1]
    mask = saliency.local_max_mask(got)
    assert np.array_equal(lm[f0 - 1 : f1], mask[1:-1])
    assert np.allclose(st.total, got[2:].sum(axis=0), rtol=1e-12)
    assert np.array_equal(st.top, got[2:].max(axis=0))
    assert np.array_equal(st.lm_n, mask[1:-1].sum(axis=0))
    assert np.array_equal(st.lm_top, np.where(mask, got, 0.0)[1:-1].max(axis=0))


# ----------------------------------------------------------------------------- offline

def test_saliency_selects_3_to_10_percent_on_walk() -> None:
    m = motion("07_01.bvh")
    keys = offline("07_01.bvh")
    captured = m.n_frames - m.first_frame
    assert 0.03 * captured <= len(keys) <= 0.10 * captured
    assert keys.params["sigma"] == 10 and keys.params["k"] == 7


def test_every_cluster_holding_a_foot_candidate_keys_on_a_foot_candidate() -> None:
    keys = offline("07_01.bvh")
    foot = set(keys.info["foot_candidates"].tolist())
    clusters = keys.info["clusters"]
    with_foot = [c for c in clusters if set(range(c["start"], c["end"] + 1)) & foot]
    assert len(with_foot) >= len(clusters) // 2  # a walk: feet are salient most of the time
    for c in with_foot:
        assert c["foot"] and c["keyframe"] in foot
    assert [c["keyframe"] for c in clusters] == keys.frames.tolist()


def test_each_keyframe_is_the_cluster_frame_nearest_the_eigenvalue_weighted_mean() -> None:
    keys = offline("07_01.bvh", False)
    w = keys.info["weights"]
    assert np.all(np.diff(w) <= 0) and len(w) == 7  # eigenvalues, largest first
    for c in keys.info["clusters"]:
        assert c["end"] - c["start"] + 1 <= 20  # at most 2 sigma frames
        frames = np.arange(c["start"], c["end"] + 1)
        # one entry per (frame, curve) on which the frame is a candidate
        weight = np.array([sum(w[j] for j, cand in enumerate(keys.info["candidates"])
                               if f in cand) for f in frames])
        assert np.all(weight > 0)  # a cluster is a run of candidates
        mean = float((weight * frames).sum() / weight.sum())
        assert abs(c["keyframe"] - mean) == pytest.approx(np.abs(frames - mean).min())


def test_turning_contact_handling_off_changes_the_keyframes() -> None:
    on, off = offline("07_01.bvh", True), offline("07_01.bvh", False)
    assert not np.array_equal(on.frames, off.frames)
    assert off.info["foot_candidates"].size == 0
    assert "left_foot" in on.info["curve_kinds"] and "left_foot" not in off.info["curve_kinds"]


@pytest.mark.slow
@pytest.mark.parametrize("name", CLIPS)
def test_saliency_returns_sorted_captured_frames_on_every_shared_clip(name: str) -> None:
    m = motion(name)
    keys = saliency.extract(m, features=features(name))
    assert len(keys) > 0
    assert np.all(np.diff(keys.frames) > 0)
    assert keys.frames[0] >= m.first_frame and keys.frames[-1] < m.n_frames
    assert np.all(np.isfinite(keys.scores)) and np.all(keys.scores > 0)
    assert keys.params["preset"] in ("low", "high")
    assert keys.info["preset_requested"] == "auto" and keys.info["auto_speed"] > 0


def test_auto_preset_picks_high_dynamic_for_a_run_and_low_for_a_walk() -> None:
    run = saliency.extract(motion("09_01.bvh"))
    walk = saliency.extract(motion("07_05.bvh"))
    assert (run.params["preset"], run.params["sigma"], run.params["k"]) == ("high", 3.0, 10)
    assert (walk.params["preset"], walk.params["sigma"], walk.params["k"]) == ("low", 10.0, 7)
    assert run.info["auto_speed"] >= saliency.AUTO_SPEED_THRESHOLD > walk.info["auto_speed"]


def test_variance_rule_keeps_at_least_7_components_and_90_percent() -> None:
    keys = saliency.extract(motion("05_18.bvh"), preset="low", variance_rule=True)
    assert keys.params["k_used"] >= 7
    assert keys.info["explained_variance"] >= 0.9
    assert keys.params["k_used"] > saliency.extract(motion("05_18.bvh"), **LOW).params["k_used"]


def test_saliency_is_deterministic_and_leaves_its_input_alone() -> None:
    m = motion("06_08.bvh")
    before = copy.deepcopy(m.channels)
    a = saliency.extract(m, preset="high")
    b = saliency.extract(m, preset="high")
    assert np.array_equal(a.frames, b.frames) and np.array_equal(a.scores, b.scores)
    assert np.array_equal(m.channels, before)


@pytest.mark.parametrize("kwargs", [{"sigma": 0}, {"sigma": float("nan")}, {"k": 0},
                                    {"k": 2.5}, {"preset": "medium"}, {"k": 2, "contact": True}])
def test_bad_parameters_raise_usage_error(kwargs: dict[str, object]) -> None:
    with pytest.raises(UsageError):
        saliency.extract(motion("07_01.bvh"), **kwargs)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------- online

@pytest.mark.slow
def test_online_with_unbounded_lookahead_equals_offline_on_every_shared_clip() -> None:
    high = [c for c in CLIPS if c.endswith(".amc")] + ["07_01.bvh", "09_06.bvh", "06_08.bvh"]
    for name in CLIPS:
        m = motion(name)
        for kw in (LOW, {"preset": "high"}) if name in high else (LOW,):
            off = saliency.extract(m, features=features(name), **kw)  # type: ignore[arg-type]
            events = run_online(m, lookahead=m.n_frames + 1, **kw)
            assert [e.frame for e in events] == off.frames.tolist(), (name, kw)
            assert np.allclose([e.score for e in events], off.scores, rtol=1e-9), (name, kw)
            assert all(e.decided_at == m.n_frames - 1 for e in events)


@pytest.mark.parametrize("kw", [{"sigma": 10.0, "k": 7, "variance_rule": True},
                                {"sigma": 10.0, "k": 7, "contact": False},
                                {"preset": "high", "variance_rule": True, "contact": False}])
def test_online_equals_offline_with_the_variance_rule_and_without_contact(
        kw: dict[str, object]) -> None:
    for name in ("05_18.bvh", "49_18.amc"):
        m = motion(name)
        off = saliency.extract(m, features=features(name), **kw)  # type: ignore[arg-type]
        events = run_online(m, lookahead=m.n_frames + 1, **kw)
        assert [e.frame for e in events] == off.frames.tolist(), (name, kw)


def test_online_keyframer_pickled_mid_stream_resumes_identically() -> None:
    m = motion("06_08.bvh")
    frames = m.frames()
    kf = saliency.Online(m.skeleton, m.fps, preset="high")
    head = kf.push_block(frames[:200])
    clone = pickle.loads(pickle.dumps(kf))
    assert kf.push_block(frames[200:]) + kf.flush() == clone.push_block(frames[200:]) + \
        clone.flush()
    assert head


def test_a_long_gap_flushes_the_window_and_starts_a_new_stream() -> None:
    m = motion("07_05.bvh")
    frames = m.frames()
    kf = saliency.Online(m.skeleton, m.fps, preset="high")
    events = kf.push_block(frames[:250]) + kf.push_block(frames[300:]) + kf.flush()
    gaps = [e for e in events if isinstance(e, GapEvent)]
    keys = [e for e in events if isinstance(e, KeyframeEvent)]
    assert len(gaps) == 1 and not gaps[0].bridged and (gaps[0].first, gaps[0].last) == (251, 300)
    before = [e for e in keys if e.frame <= 250]
    assert before and before[-1].decided_at == 250
    assert any(e.frame > 300 for e in keys)
    # the bound: the keyframer's lookahead plus the frames the noise filter holds
    assert all(e.latency_frames <= e.lookahead == kf.lookahead + kf.features.delay
               for e in keys)


def test_a_periodic_basis_update_is_spread_and_applies_spread_frames_later() -> None:
    m = motion("01_01.bvh")  # 2751 frames: the window (300) moves on, updates every 400
    kw = {**LOW, "history": 300, "update_every": 400}
    kf = saliency.Online(m.skeleton, m.fps, **kw)  # type: ignore[arg-type]
    starts, switches, events = [], [], []
    basis = None
    for i, frame in enumerate(m.frames()):
        spreading = kf.spread is not None
        events += kf.push(frame)
        if kf.spread is not None and not spreading:
            starts.append(i)
        if kf.basis is not basis and basis is not None and spreading:
            switches.append(i)
        basis = kf.basis
    events += kf.flush()
    assert len(starts) >= 4 and switches == [u + kf.setup.spread for u in starts]
    block = saliency.Online(m.skeleton, m.fps, **kw)  # type: ignore[arg-type]
    frames = m.frames()
    split = block.push_block(frames[:1000]) + block.push_block(frames[1000:2013])
    assert split + block.push_block(frames[2013:]) + block.flush() == events


@pytest.mark.parametrize(("fps", "spread"), [(30.0, 10), (60.0, 12), (120.0, 24), (240.0, 48)])
def test_a_periodic_basis_update_applies_a_fifth_of_a_second_later_at_any_rate(
        fps: float, spread: int) -> None:
    """The spread is a duration (0.2 s, at least 10 frames for its pieces): at 30 Hz a new
    basis used to apply 24 frames (0.8 s) after it was due."""
    m = resample(motion("01_01.bvh"), fps).motion
    kw = {"sigma": Duration.seconds(1 / 12), "k": 7, "history": Duration.seconds(2.5),
          "update_every": Duration.seconds(10 / 3)}
    kf = saliency.Online(m.skeleton, m.fps, **kw)  # type: ignore[arg-type]
    assert kf.setup.spread == spread
    starts, switches, basis = [], [], None
    for i, frame in enumerate(m.frames()):
        spreading = kf.spread is not None
        kf.push(frame)
        if kf.spread is not None and not spreading:
            starts.append(i)
        if kf.basis is not basis and basis is not None and spreading:
            switches.append(i)
        basis = kf.basis
    assert len(starts) >= 4 and switches == [u + spread for u in starts]


@cache
def frame_by_frame(name: str) -> tuple[Event, ...]:
    m = motion(name)
    kf = saliency.Online(m.skeleton, m.fps, sigma=3.0)
    return tuple([e for f in m.frames() for e in kf.push(f)] + kf.flush())


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.integers(min_value=1, max_value=120), min_size=1, max_size=8))
def test_push_block_gives_the_same_events_as_pushing_frame_by_frame(sizes: list[int]) -> None:
    m = motion("07_01.bvh")
    frames = m.frames()
    expected = list(frame_by_frame("07_01.bvh"))
    blocks = saliency.Online(m.skeleton, m.fps, sigma=3.0)
    got, i, j = [], 0, 0
    while i < len(frames):
        n = sizes[j % len(sizes)]
        got += blocks.push_block(frames[i : i + n])
        i, j = i + n, j + 1
    got += blocks.flush()
    assert got == expected and len(expected) > 0


def test_online_rejects_auto_preset_and_a_lookahead_below_one_frame() -> None:
    m = motion("07_01.bvh")
    with pytest.raises(UsageError):
        saliency.Online(m.skeleton, m.fps, preset="auto")
    kf = saliency.Online(m.skeleton, m.fps, sigma=10.0)
    assert kf.lookahead == kf.min_lookahead == 121  # the default is the support
    assert saliency.Online(m.skeleton, m.fps, preset="high").lookahead == 37
    for bad in (0, -5, 2.5, True):
        with pytest.raises(UsageError):
            saliency.Online(m.skeleton, m.fps, sigma=10.0, lookahead=bad)  # type: ignore[arg-type]
    assert saliency.Online(m.skeleton, m.fps, sigma=10.0, lookahead=1).lookahead == 1


def delay(m: Motion) -> int:
    """Frames the default noise filter holds each frame at the clip's rate."""
    return saliency.Online(m.skeleton, m.fps).features.delay


@pytest.mark.parametrize("name", ["07_01.bvh", "09_06.bvh", "06_08.bvh", "07_05.amc"])
def test_every_online_event_is_within_a_lookahead_shorter_than_the_support(name: str) -> None:
    m = motion(name)
    for lookahead in (10, 30, 60):
        events = run_online(m, lookahead=lookahead, **LOW)
        assert events, (name, lookahead)
        bound = lookahead + delay(m)  # the noise filter's frames are in every latency
        assert all(e.lookahead == bound for e in events)
        assert 0 <= min(e.latency_frames for e in events)
        assert max(e.latency_frames for e in events) <= bound, (name, lookahead)
        frames = [e.frame for e in events]
        assert frames == sorted(set(frames)) and frames[0] >= m.first_frame


def test_push_block_gives_the_same_events_as_push_at_a_lookahead_below_the_support() -> None:
    m = motion("07_05.amc")
    frames = m.frames()
    one = saliency.Online(m.skeleton, m.fps, lookahead=30, **LOW)
    expected = [e for f in frames for e in one.push(f)] + one.flush()
    blocks = saliency.Online(m.skeleton, m.fps, lookahead=30, **LOW)
    got, i = [], 0
    for n in (1, 29, 2, 61, 130, 7, 500):  # blocks across basis updates and decisions
        got += blocks.push_block(frames[i : i + n])
        i += n
    got += blocks.flush()
    assert got == expected and len(expected) > 10


@pytest.mark.slow
def test_every_online_event_is_within_the_default_lookahead() -> None:
    for name in CLIPS:
        events = online_default(name)
        assert events, name
        bound = 121 + delay(motion(name))
        assert max(e.latency_frames for e in events) <= events[0].lookahead == bound
        assert min(e.latency_frames for e in events) >= 0
        frames = [e.frame for e in events]
        assert frames == sorted(set(frames))


def test_online_memory_stays_bounded_on_a_long_stream() -> None:
    m = motion("07_01.bvh")
    kf = saliency.Online(m.skeleton, m.fps, preset="high")
    caps, n_events = [], 0
    n = m.n_frames - m.first_frame
    for loop in range(25):  # ~7,900 frames with consecutive seq numbers: one long stream
        frames = [Frame(f.seq + loop * n, f.time + loop * n / m.fps, f.channels)
                  for f in m.frames()]
        n_events += len(kf.push_block(frames))
        caps.append(kf.cap)
    assert n_events > 0
    assert max(caps) <= 4 * kf.window and caps[-1] == caps[-10]  # steady after ~5,000 frames


@cache
def _agreements(lookahead: int) -> tuple[Agreement, ...]:
    """One-to-one agreement within sigma frames, per shared clip (streamkey.agreement)."""
    return tuple(agreement(motion(name), "saliency", lookahead, offline(name), **LOW)
                 for name in CLIPS)


def _agreement_rows(lookahead: int = 121
                    ) -> tuple[tuple[str, int, int, float, float, float], ...]:
    return tuple((name, a.offline, a.online, a.precision, a.recall, a.f1)
                 for name, a in zip(CLIPS, _agreements(lookahead), strict=True))


def _table(rows: tuple[tuple[str, int, int, float, float, float], ...], lookahead: int
           ) -> list[str]:
    f1 = np.array([r[5] for r in rows])
    lines = [f"## Lookahead {lookahead} frames", "",
             "| clip | offline | online | P | R | F1 |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]
    lines += [f"| {n} | {a} | {b} | {p:.3f} | {r:.3f} | {f:.3f} |" for n, a, b, p, r, f in rows]
    return lines + ["", f"Mean F1 {f1.mean():.3f}, lowest {f1.min():.3f} "
                    f"({rows[int(f1.argmin())][0]}).", ""]


@pytest.mark.slow
def test_online_agreement_table_is_written_for_every_shared_clip() -> None:
    lines = ["# Saliency: online vs offline keyframes, sigma = 10, k = 7, contact on", "",
             "One-to-one matching within sigma = 10 frames; P = matched / online, "
             "R = matched / offline. 121 frames is the default lookahead (the support).", ""]
    lines += _table(_agreement_rows(), 121) + _table(_agreement_rows(240), 240)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "agreement_saliency.md").write_text("\n".join(lines), encoding="utf-8")
    assert len(_agreement_rows()) == len(CLIPS)
    assert all(r[5] > 0.5 for r in _agreement_rows() + _agreement_rows(240))


@pytest.mark.slow
def test_online_agreement_meets_the_f1_targets_at_the_default_lookahead() -> None:
    f1 = np.array([r[5] for r in _agreement_rows()])
    assert f1.mean() >= 0.92 and f1.min() >= 0.80


@pytest.mark.slow
def test_online_agreement_meets_the_f1_targets_at_twice_the_support() -> None:
    f1 = np.array([r[5] for r in _agreement_rows(240)])
    assert f1.mean() >= 0.92 and f1.min() >= 0.80


@pytest.mark.slow
def test_online_agreement_against_lookahead_is_measured_and_written() -> None:
    lookaheads = (30, 60, 121, 240)
    lines = ["# Saliency: online vs offline agreement against lookahead", "",
             "sigma = 10, k = 7, contact on; one-to-one matching within sigma = 10 frames "
             "(`streamkey.agreement.agreement`), over every shared clip. 121 frames is the "
             "support and the default; below it, frames are decided from Gaussian windows cut "
             "at the newest frame.", "",
             "| lookahead (frames) | mean F1 | lowest F1 | lowest clip | max latency |",
             "| ---: | ---: | ---: | --- | ---: |"]
    mean = {}
    for lookahead in lookaheads:
        rows = _agreements(lookahead)
        f1 = np.array([a.f1 for a in rows])
        mean[lookahead] = float(f1.mean())
        worst = max(a.max_latency for a in rows)
        assert worst <= lookahead + delay(motion(CLIPS[0]))  # the noise filter's frames too
        lines.append(f"| {lookahead} | {f1.mean():.3f} | {f1.min():.3f} | "
                     f"{CLIPS[int(f1.argmin())]} | {worst} |")
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "agreement_saliency_lookahead.md").write_text("\n".join(lines) + "\n",
                                                             encoding="utf-8")
    assert mean[60] >= 0.5  # a measurement; F1 must not collapse below the support


def test_online_saliency_exposes_a_bounded_per_frame_trace_for_live_views() -> None:
    m = motion("07_01.bvh")
    kf = saliency.Online(m.skeleton, m.fps, sigma=10, k=7)
    for f in m.frames():
        kf.push(f)
    seqs = [seq for seq, _ in kf.trace]
    assert seqs == list(range(m.first_frame, m.first_frame + len(seqs)))
    assert m.n_frames - 1 - kf.lookahead <= seqs[-1] < m.n_frames - 1  # it trails the stream
    values = np.array([v for _, v in kf.trace])
    assert np.all(np.isfinite(values)) and values.max() > 1.0
    assert kf.trace.maxlen == saliency.TRACE_FRAMES
