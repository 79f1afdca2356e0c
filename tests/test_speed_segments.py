"""Session segments and the speed cut-off: candidates in calibration holds and still
stretches stay out of Ward + Mojena's sample (a session state must not move the cut-off),
offline (`extract(segments=...)`) and online (`Online.note_segment`) alike.

Measured offline on the 33 BVH clips' variants (F1 against the clean take with the same
setting): without / with segments, calibration mean F1 0.900 / 0.890 (worst 0.42, 06_12, both),
stillness 0.929 / 0.923 (worst 0.55 both), 60 Hz 0.911 / 0.908 (worst 0.55 / 0.60): the
variants' holds are exact, so rest (`REST_SPEED`) already keeps them candidate-free, and the
segment detector reads calm motion as still (49_18: 87 of 127 candidates)."""

from __future__ import annotations

from functools import cache

import numpy as np
from cmu import DATA

from streamkey.amc import read_motion
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import speed
from streamkey.motion import Motion
from streamkey.segments import Segment, SegmentDetector, SegmentEvent, detect_segments, segments_of


@cache
def load(name: str) -> Motion:
    return read_motion(DATA / name)


def online_with_segments(m: Motion, lookahead: int) -> tuple[list[KeyframeEvent],
                                                             list[SegmentEvent]]:
    """Every frame to a segment detector and the keyframer; each segment event is noted
    before the frame that decided it is pushed (the pipeline's order)."""
    det = SegmentDetector(m.skeleton, m.fps)
    kf = speed.Online(m.skeleton, m.fps, lookahead=lookahead, segment_statistics=True)
    keys: list[KeyframeEvent] = []
    seen: list[SegmentEvent] = []
    for frame in m.frames():
        for event in det.push(frame):
            kf.note_segment(event)
            seen.append(event)
        keys += kf.push(frame)
    for event in det.flush():
        kf.note_segment(event)
        seen.append(event)
    return keys + kf.flush(), seen


def test_still_candidates_stay_out_of_the_cut_off_offline() -> None:
    """05_18 holds still three times behind the default noise filter (1.7-2.5 s each; its
    0.17 s move at 1.6 s is filtered below the motion threshold, which joins the first two
    holds): 43 of its 73 candidates lie there."""
    m = load("05_18.bvh")
    segments = detect_segments(m)
    assert sum(s.kind == "still" for s in segments) == 3
    plain, masked = speed.extract(m), speed.extract(m, segments=segments)
    assert np.array_equal(plain.info["candidates"], masked.info["candidates"])
    assert masked.info["threshold"] != plain.info["threshold"]
    whole = [Segment("take", 0, m.n_frames - 1, 0.0, (m.n_frames - 1) / m.fps)]
    assert np.array_equal(speed.extract(m, segments=whole).frames, plain.frames)


def test_online_with_segment_events_equals_offline_at_unbounded_lookahead() -> None:
    m = load("05_18.bvh")
    keys, seen = online_with_segments(m, m.n_frames + 1)
    off = speed.extract(m, segments=segments_of(seen))
    assert segments_of(seen) == detect_segments(m)
    assert [e.frame for e in keys] == off.frames.tolist()
    assert [e.score for e in keys] == off.scores.tolist()


def test_segment_events_change_nothing_on_a_take_without_stillness() -> None:
    m = load("07_05.bvh")
    keys, seen = online_with_segments(m, 120)
    assert all(e.kind == "take" for e in seen)
    plain = speed.Online(m.skeleton, m.fps, segment_statistics=True)
    assert keys == plain.push_block(m.frames()) + plain.flush()
