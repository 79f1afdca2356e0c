"""ASF/AMC clips replay as their BVH equivalent (axis pre-rotations baked in).

`bvh_equivalent` is checked by FK equality against the AMC reader on every shared AMC clip;
`replay` of an AMC file is checked end to end over OSC and ZeroMQ on loopback: the frames a
plain receiver decodes are FK-equal to the AMC reader's, and a `run` receiving the replay
gives exactly the keyframes of the online keyframers run on what was sent.
"""

from __future__ import annotations

import json
import socket
import time

import numpy as np
import pytest
import zmq
from cmu import DATA, clips
from live_helpers import (
    MS,
    free_port,
    interrupt_if_running,
    keyframes_of,
    read_jsonl,
    streamkey,
    wait_ready,
)
from pythonosc.osc_message import OscMessage

from streamkey.amc import bvh_equivalent, read_amc, read_motion
from streamkey.bvh import format_bvh, parse_bvh, read_bvh
from streamkey.cli import main
from streamkey.keyframes import KeyframeEvent
from streamkey.kinematics import forward_kinematics
from streamkey.methods import ONLINE_METHODS
from streamkey.motion import Motion
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers

AMC = DATA / "09_06.amc"


def fk(skeleton, channels) -> np.ndarray:  # type: ignore[no-untyped-def]
    return forward_kinematics(skeleton, channels).positions


@pytest.mark.parametrize("name", clips("amc"))
def test_bvh_equivalent_is_fk_equal_to_the_amc_reader(name: str) -> None:
    motion = read_motion(DATA / name)
    assert not motion.skeleton.bvh_compatible()
    plain = bvh_equivalent(motion)
    assert plain.skeleton.bvh_compatible()
    assert plain.skeleton.names == motion.skeleton.names
    want = fk(motion.skeleton, motion.channels)
    assert np.abs(fk(plain.skeleton, plain.channels) - want).max() < 1e-9
    # through BVH text (6 decimals), as replay's skeleton message and --export-bvh write it
    back = parse_bvh(format_bvh(plain))
    assert np.abs(fk(back.skeleton, back.channels) - want).max() < 1e-4
    # unwrapped: no channel jumps by a whole turn between frames
    assert np.abs(np.diff(plain.channels, axis=0)).max() < 300


def test_a_plain_bvh_motion_is_its_own_equivalent() -> None:
    motion = read_bvh(DATA / "07_01.bvh")
    assert bvh_equivalent(motion) is motion


def test_export_bvh_of_an_amc_clip_writes_fk_equal_keyposes(tmp_path, capsys) -> None:
    out = tmp_path / "k.bvh"
    code = main(["extract", str(DATA / "05_11.amc"), "--method", "uniform", "--count", "5",
                 "-q", "-o", str(tmp_path / "k.json"), "--export-bvh", str(out)])
    assert code == 0, capsys.readouterr().err
    motion = read_amc(DATA / "05_11.amc")
    frames = json.loads((tmp_path / "k.json").read_text())["files"][0]["methods"][
        "uniform"]["keyframes"]
    back = read_bvh(out)
    assert back.n_frames == 5
    assert np.abs(fk(back.skeleton, back.channels)
                  - fk(motion.skeleton, motion.channels[frames])).max() < 1e-4


def wire_motion() -> Motion:
    """What a receiver holds after the replay: the skeleton of the BVH header text, float32."""
    plain = bvh_equivalent(read_motion(AMC))
    header = parse_bvh(format_bvh(plain, np.zeros(0, dtype=np.int64))).skeleton
    return Motion(header, plain.channels.astype(np.float32), plain.fps, plain.first_frame)


def receive_osc(port: int, n_frames: int) -> tuple[str, dict[int, np.ndarray]]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(20 * MS)
    replay = streamkey("replay", str(AMC), "--to", f"osc://127.0.0.1:{port}", "--rate", "1000")
    header, frames = "", {}
    try:
        while len(frames) < n_frames or not header:
            msg = OscMessage(sock.recv(65536))
            if msg.address == "/streamkey/skeleton":
                header = msg.params[0]
            else:
                frames[msg.params[0]] = np.array(msg.params[2:])
    finally:
        sock.close()
        _, err = replay.communicate(timeout=30 * MS)
    assert replay.returncode == 0, err
    return header, frames


def receive_zmq(port: int, n_frames: int) -> tuple[str, dict[int, np.ndarray]]:
    ctx = zmq.Context.instance()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"")
    sub.setsockopt(zmq.RCVTIMEO, int(20_000 * MS))
    sub.connect(f"tcp://127.0.0.1:{port}")
    replay = streamkey("replay", str(AMC), "--to", f"zmq+tcp://127.0.0.1:{port}", "--rate",
                       "1000", "--wait", "10")
    header, frames = "", {}
    try:
        while len(frames) < n_frames or not header:
            parts = sub.recv_multipart()
            if parts[0] == b"skeleton":
                header = json.loads(parts[1])["bvh"]
            else:
                meta = json.loads(parts[1])
                frames[meta["seq"]] = np.frombuffer(parts[2], meta["dtype"]).astype(float)
    finally:
        sub.close(linger=0)
        _, err = replay.communicate(timeout=30 * MS)
    assert replay.returncode == 0, err
    return header, frames


@pytest.mark.parametrize("receive", [receive_osc, receive_zmq], ids=["osc", "zmq"])
def test_replayed_amc_frames_are_fk_equal_to_the_amc_reader(receive) -> None:  # type: ignore
    motion = read_motion(AMC)
    kind = socket.SOCK_DGRAM if receive is receive_osc else socket.SOCK_STREAM
    header, frames = receive(free_port(kind), motion.n_frames)
    skeleton = parse_bvh(header).skeleton
    assert sorted(frames) == list(range(motion.n_frames))
    got = fk(skeleton, np.array([frames[i] for i in range(motion.n_frames)]))
    want = fk(motion.skeleton, motion.channels)
    assert np.abs(got - want).max() < 1e-3  # float32 on the wire, 6-decimal offsets


def direct_events(motion: Motion) -> list[tuple[str, int, int]]:
    pipeline = Pipeline(make_keyframers(motion, list(ONLINE_METHODS)))
    events = pipeline.push_block(motion.frames()) + pipeline.flush()
    return sorted((e.method, e.frame, e.decided_at) for e in events
                  if isinstance(e, KeyframeEvent))


@pytest.mark.parametrize(("scheme", "skeleton"), [("osc", False), ("zmq+tcp", False),
                                                  ("osc", True)])
def test_run_receiving_an_amc_replay_keys_what_was_sent(tmp_path, scheme, skeleton) -> None:
    """From the wire's skeleton message, or from `--skeleton CLIP.amc` (converted alike)."""
    port = free_port(socket.SOCK_DGRAM if scheme == "osc" else socket.SOCK_STREAM)
    address = f"{scheme}://127.0.0.1:{port}"
    log = tmp_path / "events.jsonl"
    given = ["--skeleton", str(AMC)] if skeleton else []
    run = streamkey("run", "--from", address, "--to", f"jsonl:{log}", "--idle-exit",
                    str(1.5 * MS), *given)
    try:
        wait_ready(run)
        started = time.monotonic()
        replay = streamkey("replay", str(AMC), "--to", address)
        assert replay.wait(timeout=60 * MS) == 0, replay.communicate()[1]
        replay.communicate()
        _, err = run.communicate(timeout=60 * MS)
        assert time.monotonic() - started < 60 * MS
    finally:
        interrupt_if_running(run)
    assert run.returncode == 0, err
    assert f"frames in: {read_motion(AMC).n_frames}" in err
    got = keyframes_of(read_jsonl(log))
    wire = wire_motion()
    if skeleton:  # run holds the converted skeleton itself, offsets not rounded to 6 decimals
        wire.skeleton = bvh_equivalent(read_motion(AMC)).skeleton
    assert got == direct_events(wire)
    assert {m for m, _, _ in got} >= {"saliency", "simplify"}
