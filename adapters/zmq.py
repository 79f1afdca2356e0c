"""ZeroMQ: frames in (SUB or PULL), frames out (replay: PUB), events out (PUB).

Frames are multipart `[b"frame", JSON header, payload]`; the header is
`{"seq": int, "time": float, "n": channels, "dtype": "<f4" | "<f8"}` and the payload the
channel values (float32 by default, as DESIGN §7; "<f8" keeps BVH values bit-exact).
The skeleton is `[b"skeleton", JSON {"bvh": header text, "fps": float}]`, re-sent every
second by the replay so late subscribers get it. Events are `[b"event", JSON event]`.

Address options: `zmq+tcp://127.0.0.1:5555?pattern=pull` makes a source bind a PULL socket
(many PUSH senders connect); the default source pattern `sub` connects a SUB socket to a
publisher, reconnecting by itself when the publisher restarts.
"""

from __future__ import annotations

import asyncio
import json
import math

import numpy as np
import zmq
import zmq.asyncio

from streamkey.bvh import parse_bvh
from streamkey.errors import BVHError, InputError, UsageError
from streamkey.keyframes import Event
from streamkey.motion import Frame, Skeleton

from .base import MAX_CHANNELS, MAX_MESSAGE_BYTES, Address, Sink, SinkStats, Source, bind_host

__all__ = ["ZmqSource", "ZmqEventSink", "ZmqFrameSender", "encode_frame_parts",
           "decode_frame_parts"]

_DTYPES = {"<f4": np.dtype("<f4"), "<f8": np.dtype("<f8")}


def encode_frame_parts(frame: Frame, dtype: str = "<f4") -> list[bytes]:
    """Multipart message of one frame."""
    values = np.asarray(frame.channels, dtype=_DTYPES[dtype])
    header = {"seq": int(frame.seq), "time": float(frame.time), "n": len(values), "dtype": dtype}
    return [b"frame", json.dumps(header).encode(), values.tobytes()]


def decode_frame_parts(parts: list[bytes]) -> Frame:
    """Frame of a multipart message; raises ValueError saying what is wrong."""
    if len(parts) != 3:
        raise ValueError(f"frame message has {len(parts)} parts, expected 3")
    header = json.loads(parts[1])
    if not isinstance(header, dict):
        raise ValueError("frame header is not a JSON object")
    dtype = _DTYPES.get(header.get("dtype", "<f4"))
    n = header.get("n")
    if dtype is None or not isinstance(n, int) or not 0 < n <= MAX_CHANNELS:
        raise ValueError(f"frame header needs n (1..{MAX_CHANNELS}) and dtype <f4 or <f8")
    if len(parts[2]) != n * dtype.itemsize:
        raise ValueError(f"payload of {len(parts[2])} bytes, expected {n} x {dtype.itemsize}")
    seq, time = header.get("seq"), header.get("time")
    if not isinstance(seq, int) or not isinstance(time, (int, float)) or not math.isfinite(time):
        raise ValueError("frame header needs an integer seq and a finite time")
    return Frame(seq, float(time), np.frombuffer(parts[2], dtype).astype(np.float64))


class ZmqSource(Source):
    """Frames from ZeroMQ: SUB (connects to a publisher) or PULL (binds)."""

    name = "zmq"

    def __init__(self, address: Address, listen: str | None = None,
                 skeleton: Skeleton | None = None, fps: float | None = None) -> None:
        super().__init__(skeleton, fps)
        self.address = address
        self.pattern = address.options.get("pattern", "sub")
        if self.pattern not in ("sub", "pull"):
            raise UsageError(f"{address}: pattern must be sub or pull, got {self.pattern!r}")
        if self.pattern == "pull" and address.scheme == "zmq+tcp":
            bind_host(address, listen)
        self.listen = listen
        self.context = zmq.asyncio.Context.instance()
        self.socket: zmq.asyncio.Socket | None = None
        self.task: asyncio.Task[None] | None = None

    async def start(self) -> str:
        sock = self.context.socket(zmq.SUB if self.pattern == "sub" else zmq.PULL)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
        sock.setsockopt(zmq.RCVHWM, 256)
        endpoint = self.address.zmq_endpoint
        if self.pattern == "sub":
            sock.setsockopt(zmq.SUBSCRIBE, b"frame")
            sock.setsockopt(zmq.SUBSCRIBE, b"skeleton")
            sock.connect(endpoint)
        else:
            if self.listen and self.address.scheme == "zmq+tcp":
                endpoint = f"tcp://{self.listen}:{self.address.port}"
            try:
                sock.bind(endpoint)
            except zmq.ZMQError as exc:
                sock.close(linger=0)
                raise InputError(f"{self.address}: cannot bind {endpoint}: {exc}") from None
        self.socket = sock
        self.task = asyncio.create_task(self._receive())
        return f"zmq+{self.pattern} {endpoint}"

    async def _receive(self) -> None:
        assert self.socket is not None
        while True:
            parts = await self.socket.recv_multipart()
            self.handle(parts)

    def handle(self, parts: list[bytes]) -> None:
        """Decode one multipart message; never raises."""
        try:
            if parts and parts[0] == b"skeleton":
                info = json.loads(parts[1])
                skeleton = parse_bvh(info["bvh"], source="zmq skeleton").skeleton
                self.set_skeleton(skeleton, float(info.get("fps", 120.0)))
                return
            if not parts or parts[0] != b"frame":
                raise ValueError(f"unknown topic {parts[0][:32]!r}" if parts else "empty message")
            frame = decode_frame_parts(parts)
        except (ValueError, KeyError, IndexError, TypeError, BVHError) as exc:
            self.stats.reject("malformed", f"zmq: {exc}")
            return
        self.stats.received += 1
        self.frames.put(frame)

    async def close(self) -> None:
        if self.task is not None:
            self.task.cancel()
        if self.socket is not None:
            self.socket.close(linger=0)


def _pub_socket(address: Address, listen: str | None) -> tuple[zmq.Socket[bytes], str]:
    host = bind_host(address, listen) if address.scheme == "zmq+tcp" else ""
    sock = zmq.Context.instance().socket(zmq.XPUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDHWM, 1000)
    if address.scheme == "zmq+tcp":
        endpoint = f"tcp://{host}:{address.port}"
    else:
        endpoint = address.zmq_endpoint
    try:
        sock.bind(endpoint)
    except zmq.ZMQError as exc:
        sock.close(linger=0)
        raise InputError(f"{address}: cannot bind {endpoint}: {exc}") from None
    return sock, endpoint


class ZmqEventSink(Sink):
    """Events as `[b"event", JSON]` on a publisher socket (binds; subscribers connect)."""

    name = "zmq"

    def __init__(self, address: Address, listen: str | None = None) -> None:
        super().__init__()
        self.address = address
        self.listen = listen
        self.socket: zmq.Socket[bytes] | None = None

    async def start(self) -> str:
        self.socket, endpoint = _pub_socket(self.address, self.listen)
        return f"zmq+pub {endpoint}"

    def offer(self, event: Event) -> None:
        assert self.socket is not None
        try:
            self.socket.send_multipart([b"event", json.dumps(event.to_dict()).encode()],
                                       zmq.NOBLOCK)
            self.stats.sent += 1
        except zmq.Again:
            self.stats.dropped += 1

    async def close(self) -> None:
        if self.socket is not None:
            self.socket.close(linger=0)


class ZmqFrameSender:
    """Frames and the skeleton on a publisher socket: the replay side."""

    name = "zmq"

    def __init__(self, address: Address, listen: str | None = None) -> None:
        self.address = address
        self.stats = SinkStats()
        self.dtype = address.options.get("dtype", "<f4")
        if self.dtype not in _DTYPES:
            raise UsageError(f"{address}: dtype must be <f4 or <f8")
        self.socket, self.endpoint = _pub_socket(address, listen)
        self.skeleton_message: tuple[Skeleton, list[bytes]] | None = None

    def subscribers(self, timeout: float) -> int:
        """Wait up to `timeout` s for subscriptions (XPUB); returns how many arrived."""
        count = 0
        poller = zmq.Poller()
        poller.register(self.socket, zmq.POLLIN)
        remaining = int(timeout * 1000)
        while remaining > 0 and poller.poll(remaining if count == 0 else 50):
            self.socket.recv(zmq.NOBLOCK)
            count += 1
            remaining = 50
        return count

    def send_skeleton(self, skeleton: Skeleton, fps: float) -> None:
        """Announce the skeleton to subscribers."""
        from .osc import skeleton_header

        if self.skeleton_message is None or self.skeleton_message[0] is not skeleton:
            body = json.dumps({"bvh": skeleton_header(skeleton, fps), "fps": fps}).encode()
            self.skeleton_message = (skeleton, [b"skeleton", body])
        self._send(self.skeleton_message[1])

    def send_frame(self, frame: Frame) -> None:
        """Publish one frame (never blocks; a full queue counts a drop)."""
        self._send(encode_frame_parts(frame, self.dtype))

    def _send(self, parts: list[bytes]) -> None:
        try:
            self.socket.send_multipart(parts, zmq.NOBLOCK)
            self.stats.sent += 1
        except zmq.Again:
            self.stats.dropped += 1

    def close(self) -> None:
        """Close the socket."""
        self.socket.close(linger=0)
