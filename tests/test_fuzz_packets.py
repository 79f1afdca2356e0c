"""Packet fuzzing during a live run on loopback: hostile OSC datagrams and
ZeroMQ messages interleaved with a real take. The run must raise nothing, produce exactly
the events of a clean run over the valid frames, and count every hostile packet by kind.

Deterministic (derandomized hypothesis, fixed example counts) and bounded (a 240-frame
segment, 10 examples per transport; `STREAMKEY_FUZZ_EXAMPLES=N` runs a larger campaign).
"""

from __future__ import annotations

import asyncio
import json
import os
import socket
import struct

import numpy as np
import pytest
from cmu import DATA
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from live_helpers import MS, free_port, keyframes_of, run_with_handler, until
from pythonosc.osc_message_builder import OscMessageBuilder

from streamkey.adapters import parse_address
from streamkey.adapters.osc import OscSource, encode_frame
from streamkey.adapters.zmq import ZmqFrameSender, ZmqSource, encode_frame_parts
from streamkey.bvh import read_bvh
from streamkey.engine import Engine
from streamkey.motion import Frame, Motion
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers

MOTION = read_bvh(DATA / "07_01.bvh")
# CI runs 10 examples per transport; a larger campaign: STREAMKEY_FUZZ_EXAMPLES=500 pytest ...
EXAMPLES = int(os.environ.get("STREAMKEY_FUZZ_EXAMPLES", "10"))
METHODS = ["saliency", "simplify"]
FRAMES = [Frame(i, i / MOTION.fps, MOTION.channels[i]) for i in range(1, 241)]


def make(source):
    motion = Motion(source.skeleton, np.zeros((0, source.skeleton.n_channels)), source.fps)
    return make_keyframers(motion, METHODS)


def clean_events() -> list[tuple[str, int, int]]:
    pipeline = Pipeline(make_keyframers(MOTION, METHODS))
    events = pipeline.push_block(FRAMES) + pipeline.flush()
    return keyframes_of([e.to_dict() for e in events])


CLEAN = clean_events()

# ------------------------------------------------------------------ hostile OSC datagrams

VALID = encode_frame(FRAMES[0].seq, FRAMES[0].time, FRAMES[0].channels)
HEAD = b"#bundle\0" + b"\0" * 8
_builder = OscMessageBuilder("/streamkey/frame")
for _t, _v in [("f", 1e30), ("d", 0.0), *[("f", float(v)) for v in FRAMES[0].channels]]:
    _builder.add_arg(_v, _t)
SEQ_1E30 = _builder.build().dgram


def _osc_packet(kind: str, cut: int, extra: bytes, tag: int) -> bytes:
    if kind == "truncate":
        return VALID[: cut % len(VALID)]
    if kind == "extend":
        return VALID + (extra or b"\0")
    if kind == "tag":  # a non-numeric type tag in place of a channel's `f`
        at = VALID.index(b",id") + 3 + cut % 96
        bad = bytes([tag]) if chr(tag) not in "ihfd\0" else b"s"
        return VALID[:at] + bad + VALID[at + 1 :]
    if kind == "nan":
        at = len(VALID) - 4 * (1 + cut % 96)
        return VALID[:at] + struct.pack(">f", float("nan")) + VALID[at + 4 :]
    if kind == "seq":  # seq 1e30 as a float: out of range
        return SEQ_1E30
    if kind == "bundle":  # an element size that is zero, odd or past the end
        size = (0, 3, 1 << 20, -8)[cut % 4]
        return HEAD + struct.pack(">i", size) + VALID
    if kind == "skeleton":
        return b"/streamkey/skeleton\0,s\0\0" + extra + b"\0" * (-len(extra) % 4 or 4)
    return b"/" + extra  # garbage with an address-like start


osc_packets = st.builds(
    _osc_packet,
    st.sampled_from(["truncate", "extend", "tag", "nan", "seq", "bundle", "skeleton", "junk"]),
    st.integers(0, 10_000), st.binary(max_size=40), st.integers(1, 255))


def _interleave(frames_and_packets):
    """Schedule: hostile packets after the valid frames at the given positions."""
    schedule: dict[int, list] = {}
    for position, packet in frames_and_packets:
        schedule.setdefault(position % len(FRAMES), []).append(packet)
    return schedule


async def _live(source, ready, send_frame, send_hostile, schedule, connected=None):
    """A live engine on `source`: every valid frame, the scheduled hostile packets after
    it (`send_hostile` returns how many it sent), paced by the engine's progress."""
    events: list[dict] = []
    engine = Engine(source, make, [], on_event=events.append)
    task = asyncio.create_task(engine.run())
    await until(ready)
    if connected is not None:
        assert await connected()
    hostile = 0
    for i, frame in enumerate(FRAMES):
        send_frame(frame)
        for packet in schedule.get(i, []):
            hostile += send_hostile(packet)
        # stay inside the socket buffer: wait for the engine to catch up
        await until(lambda i=i: engine.summary.frames_in >= i - 8)
    await until(lambda: source.stats.received + sum(source.stats.malformed.values())
                >= len(FRAMES) + hostile, 20.0)
    engine.stop()
    return await task, events, hostile


def _check(summary, events, hostile) -> None:
    assert keyframes_of(events) == CLEAN  # the valid frames gave a clean run's events
    assert sum(summary.source["malformed"].values()) == hostile, summary.source
    assert summary.frames_in == len(FRAMES) and summary.source["queue_drops"] == 0
    assert summary.guard["invalid"] == 0 and summary.errors == []
    assert summary.source_error is None


async def _osc_run(schedule):
    port = free_port()
    source = OscSource(parse_address(f"osc://127.0.0.1:{port}"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    out.connect(("127.0.0.1", port))
    try:
        return await _live(
            source, lambda: source.sock is not None,
            lambda frame: out.send(encode_frame(frame.seq, frame.time, frame.channels)),
            lambda packet: bool(out.send(packet)) or 1, schedule)
    finally:
        out.close()


# ------------------------------------------------------------------ hostile ZeroMQ messages

GOOD_PARTS = encode_frame_parts(FRAMES[0])


def _zmq_message(kind: str, depth: int, blob: bytes) -> list[bytes]:
    if kind == "deep":
        return [b"frame", b"[" * depth * 100, b""]
    if kind == "header":
        return [b"frame", blob, GOOD_PARTS[2]]
    if kind == "seq":
        return [b"frame", json.dumps({"seq": 1e30, "time": 0, "n": 96}).encode(), GOOD_PARTS[2]]
    if kind == "payload":
        return [b"frame", GOOD_PARTS[1], GOOD_PARTS[2][: depth % len(GOOD_PARTS[2])]]
    if kind == "parts":
        return [b"frame", GOOD_PARTS[1]]
    if kind == "skeleton":
        return [b"skeleton", json.dumps({"bvh": blob.decode("latin-1"), "fps": 120}).encode()]
    if kind == "fps":
        return [b"skeleton", json.dumps({"bvh": "x", "fps": [0, None, 1e9][depth % 3]}).encode()]
    return [b"frame" + blob[:1], blob]


zmq_messages = st.builds(
    _zmq_message,
    st.sampled_from(["deep", "header", "seq", "payload", "parts", "skeleton", "fps", "topic"]),
    st.integers(1, 600), st.binary(max_size=60).filter(lambda b: not b.startswith(b"{")))


async def _zmq_run(schedule):
    port = free_port(socket.SOCK_STREAM)
    address = parse_address(f"zmq+tcp://127.0.0.1:{port}")
    source = ZmqSource(address, skeleton=MOTION.skeleton, fps=MOTION.fps)
    pub = ZmqFrameSender(address)

    async def subscribed():
        return await asyncio.to_thread(pub.subscribers, 10 * MS) >= 1

    def send_hostile(parts):
        if not parts[0].startswith((b"frame", b"skeleton")):  # not subscribed: never arrives
            return 0
        pub.socket.send_multipart(parts)
        return 1

    try:
        return await _live(source, lambda: source.socket is not None, pub.send_frame,
                           send_hostile, schedule, subscribed)
    finally:
        pub.close()


@pytest.mark.parametrize("transport", ["osc", "zmq"])
@settings(max_examples=EXAMPLES, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_packet_fuzz_during_a_live_run(transport, data):
    hostile = osc_packets if transport == "osc" else zmq_messages
    packets = data.draw(st.lists(st.tuples(st.integers(0, 10_000), hostile), min_size=1,
                                 max_size=60))
    run = _osc_run if transport == "osc" else _zmq_run
    summary, events, sent = run_with_handler(run(_interleave(packets)))
    _check(summary, events, sent)
    assert summary.source["kernel_drops"] in (0, None)  # None: not UDP (ZeroMQ)


def test_odd_type_tags_on_the_wire_are_counted_and_print_nothing(capfd):
    """Skeleton messages with type tags python-osc does not know: it printed one warning line
    per packet on stderr and took the rest; now each is refused, counted, and nothing is
    printed. Real datagrams on loopback during a live run."""
    odd = [b"/streamkey/skeleton\0" + tags + b"HIERARCHY\0\0\0"
           for tags in (b",sX\0", b",Xs\0", b",s\x7f\0", b",sdc\0\0\0\0")]
    schedule = _interleave([(5 * i, packet) for i, packet in enumerate(odd * 10)])
    summary, events, sent = run_with_handler(_osc_run(schedule))
    _check(summary, events, sent)
    assert summary.source["malformed"] == {"types": len(odd) * 10}
    assert capfd.readouterr().err == ""
