"""`run --workers N`: streams spread over worker processes by load, one set of sinks and one
summary, every stream's events exactly a one-process run's; clean shutdown."""

from __future__ import annotations

import json

from cmu import DATA
from live_helpers import MS, free_port, interrupt_if_running, read_jsonl, streamkey, wait_ready
from test_streams import per_stream, rounded, single_stream

from streamkey.bvh import read_bvh
from streamkey.summary import LatencyHistogram, RunSummary, StreamStats
from streamkey.workers import merge_summaries

CLIPS = {"s00": "07_01.bvh", "s01": "09_06.bvh", "s02": "07_12.bvh", "s03": "08_01.bvh"}


def test_four_osc_streams_over_two_workers_give_their_single_stream_events(tmp_path):
    """Four replay processes, each its own stream id, into `run --workers 2` over loopback
    OSC: the ids are placed 2 + 2, each stream's keyframes equal its one-process run's, one
    JSON Lines sink has them all, the summary counts every frame, and the run ends cleanly
    on --idle-exit (exit 0, workers gone)."""
    port = free_port()
    log, summary = tmp_path / "events.jsonl", tmp_path / "summary.json"
    run = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--method", "speed,simplify",
                    "--to", f"jsonl:{log}", "--summary", str(summary), "--workers", "2",
                    "--idle-exit", str(2 * MS))
    try:
        wait_ready(run, "listening on", timeout=300)
        replays = [streamkey("replay", str(DATA / clip), "--stream", name, "--to",
                             f"osc://127.0.0.1:{port}") for name, clip in CLIPS.items()]
        for r in replays:
            assert r.wait(timeout=120 * MS) == 0, r.communicate()[1]
            r.communicate()
        _, err = run.communicate(timeout=120 * MS)
    finally:
        interrupt_if_running(run)
    assert run.returncode == 0, err
    assert "Traceback" not in err
    got = per_stream(read_jsonl(log))
    doc = json.loads(summary.read_text())
    frames = 0
    for name, clip in CLIPS.items():
        motion = read_bvh(DATA / clip)
        frames += len(motion.frames())
        expected = single_stream(motion, ["speed", "simplify"], float32=True)
        assert rounded(got[name]) == rounded(expected), (name, err)
    workers = doc["scheduler"]["workers"]
    assert sorted(w["streams_placed"] for w in workers) == [2, 2]
    assert len({w["pid"] for w in workers}) == 2
    assert doc["frames_in"] == frames and doc["accounting"]["processed"] == frames
    assert doc["source"]["received"] == frames
    assert doc["events"]["speed"] == sum(1 for e in read_jsonl(log) if e.get("method") ==
                                         "speed" and e["type"] == "keyframe")
    assert set(doc["streams"]) == set(CLIPS)
    assert "worker 1 (pid" in err


def test_summaries_of_several_workers_merge_into_one():
    a, b = RunSummary(), RunSummary()
    a.frames_in, b.frames_in = 10, 5
    a.events["speed"], b.events["speed"] = 2, 3
    for value in (1.0, 2.0):
        a.due_latency.add(value)
    b.due_latency.add(30.0)
    a.streams["x"], b.streams["y"] = StreamStats(frames_in=10), StreamStats(frames_in=5)
    a.guard, b.guard = {"accepted": 10}, {"accepted": 5}
    merged = merge_summaries([a, b])
    assert merged.frames_in == 15 and merged.events["speed"] == 5
    assert merged.due_latency.count == 3 and merged.due_latency.max == 30.0
    assert set(merged.streams) == {"x", "y"} and merged.guard["accepted"] == 15
    h = LatencyHistogram()
    h.merge(merged.due_latency)
    assert h.percentile(50) == merged.due_latency.percentile(50)


def test_workers_out_of_range_is_a_usage_error_not_a_traceback():
    import subprocess
    import sys

    for bad in ("0", "many", "300"):
        result = subprocess.run([sys.executable, "-P", "-m", "streamkey", "run", "--from",
                                 "osc://127.0.0.1:9", "--workers", bad],
                                capture_output=True, text=True, timeout=60 * MS)
        assert result.returncode == 2 and "--workers" in result.stderr, result.stderr
        assert "Traceback" not in result.stderr


def test_ctrl_c_ends_the_workers_cleanly_and_loses_no_event(tmp_path):
    """SIGINT mid-stream (the terminal sends it to the whole group, workers included): the
    parent ends the workers in order, every stream is flushed, every event the workers
    sent reaches the sink before it closes, the workers are gone, exit 0."""
    import os
    import signal
    import time

    port = free_port()
    log, summary = tmp_path / "events.jsonl", tmp_path / "summary.json"
    run = streamkey("run", "--from", f"osc://127.0.0.1:{port}", "--method", "speed,simplify",
                    "--to", f"jsonl:{log}", "--summary", str(summary), "--workers", "2",
                    start_new_session=True)  # its own process group, as in a terminal
    replays = []
    try:
        wait_ready(run, "listening on", timeout=300)
        replays = [streamkey("replay", str(DATA / clip), "--stream", name, "--loop", "--to",
                             f"osc://127.0.0.1:{port}") for name, clip in list(CLIPS.items())[:2]]
        deadline = time.monotonic() + 120 * MS
        while not (log.exists() and len(read_jsonl(log)) >= 20):  # both workers at work
            assert time.monotonic() < deadline, "no events"
            time.sleep(0.1)
        os.killpg(run.pid, signal.SIGINT)  # Ctrl-C: the parent and its workers
        _, err = run.communicate(timeout=120 * MS)
    finally:
        for r in replays:
            r.kill()
            r.communicate()
        interrupt_if_running(run)
    assert run.returncode == 0, err
    assert "Traceback" not in err
    doc = json.loads(summary.read_text())
    events = read_jsonl(log)
    keyframes = sum(1 for e in events if e["type"] == "keyframe")
    assert keyframes == sum(doc["events"].get(m, 0) for m in ("speed", "simplify"))
    assert doc["keyframes_at_stream_end"] > 0  # the flush at the end came through
    for w in doc["scheduler"]["workers"]:
        try:
            os.kill(w["pid"], 0)
        except ProcessLookupError:
            continue
        raise AssertionError(f"worker {w['pid']} still running")
