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

import numpy as np
from cmu import DATA
from live_helpers import MS, free_port, interrupt_if_running, streamkey, wait_ready

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
    port = free_port()
    n = read_motion(str(CLIP)).skeleton.n_channels
    summary = tmp_path / "summary.json"
    proc = _run(port, "--skeleton", str(CLIP), "--summary", str(summary))
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
            line, took = _line_with(proc, "warning: frame on stream 'default' refused")
            assert "expected 96 finite channel values" in line and took < 1.0 * MS
            while (message := json.loads(ws.recv(timeout=30 * MS)))["type"] != "input":
                pass
            assert message["text"] == line.strip()  # the page shows the same line
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60 * MS)
    assert "input problems: invalid 1" in err
