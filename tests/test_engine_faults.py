"""Faults at the engine level: the stream keeps running, counters report, nothing crashes,
and the JSON Lines log loses no event that was emitted."""

from __future__ import annotations

import asyncio
import json
import socket

import numpy as np
import pytest
import zmq
from cmu import DATA
from live_helpers import MS, free_port, read_jsonl, until
from websockets.asyncio.client import connect

from streamkey.adapters import make_sink, parse_address
from streamkey.adapters.osc import OscSource, encode_frame
from streamkey.adapters.zmq import ZmqFrameSender, ZmqSource
from streamkey.bvh import read_bvh
from streamkey.engine import Engine
from streamkey.errors import InputError
from streamkey.framequeue import FrameQueue
from streamkey.motion import Motion
from streamkey.streaming import make_keyframers

MOTION = read_bvh(DATA / "07_01.bvh")


def keyframers(methods=("speed", "simplify")):
    def make(source):
        m = Motion(source.skeleton, np.zeros((0, source.skeleton.n_channels)), source.fps)
        return make_keyframers(m, list(methods))
    return make


async def osc_engine(tmp_path):
    """An engine listening for OSC frames on a free port, logging to JSON Lines."""
    port = free_port()
    source = OscSource(parse_address(f"osc://127.0.0.1:{port}"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)
    log = tmp_path / "log.jsonl"
    engine = Engine(source, keyframers(), [make_sink(parse_address(f"jsonl:{log}"))])
    task = asyncio.create_task(engine.run())
    await until(lambda: source.sock is not None)
    return port, source, log, engine, task


def sender():
    return socket.socket(socket.AF_INET, socket.SOCK_DGRAM)


async def test_malformed_osc_packets_are_counted_and_the_stream_goes_on(tmp_path):
    port, source, log, engine, task = await osc_engine(tmp_path)
    out = sender()
    target = ("127.0.0.1", port)
    good = [encode_frame(i, i / 120, MOTION.channels[i]) for i in range(1, MOTION.n_frames)]
    nan = MOTION.channels[5].copy()
    nan[7] = np.nan
    bad = [b"", b"garbage", b"/wrong/address\x00\x00,i\x00\x00\x00\x00\x00\x01",
           encode_frame(5, 0.0, nan), encode_frame(6, 0.0, MOTION.channels[6][:10]),
           b"/streamkey/frame\x00\x00\x00\x00,ids\x00\x00\x00\x00" + b"\x00" * 16,
           b"x" * 70_000]
    for i, packet in enumerate(good):
        out.sendto(packet, target)
        if i < len(bad):
            try:
                out.sendto(bad[i], target)
            except OSError:  # the kernel refuses the oversize datagram itself
                pass
        if i % 10 == 0:  # stay within what UDP buffers hold: wait for the engine
            await until(lambda i=i: engine.summary.frames_in >= i - 10)
    await until(lambda: engine.summary.frames_in == len(good) + 1)
    out.close()
    engine.stop()
    summary = await task
    assert summary.frames_in == len(good) + 1  # the wrong-channel-count frame reached the guard
    assert summary.guard["invalid"] == 1
    malformed = summary.source["malformed"]
    assert malformed.get("nan") == 1 and malformed.get("address") == 1
    assert sum(malformed.values()) >= 5
    logged = [e for e in read_jsonl(log) if e["type"] == "keyframe"]
    assert len(logged) == sum(v for k, v in summary.events.items() if k in ("speed", "simplify"))
    assert len(logged) > 5


async def test_duplicates_out_of_order_and_silence_do_not_stop_the_stream(tmp_path):
    port, source, log, engine, task = await osc_engine(tmp_path)
    out = sender()
    order = list(range(1, 150)) + [149, 148, 120] + list(range(150, 200))
    for i, seq in enumerate(order):
        out.sendto(encode_frame(seq, seq / 120, MOTION.channels[seq]), ("127.0.0.1", port))
        await until(lambda i=i: engine.summary.frames_in >= i - 10)
    await until(lambda: engine.summary.frames_in == len(order))
    await asyncio.sleep(0.5 * MS)  # the source goes silent ...
    for i, seq in enumerate(range(205, MOTION.n_frames)):  # ... and comes back after a gap
        out.sendto(encode_frame(seq, seq / 120, MOTION.channels[seq]), ("127.0.0.1", port))
        await until(lambda i=i: engine.summary.frames_in >= len(order) + i - 10)
    await until(lambda: engine.summary.frames_in == len(order) + MOTION.n_frames - 205)
    out.close()
    engine.stop()
    summary = await task
    assert summary.guard["duplicates"] == 1 and summary.guard["out_of_order"] == 2
    assert summary.guard["gaps"] == 1 and summary.guard["bridged_frames"] == 5
    accounting = summary.accounting()  # every packet that arrived, and the frames that did not
    assert accounting["never_arrived"] == 5 and accounting["processed"] == len(order) - 3 + (
        MOTION.n_frames - 205)
    assert accounting["arrived"] == accounting["processed"] + 3
    assert "5 frames never arrived" in summary.text()
    events = read_jsonl(log)
    gaps = [e for e in events if e["type"] == "gap"]
    assert [(g["first"], g["last"], g["bridged"]) for g in gaps] == [(200, 204, True)]
    assert any(e["type"] == "keyframe" and e["frame"] > 205 for e in events)


async def bind_publisher(address):
    """libzmq closes sockets in its I/O thread: the port may be busy a moment after close."""
    for _ in range(100):
        try:
            return ZmqFrameSender(address)
        except InputError:  # "cannot bind ...: Address already in use"
            await asyncio.sleep(0.05)
    raise AssertionError(f"could not bind {address}")


async def test_zmq_publisher_restart_is_survived(tmp_path):
    port = free_port(socket.SOCK_STREAM)
    address = parse_address(f"zmq+tcp://127.0.0.1:{port}")
    source = ZmqSource(address)
    log = tmp_path / "log.jsonl"
    engine = Engine(source, keyframers(("speed",)), [make_sink(parse_address(f"jsonl:{log}"))])
    task = asyncio.create_task(engine.run())
    await until(lambda: source.socket is not None)
    for attempt in range(2):  # the publisher starts, stops, and starts again from frame 1
        pub = await bind_publisher(address)
        assert await asyncio.to_thread(pub.subscribers, 5.0 * MS) >= 1
        pub.send_skeleton(MOTION.skeleton, MOTION.fps)
        for i, frame in enumerate(MOTION.frames()):
            pub.send_frame(frame)
            base = attempt * (MOTION.n_frames - 1)
            await until(lambda i=i, base=base: engine.summary.frames_in >= base + i - 10)
        want = (attempt + 1) * (MOTION.n_frames - 1)
        await until(lambda want=want: engine.summary.frames_in >= want)
        pub.close()
    engine.stop()
    summary = await task
    assert summary.frames_in == 2 * (MOTION.n_frames - 1)
    assert summary.guard["restarts"] == 1
    events = read_jsonl(log)
    assert any(e["type"] == "status" and e["status"] == "restart" for e in events)
    speed = [e["frame"] for e in events if e["type"] == "keyframe"]
    half = len(speed) // 2
    assert len(speed) % 2 == 0 and speed[:half] == speed[half:]  # same keys on both takes


async def test_absent_osc_receiver_and_a_websocket_client_that_stops_reading(tmp_path):
    dead_port = free_port()  # nobody listens there
    ws_port = free_port(socket.SOCK_STREAM)
    log = tmp_path / "log.jsonl"
    from streamkey.replay.source import MotionSource

    source = MotionSource(MOTION, rate=0.0, loop=True, end=MOTION.n_frames)
    sinks = [make_sink(parse_address(a)) for a in
             (f"osc://127.0.0.1:{dead_port}", f"ws://127.0.0.1:{ws_port}", f"jsonl:{log}")]
    sinks[1].client_queue = 16
    sinks[1].send_buffer = 4096
    engine = Engine(source, keyframers(("simplify",)), sinks)
    task = asyncio.create_task(engine.run())
    ws = sinks[1]
    await until(lambda: ws.server is not None)
    # A reader that stops reading after its first message, and a reader that keeps up.
    small = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    small.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 2048)
    small.connect(("127.0.0.1", ws_port))
    async with connect(f"ws://127.0.0.1:{ws_port}", max_queue=1, sock=small,
                       close_timeout=0.5) as lazy, \
            connect(f"ws://127.0.0.1:{ws_port}", close_timeout=0.5) as keen:
        first = json.loads(await lazy.recv())
        assert first["type"] in ("keyframe", "segment")  # the first event the run sent
        got = []
        while (ws.stats.dropped == 0 or len(got) < 100) and len(got) < 3000:
            got.append(json.loads(await asyncio.wait_for(keen.recv(), 10 * MS)))
        engine.stop()
        summary = await task
    assert all(e["method"] == "simplify" for e in got if e["type"] == "keyframe")
    # the OSC sink counts every event it carries (keyframes, and the loop's gap or status)
    assert summary.sinks["osc"]["sent"] + summary.sinks["osc"]["dropped"] == sum(
        summary.events.values()), dict(summary.events)
    assert summary.sinks["ws"]["dropped"] > 0  # the lazy client's oldest events went
    logged = [e for e in read_jsonl(log) if e["type"] == "keyframe"]
    assert len(logged) == summary.events["simplify"] >= len(got) >= 100


def test_sink_addresses_bind_loopback_unless_listen_is_given():
    from streamkey.errors import UsageError

    with pytest.raises(UsageError, match="needs --listen"):
        make_sink(parse_address("ws://0.0.0.0:9999"))
    with pytest.raises(UsageError, match="needs --listen"):
        OscSource(parse_address("osc://192.168.1.10:9000"))
    assert zmq.zmq_version()


async def test_a_failing_keyframer_is_contained_and_the_log_keeps_everything(tmp_path):
    from streamkey.methods import speed
    from streamkey.replay.source import MotionSource

    class Faulty(speed.Online):  # fault injection: one bug at one frame
        def process(self, block):
            if block.seq[0] == 100:
                raise RuntimeError("injected fault")
            return super().process(block)

    def make(source):
        return [Faulty(source.skeleton, source.fps),
                *keyframers(("simplify",))(source)]

    log = tmp_path / "log.jsonl"
    engine = Engine(MotionSource(MOTION, rate=0.0), make,
                    [make_sink(parse_address(f"jsonl:{log}"))])
    summary = await engine.run()
    assert summary.frames_in == MOTION.n_frames - 1
    assert len(summary.errors) == 1 and "injected fault" in summary.errors[0]
    events = read_jsonl(log)
    assert [e["status"] for e in events if e["type"] == "status"] == ["error"]
    assert any(e["type"] == "keyframe" and e["method"] == "simplify" and e["frame"] > 150
               for e in events)


def test_a_busy_port_is_a_clear_input_error_not_a_traceback(tmp_path):
    import subprocess
    import sys

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        for target in (f"ws://127.0.0.1:{port}", f"zmq+tcp://127.0.0.1:{port}"):
            result = subprocess.run(
                [sys.executable, "-m", "streamkey", "run", "--from", str(DATA / "09_06.bvh"),
                 "--fast", "--to", target], capture_output=True, text=True, timeout=60 * MS)
            assert result.returncode == 2, result.stderr
            assert "Traceback" not in result.stderr
            assert result.stderr.strip().splitlines()[-1].startswith(f"error: {target}: cannot")


# ----------------------------------------------------------------------------- hostile packets

FRAME = encode_frame(7, 7 / 120, MOTION.channels[7])


def test_every_truncation_of_a_frame_is_counted_by_kind_and_never_raises():
    source = OscSource(parse_address("osc://127.0.0.1:9"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)
    packets = [FRAME[:n] for n in range(len(FRAME))]
    packets += [b"/streamkey/frame\0\0\0\0,idf", FRAME + b"\0\0\0\0", FRAME[:-4] + b"\xff" * 3]
    for packet in packets:
        source.receive(packet)  # on the event loop, an exception here is a traceback per packet
    assert source.stats.received == 0
    assert sum(source.stats.malformed.values()) == len(packets)
    assert source.stats.malformed["truncated"] >= 4  # shorter by 1..4 bytes: not padded
    assert source.stats.malformed["trailing"] == 1
    source.receive(FRAME)
    assert source.stats.received == 1


def test_bundles_with_empty_or_overlong_elements_are_counted_without_log_lines(caplog):
    source = OscSource(parse_address("osc://127.0.0.1:9"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)
    head = b"#bundle\0" + b"\0" * 8
    good = head + len(FRAME).to_bytes(4, "big") + FRAME
    nested = head + len(good).to_bytes(4, "big") + good
    deep = good
    for _ in range(12):
        deep = head + len(deep).to_bytes(4, "big") + deep
    bad = [head + b"\0\0\0\0", head + b"\0\0\0\0" + len(FRAME).to_bytes(4, "big") + FRAME,
           head + b"\x00\x00\x10\x00" + FRAME, head + b"\xff\xff\xff\xf0", head[:12], deep]
    for packet in [good, nested, *bad]:
        source.receive(packet)
    assert source.stats.received == 2
    assert source.stats.malformed["bundle"] == len(bad)
    assert not caplog.records  # python-osc logged "WARNING:root" for zero-size elements


def test_frame_numbers_out_of_range_are_malformed_at_the_adapter():
    from pythonosc.osc_message_builder import OscMessageBuilder

    from streamkey.adapters.zmq import encode_frame_parts

    source = OscSource(parse_address("osc://127.0.0.1:9"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)
    for seq, t in ((1e30, 0.0), (1.5, 0.0), (-1, 0.0), (3, 1e300)):
        builder = OscMessageBuilder("/streamkey/frame")
        builder.add_arg(seq, "f" if isinstance(seq, float) else "i")
        builder.add_arg(t, "d")
        builder.add_arg(1.0, "f")
        source.receive(builder.build().dgram)
    assert source.stats.malformed["range"] == 4 and source.stats.received == 0
    zsource = ZmqSource(parse_address("zmq+tcp://127.0.0.1:9"), skeleton=MOTION.skeleton,
                        fps=MOTION.fps)
    parts = encode_frame_parts(next(iter(MOTION.frames())))
    for header in (b'{"seq": 1e30, "time": 0, "n": 96}', b'{"seq": 2.5, "time": 0, "n": 96}',
                   b'{"seq": 1, "time": 1e308, "n": 96}', b'{"seq": true, "time": 0, "n": 96}'):
        zsource.handle([b"frame", header, parts[2]])
    assert zsource.stats.malformed["malformed"] == 4 and zsource.stats.received == 0


def test_zmq_messages_that_blow_the_json_stack_are_counted_and_reading_goes_on():
    source = ZmqSource(parse_address("zmq+tcp://127.0.0.1:9"))
    nested = json.dumps({"bvh": "x", "fps": 120}).replace('"x"', "[" * 50_000 + "]" * 50_000)
    for parts in ([b"frame", b"[" * 50_000, b""], [b"frame", b"[" * 3000, b""],
                  [b"skeleton", nested.encode()], [b"skeleton", b"[" * 50_000],
                  [b"skeleton", b'{"bvh": 1}'], [], [b"other"]):
        source.handle(parts)
    assert sum(source.stats.malformed.values()) == 7 and source.skeleton is None


@pytest.mark.parametrize("fps", [0, float("nan"), 1e9, -120, "120", None])
def test_a_skeleton_with_an_unusable_frame_rate_is_counted_and_ignored(fps):
    from streamkey.adapters.osc import skeleton_header

    source = ZmqSource(parse_address("zmq+tcp://127.0.0.1:9"))
    header = skeleton_header(MOTION.skeleton, 120.0)
    source.handle([b"skeleton", json.dumps({"bvh": header, "fps": fps}).encode()])
    assert source.skeleton is None and source.stats.malformed["skeleton"] == 1
    source.handle([b"skeleton", json.dumps({"bvh": header, "fps": 120.0}).encode()])
    assert source.skeleton is not None and source.fps == 120.0


async def test_a_skeleton_the_keyframers_cannot_use_is_ignored_and_the_next_one_taken(tmp_path):
    from streamkey.adapters.osc import encode_skeleton
    from streamkey.bvh import parse_bvh

    port = free_port()
    source = OscSource(parse_address(f"osc://127.0.0.1:{port}"))
    log = tmp_path / "log.jsonl"
    engine = Engine(source, keyframers(), [make_sink(parse_address(f"jsonl:{log}"))])
    task = asyncio.create_task(engine.run())
    await until(lambda: source.sock is not None)
    lonely = parse_bvh("HIERARCHY\nROOT hips\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition "
                       "Yposition Zposition\n End Site\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\n"
                       "Frames: 0\nFrame Time: 0.0083333\n").skeleton
    out = sender()
    out.sendto(encode_skeleton(lonely, 120.0), ("127.0.0.1", port))  # no feet, no pelvis
    await until(lambda: source.stats.malformed["skeleton"] == 1)
    out.sendto(encode_skeleton(MOTION.skeleton, MOTION.fps), ("127.0.0.1", port))
    await until(lambda: engine.pipeline is not None)
    for i in range(1, MOTION.n_frames):
        out.sendto(encode_frame(i, i / 120, MOTION.channels[i]), ("127.0.0.1", port))
        await until(lambda i=i: engine.summary.frames_in >= i - 10)
    await until(lambda: engine.summary.frames_in == MOTION.n_frames - 1)
    out.close()
    engine.stop()
    summary = await task
    assert summary.source_error is None and summary.source["malformed"] == {"skeleton": 1}
    assert summary.events["speed"] > 0 and summary.events["simplify"] > 0


def test_run_from_a_file_without_frames_says_the_source_died_and_exits_2(tmp_path):
    import subprocess
    import sys

    lines = (DATA / "07_01.bvh").read_text().splitlines()
    empty = tmp_path / "z.bvh"
    motion_at = lines.index("MOTION")
    empty.write_text("\n".join(lines[: motion_at + 1] + ["Frames: 0", "Frame Time: .0083333"])
                     + "\n")
    result = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", str(empty),
                             "--fast", "--idle-exit", "1"], capture_output=True, text=True,
                            timeout=60 * MS)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith(f"error: {empty}: ")


# -------------------------------------------------------------------------- sinks' faults, exposure

async def test_a_failing_log_sink_is_that_sinks_fault_not_a_keyframer_restart(tmp_path):
    from streamkey.keyframes import KeyframeEvent
    from streamkey.replay.source import MotionSource

    seen = []
    engine = Engine(MotionSource(MOTION, rate=0.0), keyframers(),
                    [make_sink(parse_address("jsonl:/dev/full")),
                     make_sink(parse_address(f"jsonl:{tmp_path / 'ok.jsonl'}"))],
                    on_event=seen.append)
    summary = await engine.run()
    assert summary.errors == [] and summary.error_count == 0
    full = summary.sinks["jsonl"]
    assert full["disabled"] and full["errors"] >= 10 and "No space" in full["last_error"]
    assert full["errors"] + full["sent"] <= full["dropped"] + full["sent"]
    logged = read_jsonl(tmp_path / "ok.jsonl")
    keys = [e for e in logged if e["type"] == "keyframe"]
    assert len(keys) == summary.events["speed"] + summary.events["simplify"] > 5
    assert all(e["wall_latency_ms"] is not None for e in keys)  # stamped by the engine
    assert all(isinstance(e, dict) for e in seen)
    assert KeyframeEvent.__dataclass_fields__["wall_latency_ms"]


def test_senders_are_bound_to_loopback_and_connected_to_their_peer():
    from streamkey.adapters.osc import OscEventSink, OscFrameSender

    port = free_port()
    for make in (OscEventSink, OscFrameSender):
        peer = make(parse_address(f"osc://127.0.0.1:{port}"))
        sock = peer.sender.sock
        try:
            assert sock.getsockname()[0] == "127.0.0.1"
            assert sock.getpeername() == ("127.0.0.1", port)
        finally:
            sock.close()


async def test_kernel_receive_drops_are_read_and_every_datagram_is_accounted_for():
    import sys

    source = OscSource(parse_address(f"osc://127.0.0.1:{free_port()}"),
                       skeleton=MOTION.skeleton, fps=MOTION.fps)
    await source.start()
    if sys.platform != "linux":
        assert source.stats.kernel_drops is None
        return
    assert source.stats.kernel_drops == 0
    loop = asyncio.get_running_loop()
    loop.remove_reader(source.sock.fileno())  # the loop is busy: nobody reads the socket
    source.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    out = sender()
    sent = 2000
    for i in range(sent):
        out.sendto(encode_frame(i, i / 120, MOTION.channels[i % MOTION.n_frames]),
                   source.sock.getsockname())
    out.close()
    source.frames = FrameQueue(source.stats, maxsize=0)  # keep every frame that gets through
    loop.add_reader(source.sock.fileno(), source._readable)
    await until(lambda: source.counters().received + (source.stats.kernel_drops or 0) == sent)
    await source.close()
    assert source.stats.kernel_drops > 0 and source.stats.received > 0


async def test_zmq_event_sink_says_which_drops_it_cannot_see_and_counts_them_with_nodrop():
    from streamkey.keyframes import KeyframeEvent

    event = KeyframeEvent(stream="s", method="speed", frame=5, time=0.1, score=1.0, decided_at=9,
                          lookahead=4, params="p")
    for option in ("", "?nodrop=1"):
        port = free_port(socket.SOCK_STREAM)
        sink = make_sink(parse_address(f"zmq+tcp://127.0.0.1:{port}{option}"))
        await sink.start()
        lazy = zmq.Context.instance().socket(zmq.SUB)
        lazy.setsockopt(zmq.RCVHWM, 10)
        lazy.setsockopt(zmq.SUBSCRIBE, b"event")
        lazy.connect(f"tcp://127.0.0.1:{port}")
        await until(lambda s=sink: s.socket.poll(10) != 0)  # the subscription reached XPUB
        sink.socket.recv()
        for _ in range(100_000):  # a subscriber that never reads
            sink.offer(event)
        lazy.close(linger=0)
        await sink.close()
        if option:
            assert sink.stats.dropped > 0 and not sink.stats.unseen_drops
            assert sink.stats.sent + sink.stats.dropped == 100_000
        else:
            assert sink.stats.dropped == 0 and "no drop counter" in sink.stats.unseen_drops


def test_a_different_skeleton_after_the_first_good_one_is_counted_and_ignored():
    from streamkey.adapters.osc import encode_skeleton

    source = OscSource(parse_address("osc://127.0.0.1:9"))
    source.receive(encode_skeleton(MOTION.skeleton, MOTION.fps))
    for _ in range(3):  # replay re-sends the same skeleton every second: not counted
        source.receive(encode_skeleton(MOTION.skeleton, MOTION.fps))
    renamed = MOTION.skeleton
    renamed = type(renamed)(names=[n + "_x" for n in renamed.names], parents=renamed.parents,
                            offsets=renamed.offsets, channels=renamed.channels)
    source.receive(encode_skeleton(renamed, MOTION.fps))
    assert source.skeleton.names == MOTION.skeleton.names
    assert source.stats.malformed == {"skeleton_mismatch": 1}


def test_latency_histogram_percentiles_are_within_half_a_percent_in_fixed_memory():
    from streamkey.engine import LatencyHistogram

    rng = np.random.default_rng(7)
    values = np.concatenate([rng.lognormal(0.0, 1.0, 200_000), [1e-5, 3e5]])
    hist = LatencyHistogram()
    size = hist.counts.nbytes
    for v in values:
        hist.add(float(v))
    assert hist.counts.nbytes == size < 16_000 and hist.count == len(values)
    for q in (50, 90, 99, 99.9):
        exact = float(np.percentile(values, q, method="inverted_cdf"))
        assert abs(hist.percentile(q) - exact) <= 0.0051 * exact, q
    assert hist.summary()["max"] == 3e5
