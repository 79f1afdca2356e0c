from __future__ import annotations

import socket
import struct
import subprocess
import sys
import time

import numpy as np
from cmu import DATA

from streamkey.adapters.osc import decode_frame
from streamkey.bvh import read_bvh
from streamkey.replay.pacing import frame_stream, paced


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        self.now += seconds + 0.0007  # every sleep overshoots a little


def test_pacing_is_deadline_based_so_overshoot_does_not_accumulate():
    motion = read_bvh(DATA / "07_01.bvh")
    clock = FakeClock()
    stream = paced(frame_stream(motion, loop=True), 1 / 120, clock, clock.sleep)
    deadlines = []
    for _ in range(1200):
        frame, deadline = next(stream)
        deadlines.append((clock.now, deadline, frame.seq))
    now, deadline, seq = deadlines[-1]
    assert abs(now - deadline) < 0.001  # one overshoot, not 1200 of them
    assert [d[2] for d in deadlines[:3]] == [1, 2, 3]  # file numbering (frame 0 is the T-pose)
    assert deadlines[-1][2] == 1200


def test_looping_keeps_seq_increasing_and_times_consistent():
    motion = read_bvh(DATA / "09_06.bvh")
    frames = [f for _, f in zip(range(400), frame_stream(motion, loop=True), strict=False)]
    seqs = np.array([f.seq for f in frames])
    assert np.all(np.diff(seqs) == 1)
    np.testing.assert_array_equal(frames[141].channels, motion.channels[1])  # wrapped around


def test_replay_at_120_hz_over_loopback_has_no_drift(tmp_path):
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.settimeout(5.0)
    # the kernel's receive time (the send time on loopback), not this test's wake-up
    kernel = getattr(socket, "SO_TIMESTAMPNS", 35 if sys.platform == "linux" else None)
    if kernel is not None:
        receiver.setsockopt(socket.SOL_SOCKET, kernel, 1)
        receiver.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    port = receiver.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "streamkey", "replay", str(DATA / "07_01.bvh"),
                             "--loop", "--frames", "1200", "--to", f"osc://127.0.0.1:{port}"],
                            stderr=subprocess.PIPE, text=True)
    arrivals, seqs = [], []
    try:
        while len(seqs) < 1200:
            data, ancillary, _, _ = receiver.recvmsg(65536, 64)
            stamp = time.monotonic_ns()
            for level, kind, value in ancillary:
                if (level, kind) == (socket.SOL_SOCKET, kernel):
                    sec, nsec = struct.unpack_from("qq", value)
                    stamp = sec * 10**9 + nsec + time.monotonic_ns() - time.time_ns()
            if data.startswith(b"/streamkey/frame"):
                arrivals.append(stamp)
                seqs.append(decode_frame(data)[0])
    finally:
        proc.communicate(timeout=30)
        receiver.close()
    assert proc.returncode == 0
    assert seqs == list(range(1, 1201))
    t = np.array(arrivals) / 1e9
    mean_interval = (t[-1] - t[0]) / (len(t) - 1)
    assert abs(mean_interval - 1 / 120) / (1 / 120) < 0.005
    assert abs(t[-1] - (t[0] + 1199 / 120)) < 0.010
