"""Real OSC peers nobody here wrote: liblo's oscdump and oscsend (Debian liblo-tools) and
SuperCollider's sclang (Debian supercollider-language); Pure Data is in test_examples.py."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time

from cmu import DATA, ROOT
from live_helpers import (
    MS,
    free_port,
    interrupt_if_running,
    keys_sent_to_osc,
    read_jsonl,
    streamkey,
    wait_ready,
    wait_udp_bound,
)

from streamkey.adapters.osc import skeleton_header
from streamkey.bvh import read_bvh

CLIP = DATA / "07_01.bvh"
HOLES = (range(100, 130), range(200, 205))  # 30 frames: a restart; 5 frames: bridged


def require(tool: str, package: str = "liblo-tools") -> str:
    path = shutil.which(tool)
    assert path, f"{tool} not found: install Debian {package} (.ci/run does)"
    return path


def parse_oscdump(text: str) -> list[dict]:
    """Compact layout: `<timetag> /streamkey/keyframe ssiffi "stream" "method" frame time
    score latency`."""
    events = []
    for line in text.splitlines():
        parts = shlex.split(line)
        if len(parts) == 9 and parts[1] == "/streamkey/keyframe" and parts[2] == "ssiffi":
            events.append({"stream": parts[3], "method": parts[4], "frame": int(parts[5]),
                           "time": float(parts[6]), "score": float(parts[7]),
                           "latency_frames": int(parts[8])})
    return events


def dump_lines(text: str) -> list[tuple[int, str, str, list[str]]]:
    """oscdump lines as (NTP time tag, address, type tags, arguments)."""
    out = []
    for line in text.splitlines():
        parts = shlex.split(line)
        if len(parts) >= 3 and parts[1].startswith("/streamkey/"):
            seconds, fraction = parts[0].split(".")
            out.append(((int(seconds, 16) << 32) | int(fraction, 16), parts[1], parts[2],
                        parts[3:]))
    return out


def stdin_take_with_holes() -> str:
    """The clip as `run --from -` JSON Lines, with the frames of HOLES left out."""
    motion = read_bvh(CLIP)
    lines = [json.dumps({"type": "skeleton", "fps": motion.fps,
                         "bvh": skeleton_header(motion.skeleton, motion.fps)})]
    for seq in range(1, len(motion.channels)):
        if not any(seq in hole for hole in HOLES):
            lines.append(json.dumps({"seq": seq, "time": seq / motion.fps,
                                     "channels": motion.channels[seq].tolist()}))
    return "\n".join(lines) + "\n"


def test_oscdump_receives_the_numeric_layout_with_the_documented_types(tmp_path):
    port = free_port()
    dumped = tmp_path / "oscdump.txt"
    log = tmp_path / "events.jsonl"
    started = time.time()
    with dumped.open("w") as out_file:
        dump = subprocess.Popen([require("oscdump"), "-L", str(port)], stdout=out_file,
                                stderr=subprocess.DEVNULL, text=True)
    try:
        wait_udp_bound(port, "oscdump")
        run = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", "-",
                              "--method", "speed,simplify", "--stream", "take 1",
                              "--to", f"osc://127.0.0.1:{port}", "--to", f"jsonl:{log}"],
                             input=stdin_take_with_holes(), capture_output=True, text=True,
                             timeout=120 * MS)
        assert run.returncode == 0, run.stderr
        logged = read_jsonl(log)
        wait_lines(dumped, len(logged))
    finally:
        dump.send_signal(signal.SIGINT)
        dump.wait(timeout=10)
    out = dumped.read_text()
    lines = dump_lines(out)
    keys = [e for e in logged if e["type"] == "keyframe"]
    gaps = [e for e in logged if e["type"] == "gap"]
    restarts = [e for e in logged if e["type"] == "status"]
    assert len(keys) > 10 and len(gaps) == 2 and len(restarts) == 0
    by_kind: dict[str, list] = {}
    for tag, address, types, args in lines:
        by_kind.setdefault(address.rsplit("/", 1)[1], []).append((tag, address, types, args))
    got = sorted((a.split("/")[3], int(x[0]), int(x[3])) for _, a, t, x in by_kind["keyframe"])
    assert got == sorted((e["method"], e["frame"], e["latency_frames"]) for e in keys)
    for _, address, types, args in by_kind["keyframe"]:
        assert address.startswith("/streamkey/take_1/") and types == "iffi"
        assert 0.0 <= float(args[2]) <= 1.0
    assert [(a, t, x) for _, a, t, x in by_kind["gap"]] == [
        ("/streamkey/take_1/gap", "iii", ["100", "129", "0"]),
        ("/streamkey/take_1/gap", "iii", ["200", "204", "1"])]
    # one bundle per deciding frame: the keys decided by one frame share one time tag and
    # keys decided by different frames do not; the tags are the frames' wall-clock
    # arrival on this machine, in order
    # (the keys flushed by the restart at the long hole were produced by the frame after it;
    # those flushed at the end of the stream, before their lookahead, by the end: -1)
    flushed = {HOLES[0].start - 1: HOLES[0].stop}
    last = max(e["decided_at"] for e in keys)
    decided = {(e["method"], e["frame"]): -1 if e["decided_at"] == last and e["latency_frames"]
               < e["lookahead"] else flushed.get(e["decided_at"], e["decided_at"])
               for e in keys}
    frame_of_tag: dict[int, set[int]] = {}
    for tag, address, _, args in by_kind["keyframe"]:
        frame_of_tag.setdefault(tag, set()).add(decided[address.split("/")[3], int(args[0])])
    assert all(len(frames) == 1 for frames in frame_of_tag.values()), frame_of_tag
    assert len(frame_of_tag) == len(set(decided.values()))
    tags = [tag for tag, *_ in lines]
    assert tags == sorted(tags)
    unix = [(t >> 32) - 2_208_988_800 + (t & 0xFFFFFFFF) / 2**32 for t in tags]
    assert started - 1 <= min(unix) and max(unix) <= time.time() + 1


def wait_lines(path, n: int, timeout: float = 20.0) -> None:
    """Wait until the peer has written `n` /streamkey lines (UDP on loopback arrives late,
    not never)."""
    deadline = time.monotonic() + timeout * MS
    while len(dump_lines(path.read_text())) < n:
        assert time.monotonic() < deadline, f"peer wrote {path.read_text()[-2000:]}"
        time.sleep(0.05)


def test_oscdump_receives_the_compact_layout_that_parses_back_to_the_events(tmp_path):
    port = free_port()
    # liblo reads a host in the URL as a multicast group, so oscdump gets the bare port.
    dump = subprocess.Popen([require("oscdump"), "-L", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = tmp_path / "events.jsonl"
    try:
        wait_udp_bound(port, "oscdump")
        run = streamkey("run", "--from", str(CLIP), "--fast", "--stream", "take 1",
                        "--osc-layout", "compact",
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
        interrupt_if_running(run)
    assert run.returncode == 0, err
    assert "frames in: 5" in err
    import json

    data = json.loads(summary.read_text())
    assert data["frames_in"] == 5 and data["guard"]["accepted"] == 5
    assert data["source"]["malformed"] == {"types": 1}


def test_supercollider_oscdef_example_receives_every_keyframe(tmp_path):
    """examples/keyframe_osc.scd in a headless sclang (no server, no display)."""
    sclang = require("sclang", "supercollider-language")
    port = free_port()
    posted = tmp_path / "sclang.txt"
    env = {**os.environ, "SK_PORT": str(port), "SK_STREAM": "take_1",
           "QT_QPA_PLATFORM": "offscreen", "QTWEBENGINE_DISABLE_SANDBOX": "1"}
    log = tmp_path / "events.jsonl"
    with posted.open("w") as out_file:
        sc = subprocess.Popen([sclang, "-D", str(ROOT / "examples" / "keyframe_osc.scd")],
                              stdout=out_file, stderr=subprocess.STDOUT, env=env,
                              cwd=tmp_path)
    try:
        deadline = time.monotonic() + 60 * MS
        while "streamkey: listening for /streamkey/take_1" not in posted.read_text():
            assert sc.poll() is None and time.monotonic() < deadline, posted.read_text()
            time.sleep(0.05)
        keys = keys_sent_to_osc(CLIP, port, log)
        deadline = time.monotonic() + 20 * MS
        while len(sc_keys(posted.read_text())) < len(keys):
            assert time.monotonic() < deadline, posted.read_text()[-2000:]
            time.sleep(0.05)
    finally:
        sc.terminate()
        try:
            sc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sc.kill()
            sc.wait(timeout=10)
    got = sc_keys(posted.read_text())
    assert len(keys) > 10
    assert sorted((m, f, lat) for m, f, _, lat in got) == sorted(
        (e["method"], e["frame"], e["latency_frames"]) for e in keys)
    assert all(0.0 <= s <= 1.0 for *_, s, _ in got)
    assert "ERROR" not in posted.read_text()


def sc_keys(text: str) -> list[tuple[str, int, float, int]]:
    """`streamkey METHOD keyframe frame F time T strength S latency L` lines of sclang."""
    out = []
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 11 and parts[0] == "streamkey" and parts[2] == "keyframe":
            out.append((parts[1], int(parts[4]), float(parts[8]), int(parts[10])))
    return out
