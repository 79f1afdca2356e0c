"""Helpers for the cluster tests: a real redis-server on a free loopback port, a ZeroMQ
publisher of several streams (topic = stream id), and the uninterrupted reference run."""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest
import zmq
from cmu import DATA
from live_helpers import MS, free_port

from streamkey.adapters.osc import skeleton_header
from streamkey.adapters.zmq import decode_frame_parts, encode_frame_parts
from streamkey.batch import load_motion
from streamkey.cluster.live import parse_skeleton_message, stream_topic
from streamkey.motion import Frame, Motion
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers

CLIPS = ("06_02.bvh", "05_06.bvh")  # 722 and 886 frames: a few seconds each at 240 Hz


class RedisServer:
    """`redis-server` on 127.0.0.1:PORT with no persistence; `stop()` ends it."""

    def __init__(self, tmp: Path) -> None:
        exe = shutil.which("redis-server")
        assert exe, "redis-server not installed (.ci/run installs it with apt)"
        self.port = free_port(socket.SOCK_STREAM)
        self.url = f"redis://127.0.0.1:{self.port}/0"
        self.proc = subprocess.Popen(
            [exe, "--port", str(self.port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no", "--dir", str(tmp), "--protected-mode", "yes"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        assert self.proc.stdout is not None
        deadline = time.monotonic() + 30 * MS
        for line in self.proc.stdout:  # wait on its ready line, not on time
            if "Ready to accept connections" in line:
                break
            assert time.monotonic() < deadline, "redis-server did not get ready"
        else:
            raise AssertionError("redis-server ended before it was ready")

    def client(self):  # type: ignore[no-untyped-def]
        import redis

        return redis.Redis.from_url(self.url)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(20)
        if self.proc.stdout:
            self.proc.stdout.close()


class Publisher:
    """An XPUB socket on a free loopback port that publishes frames of several streams."""

    def __init__(self) -> None:
        self.socket = zmq.Context.instance().socket(zmq.XPUB)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.SNDHWM, 200_000)
        self.socket.setsockopt(zmq.XPUB_VERBOSE, 1)  # every subscriber's subscription
        self.socket.bind("tcp://127.0.0.1:0")
        self.endpoint = self.socket.getsockopt(zmq.LAST_ENDPOINT).decode()
        self.address = self.endpoint.replace("tcp://", "zmq+tcp://")
        self.subscriptions = 0

    def wait_subscribers(self, n: int, timeout: float = 60.0) -> None:
        """Wait until `n` subscriptions arrived (each subscriber subscribes once)."""
        deadline = time.monotonic() + timeout * MS
        while self.subscriptions < n:
            left = deadline - time.monotonic()
            assert left > 0, f"{self.subscriptions} of {n} subscribers after {timeout} s"
            if self.socket.poll(int(left * 1000)):
                if self.socket.recv()[:1] == b"\x01":
                    self.subscriptions += 1

    def skeleton_parts(self, motion: Motion) -> list[bytes]:
        body = json.dumps({"bvh": skeleton_header(motion.skeleton, motion.fps),
                           "fps": motion.fps}).encode()
        return [b"skeleton", body]

    def send(self, stream: str, parts: list[bytes]) -> None:
        self.socket.send_multipart(stream_topic(stream, parts))

    def close(self) -> None:
        self.socket.close(linger=0)


def stream_names(shards: int) -> list[str]:
    """One stream id per shard: ids are placed round robin in the order they are first
    seen, so the i-th id published first lands on shard i."""
    return [f"performer-{i}" for i in range(shards)]


class Clip:
    """One clip as it goes on the wire (BVH skeleton text, float64 frames), and the events
    of an uninterrupted single-process run over exactly those bytes."""

    def __init__(self, name: str, stream: str, pub: Publisher) -> None:
        motion = load_motion(DATA / name)
        self.stream = stream
        self.skeleton = pub.skeleton_parts(motion)
        self.frames = [encode_frame_parts(f, "<f8") for f in motion.frames()]

    def reference(self, methods: list[str]) -> dict[str, dict]:
        """id -> event dict of the uninterrupted run (push, idle, flush)."""
        skeleton, fps, _ = parse_skeleton_message(self.skeleton)
        source = SimpleNamespace(skeleton=skeleton, fps=fps)
        pipeline = Pipeline(make_keyframers(source, methods, {}, None,  # type: ignore[arg-type]
                                            stream=self.stream), stream=self.stream)
        events = []
        for parts in self.frames:
            frame: Frame = decode_frame_parts(parts)
            events += pipeline.push(frame) + pipeline.idle()
        events += pipeline.flush()
        out = {}
        for e in events:
            out[e.id] = e.to_dict()
        assert len(out) == len(events), "event ids must be unique in one run"
        return out


def play(pub: Publisher, clips: list[Clip], start: int = 0, stop: int | None = None,
         period: float = 0.004) -> None:
    """Publish frames start..stop of every clip, interleaved, one round per `period` s."""
    n = max(len(c.frames) for c in clips)
    next_at = time.monotonic()
    for i in range(start, n if stop is None else min(stop, n)):
        for c in clips:
            if i < len(c.frames):
                pub.send(c.stream, c.frames[i])
        next_at += period
        time.sleep(max(0.0, next_at - time.monotonic()))


def play_in_background(pub: Publisher, clips: list[Clip], period: float = 0.004
                       ) -> threading.Thread:
    """`play` every frame on a thread (skeletons first); join it to wait for the end."""
    for c in clips:
        pub.send(c.stream, c.skeleton)
    thread = threading.Thread(target=play, args=(pub, clips, 0, None, period), daemon=True)
    thread.start()
    return thread


def redis_events(client, run: str) -> Iterator[dict]:  # type: ignore[no-untyped-def]
    """Every event of a run's Redis event stream."""
    for _, fields in client.xrange(f"streamkey:{run}:events"):
        yield json.loads(fields[b"event"])


def wait_for(condition, what: str, timeout: float = 120.0, every: float = 0.05):  # type: ignore[no-untyped-def]
    """Poll `condition()` until it returns something truthy; fail after `timeout` s."""
    deadline = time.monotonic() + timeout * MS
    while True:
        value = condition()
        if value:
            return value
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(every)


@pytest.fixture(scope="module")
def redis_server(tmp_path_factory):  # type: ignore[no-untyped-def]
    """A redis-server of this test module's own."""
    server = RedisServer(tmp_path_factory.mktemp("redis"))
    yield server
    server.stop()


@pytest.fixture
def publisher():  # type: ignore[no-untyped-def]
    """A frame publisher of this test's own."""
    pub = Publisher()
    yield pub
    pub.close()
