"""Segment events live: the pipeline's segment detector beside its keyframers, its events in
the event stream (JSON Lines log, OSC), noted by the keyframers before the frame that decided
them, `extract --online` segments equal to offline's, and the edges (only stillness, a stream
that ends inside a hold, garbage)."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from dataclasses import replace
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cmu import DATA, ROOT
from pythonosc.osc_message import OscMessage

from streamkey import variants as V
from streamkey.adapters.codec import event_id, event_messages, osc_messages, record_messages
from streamkey.adapters.osc import decode_bundle
from streamkey.batch import extract_files, extract_files_online, results_json
from streamkey.bvh import read_bvh, write_bvh
from streamkey.keyframes import Event, KeyframeEvent, SegmentEvent
from streamkey.motion import Frame, Motion
from streamkey.online import FeatureBlock, OnlineKeyframer, Pipeline
from streamkey.segments import SegmentDetector, detect_segments, segments_of
from streamkey.segments import SegmentEvent as SegmentEventFromSegments
from streamkey.streaming import make_keyframers


@cache
def clip(name: str) -> Motion:
    return read_bvh(DATA / name)


class Spy(OnlineKeyframer):
    """A keyframer that decides nothing and records what the pipeline told it, in order."""

    method = "spy"

    def __init__(self, motion: Motion) -> None:
        super().__init__(motion.skeleton, motion.fps, lookahead=1)
        self.log: list[tuple[str, Any]] = []

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        self.log += [("frame", int(s)) for s in block.seq]
        return []

    def note_segment(self, event: SegmentEvent) -> None:
        self.log.append(("segment", event))

    def finish(self) -> list[KeyframeEvent]:
        self.log.append(("finish", None))
        return []

    def reset(self) -> None:
        pass


def run(pipeline: Pipeline, frames: list[Frame], cuts: np.ndarray | None = None) -> list[Event]:
    """Frame by frame (`cuts` None) or in blocks between `cuts`, then flush."""
    events: list[Event] = []
    if cuts is None:
        for f in frames:
            events += pipeline.push(f)
    else:
        for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
            events += pipeline.push_block(frames[lo:hi])
    return events + pipeline.flush()


def segment_events(events: list[Event]) -> list[SegmentEvent]:
    return [e for e in events if isinstance(e, SegmentEvent)]


def test_segment_event_lives_with_the_other_events() -> None:
    assert SegmentEventFromSegments is SegmentEvent
    with pytest.raises(TypeError):
        SegmentEvent("s", "take", 0, None, 0.0, None, 5)  # type: ignore[misc]
    e = SegmentEvent(stream="s", kind="take", start=3, end=None, start_time=0.025,
                     end_time=None, decided_at=27)
    assert e.to_dict()["type"] == "segment" and e.latency_frames == 24


def test_pipeline_sends_calibration_then_take_and_notes_them_before_the_deciding_frame(
) -> None:
    v = V.with_calibration(clip("07_01.bvh"))
    spy = Spy(v.motion)
    pipeline = Pipeline([spy, *make_keyframers(v.motion, ["speed"])])
    h, last = pipeline.delay, v.motion.n_frames - 1  # the noise filter's delay (on by default)
    assert h == 14
    events = run(pipeline, v.motion.frames())
    segs = segment_events(events)
    kinds = [(e.kind, e.end is None) for e in segs]
    assert kinds == [("still", True), ("calibration", True), ("calibration", False),
                     ("take", True), ("take", False)]
    assert segments_of(segs) == detect_segments(v.motion)
    assert segs[2].pose in ("T", "A", "N") and segs[3].start == segs[2].end + 1
    # noted before the frame that decided it: the frames given so far are all before it
    given = -1
    noted = []
    for what, item in spy.log:
        if what == "frame":
            given = item
        elif what == "segment":
            noted.append(item)
            assert given == item.decided_at - 1 or item.decided_at == given  # closing at end
    # the keyframers are told in the numbering of the (filtered) frames they are given; the
    # event stream dates each by the arrival that decided it, `delay` frames later
    assert [replace(e, decided_at=min(e.decided_at + h, last)) for e in noted] == segs
    assert spy.log[-1] == ("finish", None) and spy.log[-2] == ("segment", segs[-1])
    # in the event stream, each before the keyframes decided with it or later
    order = [(e.decided_at, not isinstance(e, SegmentEvent)) for e in events
             if isinstance(e, SegmentEvent | KeyframeEvent)]
    assert order == sorted(order)


def test_push_block_gives_the_same_segment_events_as_frame_by_frame() -> None:
    v = V.with_stillness(V.with_calibration(clip("05_02.bvh")).motion)
    frames = v.motion.frames()
    one = segment_events(run(Pipeline(make_keyframers(v.motion, ["speed"])), frames))
    cuts = np.unique(np.concatenate([[0, len(frames)],
                                     np.random.default_rng(5).integers(0, len(frames), 25)]))
    blocks = segment_events(run(Pipeline(make_keyframers(v.motion, ["speed"])), frames, cuts))
    assert blocks == one
    segs = segments_of(one)
    assert segs == detect_segments(v.motion)
    assert segs[0].kind == "calibration" and segs[-1].kind == "still"


def test_switched_off_no_segment_events_and_the_same_keys() -> None:
    v = V.with_calibration(clip("07_01.bvh"))
    on = run(Pipeline(make_keyframers(v.motion, ["speed", "simplify"])), v.motion.frames())
    off = run(Pipeline(make_keyframers(v.motion, ["speed", "simplify"]), segments=False),
              v.motion.frames())
    assert not segment_events(off) and segment_events(on)
    assert [e for e in on if not isinstance(e, SegmentEvent)] == off


def test_behind_the_noise_filter_segments_equal_offline_and_latency_counts_the_delay() -> None:
    v = V.with_calibration(V.with_noise(clip("07_01.bvh"), 0.3).motion)
    pipeline = Pipeline(make_keyframers(v.motion, ["speed"]), noise_cutoff_hz=6.0)
    assert pipeline.delay > 0
    segs = segment_events(run(pipeline, v.motion.frames()))
    assert segments_of(segs) == detect_segments(v.motion, noise_cutoff_hz=6.0)
    det = SegmentDetector(v.motion.skeleton, v.motion.fps)
    last = v.motion.n_frames - 1
    for e in segs:
        if e.decided_at != last:
            bound = (det.min_still - 1 if e.kind == "still" and e.end is None else
                     max(det.min_still, det.min_calibration) - 1 if e.end is None else
                     det.min_still if e.kind == "take" else 1)
            assert e.latency_frames <= bound + det.half + pipeline.delay, e


def extract_json(path: Path, online: bool, params: dict[str, Any] | None = None
                 ) -> list[dict[str, Any]]:
    extract = extract_files_online if online else extract_files
    results = list(extract([path], ["speed"], params))
    return json.loads(results_json(results))["files"][0]["segments"]


@pytest.mark.parametrize("variant", ["calibration", "stillness", "clean"])
def test_extract_online_segments_equal_offline(tmp_path: Path, variant: str) -> None:
    m = clip("07_01.bvh")
    v = {"calibration": V.with_calibration, "stillness": V.with_stillness,
         "clean": V.clean_take}[variant](m)
    path = tmp_path / "take.bvh"
    write_bvh(v.motion, path)
    online, offline = extract_json(path, True), extract_json(path, False)
    assert online == offline
    assert [s["kind"] for s in online] == {"calibration": ["calibration", "take"],
                                           "stillness": ["take", "still"],
                                           "clean": ["take"]}[variant]


def test_only_stillness_and_a_stream_that_ends_inside_a_hold() -> None:
    m = clip("07_01.bvh")
    rest = m.channels[5]
    still = Motion(m.skeleton, np.tile(rest, (300, 1)), m.fps)
    segs = segment_events(run(Pipeline(make_keyframers(still, ["speed"])), still.frames()))
    assert [(e.kind, e.end) for e in segs] == [("still", None), ("still", 299)]
    assert segs[-1].decided_at == 299
    # a take, then the performer stands still and the stream ends inside that hold
    v = V.with_stillness(m, 2.0)
    segs = segment_events(run(Pipeline(make_keyframers(v.motion, ["speed"])),
                              v.motion.frames()))
    last = v.motion.n_frames - 1
    assert [(e.kind, e.end is None) for e in segs] == [
        ("take", True), ("take", False), ("still", True), ("still", False)]
    assert segs[-1].end == last and segs[-1].decided_at == last
    assert segs[1].end + 1 == segs[2].start


def test_garbage_frames_and_a_long_gap_inside_a_hold() -> None:
    """NaN rows (dropped by the guard, bridged), a long hole in the middle of a calibration
    hold (the window ends: the hold closes, a new one starts): segments tile each window."""
    v = V.with_calibration(clip("07_01.bvh"))
    frames = v.motion.frames()
    frames[40] = Frame(frames[40].seq, frames[40].time, np.full_like(frames[40].channels,
                                                                     np.nan))
    kept = frames[:50] + frames[66:]  # 16 frames lost: more than the bridge
    segs = segments_of(segment_events(run(Pipeline(make_keyframers(v.motion, ["speed"])),
                                          kept)))
    assert segs[0].start == 0 and segs[0].end == 49
    assert segs[1].start == 66 and segs[1].kind == "calibration"
    assert segs[-1].kind == "take" and segs[-1].end == v.motion.n_frames - 1
    for a, b in zip(segs[1:], segs[2:], strict=False):
        assert b.start == a.end + 1


def test_osc_and_json_of_a_segment_event() -> None:
    opened = SegmentEvent(stream="take 1", kind="calibration", start=0, end=None,
                          start_time=0.0, end_time=None, decided_at=143, pose="T")
    closed = SegmentEvent(stream="take 1", kind="calibration", start=0, end=222,
                          start_time=0.0, end_time=1.85, decided_at=247, pose="T")
    for event, want in ((opened, [1, 0, -1, 0.0, -1.0, 143]),
                        (closed, [0, 0, 222, 0.0, 1.85, 25])):
        (message,) = osc_messages(event)
        msg = OscMessage(message)
        assert msg.address == "/streamkey/take_1/segment/calibration"
        assert msg.params[:3] == want[:3] and msg.params[5] == want[5]
        assert msg.params[3:5] == pytest.approx(want[3:5], abs=1e-6)
        assert record_messages(event.to_dict()) == [message]
        assert event_messages(event.to_dict()) == [message]
        record = {k: v for k, v in event.to_dict().items() if k != "id"}
        assert event_id(record) == event.id
    assert OscMessage(osc_messages(closed, "d")[0]).params[4] == 1.85


def _receive_all(sock: socket.socket) -> list[OscMessage]:
    out = []
    sock.settimeout(2.0)
    while True:
        try:
            data = sock.recv(65536)
        except TimeoutError:
            return out
        if data.startswith(b"#bundle"):
            out += [OscMessage(m) for m in decode_bundle(data)[1]]
        else:
            out.append(OscMessage(data))


def test_run_over_the_engine_logs_and_sends_calibration_then_take(tmp_path: Path) -> None:
    """`streamkey run` (the real engine) over a BVH file of 07_01 recorded after a T-pose
    hold, to a JSON Lines log and a loopback OSC port: both carry the calibration hold
    opened and closed, then the take, in order with the keyframes."""
    v = V.with_calibration(clip("07_01.bvh"))
    path, log = tmp_path / "calibrated.bvh", tmp_path / "events.jsonl"
    write_bvh(v.motion, path)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
        proc = subprocess.run([sys.executable, "-P", "-m", "streamkey", "run", "--from",
                               str(path), "--fast", "--method", "speed", "--to",
                               f"jsonl:{log}", "--to", f"osc://127.0.0.1:{port}"], cwd=ROOT,
                              capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, proc.stderr
        messages = _receive_all(sock)
    logged = [json.loads(line) for line in log.read_text().splitlines()]
    segs = [e for e in logged if e["type"] == "segment"]
    assert [(e["kind"], e["end"] is None) for e in segs] == [
        ("still", True), ("calibration", True), ("calibration", False), ("take", True),
        ("take", False)]
    assert segs[2]["pose"] in ("T", "A", "N") and segs[3]["start"] == segs[2]["end"] + 1
    expected = detect_segments(v.motion)
    assert [(s["kind"], s["start"], s["end"]) for s in segs if s["end"] is not None] == [
        (s.kind, s.start, s.end) for s in expected]
    assert [e for e in logged if e["type"] == "keyframe"]
    sent = [(m.address.rsplit("/", 1)[1], m.params[0], m.params[1], m.params[2])
            for m in messages if "/segment/" in m.address]
    assert sent == [(e["kind"], int(e["end"] is None), e["start"],
                     -1 if e["end"] is None else e["end"]) for e in segs]


def test_a_pipeline_restored_from_a_snapshot_inside_a_hold_sends_the_same_segments() -> None:
    v = V.with_calibration(clip("07_01.bvh"))
    frames = v.motion.frames()
    whole = segment_events(run(Pipeline(make_keyframers(v.motion, ["speed"])), frames))
    first = Pipeline(make_keyframers(v.motion, ["speed"]))
    before = first.push_block(frames[:150])  # inside the calibration hold, still open
    restored = Pipeline.restore(first.snapshot())
    after = restored.push_block(frames[150:]) + restored.flush()
    assert segment_events(before + after) == whole


def test_extract_online_segments_equal_offline_behind_the_noise_filter(tmp_path: Path) -> None:
    v = V.with_calibration(V.with_noise(clip("07_01.bvh"), 0.3).motion)
    path = tmp_path / "noisy.bvh"
    write_bvh(v.motion, path)
    params = {"*": {"noise_cutoff_hz": 6.0}}
    online, offline = extract_json(path, True, params), extract_json(path, False, params)
    assert online == offline
    filtered = [s.to_dict() for s in detect_segments(read_bvh(path), noise_cutoff_hz=6.0)]
    assert offline == filtered and [s["kind"] for s in online][:2] == ["calibration", "take"]


def test_run_no_segments_sends_none_and_the_same_keys(tmp_path: Path) -> None:
    """`run --no-segments` over the same calibrated take: no segment event, and the keyframe
    events are those of a run that sends them."""
    v = V.with_calibration(clip("07_01.bvh"))
    path = tmp_path / "calibrated.bvh"
    write_bvh(v.motion, path)
    logs = []
    for extra in ([], ["--no-segments"]):
        log = tmp_path / f"events{len(extra)}.jsonl"
        proc = subprocess.run([sys.executable, "-P", "-m", "streamkey", "run", "--from",
                               str(path), "--fast", "--method", "speed", "--to",
                               f"jsonl:{log}", *extra], cwd=ROOT, capture_output=True,
                              text=True, timeout=900)
        assert proc.returncode == 0, proc.stderr
        logs.append([json.loads(line) for line in log.read_text().splitlines()])
    with_segments, without = logs
    assert any(e["type"] == "segment" for e in with_segments)
    assert not any(e["type"] == "segment" for e in without)

    def keys(events: list[dict[str, object]]) -> list[object]:
        return [(e["frame"], e["score"]) for e in events if e["type"] == "keyframe"]

    assert keys(with_segments) == keys(without) != []
