"""The ZeroMQ source read by the event loop: real sockets, overflow provoked by a loop that
does not read for a while; every frame that does not reach the keyframers is counted."""

from __future__ import annotations

import asyncio
import json
import threading
import time

import pytest
import zmq
from cmu import DATA
from live_helpers import MS, free_port, until

from streamkey.adapters import parse_address
from streamkey.adapters.osc import skeleton_header
from streamkey.adapters.zmq import ZmqSource, encode_frame_parts, topic
from streamkey.bvh import read_bvh
from streamkey.errors import UsageError
from streamkey.live import build_engine
from streamkey.motion import Frame

CLIP = read_bvh(DATA / "07_01.bvh")


def frame(seq: int) -> Frame:
    """Frame `seq` of the clip played in a loop (seq numbers keep counting up)."""
    return Frame(seq, seq / CLIP.fps, CLIP.channels[seq % len(CLIP.channels)])


def hold_the_loop(seconds: float) -> None:
    """Keep the event loop from anything else, as a long push would."""
    time.sleep(seconds)


def skeleton_parts() -> list[bytes]:
    body = json.dumps({"bvh": skeleton_header(CLIP.skeleton, CLIP.fps), "fps": CLIP.fps})
    return [topic("skeleton"), body.encode()]


async def serve(source: ZmqSource, feed, total: int) -> tuple[object, float]:
    """Run an engine (speed only) on `source`; `feed(engine)` sends, from the test's side,
    while the test blocks the loop; returns the run's summary once `total` frames are
    accounted for (pushed or counted as never arrived), and how long the loop was blocked."""
    engine = build_engine(source, ["speed"], [], on_ready=lambda line: None)
    task = asyncio.create_task(engine.run())
    try:
        blocked = await feed(engine)

        def accounted() -> bool:
            state = engine.streams.get("default")
            lost = 0 if state is None else state.pipeline.guard.counters.lost
            return engine.summary.frames_in + lost >= total

        await until(lambda: engine.summary.frames_in > 0, 60 * MS)
        await until(accounted, 120 * MS)
        engine.stop()
        return await task, blocked
    finally:
        if not task.done():
            engine.stop()
            await task


@pytest.mark.parametrize("reader", ["loop", "thread"])
async def test_a_sub_socket_overflow_while_the_loop_is_busy_is_counted_frame_by_frame(reader):
    port = free_port(1)
    pub = zmq.Context.instance().socket(zmq.XPUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.setsockopt(zmq.SNDHWM, 100)
    pub.bind(f"tcp://127.0.0.1:{port}")
    source = ZmqSource(parse_address(f"zmq+tcp://127.0.0.1:{port}?reader={reader}"))
    burst, tail = 40_000, 20
    total = burst + tail

    async def feed(engine) -> float:
        await until(lambda: pub.poll(10) != 0, 30 * MS)  # the source subscribed
        pub.recv()
        pub.send_multipart(skeleton_parts())
        await until(lambda: "default" in engine.streams, 30 * MS)
        for seq in range(20):  # the stream runs
            pub.send_multipart(encode_frame_parts(frame(seq), "<f8"))
        await until(lambda: engine.summary.frames_in == 20, 30 * MS)
        sender = threading.Thread(target=lambda: [
            pub.send_multipart(encode_frame_parts(frame(seq), "<f8"), zmq.NOBLOCK)
            for seq in range(20, burst)])
        t0 = time.monotonic()
        sender.start()
        sender.join()  # the loop is blocked the while: nothing reads the socket
        hold_the_loop(0.5)
        blocked = time.monotonic() - t0
        for seq in range(burst, total):  # the stream goes on at 120 Hz after the burst
            pub.send_multipart(encode_frame_parts(frame(seq), "<f8"))
            await asyncio.sleep(1 / 120)
        return blocked

    try:
        summary, blocked = await serve(source, feed, total)
    finally:
        pub.close(linger=0)
    a = summary.accounting()
    # libzmq dropped frames without a counter of its own: each one is a seq hole (and so is
    # each frame the thread reader's hand-over queue dropped, counted there too)
    assert a["never_arrived"] > 0, (a, blocked)
    assert a["processed"] + a["never_arrived"] == total, a
    assert a["arrived"] == a["processed"] + a["queue_drops"], a  # the accounting adds up
    if reader == "loop":  # it reads only what the frame queue has room for
        assert a["queue_drops"] == 0, a
    else:  # the thread read on: its hand-over queue dropped the oldest, each a seq hole too
        assert 0 < a["queue_drops"] <= a["never_arrived"], a
    assert summary.streams["default"].guard["lost"] == a["never_arrived"]


async def test_with_the_loop_reader_a_pull_socket_never_drops_its_senders_wait():
    port = free_port(1)
    source = ZmqSource(parse_address(f"zmq+tcp://127.0.0.1:{port}?pattern=pull&reader=loop"))
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    push.setsockopt(zmq.SNDHWM, 10)
    push.setsockopt(zmq.SNDBUF, 4096)
    total = 10_000

    async def feed(engine) -> float:
        push.connect(f"tcp://127.0.0.1:{port}")
        push.send_multipart(skeleton_parts())
        await until(lambda: "default" in engine.streams, 30 * MS)
        sent = threading.Event()

        def send() -> None:
            for seq in range(total):  # blocking sends: a full queue makes the sender wait
                push.send_multipart(encode_frame_parts(frame(seq), "<f8"))
            sent.set()

        t0 = time.monotonic()
        threading.Thread(target=send, daemon=True).start()
        hold_the_loop(1.0)  # the loop is blocked: the queues fill, the sender waits
        waited = not sent.is_set()
        await until(sent.is_set, 120 * MS)
        return (time.monotonic() - t0) if waited else -1.0

    try:
        summary, blocked = await serve(source, feed, total)
    finally:
        push.close(linger=0)
    a = summary.accounting()
    assert blocked > 0, "the sender never had to wait: the queues did not fill"
    assert a["processed"] == total and a["never_arrived"] == 0 and a["queue_drops"] == 0, a


async def test_the_loop_reader_counts_frames_still_in_libzmq_at_stop_as_unread():
    port = free_port(1)
    source = ZmqSource(parse_address(f"zmq+tcp://127.0.0.1:{port}?pattern=pull&reader=loop"))
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    engine = build_engine(source, ["speed"], [], on_ready=lambda line: None)
    task = asyncio.create_task(engine.run())
    try:
        push.connect(f"tcp://127.0.0.1:{port}")
        push.send_multipart(skeleton_parts())
        await until(lambda: "default" in engine.streams, 30 * MS)
        for seq in range(200):
            push.send_multipart(encode_frame_parts(frame(seq), "<f8"))
        hold_the_loop(0.5)  # they reach libzmq's queue while the loop reads nothing
        engine.stop()
        summary = await task
    finally:
        push.close(linger=0)
        if not task.done():
            engine.stop()
            await task
    a = summary.accounting()
    assert a["processed"] + a["left_in_queue"] + a["queue_drops"] == 200, a
    assert a["arrived"] == 200, a


@pytest.mark.parametrize("reader", ["loop", "thread"])
async def test_both_readers_deliver_every_frame_of_a_paced_stream(reader):
    port = free_port(1)
    pub = zmq.Context.instance().socket(zmq.XPUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind(f"tcp://127.0.0.1:{port}")
    source = ZmqSource(parse_address(f"zmq+tcp://127.0.0.1:{port}?reader={reader}"))
    total = 240

    async def feed(engine) -> float:
        await until(lambda: pub.poll(10) != 0, 30 * MS)
        pub.recv()
        pub.send_multipart(skeleton_parts())
        await until(lambda: "default" in engine.streams, 30 * MS)
        for seq in range(total):
            pub.send_multipart(encode_frame_parts(frame(seq), "<f8"))
            await asyncio.sleep(1 / 240)
        return 0.0

    try:
        summary, _ = await serve(source, feed, total)
    finally:
        pub.close(linger=0)
    assert summary.frames_in == total and summary.streams["default"].guard["lost"] == 0
    assert (source.thread is not None) == (reader == "thread")


def test_the_thread_reader_is_the_default():
    assert ZmqSource(parse_address("zmq+tcp://127.0.0.1:9")).reader == "thread"


def test_an_unknown_reader_is_a_usage_error_naming_the_choices():
    with pytest.raises(UsageError, match="reader must be loop or thread"):
        ZmqSource(parse_address("zmq+tcp://127.0.0.1:9?reader=fast"))


async def test_the_loop_reader_reads_between_turns_while_a_backlog_is_computed():
    """Drain before compute, with the loop reader: 300 frames of stream a queued, each push
    made 0.5 ms dearer; a frame of stream b pushed to the socket when the 10th is pushed
    is read within a few turns, not after the whole backlog."""
    from streamkey.engine import Engine
    from streamkey.framequeue import FrameQueue
    from streamkey.methods import speed

    class Dear(speed.Online):
        def process(self, block):
            until_ns = time.thread_time_ns() + 500_000
            while time.thread_time_ns() < until_ns:
                pass
            return super().process(block)

    port = free_port(1)
    address = parse_address(f"zmq+tcp://127.0.0.1:{port}?pattern=pull&reader=loop")
    source = ZmqSource(address, None, CLIP.skeleton, CLIP.fps)
    source.frames = FrameQueue(source.stats, maxsize=0)
    for seq in range(300):
        source.frames.put(frame(seq), None, "a")
    source.frames.put(None)
    push = zmq.Context.instance().socket(zmq.PUSH)
    push.setsockopt(zmq.LINGER, 0)
    read_at: list[int] = []
    handle = source.handle

    def handled(parts, arrival_ns=None):  # type: ignore[no-untyped-def]
        read_at.append(engine.summary.frames_in)
        handle(parts, arrival_ns)

    source.handle = handled  # type: ignore[method-assign]

    def on_frame(_frame: Frame) -> None:
        if engine.summary.frames_in == 1:
            push.connect(f"tcp://127.0.0.1:{port}")
        if engine.summary.frames_in == 10:
            push.send_multipart(encode_frame_parts(frame(0), "<f8", "b"))

    engine = Engine(source, lambda spec: [Dear(spec.skeleton, spec.fps, stream=spec.stream)],
                    [], on_frame=on_frame)
    try:
        summary = await engine.run()
    finally:
        push.close(linger=0)
    assert summary.frames_in == 300 and read_at, "the frame of b was never read"
    assert read_at[0] <= 10 + 40, f"read after {read_at[0]} frames, sent after 10"
    assert summary.scheduler["turns"] >= 300 * 0.5 / 1.0 / 2
