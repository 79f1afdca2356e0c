"""Session segments (calibration holds, still stretches, takes) on the shared CMU clips and
their variants: offline, online frame by frame and in blocks, at 30/60/120 Hz, with noise."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest
from cmu import DATA, clips

from streamkey import variants as V
from streamkey.amc import read_motion
from streamkey.bvh import read_bvh
from streamkey.errors import UsageError
from streamkey.filters import DEFAULT_NOISE_CUTOFF_HZ
from streamkey.motion import Frame, Motion
from streamkey.online import FeatureStage
from streamkey.segments import (
    Segment,
    SegmentDetector,
    SegmentEvent,
    detect_segments,
    motion_mask,
    segments_of,
)

ALL_CLIPS = clips()
FAST = ["07_01.bvh", "49_18.amc", "131_03.bvh", "05_02.bvh"]
# Gait clips: walking or running the whole take, never still for half a second.
GAIT = ["02_01.bvh", "02_03.bvh", "03_01.bvh", "06_06.bvh", "06_08.bvh", "07_01.bvh",
        "07_05.amc", "07_05.bvh", "07_12.bvh", "08_01.bvh", "09_01.bvh", "09_06.amc",
        "09_06.bvh", "09_12.bvh", "16_11.bvh", "35_01.amc"]


def _params(names: list[str]) -> list[object]:
    return [pytest.param(n, marks=() if n in FAST else pytest.mark.slow) for n in names]


@cache
def load(name: str) -> Motion:
    """A shared clip, BVH or AMC."""
    return read_bvh(DATA / name) if name.endswith(".bvh") else read_motion(DATA / name)


def _blend_start(v: V.Variant) -> int:
    return v.take_start - round(0.5 * v.motion.fps)


def _check_calibration(v: V.Variant, segs: list[Segment]) -> None:
    fps = v.motion.fps
    cal = [s for s in segs if s.kind == "calibration"]
    assert len(cal) == 1, segs
    assert segs[0] is cal[0] and segs[1].kind == "take", segs
    assert cal[0].start / fps <= 0.1
    assert abs(cal[0].end + 1 - _blend_start(v)) / fps <= 0.3, (cal[0], _blend_start(v))
    assert cal[0].pose in ("T", "A", "N")


def _check_partition(segs: list[Segment], motion: Motion) -> None:
    assert segs[0].start == motion.first_frame and segs[-1].end == motion.n_frames - 1
    for a, b in zip(segs, segs[1:], strict=False):
        assert b.start == a.end + 1 and a.kind != b.kind and "take" in (a.kind, b.kind)


@pytest.mark.parametrize("name", _params(ALL_CLIPS))
def test_calibration_hold_is_one_calibration_segment_then_a_take(name: str) -> None:
    m = load(name)
    v = V.with_calibration(m)
    segs = detect_segments(v.motion)
    _check_calibration(v, segs)
    _check_partition(segs, v.motion)


@pytest.mark.parametrize("name", _params(ALL_CLIPS))
def test_calibration_with_noise_before_or_after(name: str) -> None:
    m = load(name)
    noisy_take = V.with_calibration(V.with_noise(m, 0.3).motion)  # noise on the take only
    _check_calibration(noisy_take, detect_segments(noisy_take.motion))
    v = V.with_calibration(m)  # noise on the hold too
    noisy = V.Variant("cal+noise", V.with_noise(v.motion, 0.3).motion, v.clean_fps, v.offset,
                      v.take_start)
    _check_calibration(noisy, detect_segments(noisy.motion))


# measured behind the default 5 Hz noise filter: 05_06's final hold (still 6.71-7.34 s, then
# a 0.02 s take at 120 and 60 Hz) stays above the stillness threshold at 30 Hz (one take);
# 05_18's three holds agree at all three rates (at 6 Hz a 0.17 s move split one at 30 Hz)
_RATE_MISSES = {"05_06.bvh": "measured: 05_06 clean take behind the 5 Hz filter: take, still "
                             "6.71-7.34 s, take at 120 and 60 Hz; one take at 30 Hz"}


@pytest.mark.parametrize("name", [
    pytest.param(n, marks=[*p.marks, pytest.mark.xfail(strict=True, reason=_RATE_MISSES[n])])
    if n in _RATE_MISSES else p for n, p in zip(ALL_CLIPS, _params(ALL_CLIPS), strict=True)])
def test_calibration_segments_in_seconds_at_30_and_60_hz(name: str) -> None:
    m = load(name)
    ref = V.with_calibration(m)
    ref_cal = detect_segments(ref.motion)[0]
    for fps in (60.0, 30.0):
        v = V.with_calibration(V.resample(m, fps).motion)
        segs = detect_segments(v.motion)
        _check_calibration(v, segs)
        # the same hold in seconds (measured on every clip: within 0.05 s at 60 Hz, 0.067 s
        # at 30 Hz: the blend's first frames fall elsewhere)
        assert abs(segs[0].end_time - ref_cal.end_time) <= 0.1, (segs[0], ref_cal)
    # the clean take's own segments: the same kinds, boundaries within 0.1 s (measured 0.025)
    clean = detect_segments(V.clean_take(m).motion)
    for fps in (60.0, 30.0):
        other = detect_segments(V.resample(m, fps).motion)
        assert [s.kind for s in other] == [s.kind for s in clean]
        for a, b in zip(clean, other, strict=True):
            assert abs(a.start_time - b.start_time) <= 0.1 and abs(a.end_time - b.end_time) <= 0.1


def _clean_final_holds(m: Motion) -> list[float]:
    """Starts (s) of the clean take's own holds that last until 0.6 s before its end."""
    clean = V.clean_take(m).motion
    end = (clean.n_frames - 1) / clean.fps
    return [s.start_time for s in detect_segments(clean)
            if s.kind == "still" and s.end_time >= end - 0.6]


@pytest.mark.parametrize("name", _params(ALL_CLIPS))
def test_stillness_after_the_take_is_a_still_segment(name: str) -> None:
    m = load(name)
    holds = _clean_final_holds(m)
    for fps, noise in ((120.0, 0.0), (120.0, 0.3), (30.0, 0.0)):
        base = m if fps == 120.0 else V.resample(m, fps).motion
        v = V.with_stillness(base)
        motion = V.with_noise(v.motion, noise).motion if noise else v.motion
        segs = detect_segments(motion)
        last = segs[-1]
        assert last.kind == "still" and last.end == motion.n_frames - 1, segs[-3:]
        # starts where the take ends, or where a hold of the clean take's own ending starts
        # (02_07, 02_10, 05_06, 49_18, 131_04 end still: the added stillness continues it)
        expected = [v.take_end / fps] + holds
        assert min(abs(last.start_time - t) for t in expected) <= 0.6, (last, expected)


@pytest.mark.slow
def test_clean_clips_have_no_calibration_and_gait_clips_no_still_segment() -> None:
    """Measured on the 35 shared clips: no calibration segment; 18 still segments, 22.5 s in
    all (holds in playground, dance, balance and sword clips), none in a gait clip."""
    still: list[tuple[str, float, float]] = []
    for name in ALL_CLIPS:
        segs = detect_segments(V.clean_take(load(name)).motion)
        assert not [s for s in segs if s.kind == "calibration"], (name, segs)
        still += [(name, s.start_time, s.end_time - s.start_time) for s in segs
                  if s.kind == "still"]
    assert not [s for s in still if s[0] in GAIT], still
    assert len(still) <= 18 and sum(s[2] for s in still) <= 23.0, still


def _online(motion: Motion, split: np.ndarray | None = None) -> list[SegmentEvent]:
    det = SegmentDetector(motion.skeleton, motion.fps)
    frames = motion.frames()
    events: list[SegmentEvent] = []
    if split is None:
        for f in frames:
            events += det.push(f)
    else:
        for lo, hi in zip(split[:-1], split[1:], strict=True):
            events += det.push_block(frames[lo:hi])
    return events + det.flush()


@pytest.mark.parametrize("name", _params(ALL_CLIPS))
def test_online_equals_offline(name: str) -> None:
    m = load(name)
    rng = np.random.default_rng(7)
    for v in (V.with_calibration(m), V.with_stillness(V.resample(m, 30.0).motion),
              V.clean_take(m)):
        offline = detect_segments(v.motion)
        assert segments_of(_online(v.motion)) == offline
        n = v.motion.n_frames
        cuts = np.unique(np.concatenate([[0, n], rng.integers(0, n, 12)]))
        assert segments_of(_online(v.motion, cuts)) == offline


def test_online_through_a_feature_stage_equals_offline() -> None:
    """The pipeline's front end: `process(FeatureBlock)` after another keyframer's FK."""
    v = V.with_calibration(load("05_02.bvh"))
    stage = FeatureStage(v.motion.skeleton, v.motion.fps)
    det = SegmentDetector(v.motion.skeleton, v.motion.fps)
    events: list[SegmentEvent] = []
    frames = v.motion.frames()
    for lo in range(0, len(frames), 7):
        events += det.process(stage.compute(frames[lo:lo + 7]))
    events += det.process(stage.drain()) + det.finish()
    assert segments_of(events) == detect_segments(v.motion)


@pytest.mark.parametrize("name", _params(ALL_CLIPS))
def test_latency_bound(name: str) -> None:
    m = load(name)
    for v in (V.with_calibration(m), V.with_stillness(V.resample(m, 60.0).motion)):
        det = SegmentDetector(v.motion.skeleton, v.motion.fps)
        h, still, cal = det.half, det.min_still, max(det.min_still, det.min_calibration)
        last = v.motion.n_frames - 1
        events = _online(v.motion)
        opened = {e.start for e in events if e.end is None and e.kind == "still"}
        for e in events:
            if e.end is None and e.kind == "still":
                assert e.latency_frames <= still - 1 + h
            elif e.end is None and e.kind == "calibration":
                assert e.start in opened and e.latency_frames <= cal - 1 + h
            elif e.end is not None and e.kind != "take":
                assert e.decided_at == last or e.latency_frames == h + 1, e
            elif e.end is not None:  # a take ends with the next hold's confirmation
                assert e.decided_at == last or e.decided_at - e.end <= still + h, e
        # the documented figures in seconds at this rate
        assert (still - 1 + h) / v.motion.fps <= 0.7 + 1e-9
        assert (h + 1) / v.motion.fps <= 0.2 + 1.5 / v.motion.fps


def test_calibration_then_take_events_in_order() -> None:
    v = V.with_calibration(load("07_01.bvh"))
    events = _online(v.motion)
    kinds = [(e.kind, e.end is None) for e in events]
    assert kinds[:4] == [("still", True), ("calibration", True), ("calibration", False),
                         ("take", True)]
    assert kinds[-1] == ("take", False)
    for e in events:
        assert e.to_dict()["id"] == e.id


def test_motion_mask_covers_the_take_only() -> None:
    v = V.with_calibration(load("07_01.bvh"))
    segs = detect_segments(v.motion)
    mask = motion_mask(segs, v.motion.n_frames)
    assert not mask[: segs[0].end + 1].any()
    assert mask[v.take_start:].all()
    assert mask.sum() == sum(s.frames for s in segs if s.kind == "take")


def test_fuzz_random_nan_constant_inputs() -> None:
    """Garbage in: segments or a documented `UsageError`, never another exception."""
    m = load("07_01.bvh")
    skel = m.skeleton
    rng = np.random.default_rng(3)
    n_ch = skel.n_channels
    cases = [rng.normal(0, 180, (300, n_ch)), np.zeros((300, n_ch)),
             np.full((200, n_ch), 1e300), np.tile(m.channels[5], (150, 1))]
    nan = m.channels[1:400].copy()
    nan[50:80] = np.nan
    nan[200, 3] = np.inf
    cases += [nan, m.channels[1:2], m.channels[1:3]]
    for x in cases:
        det = SegmentDetector(skel, 120.0)
        events: list[SegmentEvent] = []
        for i, row in enumerate(x):
            events += det.push(Frame(i, i / 120.0, row))
        segs = segments_of(events + det.flush())
        assert segs[0].start == 0 and segs[-1].end == len(x) - 1
        assert all(b.start == a.end + 1 for a, b in zip(segs, segs[1:], strict=False))
    constant = segments_of(_online(Motion(skel, np.tile(m.channels[5], (150, 1)), 120.0)))
    assert [s.kind for s in constant] == ["still"]
    det = SegmentDetector(skel, 120.0)
    with pytest.raises(UsageError):
        det.push(Frame(0, 0.0, np.zeros(n_ch + 1)))
    with pytest.raises(UsageError):
        SegmentDetector(skel, 0.0)
    with pytest.raises(UsageError):
        SegmentDetector(skel, 120.0, still_speed=0.2, motion_speed=0.1)
    assert det.flush() == []
    assert detect_segments(Motion(skel, np.zeros((0, n_ch)), 120.0)) == []


def test_online_equals_offline_behind_the_noise_filter() -> None:
    """With the sensor-noise front end at its default cut-off, as a pipeline runs it."""
    v = V.with_calibration(V.with_noise(load("49_18.amc"), 0.3).motion)
    offline = detect_segments(v.motion, noise_cutoff_hz=DEFAULT_NOISE_CUTOFF_HZ)
    _check_calibration(v, offline)
    det = SegmentDetector(v.motion.skeleton, v.motion.fps,
                          noise_cutoff_hz=DEFAULT_NOISE_CUTOFF_HZ)
    events: list[SegmentEvent] = []
    for f in v.motion.frames():
        events += det.push(f)
    assert segments_of(events + det.flush()) == offline


def test_fuzz_garbage_in_random_blocks() -> None:
    """Random, NaN and constant rows in random block sizes: same segments as one block."""
    m = load("07_01.bvh")
    rng = np.random.default_rng(11)
    x = m.channels[1:].copy()
    x[rng.integers(0, len(x), 20)] = np.nan
    x[100:160] = x[100]
    x[200:220] = rng.normal(0, 90, (20, x.shape[1]))
    motion = Motion(m.skeleton, x, m.fps)
    whole = segments_of(_online(motion, np.array([0, len(x)])))
    cuts = np.unique(np.concatenate([[0, len(x)], rng.integers(0, len(x), 40)]))
    assert segments_of(_online(motion, cuts)) == whole
    det = SegmentDetector(m.skeleton, m.fps)
    with pytest.raises(UsageError):
        det.push_points([0, 1], [0.0], np.zeros((2, 18, 3)))


def test_extract_writes_the_segments_of_a_take_recorded_after_a_calibration_hold(
        tmp_path: Path) -> None:
    """A BVH file of 07_01 after a 2 s T-pose hold and a 0.5 s blend: `extract`'s JSON names
    the hold as a calibration segment, then the take, in the file's frame numbers."""
    import json

    from streamkey.bvh import write_bvh
    from streamkey.cli import main

    m = read_motion(DATA / "07_01.bvh")
    variant = V.with_calibration(m)
    path = tmp_path / "calibrated.bvh"
    write_bvh(variant.motion, path)
    out = tmp_path / "keys.json"
    assert main(["extract", str(path), "--method", "speed", "-o", str(out)]) == 0
    segments = json.loads(out.read_text())["files"][0]["segments"]
    assert [s["kind"] for s in segments] == ["calibration", "take"]
    hold, take = segments
    assert hold["start"] == 0 and hold["pose"]
    assert abs(hold["end_time"] - 2.0) <= 0.3 and take["start"] == hold["end"] + 1
    assert take["end"] == variant.motion.n_frames - 1
