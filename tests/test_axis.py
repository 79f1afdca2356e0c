"""Axis Neuron BVH broadcast source: parser (text and binary, any split), layouts, a real TCP
sender process (partial reads, two frames in one read, a reconnecting server), UDP, fuzz."""

from __future__ import annotations

import asyncio
import json
import random
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from cmu import DATA
from live_helpers import MS, free_port, interrupt_if_running, keyframes_of, read_jsonl, streamkey

from streamkey.adapters.axis import (
    AxisLayout,
    AxisParser,
    AxisSource,
    encode_binary,
    encode_text,
)
from streamkey.adapters.base import SourceStats, parse_address
from streamkey.bvh import read_bvh
from streamkey.methods import ONLINE_METHODS
from streamkey.rigs import axis_skeleton

CLIP = DATA / "07_01.bvh"
SENDER = Path(__file__).with_name("axis_sender.py")


def _two_frames(kind: str) -> tuple[bytes, list[np.ndarray]]:
    rng = np.random.default_rng(3)
    values = [rng.normal(size=180).astype(np.float32).astype(float) for _ in range(2)]
    if kind == "text":
        return b"".join(encode_text(0, "Avatar00", v) for v in values), values
    return b"".join(encode_binary(0, "Avatar00", 7 + i, v) for i, v in enumerate(values)), values


@pytest.mark.parametrize("kind", ["text", "binary"])
def test_every_split_of_two_frames_gives_both_frames(kind):
    data, values = _two_frames(kind)
    first = len(data) // 2
    cuts = set(range(0, len(data) + 1, 11)) | set(range(70)) | set(range(first - 70, first + 70))
    for cut in sorted(cuts | {len(data) - 1, len(data)}):
        stats = SourceStats()
        parser = AxisParser(stats)
        packets = parser.feed(data[:cut]) + parser.feed(data[cut:])
        assert [p.values.tolist() for p in packets] == [v.tolist() for v in values], cut
        assert not stats.malformed
    packets = AxisParser(SourceStats()).feed(data)  # two frames in one read
    assert len(packets) == 2 and packets[0].avatar == 0 and packets[0].name == "Avatar00"
    if kind == "binary":
        assert [p.frame_index for p in packets] == [7, 8]


def test_garbage_between_frames_is_counted_and_the_reader_resynchronises():
    text, _ = _two_frames("text")
    binary, _ = _two_frames("binary")
    stats = SourceStats()
    parser = AxisParser(stats)
    bad_header = bytearray(binary[:64])
    bad_header[62:64] = b"\0\0"
    stream = (b"hello ||" + text + b"\xff\xdd" + bytes(62) + binary + bytes(bad_header)
              + b"0 A 1 2 x ||" + text)
    packets = parser.feed(stream)
    assert len(packets) == 6
    # text: "hello", the zeros after a lone token, the bad header's tail with "0 A 1 2 x"
    assert stats.malformed["text"] == 3 and stats.malformed["binary"] == 2


def test_layouts_plain_reference_displacement():
    skel = axis_skeleton()
    assert skel.n_joints == 59 and skel.n_channels == 180
    layout = AxisLayout(skel)
    plain = np.arange(180.0)
    disp = np.concatenate([np.r_[plain[:6]]] + [np.r_[-1, -1, -1, plain[6 + 3 * j: 9 + 3 * j]]
                                                for j in range(58)])
    assert np.array_equal(layout.channels(plain), plain)
    assert np.array_equal(layout.channels(np.r_[np.full(6, 9.0), plain]), plain)
    assert np.array_equal(layout.channels(disp), plain)
    assert np.array_equal(layout.channels(np.r_[np.full(6, 9.0), disp]), plain)
    with pytest.raises(ValueError, match="181 values fit no layout"):
        layout.channels(np.zeros(181))


def _run_against_sender(tmp_path: Path, *sender_args: str) -> tuple[list, str]:
    sender = subprocess.Popen([sys.executable, str(SENDER), str(CLIP), "--rate", "400",
                               *sender_args], stdout=subprocess.PIPE, text=True)
    log = tmp_path / "axis.jsonl"
    try:
        assert sender.stdout is not None
        port = int(sender.stdout.readline().split()[1])  # waits for "listening PORT"
        run = streamkey("run", "--from", f"axis+tcp://127.0.0.1:{port}", "--skeleton", str(CLIP),
                        "--to", f"jsonl:{log}", "--idle-exit", str(1.5 * MS))
        _, err = run.communicate(timeout=120 * MS)
        assert sender.wait(timeout=30 * MS) == 0
    finally:
        if sender.poll() is None:
            sender.kill()
            sender.wait()
        assert sender.stdout is not None
        sender.stdout.close()
    assert run.returncode == 0, err
    return keyframes_of(read_jsonl(log)), err


@pytest.fixture(scope="module")
def file_keyframes(tmp_path_factory):
    log = tmp_path_factory.mktemp("axis") / "file.jsonl"
    ref = subprocess.run([sys.executable, "-m", "streamkey", "run", "--from", str(CLIP), "--fast",
                          "--to", f"jsonl:{log}"], capture_output=True, text=True,
                         timeout=120 * MS)
    assert ref.returncode == 0, ref.stderr
    return keyframes_of(read_jsonl(log))


@pytest.mark.parametrize("sender_args", [
    ("--format", "text"),
    ("--format", "binary", "--disp", "--ref"),
    ("--format", "text", "--ref", "--restart-after", "150", "--other-avatar"),
], ids=["text", "binary-disp-ref", "text-ref-reconnect-two-avatars"])
def test_run_from_axis_tcp_equals_run_from_the_file(tmp_path, file_keyframes, sender_args):
    got, err = _run_against_sender(tmp_path, *sender_args)
    assert "frames in: 316" in err and "0 queue" in err
    assert got == file_keyframes
    assert {m for m, _, _ in got} == set(ONLINE_METHODS)


def test_udp_datagrams_with_the_built_in_axis_skeleton():
    port = free_port()
    rng = np.random.default_rng(0)
    values = [rng.normal(size=180) for _ in range(5)]

    async def main() -> tuple[list, SourceStats]:
        source = AxisSource(parse_address(f"axis+udp://127.0.0.1:{port}"))
        assert source.skeleton is not None and source.skeleton.n_joints == 59
        await source.start()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for i, v in enumerate(values):
            data = encode_text(0, "A", v) if i % 2 else encode_binary(0, "A", 100 + i, v)
            sock.sendto(data, ("127.0.0.1", port))
            sock.sendto(data[: len(data) // 2], ("127.0.0.1", port))  # a cut datagram
        sock.close()
        got = [await asyncio.wait_for(source.get(), 10 * MS) for _ in values]
        got = [(item.frame, item.arrival_ns) for item in got]
        await source.close()
        return got, source.stats

    got, stats = asyncio.run(main())
    assert [f.seq for f, _ in got] == [100, 2, 102, 4, 104]
    assert np.allclose(got[1][0].channels, values[1])
    assert np.allclose(got[0][0].channels, values[0].astype(np.float32))
    assert sum(stats.malformed.values()) == 5


def test_fuzzed_axis_streams_never_raise():
    text, _ = _two_frames("text")
    binary, _ = _two_frames("binary")
    rng = random.Random(7)
    for _ in range(300):
        stream = bytearray(rng.choice([text, binary]) * rng.randrange(1, 4))
        for _ in range(rng.randrange(1, 8)):
            pos = rng.randrange(len(stream))
            choice = rng.randrange(4)
            if choice == 0:
                stream[pos] = rng.randrange(256)
            elif choice == 1:
                del stream[pos: pos + rng.randrange(1, 80)]
            elif choice == 2:
                stream[pos:pos] = rng.choice([b"\xff\xdd", b"||", b"\xff\xee", bytes(70)])
            else:
                stream[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
        stats = SourceStats()
        source_like = AxisParser(stats)
        packets, pos = [], 0
        while pos < len(stream):
            step = rng.randrange(1, 200)
            packets += source_like.feed(bytes(stream[pos: pos + step]))
            pos += step
        source_like.end_of_message()
        assert len(source_like.buffer) == 0
        assert all(len(p.values) <= 1024 for p in packets)


def test_a_garbage_server_leaves_run_clean(tmp_path):
    """Random bytes, then real frames, over TCP: run drops and counts, never a traceback."""
    motion = read_bvh(CLIP)
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    port = listener.getsockname()[1]
    rng = random.Random(3)

    def serve() -> None:
        conn, _ = listener.accept()
        conn.sendall(bytes(rng.randrange(256) for _ in range(30000)) + b" ||")
        for seq in range(1, 60):
            conn.sendall(encode_text(0, "A", motion.channels[seq]))
        conn.close()
        listener.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    log = tmp_path / "g.jsonl"
    run = streamkey("run", "--from", f"axis+tcp://127.0.0.1:{port}", "--skeleton", str(CLIP),
                    "--to", f"jsonl:{log}", "--idle-exit", str(1.0 * MS), "--summary",
                    str(tmp_path / "s.json"))
    try:
        _, err = run.communicate(timeout=60 * MS)
    finally:
        interrupt_if_running(run)
    thread.join(10)
    assert run.returncode == 0, err
    assert "Traceback" not in err
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["frames_in"] >= 58 and sum(summary["source"]["malformed"].values()) >= 1


@pytest.mark.parametrize("rig", ["axis", "humanoid"])
def test_built_in_skeletons_drive_every_online_method(rig):
    from streamkey.methods import ONLINE_METHODS
    from streamkey.motion import Motion
    from streamkey.online import Pipeline
    from streamkey.rigs import humanoid_skeleton
    from streamkey.roles import detect_rig
    from streamkey.streaming import make_keyframers

    skel = axis_skeleton() if rig == "axis" else humanoid_skeleton()
    assert detect_rig(skel) == ("axis" if rig == "axis" else "unity")
    t = np.arange(600) / 60.0
    channels = np.zeros((600, skel.n_channels))
    rot = skel.rotation_columns()
    channels[:, rot] = 30 * np.sin(2 * np.pi * (0.5 + 0.01 * np.arange(len(rot))) * t[:, None])
    motion = Motion(skel, channels, 60.0)
    pipeline = Pipeline(make_keyframers(motion, list(ONLINE_METHODS)))
    events = pipeline.push_block(motion.frames()) + pipeline.flush()
    assert {e.method for e in events if hasattr(e, "score")} == set(ONLINE_METHODS)
