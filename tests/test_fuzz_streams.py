"""Fuzzing the stream-id input paths: hostile stream ids in OSC addresses,
ZeroMQ topics and JSON Lines, and more streams than the cap, interleaved with a real take.
The run raises nothing, the unnamed stream gives a clean run's events, and every hostile
frame is counted: malformed (by kind), refused (over the cap) or taken by its own stream."""

from __future__ import annotations

import asyncio
import json
import os
import re
import socket

import numpy as np
import pytest
from cmu import DATA
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from live_helpers import MS, free_port, keyframes_of, run_with_handler, until

from streamkey.adapters import parse_address
from streamkey.adapters.osc import OscSource, encode_frame, encode_skeleton
from streamkey.adapters.zmq import ZmqFrameSender, ZmqSource, encode_frame_parts
from streamkey.bvh import read_bvh
from streamkey.engine import Engine
from streamkey.motion import Frame, Motion
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers

MOTION = read_bvh(DATA / "07_01.bvh")
EXAMPLES = int(os.environ.get("STREAMKEY_FUZZ_EXAMPLES", "8"))
METHODS = ["simplify"]
FRAMES = [Frame(i, i / MOTION.fps, MOTION.channels[i]) for i in range(1, 161)]
CAP = 4
SKELETON_KINDS = ("stream_limit", "skeleton_mismatch")  # what a well-named skeleton may get
VALID_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}")  # the documented grammar


def make(spec):
    motion = Motion(spec.skeleton, np.zeros((0, spec.skeleton.n_channels)), spec.fps)
    return make_keyframers(motion, METHODS, stream=spec.stream)


def clean() -> list[tuple[str, int, int]]:
    pipeline = Pipeline(make_keyframers(MOTION, METHODS))
    return keyframes_of([e.to_dict() for e in pipeline.push_block(FRAMES) + pipeline.flush()])


CLEAN = clean()
HOSTILE_IDS = ["", "/", "a/b", "..", "x" * 65, "ü", "a b", "-a", "a\x00b", "%s", "\u202e",
               "frame", "skeleton", "s1", "s2", "s3", "s4", "s5", "s6"]
stream_ids = st.one_of(st.sampled_from(HOSTILE_IDS), st.text(max_size=70),
                       st.from_regex(VALID_ID, fullmatch=True)).filter(lambda s: s != "default")


async def _live(source, ready, send_frame, send_hostile, schedule, connected=None):
    events: list[dict] = []
    engine = Engine(source, make, [], on_event=events.append, max_streams=CAP)
    task = asyncio.create_task(engine.run())
    await until(ready)
    if connected is not None:
        assert await connected()
    hostile = 0
    for i, frame in enumerate(FRAMES):
        send_frame(frame)
        for stream, kind in schedule.get(i, []):
            hostile += send_hostile(stream, kind, frame)
        await until(lambda i=i: "default" in engine.summary.streams
                    and engine.summary.streams["default"].frames_in >= i - 8)
    await until(lambda: source.stats.received + sum(
        v for k, v in source.stats.malformed.items() if k not in SKELETON_KINDS)
        >= len(FRAMES) + hostile, 20.0)
    engine.stop()
    return await task, events, hostile


def osc_string(text: str) -> bytes:
    raw = text.encode() + b"\0"
    return raw + b"\0" * (-len(raw) % 4)


SKELETON_ARGS = encode_skeleton(MOTION.skeleton, MOTION.fps)[len(osc_string(
    "/streamkey/skeleton")):]


def counted(stream: str, kind: str) -> int:
    """1 if the packet ends as a frame or as a malformed count (a well-named skeleton is
    adopted silently)."""
    return int(kind == "frame" or not VALID_ID.fullmatch(stream))


def _schedule(draws):
    schedule: dict[int, list] = {}
    for position, stream, kind in draws:
        schedule.setdefault(position % len(FRAMES), []).append((stream, kind))
    return schedule


async def _osc_run(schedule):
    port = free_port()
    source = OscSource(parse_address(f"osc://127.0.0.1:{port}"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.connect(("127.0.0.1", port))

    def hostile(stream, kind, frame):
        address = f"/streamkey/{stream}/{kind}"
        if kind == "skeleton":
            out.send(osc_string(address) + SKELETON_ARGS)  # any address, even with a NUL
        else:
            out.send(encode_frame(frame.seq, frame.time, frame.channels, address))
        return counted(stream, kind)

    try:
        return await _live(
            source, lambda: source.sock is not None,
            lambda frame: out.send(encode_frame(frame.seq, frame.time, frame.channels)),
            hostile, schedule)
    finally:
        out.close()


async def _zmq_run(schedule):
    port = free_port(socket.SOCK_STREAM)
    address = parse_address(f"zmq+tcp://127.0.0.1:{port}")
    source = ZmqSource(address, skeleton=MOTION.skeleton, fps=MOTION.fps)
    pub = ZmqFrameSender(address)

    async def subscribed():
        return await asyncio.to_thread(pub.subscribers, 10 * MS) >= 1

    def hostile(stream, kind, frame):
        parts = encode_frame_parts(frame)
        topic = stream.encode("utf-8", "surrogatepass") + b"/" + kind.encode()
        if kind == "skeleton":
            pub.send_skeleton(MOTION.skeleton, MOTION.fps)
            parts = [topic, pub.skeleton_message[1][1]]
        pub.socket.send_multipart([topic, *parts[1:]])
        return counted(stream, kind)

    try:
        return await _live(source, lambda: source.socket is not None, pub.send_frame, hostile,
                           schedule, subscribed)
    finally:
        pub.close()


@pytest.mark.parametrize("transport", ["osc", "zmq"])
@settings(max_examples=EXAMPLES, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_hostile_stream_ids_and_too_many_streams_during_a_live_run(transport, data):
    draws = data.draw(st.lists(st.tuples(st.integers(0, 10_000), stream_ids,
                                         st.sampled_from(["frame", "frame", "skeleton"])),
                               min_size=1, max_size=40))
    run = _osc_run if transport == "osc" else _zmq_run
    summary, events, sent = run_with_handler(run(_schedule(draws)))
    bad = [s for _, s, _ in draws if not VALID_ID.fullmatch(s)]
    malformed = summary.source["malformed"]
    # every frame or skeleton with a hostile id is counted as such, nothing else is lost
    assert malformed.get("stream_id", 0) + malformed.get("address", 0) + malformed.get(
        "topic", 0) == len(bad)
    good_frames = [s for _, s, k in draws if VALID_ID.fullmatch(s) and k == "frame"]
    named = {n: st for n, st in summary.streams.items() if n != "default"}
    assert sum(st.frames_in + st.waiting_drops for st in named.values()) + (
        summary.refused_frames + summary.waiting_at_stop) == len(good_frames)
    assert len(named) <= CAP - 1 and summary.streams["default"].frames_in == len(FRAMES)
    assert keyframes_of([e for e in events if e["stream"] == "default"]) == CLEAN
    assert summary.errors == [] and summary.source_error is None
    assert summary.source["queue_drops"] == 0 and summary.guard["invalid"] == 0


def test_hostile_stream_ids_in_json_lines_are_counted_by_line(tmp_path):
    import subprocess
    import sys

    lines = [json.dumps({"seq": f.seq, "time": f.time, "channels": f.channels.tolist(),
                         **({"stream": s} if s is not None else {})})
             for f, s in zip(FRAMES[:20], [None, "", "a/b", 7, ["x"], "ok", "x" * 99, "é",
                                           *[None] * 12], strict=True)]
    from streamkey.adapters.osc import skeleton_header

    head = json.dumps({"type": "skeleton", "fps": 120.0,
                       "bvh": skeleton_header(MOTION.skeleton, 120.0)})
    result = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", "-", "--method",
                             "simplify", "--to", "-", "--max-streams", "1"],
                            input="\n".join([head, *lines]) + "\n", capture_output=True,
                            text=True, timeout=60 * MS)
    assert result.returncode == 0, result.stderr
    assert "Traceback" not in result.stderr
    assert "stream_id 6" in result.stderr  # "", a/b, 7, ["x"], x*99, é
    assert "1 refused (1 frames; --max-streams 1)" in result.stderr  # "ok" over the cap
