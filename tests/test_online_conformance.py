"""One conformance suite for every online keyframer (river's check_estimator idea)."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from cmu import DATA

from streamkey.amc import read_motion
from streamkey.keyframes import GapEvent, KeyframeEvent
from streamkey.methods import ONLINE_METHODS, online_class
from streamkey.motion import Frame

CLIPS = ["07_01.bvh", "05_11.amc"]


def keyframes(events):
    return [(e.frame, e.decided_at) for e in events if isinstance(e, KeyframeEvent)]


def run(kf, frames):
    out = []
    for f in frames:
        out += kf.push(f)
    return out + kf.flush()


@pytest.fixture(scope="module", params=CLIPS)
def motion(request):
    return read_motion(DATA / request.param)


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_a_second_pass_after_flush_gives_identical_events(method, motion):
    kf = online_class(method)(motion.skeleton, motion.fps)
    first = run(kf, motion.frames())
    second = run(kf, motion.frames())
    assert keyframes(first) == keyframes(second) and keyframes(first)


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_damaged_streams_never_raise_and_report_the_missing_frames(method, motion):
    rng = np.random.default_rng(7)
    frames = motion.frames()
    keep = [f for f in frames if rng.random() >= 0.05]  # 5 % dropped
    damaged: list[Frame] = []
    for f in keep:
        damaged.append(f)
        if rng.random() < 0.05:
            damaged.append(f)  # duplicated
    for i in range(1, len(damaged) - 1, 17):  # shuffled by one
        damaged[i], damaged[i + 1] = damaged[i + 1], damaged[i]
    bad = motion.frames()[3]
    damaged.insert(40, Frame(bad.seq, bad.time, np.full_like(bad.channels, np.nan)))
    kf = online_class(method)(motion.skeleton, motion.fps)
    events = run(kf, damaged)
    gaps = [e for e in events if isinstance(e, GapEvent)]
    received = {f.seq for f in damaged if np.all(np.isfinite(f.channels))}
    seqs = sorted(f.seq for f in frames)
    missing = [s for s in seqs[1:] if s not in received]
    covered = {s for g in gaps for s in range(g.first, g.last + 1)}
    # Every frame that never arrived is inside a gap event (a swapped pair may add a few
    # more: the later frame arrives first and its predecessor is then out of order).
    assert set(missing) <= covered
    c = kf.guard.counters
    assert c.duplicates > 0 and c.out_of_order > 0 and c.invalid == 1 and c.gaps >= len(gaps)
    # the latency bound: the keyframer's lookahead plus the noise filter's delay (on by default)
    bound = kf.lookahead + kf.features.delay
    assert kf.features.delay > 0
    assert all(e.lookahead == bound for e in events if isinstance(e, KeyframeEvent))
    assert all(0 <= e.latency_frames <= bound for e in events
               if isinstance(e, KeyframeEvent) and e.decided_at < seqs[-1])
    assert keyframes(events)


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_keyframer_pickled_mid_stream_resumes_identically(method, motion):
    frames = motion.frames()
    whole = run(online_class(method)(motion.skeleton, motion.fps), frames)
    kf = online_class(method)(motion.skeleton, motion.fps)
    head = [e for f in frames[:200] for e in kf.push(f)]
    clone = pickle.loads(pickle.dumps(kf))
    assert keyframes(head + run(clone, frames[200:])) == keyframes(whole)


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_pushing_does_not_mutate_the_frames(method, motion):
    frames = motion.frames()[:150]
    before = [f.channels.copy() for f in frames]
    run(online_class(method)(motion.skeleton, motion.fps), frames)
    for f, b in zip(frames, before, strict=True):
        np.testing.assert_array_equal(f.channels, b)


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_push_block_gives_the_same_events_as_pushing_frame_by_frame(method):
    m = read_motion(DATA / "07_01.bvh")
    frames = m.frames()
    by_frame = run(online_class(method)(m.skeleton, m.fps), frames)
    kf = online_class(method)(m.skeleton, m.fps)
    edges = [0, 1, 17, 18, 150, 151, 260, len(frames)]
    by_block = [e for lo, hi in zip(edges[:-1], edges[1:], strict=True)
                for e in kf.push_block(frames[lo:hi])] + kf.flush()
    assert by_block == by_frame


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_every_keyframer_class_documents_itself(method):
    cls = online_class(method)
    assert cls.__doc__ and cls.method == method
    assert cls.__module__.startswith("streamkey.methods.")


PLAYABLE = {"*": {"provisional": True, "min_interval": {"*": 0.1}, "signal": 5}}


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
def test_playable_wrappers_pickled_mid_stream_resume_identically(method):
    from streamkey.streaming import make_keyframers

    m = read_motion(DATA / "07_01.bvh")
    frames = m.frames()
    whole = run(make_keyframers(m, [method], PLAYABLE)[0], frames)
    kf = make_keyframers(m, [method], PLAYABLE)[0]
    head = [e for f in frames[:200] for e in kf.push(f)]
    clone = pickle.loads(pickle.dumps(kf))
    assert head + run(clone, frames[200:]) == whole
    assert keyframes(whole) and kf.lookahead >= online_class(method)(m.skeleton, m.fps).lookahead
