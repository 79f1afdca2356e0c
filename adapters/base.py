"""What every source and sink shares: counters, the drop-oldest frame queue, the interfaces.

A source delivers `(Frame, arrival_ns)` pairs from `get()` (None at end of stream) and may
learn its skeleton from the wire (`skeleton_ready`). A sink takes events with `offer()`,
which never blocks: live sinks drop the oldest pending message when they fall behind and
count it; the JSON Lines sink never drops.
"""

from __future__ import annotations

import asyncio
import ipaddress
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import parse_qs, urlsplit

from streamkey.errors import UsageError
from streamkey.motion import Frame, Skeleton

__all__ = ["Address", "parse_address", "FrameQueue", "Source", "Sink", "SourceStats",
           "SinkStats", "put_drop_oldest", "LOOPBACK", "bind_host", "MAX_CHANNELS",
           "MAX_MESSAGE_BYTES"]

LOOPBACK = "127.0.0.1"
MAX_CHANNELS = 1024          # more channels than any skeleton we know of (CMU: 96)
MAX_MESSAGE_BYTES = 65_000   # one UDP datagram; also the ZeroMQ frame and WebSocket limit

_SCHEMES = {"osc", "zmq+tcp", "zmq+ipc", "ws", "jsonl", "-"}
_SCHEMES |= {"axis+tcp", "axis+udp", "vmc"}  # capture-system sources (issue 11)


@dataclass(frozen=True)
class Address:
    """A parsed `osc://host:port`, `zmq+tcp://host:port`, `ws://host:port`, `jsonl:PATH`, `-`."""

    scheme: str
    host: str = ""
    port: int = 0
    path: str = ""
    options: dict[str, str] = field(default_factory=dict)

    def __str__(self) -> str:
        if self.scheme == "-":
            return "-"
        if self.scheme == "jsonl":
            return f"jsonl:{self.path}"
        if self.scheme == "zmq+ipc":
            return f"zmq+ipc://{self.path}"
        return f"{self.scheme}://{self.host}:{self.port}"

    @property
    def zmq_endpoint(self) -> str:
        """The libzmq endpoint string (tcp://host:port or ipc://path)."""
        return f"ipc://{self.path}" if self.scheme == "zmq+ipc" else f"tcp://{self.host}:{self.port}"


def parse_address(text: str) -> Address:
    """Parse an address; raises `UsageError` naming what is wrong."""
    if text == "-":
        return Address("-")
    if text.startswith("jsonl:"):
        path = text[len("jsonl:") :]
        if not path:
            raise UsageError("jsonl: address needs a file path, e.g. jsonl:session.jsonl")
        return Address("jsonl", path=path)
    parts = urlsplit(text)
    if parts.scheme not in _SCHEMES:
        raise UsageError(f"address {text!r}: unknown scheme {parts.scheme!r}; expected one of "
                         "osc://HOST:PORT, zmq+tcp://HOST:PORT, ws://HOST:PORT, jsonl:PATH, -, "
                         "axis+tcp://HOST:PORT, axis+udp://HOST:PORT, vmc://HOST:PORT")
    options = {k: v[-1] for k, v in parse_qs(parts.query).items()}
    if parts.scheme == "zmq+ipc":
        return Address("zmq+ipc", path=parts.netloc + parts.path, options=options)
    try:
        port = parts.port
    except ValueError:
        port = None
    if port is None:
        raise UsageError(f"address {text!r}: expected a port, e.g. {parts.scheme}://127.0.0.1:9000")
    return Address(parts.scheme, parts.hostname or LOOPBACK, port, parts.path, options)


def bind_host(address: Address, listen: str | None) -> str:
    """Host a listener binds to: loopback unless `--listen` allows another interface."""
    if listen:
        return listen
    host = address.host or LOOPBACK
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise UsageError(f"{address}: listening on {host} needs --listen {host} "
                         "(listeners bind to 127.0.0.1 by default)")
    return host


@dataclass
class SourceStats:
    """Counters of a source: frames received, dropped (queue full), malformed, last error."""

    received: int = 0
    queue_drops: int = 0
    malformed: Counter[str] = field(default_factory=Counter)
    last_error: str = ""

    def reject(self, kind: str, message: str) -> None:
        """Count a malformed message of `kind` and remember why."""
        self.malformed[kind] += 1
        self.last_error = message

    def as_dict(self) -> dict[str, Any]:
        """Counters as a plain dict."""
        return {"received": self.received, "queue_drops": self.queue_drops,
                "malformed": dict(self.malformed), "last_error": self.last_error}


@dataclass
class SinkStats:
    """Counters of a sink: events sent, dropped (slow or absent peer), errors."""

    sent: int = 0
    dropped: int = 0
    errors: int = 0
    last_error: str = ""

    def as_dict(self) -> dict[str, Any]:
        """Counters as a plain dict."""
        return dict(self.__dict__)


def put_drop_oldest(queue: asyncio.Queue[Any], item: Any) -> int:
    """Put `item` without waiting, dropping the oldest entries to make room; returns how
    many were dropped (live consumers want the newest data, not a backlog)."""
    dropped = 0
    while True:
        try:
            queue.put_nowait(item)
            return dropped
        except asyncio.QueueFull:
            queue.get_nowait()
            dropped += 1


class FrameQueue:
    """Bounded frame queue between a network callback and the engine: drop-oldest when full.

    A real-time keyframer wants the newest frames, not a backlog (notes/ecosystem.md: big
    buffers only make frames stale).
    """

    def __init__(self, stats: SourceStats, maxsize: int = 256) -> None:
        self.queue: asyncio.Queue[tuple[Frame, int] | None] = asyncio.Queue(maxsize)
        self.stats = stats

    def put(self, frame: Frame | None) -> None:
        """Enqueue a frame (stamped with its arrival time) or the end-of-stream marker."""
        item = None if frame is None else (frame, time.monotonic_ns())
        self.stats.queue_drops += put_drop_oldest(self.queue, item)

    async def get(self) -> tuple[Frame, int] | None:
        """Next frame and its arrival time (ns, monotonic), or None at end of stream."""
        return await self.queue.get()


class Source:
    """Base of frame sources: a queue, counters, and the skeleton (given or from the wire)."""

    name = "source"

    def __init__(self, skeleton: Skeleton | None = None, fps: float | None = None) -> None:
        self.stats = SourceStats()
        self.frames = FrameQueue(self.stats)
        self.skeleton = skeleton
        self.fps = fps
        self.skeleton_ready = asyncio.Event()
        if skeleton is not None:
            self.skeleton_ready.set()

    def set_skeleton(self, skeleton: Skeleton, fps: float) -> None:
        """Adopt a skeleton announced on the wire (first one wins; a changed one is counted)."""
        if self.skeleton is None:
            self.skeleton, self.fps = skeleton, fps
            self.skeleton_ready.set()
        elif skeleton.n_channels != self.skeleton.n_channels:
            self.stats.reject("skeleton_mismatch",
                              f"skeleton with {skeleton.n_channels} channels ignored; stream has "
                              f"{self.skeleton.n_channels}")

    async def start(self) -> str:
        """Open the transport; returns a description for the ready line."""
        raise NotImplementedError

    async def get(self) -> tuple[Frame, int] | None:
        """Next frame and its arrival time, or None when the stream ends."""
        return await self.frames.get()

    async def close(self) -> None:
        """Release the transport."""


class Sink:
    """Base of event sinks. `offer` must never block the engine."""

    name = "sink"
    live = True  # live sinks may drop under backpressure; the log sink never does

    def __init__(self) -> None:
        self.stats = SinkStats()

    async def start(self) -> str:
        """Open the transport; returns a description for the ready line."""
        return self.name

    def offer(self, event: dict[str, Any]) -> None:
        """Hand over one event (a JSON-ready dict); must not block."""
        raise NotImplementedError

    async def close(self) -> None:
        """Drain (bounded time) and release the transport."""
