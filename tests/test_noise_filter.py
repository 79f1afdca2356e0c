"""The sensor-noise front end: the filter's facts, online = offline through it, and what it
buys on noisy takes of the shared clips."""

from __future__ import annotations

import pickle
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from cmu import DATA

from streamkey import variants as V
from streamkey.amc import read_motion
from streamkey.features import compute_features
from streamkey.filters import (
    RECOMMENDED_NOISE_CUTOFF_HZ,
    FrontEnd,
    LowPass,
    frequency_response,
    gaussian_sigma,
    lowpass_kernel,
    smooth,
)
from streamkey.keyframes import KeyframeEvent, Keyframes
from streamkey.methods import offline_method, saliency, simplify, speed
from streamkey.methods import optimal as optimal_method
from streamkey.motion import Frame, Motion
from streamkey.online import OnlineKeyframer, Pipeline

FC = RECOMMENDED_NOISE_CUTOFF_HZ


@cache
def motion(name: str) -> Motion:
    return read_motion(DATA / name)


# --- the filter --------------------------------------------------------------------------

@pytest.mark.parametrize("fps", [120.0, 60.0, 30.0])
def test_the_gain_is_half_at_the_cut_off_and_the_delay_follows_the_rate(fps: float) -> None:
    taps = lowpass_kernel(FC, fps)
    h = (len(taps) - 1) // 2
    assert np.all(taps > 0) and np.array_equal(taps, taps[::-1])
    assert abs(taps.sum() - 1.0) < 1e-12
    assert h == int(np.ceil(3.0 * gaussian_sigma(FC, fps)))
    # about the same time span at every rate: 14, 7, 4 frames = 117, 117, 133 ms
    assert h == {120.0: 14, 60.0: 7, 30.0: 4}[fps]
    gain = frequency_response(taps, np.array([0.0, 1.0, FC, 15.0]), fps)
    assert gain[0] == pytest.approx(1.0, abs=1e-12)
    assert gain[1] > 0.97  # movement passes
    assert gain[2] == pytest.approx(0.5, abs=0.005)  # 50 % at the cut-off
    f = np.linspace(0.0, fps / 2, 400)
    full = frequency_response(taps, f, fps)
    low = full < 0.01  # where the Gaussian's own gain falls below 1 % (not at 30 Hz)
    band = int(np.argmax(low)) if low.any() else len(full)
    assert np.all(np.diff(full[: band + 1]) < 0)  # monotone: no overshoot, no ringing
    assert np.all(np.abs(full[band:]) < 0.01)  # truncating the taps leaves < 1 % ripple
    if fps == 120.0:
        assert gain[3] < 0.02  # noise at 15 Hz: -34 dB


def test_the_taps_are_the_discrete_gaussian_whose_response_is_known_in_closed_form() -> None:
    fps = 120.0
    taps = lowpass_kernel(FC, fps)
    t = gaussian_sigma(FC, fps) ** 2
    f = np.linspace(0.0, 60.0, 121)
    exact = np.exp(t * (np.cos(2 * np.pi * f / fps) - 1.0))  # Lindeberg's, untruncated
    assert np.max(np.abs(frequency_response(taps, f, fps) - exact)) < 0.005


def test_the_filter_has_no_phase_a_ramp_passes_and_a_sine_is_not_shifted() -> None:
    fps = 120.0
    n = np.arange(600)
    ramp = smooth(0.3 * n, FC, fps)
    h = (len(lowpass_kernel(FC, fps)) - 1) // 2
    np.testing.assert_allclose(ramp[h:-h], 0.3 * n[h:-h], atol=1e-9)
    x = np.sin(2 * np.pi * 2.0 * n / fps)
    y = smooth(x, FC, fps)
    lags = list(range(-5, 6))
    corr = [float(np.dot(x[50:-50], np.roll(y, k)[50:-50])) for k in lags]
    assert lags[int(np.argmax(corr))] == 0


def test_noise_shrinks_by_the_tap_energy_and_its_second_difference_by_far_more() -> None:
    rng = np.random.default_rng(1)
    noise = rng.normal(0.0, 1.0, (20000, 4))
    out = smooth(noise, FC, 120.0)
    taps = lowpass_kernel(FC, 120.0)
    assert np.std(out) == pytest.approx(np.sqrt(np.sum(taps**2)), rel=0.05)  # ~0.27
    acc = np.std(np.diff(out, 2, axis=0)) / np.std(np.diff(noise, 2, axis=0))
    assert acc < 0.01


def test_any_split_into_blocks_gives_the_same_bits_edges_included() -> None:
    rng = np.random.default_rng(2)
    for n in (1, 5, 12, 25, 300):
        x = rng.normal(size=(n, 3)).cumsum(axis=0)
        whole = smooth(x, FC, 120.0)
        lp = LowPass(lowpass_kernel(FC, 120.0))
        parts, i = [], 0
        for k in (1, 2, 7, 1, 40, 1000):
            parts.append(lp.push(x[i : i + k]))
            i += k
        assert lp.pending == min(n, (len(lp.taps) - 1) // 2)
        parts.append(lp.drain())
        assert lp.pending == 0
        got = np.concatenate([p.reshape(-1, 3) for p in parts])
        assert np.array_equal(got, whole), n


@pytest.mark.parametrize("order", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"])
def test_joint_quaternions_and_angles_are_scipys_rotations_both_ways(order: str) -> None:
    from scipy.spatial.transform import Rotation

    from streamkey.filters import joint_angles, joint_quaternions

    rng = np.random.default_rng(3)
    angles = rng.uniform(-179.0, 179.0, (500, 3))
    angles[:3, 1] = [90.0, -90.0, 89.99999]  # gimbal lock and near it
    axes = np.array([["XYZ".index(a) for a in order]])
    q = np.empty((500, 4))
    joint_quaternions(angles, np.array([[0, 1, 2]]), axes, np.full((1, 4), 2.0), q)
    want = Rotation.from_euler(order, angles, degrees=True).as_quat()[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(np.abs(np.sum(q * want, axis=1)), 1.0, atol=1e-12)
    assert np.all(np.sum(q[1:] * q[:-1], axis=1) >= 0)  # one side of the sphere
    back = np.empty((500, 3))
    joint_angles(q, axes, angles, np.array([[0, 1, 2]]), back)
    np.testing.assert_allclose(back[3:], angles[3:], atol=1e-8)  # the same triple
    np.testing.assert_allclose(Rotation.from_euler(order, back, degrees=True).as_matrix(),
                               Rotation.from_euler(order, angles, degrees=True).as_matrix(),
                               atol=1e-7)


def test_an_euler_flip_in_the_data_changes_no_filtered_pose() -> None:
    """(a, b, c) -> (a + 180, 180 - b, c + 180) is the same rotation: filtering the
    quaternion, the filtered positions do not see it (averaging angles would bend the leg)."""
    m = motion("07_01.bvh")
    j = m.skeleton.index("RightUpLeg")
    cols = [m.skeleton.channel_index(j, c) for c in m.skeleton.rotation_order[j]]
    flipped = m.channels.copy()
    flipped[150:, cols[0]] += 180.0
    flipped[150:, cols[1]] = 180.0 - flipped[150:, cols[1]]
    flipped[150:, cols[2]] += 180.0
    other = Motion(m.skeleton, flipped, m.fps, m.first_frame, m.name)
    a, b = compute_features(m, noise_cutoff_hz=FC), compute_features(other, noise_cutoff_hz=FC)
    assert np.max(np.abs(a.fk.positions - b.fk.positions)) < 1e-9 * a.body_height
    # unfiltered, the raw poses are the same too; the angles are not
    raw = compute_features(other, noise_cutoff_hz=None)
    assert np.max(np.abs(raw.fk.positions - compute_features(m, noise_cutoff_hz=None)
                         .fk.positions)) < 1e-9 * a.body_height


def test_off_is_the_raw_channels_and_no_delay() -> None:
    m = motion("07_01.bvh")
    front = FrontEnd(m.skeleton, m.fps, None)
    assert front.delay == 0
    f = compute_features(m, noise_cutoff_hz=None)
    assert f.motion is m and f.noise_cutoff_hz is None
    assert compute_features(m, noise_cutoff_hz=0).motion is m
    on = compute_features(m, noise_cutoff_hz=FC)
    assert on.noise_cutoff_hz == FC
    first = m.first_frame
    assert np.array_equal(on.motion.channels[:first], m.channels[:first])  # reference pose
    rot = m.skeleton.rotation_columns()
    assert np.array_equal(on.motion.channels[first:, rot], on.rotations[first:])
    assert np.percentile(np.abs(on.rotations[first:] - f.rotations[first:]), 99) < 5.0  # 3.3


# --- online = offline ---------------------------------------------------------------------

def _events(kf: object, frames: list[Frame]) -> list[KeyframeEvent]:
    out = []
    for f in frames:
        out += kf.push(f)  # type: ignore[attr-defined]
    out += kf.flush()  # type: ignore[attr-defined]
    return [e for e in out if isinstance(e, KeyframeEvent)]


def _filtered(kf: OnlineKeyframer) -> OnlineKeyframer:
    """`kf` with its own feature stage filtering at `FC` (as a pipeline at `FC` sets it)."""
    kf.features.configure(FC)
    return kf


def _online(method: str, m: Motion) -> OnlineKeyframer:
    n = m.n_frames + 1
    if method == "saliency":
        return _filtered(saliency.Online(m.skeleton, m.fps, lookahead=n, preset="low"))
    if method == "speed":
        return _filtered(speed.Online(m.skeleton, m.fps, lookahead=n))
    if method == "simplify":
        return _filtered(simplify.Online(m.skeleton, m.fps, lookahead=n))
    return _filtered(optimal_method.Online(m.skeleton, m.fps, lookahead=n))


def _offline(method: str, m: Motion, cutoff: float | None = FC) -> Keyframes:
    if method == "saliency":
        return saliency.extract(m, preset="low", noise_cutoff_hz=cutoff)
    return offline_method(method)(m, noise_cutoff_hz=cutoff)  # type: ignore[no-any-return]


@pytest.mark.parametrize("method", ["saliency", "speed", "simplify", "optimal"])
@pytest.mark.parametrize("name", ["07_01.bvh", "05_11.amc"])
def test_online_equals_offline_with_the_filter_at_unbounded_lookahead(method: str,
                                                                      name: str) -> None:
    m = motion(name)
    kf = _online(method, m)
    assert kf.features.delay == 14  # type: ignore[attr-defined]
    events = _events(kf, m.frames())
    keys = _offline(method, m)
    off = keys.frames
    assert [e.frame for e in events] == off.tolist() and len(off) > 1
    last = m.n_frames - 1
    assert all(0 <= e.latency_frames <= e.lookahead and e.decided_at <= last for e in events)
    assert all(e.lookahead == kf.lookahead + 14 for e in events)  # type: ignore[attr-defined]
    # and the filter is what the offline keys went through: off, they differ (simplify's
    # frames on 07_01 stay on the same dyadic grid frames; their scores differ)
    plain = _offline(method, m, None)
    assert (plain.frames.tolist(), plain.scores.tolist()) != (off.tolist(), keys.scores.tolist())


@pytest.mark.parametrize("method", ["saliency", "speed", "simplify", "optimal"])
def test_the_default_is_the_filter_and_online_equals_offline_through_it(method: str) -> None:
    """Nothing asked: the library, `make_keyframers`, a `Pipeline` and the CLI's parameters
    all filter at the default cut-off, and the online keys at unbounded lookahead are the
    offline keys, each event's latency bound counting the filter's delay."""
    import argparse

    from streamkey.batch import extract_motion
    from streamkey.cli.options import method_params
    from streamkey.filters import DEFAULT_NOISE_CUTOFF_HZ
    from streamkey.streaming import make_keyframers

    assert DEFAULT_NOISE_CUTOFF_HZ == FC
    m = motion("07_01.bvh")
    n = m.n_frames + 1
    own = {"saliency": {"preset": "low"}} if method == "saliency" else {}
    cli = method_params(argparse.Namespace(method=method), online=True)
    assert cli["*"]["noise_cutoff_hz"] == FC
    off = extract_motion(m, [method], own)[method]
    assert off.frames.tolist() == _offline(method, m).frames.tolist()
    for params in (own, {**cli, **own}):
        kfs = make_keyframers(m, [method], params, lookahead=n)
        pipe = Pipeline(kfs)
        assert pipe.delay == 14 and kfs[0].features.noise_cutoff_hz == FC
        events = _events(pipe, m.frames())
        assert [e.frame for e in events] == off.frames.tolist() and len(events) > 1
        assert all(e.lookahead == kfs[0].lookahead + 14 for e in events)
        assert all(0 <= e.latency_frames <= e.lookahead for e in events)


def test_zero_turns_the_filter_off_everywhere() -> None:
    import argparse

    from streamkey.batch import extract_motion
    from streamkey.cli.options import method_params
    from streamkey.streaming import make_keyframers

    m = motion("07_01.bvh")
    cli = method_params(argparse.Namespace(method="speed", noise_cutoff=0.0), online=True)
    assert cli["*"]["noise_cutoff_hz"] is None
    off = extract_motion(m, ["speed"], cli)["speed"]
    assert off.frames.tolist() == speed.extract(m, noise_cutoff_hz=None).frames.tolist()
    for params in (cli, {"*": {"noise_cutoff_hz": 0}}):
        pipe = Pipeline(make_keyframers(m, ["speed"], params, lookahead=m.n_frames + 1))
        assert pipe.delay == 0 and pipe.features.noise_cutoff_hz is None
        assert [e.frame for e in _events(pipe, m.frames())] == off.frames.tolist()


def test_decisions_are_dated_by_the_arrival_that_made_them() -> None:
    m = motion("07_01.bvh")
    kf = _filtered(speed.Online(m.skeleton, m.fps))
    h = kf.features.delay
    frames = m.frames()
    seen = []
    for f in frames:
        for e in kf.push(f):
            if isinstance(e, KeyframeEvent):
                assert e.decided_at == f.seq  # decided by this frame's arrival
                assert 0 <= e.latency_frames <= e.lookahead == kf.lookahead + h
                seen.append(e)
    tail = [e for e in kf.flush() if isinstance(e, KeyframeEvent)]
    assert seen and all(e.decided_at == frames[-1].seq for e in tail)


def test_a_pipeline_sets_the_cut_off_and_off_is_the_raw_keyframers() -> None:
    m = motion("07_01.bvh")
    n = m.n_frames + 1
    raw = Pipeline([speed.Online(m.skeleton, m.fps, lookahead=n)], noise_cutoff_hz=None)
    assert raw.delay == 0
    got = [e for e in raw.push_block(m.frames()) + raw.flush() if isinstance(e, KeyframeEvent)]
    assert [e.frame for e in got] == speed.extract(m, noise_cutoff_hz=None).frames.tolist()
    slow = Pipeline([speed.Online(m.skeleton, m.fps, lookahead=n)], noise_cutoff_hz=3.0)
    assert slow.delay == 23  # half the cut-off: twice the half-width (ceil 3 sigma)
    got = [e for e in slow.push_block(m.frames()) + slow.flush()
           if isinstance(e, KeyframeEvent)]
    assert [e.frame for e in got] == speed.extract(m, noise_cutoff_hz=3.0).frames.tolist()


def test_a_long_gap_ends_the_filter_window_as_a_clip_ends() -> None:
    """Each side of a hole too long to bridge is filtered as a clip of its own (its ends
    repeated), the unwrap state carried over the hole."""
    from streamkey.online import FeatureStage

    m = motion("07_01.bvh")
    frames = m.frames()
    stage = FeatureStage(m.skeleton, m.fps, noise_cutoff_hz=FC)
    a = [stage.compute(frames[:150]), stage.drain()]
    stage.restart()
    b = [stage.compute(frames[180:]), stage.drain()]
    for parts, lo, hi in ((a, 1, 151), (b, 181, m.n_frames)):
        piece = Motion(m.skeleton, m.channels[lo:hi], m.fps, 0, m.name)
        want = compute_features(piece, noise_cutoff_hz=FC)
        got = np.concatenate([p.positions for p in parts])
        assert np.concatenate([p.seq for p in parts]).tolist() == list(range(lo, hi))
        np.testing.assert_allclose(got, want.fk.positions, rtol=0, atol=1e-9)


def test_a_flush_before_any_frame_and_a_second_flush_give_nothing() -> None:
    m = motion("07_01.bvh")
    for kf in (_filtered(speed.Online(m.skeleton, m.fps)),
               Pipeline([simplify.Online(m.skeleton, m.fps)], noise_cutoff_hz=FC)):
        assert kf.flush() == []
        kf.push(m.frames()[0])
        kf.flush()
        assert kf.flush() == []


def test_a_pipeline_pickled_inside_the_filter_delay_resumes_identically() -> None:
    m = motion("07_01.bvh")
    frames = m.frames()

    def pipe() -> Pipeline:
        return Pipeline([speed.Online(m.skeleton, m.fps), simplify.Online(m.skeleton, m.fps)],
                        noise_cutoff_hz=FC)

    p = pipe()
    whole = [e for f in frames for e in p.push(f)] + p.flush()
    for cut in (5, 150):
        q = pipe()
        head = [e for f in frames[:cut] for e in q.push(f)]
        clone = pickle.loads(pickle.dumps(q))
        rest = [e for f in frames[cut:] for e in clone.push(f)] + clone.flush()
        assert head + rest == whole, cut


# --- noisy takes ----------------------------------------------------------------------------

# A walk, a run, a jump, a dance (AMC) and a slow take (AMC), all filtered.
NOISE_CLIPS = ["07_01.bvh", "16_11.bvh", "02_01.bvh", "05_11.amc", "49_18.amc"]


@cache
def noisy_agreement(method: str, name: str, degrees: float) -> tuple[float, float]:
    """(key count ratio, F1) of the take with noise against the clean take, offline."""
    m = motion(name)
    clean = V.clean_take(m)
    variant = V.with_noise(m, degrees)
    extract = offline_method(method)
    ck = extract(clean.motion, noise_cutoff_hz=FC).frames
    vk = V.keys_in_take(variant, extract(variant.motion, noise_cutoff_hz=FC).frames)
    return len(vk) / max(1, len(ck)), V.f1_against(ck, vk, clean.motion.fps)


def _unmet(reason: str) -> pytest.MarkDecorator:
    return pytest.mark.xfail(strict=True, reason=f"measured at 0.3 degrees, filter on: {reason}")


@pytest.mark.slow
@pytest.mark.parametrize("method", [
    "saliency",
    pytest.param("speed", marks=_unmet("49_18.amc 2.18x (its 11 clean keys are fragile); "
                                       "1.0, 1.0, 1.17, 1.0 on the others")),
    "simplify", "optimal"])
def test_with_the_filter_0_3_degrees_of_noise_keeps_the_key_count(method: str) -> None:
    ratios = [noisy_agreement(method, name, 0.3)[0] for name in NOISE_CLIPS]
    assert all(0.8 <= r <= 1.25 for r in ratios), ratios


@pytest.mark.slow
@pytest.mark.parametrize("method", [
    "saliency",  # met since its columns are standardised above a noise floor
    pytest.param("speed", marks=_unmet("F1 1.0, 1.0, 0.92, 1.0, 0.46 (mean 0.88): 49_18.amc")),
])
def test_with_the_filter_0_3_degrees_of_noise_keeps_the_keys(method: str) -> None:
    f1 = [noisy_agreement(method, name, 0.3)[1] for name in NOISE_CLIPS]
    assert np.mean(f1) >= 0.9 and min(f1) >= 0.75, f1


def test_the_cli_and_the_library_filter_alike_and_on_is_the_default(tmp_path: Path) -> None:
    """`extract` (offline and --online) gives the library's filtered keys and the segments
    found behind the same filter; `--noise-cutoff 0` the unfiltered ones; `--noise-cutoff 3`
    another cut-off; a negative one is a usage error."""
    import json

    from streamkey.batch import extract_motion
    from streamkey.cli import main
    from streamkey.segments import detect_segments
    from streamkey.streaming import run_online

    m = motion("07_01.bvh")
    path = str(DATA / "07_01.bvh")
    filtered = extract_motion(m, ["speed"])["speed"]
    assert filtered.frames.tolist() == speed.extract(m, noise_cutoff_hz=FC).frames.tolist()
    raw = extract_motion(m, ["speed"], {"*": {"noise_cutoff_hz": None}})["speed"]
    assert raw.frames.tolist() == speed.extract(m, noise_cutoff_hz=None).frames.tolist()
    assert raw.frames.tolist() != filtered.frames.tolist()
    for cutoff in (None, 0.0, 3.0):
        given = [] if cutoff is None else ["--noise-cutoff", f"{cutoff:g}"]
        hz = FC if cutoff is None else cutoff or None
        params = {"*": {"noise_cutoff_hz": hz}}
        for online in (False, True):
            out = tmp_path / f"keys{online}{cutoff}.json"
            argv = ["extract", path, "--method", "speed", *given, "-o", str(out)]
            assert main(argv + (["--online"] if online else [])) == 0
            doc = json.loads(out.read_text())["files"][0]
            keys = doc["methods"]["speed"]["keyframes"]
            run = run_online if online else extract_motion
            assert keys == run(m, ["speed"], params)["speed"].frames.tolist(), (online, cutoff)
            if not online:
                want = detect_segments(m, noise_cutoff_hz=hz)
                assert doc["segments"] == [s.to_dict() for s in want], cutoff
    assert main(["extract", path, "--noise-cutoff", "-1", "-o", str(tmp_path / "x")]) == 2
