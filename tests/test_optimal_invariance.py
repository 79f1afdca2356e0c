"""Optimal keys are keys of the motion, not of the recording: the same take at 60 or 30 Hz,
after a calibration hold or followed by stillness gets the clean take's keys — as many
(0.8–1.25x) and as good (E of the clean motion rebuilt from them, mapped back and rounded,
within 1.10x of the clean keys' E) — offline and online, on the shared CMU clips."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
import pytest
from cmu import DATA, clips

from streamkey import variants as V
from streamkey.amc import read_motion
from streamkey.errors import UsageError
from streamkey.evaluate import error_e, reconstruct
from streamkey.features import DEFAULT_NOISE_CUTOFF_HZ
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import optimal
from streamkey.motion import Motion
from streamkey.units import Duration

FEW = ["07_01.bvh", "05_02.bvh", "49_18.amc", "131_01.bvh"]
VARIANTS: dict[str, Callable[[Motion], V.Variant]] = {
    "60 Hz": lambda m: V.resample(m, 60.0),
    "30 Hz": lambda m: V.resample(m, 30.0),
    "calibration before": V.with_calibration,
    "stillness after": V.with_stillness,
}
COUNT_RANGE = (0.8, 1.25)
E_RATIO = 1.10


@cache
def load(name: str) -> Motion:
    return read_motion(DATA / name)


def keys_of(motion: Motion, online: bool, lookahead: int | Duration | None = None,
            filtered: bool = True, **mode: float | bool) -> np.ndarray:
    """Key frames of `motion`: offline `extract`, or the online keyframer fed frame blocks
    (default lookahead unless given); `filtered=False`: the sensor-noise filter off."""
    cutoff = DEFAULT_NOISE_CUTOFF_HZ if filtered else None
    if not online:
        return np.asarray(optimal.extract(motion, noise_cutoff_hz=cutoff, **mode).frames)
    kw = {} if lookahead is None else {"lookahead": lookahead}
    kf = optimal.Online(motion.skeleton, motion.fps, **kw, **mode)
    kf.features.configure(cutoff)
    events = kf.push_block(motion.frames()) + kf.flush()
    return np.array([e.frame for e in events if isinstance(e, KeyframeEvent)])


def e_on_clean(clean: Motion, frames: np.ndarray) -> float:
    """E of the clean motion rebuilt from `frames` (clean-take frame numbers, rounded)."""
    rows = np.unique(np.clip(np.round(frames).astype(np.int64), 0, clean.n_frames - 1))
    return error_e(clean, reconstruct(clean, rows))


@cache
def clean_result(name: str, online: bool) -> tuple[np.ndarray, float]:
    clean = V.clean_take(load(name)).motion
    frames = keys_of(clean, online)
    return frames, e_on_clean(clean, frames)


@cache
def measure(name: str, variant: str, online: bool) -> tuple[float, float]:
    """(keys in the take / the clean take's keys, E of the mapped keys / the clean keys' E)."""
    m = load(name)
    clean = V.clean_take(m).motion
    frames, e_clean = clean_result(name, online)
    v = VARIANTS[variant](m)
    mapped = V.keys_in_take(v, keys_of(v.motion, online))
    return len(mapped) / len(frames), e_on_clean(clean, mapped) / e_clean


def _mode_id(online: bool) -> str:
    return "online" if online else "offline"


@pytest.mark.parametrize("online", [False, True], ids=_mode_id)
@pytest.mark.parametrize("variant", list(VARIANTS))
@pytest.mark.parametrize("name", FEW)
def test_variant_gets_as_many_keys_as_the_clean_take(name: str, variant: str,
                                                      online: bool) -> None:
    count, _ = measure(name, variant, online)
    assert COUNT_RANGE[0] <= count <= COUNT_RANGE[1], count


# Measured misses (keys ratio, E ratio), with the sensor-noise front end on (the default):
# at 5 Hz every case of FEW meets the E target (at 6 Hz 07_01, 05_02 and 131_01 missed it at
# 30 Hz, 131_01 with stillness after). (With still stretches keyless too, 05_02 and 49_18 met
# it at 60 and 30 Hz, at the price of E 2-25x on the clean takes: `optimal.KEYLESS`.)
MISSES: dict[tuple[str, str, bool], str] = {}


def _cases() -> list[object]:
    out: list[object] = []
    for name in FEW:
        for variant in VARIANTS:
            for online in (False, True):
                reason = MISSES.get((name, variant, online))
                marks = [pytest.mark.xfail(strict=True, reason=f"measured: {reason}")] if (
                    reason) else []
                out.append(pytest.param(name, variant, online, marks=marks,
                                        id=f"{name}-{variant}-{_mode_id(online)}"))
    return out


@pytest.mark.parametrize(("name", "variant", "online"), _cases())
def test_variant_keys_rebuild_the_clean_motion_as_well(name: str, variant: str,
                                                       online: bool) -> None:
    _, e = measure(name, variant, online)
    assert e <= E_RATIO, e


@pytest.mark.slow
@pytest.mark.parametrize("online", [False, True], ids=_mode_id)
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_variant_gets_as_many_keys_on_every_clip(variant: str, online: bool) -> None:
    counts = {name: round(measure(name, variant, online)[0], 3) for name in clips()}
    missed = {k: v for k, v in counts.items() if not COUNT_RANGE[0] <= v <= COUNT_RANGE[1]}
    assert not missed, missed


# On every shared clip; measured misses as (clip: keys ratio, E ratio). Every key count is
# within 0.91-1.07x; E of linear interpolation falls about as K^-4 on smooth motion, so 1.10x
# asks for counts within ~2.5 %, and on the short clips (1.2-2.6 s, 11-20 keys) one key is
# 5-8 %. The 30 Hz keys also snap to every 4th clean frame.
ALL_MISSES = {  # measured with no key inside a calibration hold and the noise front end on
    ("60 Hz", False): "02_01 (0.947, 1.188); count 0.95-1.03x",
    ("60 Hz", True): "05_11.amc (1.0, 1.116); count 0.99-1.03x",
    ("30 Hz", False): "02_01 (0.947, 1.207), 05_11.amc (1.0, 1.148), 05_13 (1.0, 1.122), 08_01 "
                      "(0.944, 1.286), 09_01 (0.917, 1.28); count 0.92-1.07x",
    ("30 Hz", True): "05_06 (0.967, 1.196), 06_02 (0.97, 1.125), 08_01 (0.944, 1.239), 09_01 "
                     "(0.917, 1.251); count 0.92-1.06x",
    ("calibration before", False): "06_12 (0.966, 1.108): the 0.5 s blend out of the T-pose "
                                   "is motion and lifts lambda; count 0.91-1.04x",
}


def _all_cases() -> list[object]:
    out: list[object] = []
    for variant in VARIANTS:
        for online in (False, True):
            reason = ALL_MISSES.get((variant, online))
            marks = [pytest.mark.slow]
            if reason:
                marks.append(pytest.mark.xfail(strict=True, reason=f"measured: {reason}"))
            out.append(pytest.param(variant, online, marks=marks,
                                    id=f"{variant}-{_mode_id(online)}"))
    return out


@pytest.mark.parametrize(("variant", "online"), _all_cases())
def test_variant_keys_rebuild_the_clean_motion_as_well_on_every_clip(variant: str,
                                                                     online: bool) -> None:
    missed = {}
    for name in clips():
        count, e = measure(name, variant, online)
        if e > E_RATIO:
            missed[name] = (round(count, 3), round(e, 3))
    assert not missed, missed


# --- the same computation at any rate ------------------------------------------------------

@pytest.mark.parametrize("fps", [60.0, 30.0])
@pytest.mark.parametrize("mode", [{"rate": 6.0}, {"lam": 2e-3}, {"tolerance": 1e-4}])
def test_online_with_unbounded_lookahead_equals_offline_at_lower_rates(fps, mode):
    v = V.resample(load("49_18.amc"), fps).motion
    online = keys_of(v, True, lookahead=v.n_frames, **mode)
    assert np.array_equal(online, keys_of(v, False, **mode))


@pytest.mark.parametrize("make", [V.with_calibration, V.with_stillness])
def test_online_with_unbounded_lookahead_equals_offline_around_holds(make):
    """Chunks with still frames weigh them by their motion (`optimal.motion_weights`), the
    same sums online and offline."""
    v = make(load("07_01.bvh")).motion
    online = keys_of(v, True, lookahead=v.n_frames)
    assert np.array_equal(online, keys_of(v, False))


def test_online_latency_stays_within_the_lookahead_at_30_hz():
    m = V.resample(load("05_02.bvh"), 30.0).motion
    kf = optimal.Online(m.skeleton, m.fps)
    assert kf.lookahead == 30  # the default, 1 s, in frames of the stream
    events = [e for e in kf.push_block(m.frames()) if isinstance(e, KeyframeEvent)]
    assert events and all(e.lookahead == 30 + kf.features.delay for e in events)
    assert max(e.latency_frames for e in events) <= 30 + kf.features.delay  # filter delay too


def test_durations_keep_their_meaning_and_plain_numbers_theirs():
    m = load("07_01.bvh")
    assert optimal.Online(m.skeleton, 120.0).lookahead == 120
    assert optimal.Online(m.skeleton, 120.0, lookahead=Duration.seconds(0.5)).lookahead == 60
    assert optimal.Online(m.skeleton, 60.0, lookahead=90).lookahead == 90  # frames
    assert optimal.Online(m.skeleton, 60.0).max_len == 120  # 2 s
    for bad in (Duration.seconds(0.1), 15, 2.5, Duration.seconds(float("inf"))):
        with pytest.raises(UsageError):
            optimal.Online(m.skeleton, 120.0, lookahead=bad)  # type: ignore[arg-type]
    base = optimal.extract(m).frames
    assert np.array_equal(optimal.extract(m, max_segment=Duration.frames(240)).frames, base)
    assert np.array_equal(optimal.extract(m, max_segment=Duration.seconds(2.0)).frames, base)
    assert np.diff(optimal.extract(m, max_segment=0.1).frames).max() <= 12  # seconds
    with pytest.raises(UsageError):
        optimal.extract(m, max_segment=Duration.seconds(-1.0))


def test_stillness_and_a_calibration_hold_earn_no_weight_in_the_rate_controller():
    """A held pose adds no motion seconds, so λ is (nearly) the clean take's: only the
    key-spaced segments that reach from the take into the hold differ."""
    m = load("05_02.bvh")
    lam = optimal.extract(V.clean_take(m).motion).info["lambda"]
    for make in (V.with_stillness, V.with_calibration):
        other = optimal.extract(make(m).motion).info["lambda"]
        assert other == pytest.approx(lam, rel=0.15), make.__name__


def test_at_120_hz_the_defaults_give_the_keys_they_gave_in_frames():
    """Costs and λ in ticks of 1/120 s, 1 s of lookahead: at 120 Hz the frame sums and the
    120-frame lookahead of before (keys measured before the change, clean take's frames,
    without the sensor-noise filter that came later)."""
    clean = V.clean_take(load("07_01.bvh")).motion
    assert keys_of(clean, False, filtered=False).tolist() == [
        0, 13, 31, 50, 65, 80, 100, 118, 134, 147, 166, 182, 197, 211, 231, 247, 263, 278, 301,
        315]
    assert keys_of(clean, True, filtered=False).tolist() == [
        0, 13, 31, 50, 65, 80, 100, 117, 133, 146, 165, 182, 197, 211, 231, 247, 263, 278, 301,
        315]
    # 49_18 holds still over frames 0-141 and 500-1101 (`streamkey.segments`): those frames
    # stay out of lambda now (1.44e-3 instead of 4.6e-4), so it gets 14 keys, not 16-21, and
    # with keys allowed inside the holds it gets the keys of before
    quiet = V.clean_take(load("49_18.amc")).motion
    assert keys_of(quiet, True, filtered=False, hold_keys=True).tolist() == [
        0, 84, 146, 210, 263, 301, 358, 410, 457, 508, 578, 810, 862, 1101]
    # 49_18 has no calibration hold, so by default (only calibration holds are keyless) the
    # keys are the same
    assert keys_of(quiet, True).tolist() == keys_of(quiet, True, hold_keys=True).tolist()


def test_a_still_stretch_of_the_take_stays_out_of_lambda():
    """49_18 (balance on one leg) holds still over frames 0-141 and 500-1101: its λ is that
    of its moving part, as if the holds were cut off (before: 3.2x lower, 21 keys for 9 s)."""
    m = load("49_18.amc")
    lam = optimal.extract(m).info["lambda"]
    take = V.clean_take(m).motion
    moving = Motion(take.skeleton, take.channels[142:500], take.fps)
    assert lam == pytest.approx(optimal.extract(moving).info["lambda"], rel=0.15)


def test_motion_weights_count_a_still_stretch_as_no_time():
    costs = np.array([0.0, 0.5e-8 * 20, 1e-8 * 20, 1e-3])
    assert optimal.motion_weights(costs, 20, 4.0).tolist() == [0.0, 2.0, 4.0, 4.0]


def test_a_take_after_a_still_stretch_gets_the_same_keys_whatever_the_block_split():
    """05_02 starts with 2.7 s of stillness: the segment status that keeps it out of λ is
    known at the same frame whether the frames come one by one or in one block."""
    m = load("05_02.bvh")
    whole = keys_of(m, True)
    kf = optimal.Online(m.skeleton, m.fps)
    events = []
    frames = m.frames()
    for i in range(0, len(frames), 7):
        events += kf.push_block(frames[i : i + 7])
        events += kf.idle()
    events += kf.flush()
    assert [e.frame for e in events if isinstance(e, KeyframeEvent)] == whole.tolist()
