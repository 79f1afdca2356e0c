"""The runnable examples, smoke-run on loopback against real peers (Pd, ZeroMQ, a shell)."""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import time

from cmu import DATA, ROOT
from live_helpers import (
    MS,
    free_port,
    keys_sent_to_osc,
    read_jsonl,
    streamkey,
    wait_ready,
    wait_udp_bound,
)

from streamkey.methods import ONLINE_METHODS

EXAMPLES = ROOT / "examples"
CLIP = DATA / "07_01.bvh"


def test_pure_data_patch_receives_and_prints_keyframes(tmp_path):
    pd = shutil.which("pd")
    assert pd, "Pure Data not found: install Debian puredata-core (.ci/run does)"
    port = free_port()
    patch = tmp_path / "keyframe_click.pd"
    patch.write_text((EXAMPLES / "keyframe_click.pd").read_text().replace("9001", str(port)))
    proc = subprocess.Popen([pd, "-nogui", "-noaudio", "-nomidi", "-stderr", "-open", str(patch)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_udp_bound(port, "Pure Data")
        keys = keys_sent_to_osc(CLIP, port, tmp_path / "events.jsonl")
        printed = []
        deadline = time.monotonic() + 20 * MS
        while len(printed) < len(keys):  # Pd prints each key as it comes: wait for all
            line = proc.stderr.readline()
            assert line and time.monotonic() < deadline, printed
            if line.split(":")[0] in ("speed", "simplify"):
                printed.append(line)
    finally:
        proc.send_signal(signal.SIGTERM)
        _, pd_err = proc.communicate(timeout=10)
    # routed by method: "speed: frame time strength latency_frames"
    got = sorted((ln.split(":")[0], int(float(ln.split()[1])), int(float(ln.split()[4])))
                 for ln in printed)
    assert len(keys) > 10
    assert got == sorted((e["method"], e["frame"], e["latency_frames"]) for e in keys)
    assert all(0.0 <= float(ln.split()[3]) <= 1.0 for ln in printed)
    assert "error" not in pd_err.lower()


def test_python_zmq_subscriber_example_prints_keyframes():
    port = free_port(1)
    sub = subprocess.Popen([sys.executable, str(EXAMPLES / "zmq_subscriber.py"),
                            f"tcp://127.0.0.1:{port}", "--count", "3"],
                           stdout=subprocess.PIPE, text=True)
    try:
        assert sub.stdout.readline().startswith("subscribed")
        run = streamkey("run", "--from", str(CLIP), "--method", "simplify",
                        "--to", f"zmq+tcp://127.0.0.1:{port}")  # paced: the subscriber joins
        out, _ = sub.communicate(timeout=60 * MS)
        run.send_signal(signal.SIGINT)
        run.communicate(timeout=60 * MS)
    finally:
        for p in (sub,):
            if p.poll() is None:
                p.kill()
    keys = [ln for ln in out.splitlines() if "keyframe" in ln]
    assert len(keys) == 3 and all("simplify" in k for k in keys)


def test_annotate_session_recipe_logs_a_replayed_take(tmp_path):
    bash = shutil.which("bash")
    assert bash
    port_in, port_out = free_port(), free_port()
    log = tmp_path / "take.jsonl"
    # As the README gives it: from the repository root, relative path, no venv activated (an
    # empty PATH entry, i.e. the current folder, where `streamkey/` is the package folder).
    env = {"OSC_IN": str(port_in), "OSC_OUT": str(port_out), "IDLE_EXIT": str(1.5 * MS),
           "PATH": ":/usr/bin:/bin"}
    session = subprocess.Popen(["examples/annotate_session.sh", str(CLIP), str(log)], cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    wait_ready(session)
    replay = streamkey("replay", str(CLIP), "--to", f"osc://127.0.0.1:{port_in}")
    replay.communicate(timeout=60 * MS)
    _, err = session.communicate(timeout=60 * MS)
    assert session.returncode == 0, err
    events = read_jsonl(log)
    assert {e["method"] for e in events if e["type"] == "keyframe"} == set(ONLINE_METHODS)
    summary = (tmp_path / "take.summary.json").read_text()
    assert '"frames_in": 316' in summary
