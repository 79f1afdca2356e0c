"""Real OSC peers nobody here wrote: liblo's oscdump and oscsend (Debian liblo-tools)."""

from __future__ import annotations

import shlex
import shutil
import signal
import subprocess
import time

from cmu import DATA
from live_helpers import MS, free_port, read_jsonl, streamkey, wait_ready, wait_udp_bound

from streamkey.bvh import read_bvh

CLIP = DATA / "07_01.bvh"


def require(tool: str) -> str:
    path = shutil.which(tool)
    assert path, f"{tool} not found: install Debian liblo-tools (.ci/run does)"
    return path


def parse_oscdump(text: str) -> list[dict]:
    """`<timetag> /streamkey/keyframe ssiffi "stream" "method" frame time score latency`."""
    events = []
    for line in text.splitlines():
        parts = shlex.split(line)
        if len(parts) == 9 and parts[1] == "/streamkey/keyframe" and parts[2] == "ssiffi":
            events.append({"stream": parts[3], "method": parts[4], "frame": int(parts[5]),
                           "time": float(parts[6]), "score": float(parts[7]),
                           "latency_frames": int(parts[8])})
    return events


def test_oscdump_receives_keyframe_messages_that_parse_back_to_the_events(tmp_path):
    port = free_port()
    # liblo reads a host in the URL as a multicast group, so oscdump gets the bare port.
    dump = subprocess.Popen([require("oscdump"), "-L", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = tmp_path / "events.jsonl"
    try:
        wait_udp_bound(port, "oscdump")
        run = streamkey("run", "--from", str(CLIP), "--fast", "--stream", "take 1",
                        "--to", f"osc://127.0.0.1:{port}", "--to", f"jsonl:{log}")
        _, err = run.communicate(timeout=120 * MS)
        assert run.returncode == 0, err
        time.sleep(0.3 * MS)
    finally:
        dump.send_signal(signal.SIGINT)
        out, _ = dump.communicate(timeout=10)
    logged = [e for e in read_jsonl(log) if e["type"] == "keyframe"]
    dumped = parse_oscdump(out)
    assert len(logged) > 10
    assert len(dumped) == len(logged)
    for got, want in zip(sorted(dumped, key=lambda e: (e["method"], e["frame"])),
                         sorted(logged, key=lambda e: (e["method"], e["frame"])), strict=True):
        assert (got["stream"], got["method"], got["frame"], got["latency_frames"]) == (
            want["stream"], want["method"], want["frame"], want["latency_frames"])
        assert abs(got["time"] - want["time"]) <= 1e-6 * max(1.0, want["time"])
        assert abs(got["score"] - want["score"]) <= 1e-6 * max(1.0, abs(want["score"]))


def test_frames_sent_with_oscsend_are_accepted_by_streamkey_run(tmp_path):
    oscsend = require("oscsend")
    motion = read_bvh(CLIP)
    port = free_port()
    summary = tmp_path / "summary.json"
    run = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--skeleton", str(CLIP),
                    "--to", f"jsonl:{tmp_path / 'e.jsonl'}", "--summary", str(summary),
                    "--idle-exit", str(2 * MS))
    try:
        wait_ready(run)
        for seq in range(1, 6):
            values = [f"{v:.4f}" for v in motion.channels[seq]]
            cmd = [oscsend, f"osc.udp://127.0.0.1:{port}", "/streamkey/frame",
                   "id" + "f" * len(values), str(seq), str(seq / 120), *values]
            assert subprocess.run(cmd, timeout=10 * MS).returncode == 0
        # a malformed one (a string where a channel belongs) is counted, not fatal
        subprocess.run([oscsend, f"osc.udp://127.0.0.1:{port}", "/streamkey/frame", "ids",
                        "6", "0.05", "oops"], timeout=10 * MS, check=True)
        _, err = run.communicate(timeout=60 * MS)
    finally:
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
            run.communicate(timeout=30)
    assert run.returncode == 0, err
    assert "frames in: 5" in err
    import json

    data = json.loads(summary.read_text())
    assert data["frames_in"] == 5 and data["guard"]["accepted"] == 5
    assert data["source"]["malformed"] == {"types": 1}
