"""Live input that explains itself: `run` names refused input on stderr within a second, once
per kind then rate-limited, and counts it at the end (real processes, real UDP packets)."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
from cmu import DATA
from live_helpers import MS, free_port, interrupt_if_running, read_jsonl, streamkey, wait_ready
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage

from streamkey.adapters.osc import encode_frame, osc_string
from streamkey.amc import read_motion

CLIP = DATA / "07_05.bvh"


def _send(port: int, packet: bytes) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(packet, ("127.0.0.1", port))


def _line_with(proc: subprocess.Popen, needle: str, seconds: float = 10.0) -> tuple[str, float]:
    """The next stderr line containing `needle` and how long it took to come."""
    start = time.monotonic()
    while True:
        line = proc.stderr.readline()
        assert line, f"process ended before {needle!r}"
        if needle in line:
            return line, time.monotonic() - start
        assert time.monotonic() - start < seconds * MS, f"no {needle!r} in time"


def _run(port: int, *extra: str) -> subprocess.Popen:
    proc = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--method", "simplify",
                     "--to", "-", *extra)
    wait_ready(proc, timeout=300)
    return proc


def test_wrong_address_and_channel_count_are_explained_once_then_counted(tmp_path):
    _address_and_channels(tmp_path)


def test_with_worker_processes_refused_input_is_explained_the_same(tmp_path):
    """`--workers 2`: the source's refusals explained by the parent, a stream's by the
    worker that serves it; one end line counts both."""
    _address_and_channels(tmp_path, "--workers", "2")


def _address_and_channels(tmp_path: Any, *extra: str) -> None:
    port = free_port()
    n = read_motion(str(CLIP)).skeleton.n_channels
    summary = tmp_path / "summary.json"
    proc = _run(port, "--skeleton", str(CLIP), "--summary", str(summary), *extra)
    try:
        _send(port, osc_string("/foo/bar") + osc_string(",i") + b"\0\0\0\1")
        line, took = _line_with(proc, "warning: input refused (address)")
        assert "'/foo/bar'" in line and "expected /streamkey/frame" in line
        assert took < 1.0 * MS
        for seq in range(3):  # one line for the first; the others within 5 s are counted
            _send(port, encode_frame(seq, seq / 120, np.zeros(n - 1)))
        line, took = _line_with(proc, "warning: frame with")
        assert f"frame with {n - 1} values on stream 'default': its skeleton has {n} " \
               "channels" in line
        assert took < 1.0 * MS
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60 * MS)
    assert "warning: frame with" not in err  # rate-limited: no second line
    assert "input problems: address 1, channels 3" in err
    assert proc.returncode == 0
    assert json.loads(summary.read_text())["input_problems"] == {"address": 1, "channels": 3}


def test_frames_before_any_skeleton_are_explained(tmp_path):
    port = free_port()
    proc = _run(port)
    try:
        _send(port, encode_frame(0, 0.0, np.zeros(96)))
        line, took = _line_with(proc, "before any skeleton")
        assert "send /streamkey/skeleton" in line and "--skeleton FILE" in line
        assert took < 1.0 * MS
    finally:
        interrupt_if_running(proc, 60 * MS)


def test_a_first_frame_in_reference_pose_is_pointed_out(tmp_path):
    port = free_port()
    proc = _run(port, "--skeleton", str(CLIP), "--quiet")
    quiet_err = None
    try:
        motion = read_motion(str(CLIP))
        assert motion.first_frame == 1  # frame 0 is the T-pose reference frame
        for seq in range(3):
            _send(port, encode_frame(seq, seq / 120, motion.channels[seq]))
    finally:
        proc.send_signal(signal.SIGINT)
        _, quiet_err = proc.communicate(timeout=60 * MS)
    assert "warning" not in quiet_err and "input problems: reference_pose 1" in quiet_err
    port = free_port()
    proc = _run(port, "--skeleton", str(CLIP))
    try:
        for seq in range(3):
            _send(port, encode_frame(seq, seq / 120, motion.channels[seq]))
        line, _ = _line_with(proc, "reference pose")
        assert "frame-0 T-pose" in line and "seq 0" in line
    finally:
        interrupt_if_running(proc, 60 * MS)


def test_positions_only_stdin_lines_are_explained(tmp_path):
    lines = [json.dumps({"seq": i, "time": i / 120, "positions": [[0.0, 1.0, 0.0]] * 31})
             for i in range(5)]
    done = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", "-",
                           "--skeleton", str(CLIP), "--method", "simplify"],
                          input="\n".join(lines) + "\n", capture_output=True, text=True,
                          timeout=300 * MS)
    assert done.returncode == 0, done.stderr
    warnings = [ln for ln in done.stderr.splitlines() if ln.startswith("warning:")]
    assert len(warnings) == 1 and "rotation channels" in warnings[0], done.stderr
    assert "input problems:" in done.stderr and " 5" in done.stderr.split("input problems:")[1]


def test_with_the_dashboard_too_refused_input_is_explained(tmp_path):
    port = free_port()
    from websockets.sync.client import connect

    proc = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--method", "simplify",
                     "--skeleton", str(CLIP), "--dashboard", "0", "--log",
                     str(tmp_path / "session.jsonl"))
    try:
        lines = "".join(wait_ready(proc, "dashboard on", timeout=300))
        if "listening on" not in lines:  # the page binds first, then the source
            wait_ready(proc, timeout=300)
        page = re.search(r"dashboard on (http://\S+?)/?\s", lines).group(1)
        with connect(page.replace("http://", "ws://") + "/ws") as ws:
            assert json.loads(ws.recv(timeout=30 * MS))["type"] == "hello"
            _send(port, encode_frame(0, 0.0, np.zeros(5)))
            line, took = _line_with(proc, "warning: frame with 5 values on stream 'default'")
            assert "its skeleton has 96 channels" in line and took < 1.0 * MS
            while (message := json.loads(ws.recv(timeout=30 * MS)))["type"] != "status":
                pass
            assert message["status"] == "input_channels"  # the page gets the same line
            assert "warning: " + message["detail"]["message"] == line.strip()
        with connect(page.replace("http://", "ws://") + "/ws") as late:  # a page opened later
            hello = json.loads(late.recv(timeout=30 * MS))
            assert [n["detail"]["message"] for n in hello["notices"]] == [message["detail"][
                "message"]]
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60 * MS)
    assert "input problems: channels 1" in err
    logged = [e for e in read_jsonl(tmp_path / "session.jsonl") if e["type"] == "status"]
    assert [e["status"] for e in logged] == ["input_channels"]


def _osc_messages(sock: socket.socket, seconds: float) -> Iterator[tuple[str, list[Any]]]:
    """(address, arguments) of every message of the OSC packets arriving on `sock`."""
    deadline = time.monotonic() + seconds * MS
    while time.monotonic() < deadline:
        sock.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            packet = sock.recv(65536)
        except TimeoutError:
            break
        if OscBundle.dgram_is_bundle(packet):
            for item in OscBundle(packet):
                if isinstance(item, OscMessage):
                    yield item.address, list(item.params)
        else:
            message = OscMessage(packet)
            yield message.address, list(message.params)
    raise AssertionError("no such OSC message in time")


def test_refused_input_is_a_status_event_on_every_sink_with_the_same_rate_limit(tmp_path):
    """The stderr line is also a `status` event (`input_<kind>`, its message the line) in
    the JSON Lines log, on OSC (`/streamkey/<stream>/status/input_<kind> i seq`) and in the
    `--summary` counts; `--quiet` silences stderr, not the events."""
    port, log = free_port(), tmp_path / "events.jsonl"
    n = read_motion(str(CLIP)).skeleton.n_channels
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as peer:
        peer.bind(("127.0.0.1", 0))
        out = peer.getsockname()[1]
        proc = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--method", "simplify",
                         "--skeleton", str(CLIP), "--to", f"jsonl:{log}", "--to",
                         f"osc://127.0.0.1:{out}", "--quiet", "--summary",
                         str(tmp_path / "summary.json"))
        try:
            wait_ready(proc, timeout=300)
            motion = read_motion(str(CLIP))
            for seq in range(1, 4):  # good frames first: the event names the newest one
                _send(port, encode_frame(seq, seq / 120, motion.channels[seq]))
            for seq in range(4, 7):  # three refusals: one event, the others counted
                _send(port, encode_frame(seq, seq / 120, np.zeros(n + 2)))
            start = time.monotonic()
            address, arguments = next(m for m in _osc_messages(peer, 10) if "/status/" in m[0])
            assert time.monotonic() - start < 1.0 * MS
            assert address == "/streamkey/default/status/input_channels"
            assert arguments[0] in (4, 5, 6)  # the stream's newest frame: a refused one
        finally:
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=60 * MS)
    assert proc.returncode == 0 and "warning" not in err and "input problems: channels 3" in err
    status = [e for e in read_jsonl(log) if e["type"] == "status"]
    assert len(status) == 1, status  # the same rate limit as the stderr line
    assert status[0]["status"] == "input_channels" and status[0]["stream"] == "default"
    detail = status[0]["detail"]
    assert detail["kind"] == "channels" and detail["seq"] == arguments[0]
    assert detail["count"] == arguments[0] - 3  # the refusals until it was noticed
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["input_problems"] == {"channels": 3} and summary["events"]["status"] == 1
    assert detail["message"].startswith(f"frame with {n + 2} values on stream 'default': "
                                        f"its skeleton has {n} channels")


def test_a_cluster_shard_explains_refused_input_as_status_events_and_notices(tmp_path):
    """`cluster run`'s shard worker (no Ray: messages handed over by hand, a real
    redis-server): frames before the skeleton, a wrong channel count and a bad topic are
    each one `input_<kind>` status event in the run's event stream and one line in its
    notice list (the driver prints those), rate-limited per kind, and counted."""
    from cluster_helpers import RedisServer, redis_events

    from streamkey.adapters.osc import skeleton_header
    from streamkey.adapters.zmq import encode_frame_parts
    from streamkey.cluster.live import ClusterConfig, ShardWorker, new_notices, stream_topic
    from streamkey.motion import Frame

    server = RedisServer(tmp_path)
    try:
        cfg = ClusterConfig("tcp://127.0.0.1:1", server.url, 1, ["simplify"], {}, run="input",
                            snapshot_every=100_000)
        worker = ShardWorker(cfg, 0)  # not started: messages are handed over by hand
        motion = read_motion(str(CLIP))
        n = motion.skeleton.n_channels

        def frame(seq: int, values: np.ndarray) -> list[bytes]:
            return stream_topic("dancer", encode_frame_parts(Frame(seq, seq / 120, values)))

        worker.handle(frame(1, motion.channels[1]))  # before the skeleton
        worker.handle(stream_topic("dancer", [b"skeleton", json.dumps(
            {"bvh": skeleton_header(motion.skeleton, motion.fps), "fps": motion.fps}).encode()]))
        for seq in range(2, 5):
            worker.handle(frame(seq, motion.channels[seq]))
        for seq in range(5, 8):  # three of the wrong size: one explanation
            worker.handle(frame(seq, np.zeros(n - 1)))
        worker.handle([b"dancer/nonsense", b""])
        notices = new_notices(server.client(), "input", 0)
        events = [e for e in redis_events(server.client(), "input") if e["type"] == "status"]
        problems = worker.status()["input_problems"]
    finally:
        server.stop()
    assert [e["status"] for e in events] == ["input_no_skeleton", "input_channels",
                                             "input_malformed"]
    channels = events[1]["detail"]
    assert channels["message"].startswith(f"frame with {n - 1} values on stream 'dancer': "
                                          f"expected {n} finite channel values")
    assert events[1]["stream"] == "dancer" and channels["seq"] == 4
    assert "unknown topic b'dancer/nonsense'; expected the topic <stream>/frame or " \
           "<stream>/skeleton" in events[2]["detail"]["message"]
    assert notices == [f"shard 0: {e['detail']['message']}" for e in events]
    assert problems == {"no_skeleton": 1, "channels": 3, "malformed": 1}
