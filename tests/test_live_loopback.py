from __future__ import annotations

import numpy as np
import pytest
from cmu import DATA
from live_helpers import (
    MS,
    free_port,
    interrupt_if_running,
    keyframes_of,
    read_jsonl,
    streamkey,
    wait_ready,
)

from streamkey.bvh import read_bvh
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import ONLINE_METHODS
from streamkey.motion import Motion
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers

CLIP = DATA / "07_01.bvh"


def direct_events(float32: bool) -> list[tuple[str, int, int]]:
    """The online keyframers on the file directly (channels as sent on the wire)."""
    motion = read_bvh(CLIP)
    if float32:
        motion = Motion(motion.skeleton, motion.channels.astype(np.float32), motion.fps,
                        motion.first_frame)
    pipeline = Pipeline(make_keyframers(motion, list(ONLINE_METHODS)))
    events = pipeline.push_block(motion.frames()) + pipeline.flush()
    return sorted((e.method, e.frame, e.decided_at) for e in events
                  if isinstance(e, KeyframeEvent))


@pytest.mark.parametrize("scheme", ["osc", "zmq+tcp"])
def test_replay_and_run_as_two_processes_lose_no_event(tmp_path, scheme):
    kind = "udp" if scheme == "osc" else "tcp"
    port = free_port(2 if kind == "udp" else 1)
    address = f"{scheme}://127.0.0.1:{port}"
    log = tmp_path / "events.jsonl"
    run = streamkey("run", "--from", address, "--skeleton", str(CLIP), "--to", f"jsonl:{log}",
                    "--idle-exit", str(1.5 * MS))
    try:
        wait_ready(run)
        replay = streamkey("replay", str(CLIP), "--to", address)
        assert replay.wait(timeout=60 * MS) == 0, replay.communicate()[1]
        replay.communicate()
        _, err = run.communicate(timeout=60 * MS)
    finally:
        interrupt_if_running(run)
    assert run.returncode == 0, err
    got = keyframes_of(read_jsonl(log))
    assert "frames in: 316" in err
    assert got == direct_events(float32=(scheme == "osc" or scheme == "zmq+tcp"))
    assert got == direct_events(float32=False), "float32 wire rounding changed a decision"
    assert {m for m, _, _ in got} == set(ONLINE_METHODS)


WS_CLIENT = """
import asyncio, sys
from websockets.asyncio.client import connect
from websockets.exceptions import ConnectionClosed

async def main():
    async with connect(sys.argv[1]) as ws:
        print("connected", flush=True)
        try:
            async for message in ws:
                print(message, flush=True)
        except ConnectionClosed:
            pass

asyncio.run(main())
"""


def test_a_websocket_client_in_another_process_receives_the_events_as_json(tmp_path):
    import json
    import subprocess
    import sys

    osc_port, ws_port = free_port(), free_port(1)
    log = tmp_path / "events.jsonl"
    run = streamkey("run", "--from", f"osc://127.0.0.1:{osc_port}", "--skeleton", str(CLIP),
                    "--to", f"ws://127.0.0.1:{ws_port}", "--to", f"jsonl:{log}",
                    "--idle-exit", str(1.5 * MS))
    client = None
    try:
        wait_ready(run)
        client = subprocess.Popen([sys.executable, "-c", WS_CLIENT, f"ws://127.0.0.1:{ws_port}"],
                                  stdout=subprocess.PIPE, text=True)
        assert client.stdout.readline().strip() == "connected"
        replay = streamkey("replay", str(CLIP), "--to", f"osc://127.0.0.1:{osc_port}")
        replay.communicate(timeout=60 * MS)
        _, err = run.communicate(timeout=60 * MS)
        out, _ = client.communicate(timeout=30 * MS)
    finally:
        for proc in (run, client):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.communicate()
    assert run.returncode == 0, err
    received = [json.loads(line) for line in out.splitlines() if line.strip()]
    assert received == read_jsonl(log)
    assert sum(e["type"] == "keyframe" for e in received) > 10
