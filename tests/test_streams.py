"""Many streams in one run: stream ids on every input, per-stream pipelines
equal to single-stream runs, the stream cap, idle retirement, due-first re-analysis."""

from __future__ import annotations

import asyncio
import json
import time

import numpy as np
import zmq
from cmu import DATA
from live_helpers import (
    MS,
    free_port,
    interrupt_if_running,
    read_jsonl,
    streamkey,
    until,
    wait_ready,
)

from streamkey.adapters import parse_address
from streamkey.adapters.osc import OscSource, encode_frame, encode_skeleton, stream_address
from streamkey.adapters.zmq import ZmqSource, encode_frame_parts, topic
from streamkey.bvh import read_bvh
from streamkey.engine import Engine
from streamkey.framequeue import FrameQueue
from streamkey.keyframes import KeyframeEvent
from streamkey.live import build_engine
from streamkey.methods import ONLINE_METHODS
from streamkey.motion import Motion
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers

METHODS = list(ONLINE_METHODS)
CLIPS = {"walk-02": "02_01.bvh", "terrain": "03_01.bvh", "dribble-back": "06_06.bvh",
         "dribble-side": "06_08.bvh", "walk-07": "07_01.bvh", "brisk": "07_12.bvh",
         "walk-08": "08_01.bvh", "dance": "05_11.bvh"}


def single_stream(motion: Motion, methods=METHODS, float32: bool = False) -> list[tuple]:
    """(method, frame, decided_at, score) of one pipeline run on the clip alone."""
    if float32:
        motion = Motion(motion.skeleton, motion.channels.astype(np.float32), motion.fps,
                        motion.first_frame)
    pipe = Pipeline(make_keyframers(motion, methods))
    events = pipe.push_block(motion.frames()) + pipe.flush()
    return [(e.method, e.frame, e.decided_at, e.score) for e in events
            if isinstance(e, KeyframeEvent)]


def per_stream(events: list[dict]) -> dict[str, list[tuple]]:
    out: dict[str, list[tuple]] = {}
    for e in events:
        if e["type"] == "keyframe":
            out.setdefault(e["stream"], []).append(
                (e["method"], e["frame"], e["decided_at"], e["score"]))
    return out


def rounded(events: list[tuple]) -> list[tuple]:
    """Sorted, scores as the JSON carries them (the interleaving of methods may differ)."""
    return sorted((m, f, d, round(s, 6)) for m, f, d, s in events)


async def test_eight_concurrent_120hz_zeromq_streams_each_give_their_single_stream_events():
    motions = {name: read_bvh(DATA / clip) for name, clip in CLIPS.items()}
    port = free_port(1)
    pub = zmq.Context.instance().socket(zmq.XPUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind(f"tcp://127.0.0.1:{port}")
    source = ZmqSource(parse_address(f"zmq+tcp://127.0.0.1:{port}"))
    events: list[dict] = []
    engine = build_engine(source, METHODS, [], on_event=events.append,
                          on_ready=lambda line: None, max_streams=8)
    task = asyncio.create_task(engine.run())
    try:
        await until(lambda: pub.poll(10) != 0, 20.0)  # the engine subscribed
        pub.recv()
        for name, m in motions.items():
            from streamkey.adapters.osc import skeleton_header

            body = json.dumps({"bvh": skeleton_header(m.skeleton, m.fps), "fps": m.fps})
            pub.send_multipart([topic("skeleton", name), body.encode()])
        await until(lambda: len(engine.streams) == 8, 30.0)
        frames = {name: m.frames() for name, m in motions.items()}
        longest = max(len(f) for f in frames.values())
        t0 = time.monotonic()
        for i in range(longest):  # one frame of every stream per tick, 120 Hz at most
            for name, fs in frames.items():
                if i < len(fs):
                    pub.send_multipart(encode_frame_parts(fs[i], "<f8", name))
            await asyncio.sleep(max(0.0, t0 + (i + 1) / 120 - time.monotonic()))
            # stay well inside the queues on a loaded machine: the events must not depend
            # on pacing, and no frame may be dropped
            await until(lambda i=i: engine.summary.frames_in >= sum(
                min(i + 1, len(fs)) for fs in frames.values()) - 64, 60.0)
        total = sum(len(fs) for fs in frames.values())
        await until(lambda: engine.summary.frames_in == total, 60.0)
        engine.stop()
        summary = await task
    finally:
        pub.close(linger=0)
        if not task.done():
            engine.stop()
            await task
    assert summary.source["queue_drops"] == 0 and summary.refused_streams == 0
    got = per_stream(events)
    assert set(got) == set(CLIPS)
    for name, m in motions.items():
        stats = summary.streams[name]
        assert stats.frames_in == len(frames[name]) and stats.guard["gaps"] == 0
        assert rounded(got[name]) == rounded(single_stream(m)), name
        assert {e[0] for e in got[name]} == set(METHODS)


def test_two_replay_processes_with_stream_ids_feed_one_run_over_osc(tmp_path):
    clips = {"left": DATA / "07_01.bvh", "right": DATA / "09_06.bvh"}
    port = free_port()
    log = tmp_path / "events.jsonl"
    summary = tmp_path / "summary.json"
    run = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--method", "speed,simplify",
                    "--to", f"jsonl:{log}", "--summary", str(summary), "--max-streams", "2",
                    "--idle-exit", str(1.5 * MS))
    try:
        wait_ready(run)
        replays = [streamkey("replay", str(clip), "--stream", name, "--to",
                             f"osc://127.0.0.1:{port}") for name, clip in clips.items()]
        for r in replays:
            assert r.wait(timeout=60 * MS) == 0, r.communicate()[1]
            r.communicate()
        _, err = run.communicate(timeout=60 * MS)
    finally:
        interrupt_if_running(run)
    assert run.returncode == 0, err
    got = per_stream(read_jsonl(log))
    for name, clip in clips.items():
        expected = single_stream(read_bvh(clip), ["speed", "simplify"], float32=True)
        assert rounded(got[name]) == rounded(expected), (name, err)  # err: frames lost?
    streams = json.loads(summary.read_text())["streams"]
    assert set(streams) == set(clips) and "stream left:" in err


def test_json_lines_streams_on_stdin_each_get_their_own_pipeline(tmp_path):
    import subprocess
    import sys

    a, b = read_bvh(DATA / "07_12.bvh"), read_bvh(DATA / "08_01.bvh")
    from streamkey.adapters.osc import skeleton_header

    lines = [json.dumps({"type": "skeleton", "fps": 120.0, "bvh": skeleton_header(a.skeleton,
                                                                                  120.0)}),
             json.dumps({"type": "skeleton", "fps": 120.0, "stream": "b",
                         "bvh": skeleton_header(b.skeleton, 120.0)})]
    fa, fb = a.frames(), b.frames()
    for i in range(max(len(fa), len(fb))):
        for name, fs in (("a", fa), ("b", fb)):
            if i < len(fs):
                lines.append(json.dumps({"seq": fs[i].seq, "time": fs[i].time, "stream": name,
                                         "channels": fs[i].channels.tolist()}))
    lines.insert(5, json.dumps({"seq": 1, "stream": "../etc", "channels": [0.0]}))
    result = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", "-",
                             "--method", "speed,simplify", "--to", "-"],
                            input="\n".join(lines) + "\n", capture_output=True, text=True,
                            timeout=120 * MS)
    assert result.returncode == 0, result.stderr
    got = per_stream([json.loads(x) for x in result.stdout.splitlines()])
    assert rounded(got["a"]) == rounded(single_stream(a, ["speed", "simplify"]))
    assert rounded(got["b"]) == rounded(single_stream(b, ["speed", "simplify"]))
    assert "stream_id 1" in result.stderr


async def osc_engine(**kwargs):
    port = free_port()
    source = OscSource(parse_address(f"osc://127.0.0.1:{port}"))
    said: list[str] = []
    events: list[dict] = []
    engine = build_engine(source, ["speed", "simplify"], [], on_event=events.append,
                          on_ready=said.append, **kwargs)
    task = asyncio.create_task(engine.run())
    await until(lambda: source.sock is not None)
    import socket

    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    return engine, task, (lambda data: out.sendto(data, ("127.0.0.1", port))), said, events, out


async def test_streams_beyond_the_cap_are_refused_clearly_and_counted():
    m = read_bvh(DATA / "07_01.bvh")
    engine, task, send, said, events, out = await osc_engine(max_streams=2)
    for name in ("one", "two", "three"):
        send(encode_skeleton(m.skeleton, m.fps, stream_address("skeleton", name)))
    await until(lambda: len(engine.streams) == 2 and engine.source.stats.malformed[
        "stream_limit"] == 1)
    for f in m.frames()[:40]:
        for name in ("one", "two", "four"):
            send(encode_frame(f.seq, f.time, f.channels, stream_address("frame", name)))
        await until(lambda f=f: engine.summary.frames_in >= 3 * (f.seq - 1) - 6)
    await until(lambda: engine.summary.frames_in == 120)
    engine.stop()
    summary = await task
    out.close()
    assert summary.refused_streams == 1 and summary.refused_frames == 40
    assert [line for line in said if "refused" in line] == [
        "stream 'four' refused: this run already serves 2 streams (--max-streams); its "
        "frames are dropped and counted"]
    assert summary.streams["one"].frames_in == summary.streams["two"].frames_in == 40
    assert "streams: 2 served, 1 refused (40 frames; --max-streams 2)" in summary.text()
    assert summary.accounting()["refused_streams"] == 40


async def test_an_idle_stream_is_retired_flushed_and_starts_afresh_when_it_returns():
    m = read_bvh(DATA / "07_01.bvh")
    engine, task, send, said, events, out = await osc_engine(stream_idle=0.3)
    send(encode_skeleton(m.skeleton, m.fps, stream_address("skeleton", "solo")))
    frames = m.frames()
    for f in frames:
        send(encode_frame(f.seq, f.time, f.channels, stream_address("frame", "solo")))
        await until(lambda f=f: engine.summary.frames_in >= f.seq - 8)
    await until(lambda: "solo" not in engine.streams, 10.0)  # retired: flushed
    first = [e for e in events if e["type"] == "keyframe"]
    assert any("retired after 0.3 s" in line for line in said)
    expected = single_stream(m, ["speed", "simplify"], float32=True)
    assert rounded([(e["method"], e["frame"], e["decided_at"], e["score"]) for e in first]) \
        == rounded(expected)
    send(encode_skeleton(m.skeleton, m.fps, stream_address("skeleton", "solo")))
    for f in frames[:30]:  # back again: a new session
        send(encode_frame(f.seq, f.time, f.channels, stream_address("frame", "solo")))
    await until(lambda: engine.summary.streams["solo"].sessions == 2)
    engine.stop()
    summary = await task
    out.close()
    assert summary.streams["solo"].retired == 2


async def test_due_decisions_of_every_stream_go_before_any_re_analysis():
    """Frames of two streams queued together: with due-first, stream b's frame is processed
    before stream a's deferred re-analysis of the same tick; without, after it."""
    from streamkey.methods import speed
    from streamkey.replay.source import MotionSource

    m = read_bvh(DATA / "07_01.bvh")
    frames = m.frames()[:120]

    async def order(due_first: bool) -> list[tuple[str, str, int]]:
        calls: list[tuple[str, str, int]] = []

        class Traced(speed.Online):  # the real keyframer, its calls recorded
            def process(self, block):
                calls.append(("process", self.stream, int(block.seq[-1])))
                return super().process(block)

            def idle(self):
                if self._analysis_due:
                    calls.append(("idle", self.stream, self._last_seq))
                return super().idle()

        source = MotionSource(m, rate=0.0)
        source.frames = FrameQueue(source.stats, maxsize=0)
        for f in frames:
            for name in ("a", "b"):
                source.frames.put(f, None, name)
        source.frames.put(None)
        source.start = lambda: asyncio.sleep(0, "preloaded")  # type: ignore[method-assign]
        def traced(spec):  # unfiltered: the calls are traced in the frames' own seq
            kf = Traced(spec.skeleton, spec.fps, stream=spec.stream)
            kf.features.configure(None)
            return [kf]

        engine = Engine(source, traced, [], due_first=due_first)
        await engine.run()
        return calls

    for due_first in (True, False):
        calls = await order(due_first)
        idles = [c for c in calls if c[0] == "idle" and c[1] == "a"]
        assert idles
        for _, _, seq in idles:
            b_done = calls.index(("process", "b", seq)) < calls.index(("idle", "a", seq))
            assert b_done == due_first


async def test_an_engine_takes_over_a_stream_from_another_engines_snapshot():
    """Worker handover: engine one serves a stream, its snapshot goes to engine two, which
    gets the frames from the snapshot on; together they give the single-stream events."""
    from streamkey.replay.source import MotionSource

    m = read_bvh(DATA / "07_12.bvh")
    frames = m.frames()

    def preloaded(part):
        source = MotionSource(m, rate=0.0)
        source.frames = FrameQueue(source.stats, maxsize=0)
        for f in part:
            source.frames.put(f, None, "take")
        source.start = lambda: asyncio.sleep(0, "preloaded")  # type: ignore[method-assign]
        return source

    snapshots: list[bytes] = []
    events: list[dict] = []

    def at_cut(frame):
        if frame.seq == frames[120].seq:
            snapshots.append(one.snapshot_stream("take"))

    one = build_engine(preloaded(frames[:160]), METHODS, [], on_event=events.append,
                       on_ready=lambda line: None, on_frame=at_cut)
    one.source.frames.put(None)
    task = asyncio.create_task(one.run())
    await until(lambda: one.summary.frames_in == 160)
    first = [e for e in events if e["type"] == "keyframe" and e["decided_at"] <= frames[120].seq]
    one.stop()
    await task
    two_events: list[dict] = []
    two = build_engine(preloaded(frames[121:]), METHODS, [], on_event=two_events.append,
                       on_ready=lambda line: None)
    two.restore_stream("take", snapshots[0])
    two.source.frames.put(None)
    await two.run()
    from streamkey.adapters.sinks import event_id

    # the snapshot was taken between frame 120's push and its re-analysis: events decided
    # at frame 120 may come from both engines, with the same ids (dropped as duplicates)
    unique = {event_id(e): e for e in first + two_events if e["type"] == "keyframe"}
    got = per_stream(list(unique.values()))["take"]
    assert rounded(got) == rounded(single_stream(m))


async def test_the_sockets_are_read_between_turns_while_a_backlog_is_computed():
    """Drain before compute: 300 frames of stream a queued, each push made 0.5 ms dearer
    (a busy wait in the real keyframer); a datagram sent when the 10th is pushed is read
    within a turn (1 ms of work, two or three pushes), not after the whole backlog."""
    import socket

    from streamkey.methods import speed

    m = read_bvh(DATA / "07_01.bvh")

    class Dear(speed.Online):
        def process(self, block):
            until_ns = time.thread_time_ns() + 500_000
            while time.thread_time_ns() < until_ns:
                pass
            return super().process(block)

    port = free_port()
    source = OscSource(parse_address(f"osc://127.0.0.1:{port}"), None, m.skeleton, m.fps)
    source.frames = FrameQueue(source.stats, maxsize=0)
    for f in m.frames()[:300]:
        source.frames.put(f, None, "a")
    source.frames.put(None)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    read_at: list[int] = []
    receive = source.receive

    def received(data, arrival_ns=None, depth=0):  # type: ignore[no-untyped-def]
        read_at.append(engine.summary.frames_in)
        receive(data, arrival_ns, depth)

    source.receive = received  # type: ignore[method-assign]
    f0 = m.frames()[0]

    def on_frame(frame):  # type: ignore[no-untyped-def]
        if engine.summary.frames_in == 10:
            out.sendto(encode_frame(f0.seq, f0.time, f0.channels, stream_address("frame", "b")),
                       ("127.0.0.1", port))

    def dear(spec):  # type: ignore[no-untyped-def]  # unfiltered: every push is dear at once
        kf = Dear(spec.skeleton, spec.fps, stream=spec.stream)
        kf.features.configure(None)
        return [kf]

    engine = Engine(source, dear, [], on_frame=on_frame)
    try:
        summary = await engine.run()
    finally:
        out.close()
    assert summary.frames_in == 300 and read_at, "the datagram was never read"
    assert read_at[0] <= 10 + 4, f"read after {read_at[0]} frames, sent after 10"
    assert summary.scheduler["turns"] >= 300 * 0.5 / 1.0 / 2
    stats = summary.streams["a"].as_dict()["due_latency_ms"]  # measured per stream
    assert stats["max"] is not None and stats["p99"] <= stats["max"]


def test_the_scheduler_puts_due_work_first_and_deferred_work_oldest_first():
    from streamkey.scheduler import Scheduler

    s: Scheduler[str] = Scheduler(budget_ns=1000)
    s.defer("a", "a1")
    s.defer("b", "b1")
    s.defer("a", "a2")  # a's newer work goes behind b's
    assert len(s) == 2 and "a" in s
    assert s.take("b") == "b1" and s.take("b") is None  # before b's next push
    s.defer("c", "c1")
    assert [s.next_deferred(), s.next_deferred(), s.next_deferred()] == ["a2", "c1", None]
    s.begin(10)
    s.begin(500)  # the same turn
    assert not s.should_drain(1009) and s.should_drain(1010)
    s.drained(1500)
    assert not s.should_drain(10**9)  # no turn open
    assert s.stats.turns == 1 and s.stats.longest_turn_ms == 1490 / 1e6
    assert s.stats.deferred_in_order == 1 and s.stats.deferred_idle == 2


async def test_a_stream_is_not_retired_while_its_frames_wait_behind_a_slow_push():
    """Idleness on the arrival clock: frames of streams a and b queued together, one push
    of a takes twice `stream_idle`; neither stream is idle (their frames had arrived), so
    both keep one session and decide as they would alone."""
    from streamkey.engine import EngineConfig
    from streamkey.methods import speed

    m = read_bvh(DATA / "07_01.bvh")
    frames = m.frames()[:240]

    class Stalls(speed.Online):
        def process(self, block):
            if self.stream == "a" and 100 in np.asarray(block.seq):
                time.sleep(0.6)
            return super().process(block)

    source = OscSource(parse_address(f"osc://127.0.0.1:{free_port()}"), None, m.skeleton, m.fps)
    source.frames = FrameQueue(source.stats, maxsize=0)
    for f in frames:
        for tag in ("a", "b"):
            source.frames.put(f, None, tag)
    source.frames.put(None)
    said: list[str] = []
    engine = Engine(source, lambda spec: [Stalls(spec.skeleton, spec.fps, stream=spec.stream)],
                    [], config=EngineConfig(stream_idle=0.3, on_ready=said.append))
    summary = await engine.run()
    assert not [line for line in said if "retired after" in line]
    for tag in ("a", "b"):
        assert summary.streams[tag].sessions == 1 and summary.streams[tag].frames_in == 240
