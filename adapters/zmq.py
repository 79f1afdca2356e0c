"""ZeroMQ: frames in (SUB or PULL), frames out (replay: PUB), events out (PUB).

Frames are multipart `[b"frame", JSON header, payload]`; the header is
`{"seq": int, "time": float, "n": channels, "dtype": "<f4" | "<f8"}` and the payload the
channel values (float32 by default; "<f8" keeps BVH values bit-exact).
The skeleton is `[b"skeleton", JSON {"bvh": header text, "fps": float}]`, re-sent every
second by the replay so late subscribers get it. Events are `[b"event", JSON event]`.

Stream ids: the topic starts with the stream id. `b"STREAM/frame"` and `b"STREAM/skeleton"`
carry stream STREAM (`replay --stream STREAM`); the bare `b"frame"` / `b"skeleton"` are the
unnamed stream (`default`). A subscriber of one stream subscribes to `b"STREAM/"`.

Address options: `zmq+tcp://127.0.0.1:5555?pattern=pull` makes a source bind a PULL socket
(many PUSH senders connect); the default source pattern `sub` connects a SUB socket to a
publisher, reconnecting by itself when the publisher restarts, and takes every stream
(`?streams=a,b` subscribes to those streams only).

Reading: by default a dedicated thread reads the socket (`?reader=thread`); `?reader=loop`
has the event loop read it between two turns of work (see `ZmqSource`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import threading
import time
from collections import deque
from typing import Any, cast

import numpy as np
import zmq

from streamkey.bvh import parse_bvh
from streamkey.errors import InputError, UsageError
from streamkey.io import MAX_STREAM_ID, stream_id_problem, stream_tag
from streamkey.keyframes import Event
from streamkey.motion import Frame, Skeleton

from .base import (
    MAX_CHANNELS,
    MAX_MESSAGE_BYTES,
    Address,
    Sink,
    SinkStats,
    Source,
    SourceStats,
    bind_host,
    fps_problem,
    frame_numbers_problem,
)
from .codec import event_json

__all__ = ["ZmqSource", "ZmqEventSink", "ZmqFrameSender", "encode_frame_parts",
           "decode_frame_parts", "decode_skeleton_parts", "topic", "parse_topic"]

_DTYPES: dict[str, np.dtype[Any]] = {"<f4": np.dtype("<f4"), "<f8": np.dtype("<f8")}


def topic(kind: str, stream: str | None = None) -> bytes:
    """The topic of a `frame` or `skeleton` message of `stream` (None: the unnamed one)."""
    tag = stream_tag(stream)
    return kind.encode() if tag is None else f"{tag}/{kind}".encode()


def parse_topic(raw: bytes) -> tuple[str, str | None]:
    """(kind, stream tag) of a topic; ValueError naming what is wrong."""
    if raw in (b"frame", b"skeleton"):
        return raw.decode(), None
    name, sep, kind = raw[:MAX_STREAM_ID + 16].decode("ascii", "replace").rpartition("/")
    if not sep or kind not in ("frame", "skeleton"):
        raise LookupError(f"unknown topic {raw[:32]!r}")
    problem = stream_id_problem(name)
    if problem is not None:
        raise ValueError(f"topic {raw[:32]!r}: {problem}")
    return kind, stream_tag(name)


def encode_frame_parts(frame: Frame, dtype: str = "<f4", stream: str | None = None
                       ) -> list[bytes]:
    """Multipart message of one frame (of `stream`; None: the unnamed stream)."""
    values = np.asarray(frame.channels, dtype=_DTYPES[dtype])
    header = {"seq": int(frame.seq), "time": float(frame.time), "n": len(values), "dtype": dtype}
    return [topic("frame", stream), json.dumps(header).encode(), values.tobytes()]


MAX_HEADER_BYTES = 4096
_INBOX = 256  # messages between the reader thread and the loop (drop-oldest, counted)
_RCVHWM = 256  # messages libzmq queues for the source (a SUB socket drops past it)
_READ_BATCH = 512  # messages read by one pass of the loop's reader before other work
READERS = ("loop", "thread")


def decode_frame_parts(parts: list[bytes]) -> Frame:
    """Frame of a multipart message; raises ValueError saying what is wrong."""
    if len(parts) != 3:
        raise ValueError(f"frame message has {len(parts)} parts, expected 3")
    if len(parts[1]) > MAX_HEADER_BYTES:
        raise ValueError(f"frame header of {len(parts[1])} bytes, more than {MAX_HEADER_BYTES}")
    header = json.loads(parts[1])
    if not isinstance(header, dict):
        raise ValueError("frame header is not a JSON object")
    dtype_name = header.get("dtype", "<f4")
    dtype = _DTYPES.get(dtype_name) if isinstance(dtype_name, str) else None
    n = header.get("n")
    if dtype is None or isinstance(n, bool) or not isinstance(n, int) or not 0 < n <= MAX_CHANNELS:
        raise ValueError(f"frame header needs n (1..{MAX_CHANNELS}) and dtype <f4 or <f8")
    if len(parts[2]) != n * dtype.itemsize:
        raise ValueError(f"payload of {len(parts[2])} bytes, expected {n} x {dtype.itemsize}")
    seq: Any = header.get("seq")
    time_s: Any = header.get("time")
    problem = frame_numbers_problem(seq, time_s)
    if problem is not None:
        raise ValueError(f"frame header: {problem}")
    return Frame(int(seq), float(time_s), np.frombuffer(parts[2], dtype).astype(np.float64))


def decode_skeleton_parts(parts: list[bytes]) -> tuple[Skeleton, float, str]:
    """(skeleton, fps, BVH text) of a `[b"skeleton", JSON]` message; raises on bad input."""
    if len(parts) != 2:
        raise ValueError(f"skeleton message has {len(parts)} parts, expected 2")
    info = json.loads(parts[1])
    if not isinstance(info, dict) or not isinstance(info.get("bvh"), str):
        raise ValueError("skeleton message needs a JSON object with a 'bvh' string")
    fps = info.get("fps", 120.0)
    problem = fps_problem(fps)
    if problem is not None:
        raise ValueError(problem)
    return parse_bvh(info["bvh"], source="zmq skeleton").skeleton, float(fps), info["bvh"]


def _has_message(sock: zmq.Socket[bytes]) -> bool:
    """True if a message can be read now (and the descriptor re-armed: reading the events
    is what lets libzmq's edge-triggered descriptor signal again)."""
    return bool(cast(int, sock.getsockopt(zmq.EVENTS)) & zmq.POLLIN)


class ZmqSource(Source):
    """Frames from ZeroMQ: SUB (connects to a publisher) or PULL (binds).

    Reader `thread` (default): a dedicated thread receives and stamps each message's
    arrival, so frames waiting while the loop is busy count in the wall latency. `loop`: the
    event loop watches the socket's descriptor and reads every waiting message between two
    turns of the engine's work, with no thread hand-over; the loop stamps a frame when it
    reads it (an external receiver measures the whole path either way). Measured paired
    on a 2-core machine at load 8-13 (external receiver, all methods, 20 s runs, 11 pairs),
    the loop reader against the thread: p50 0.84x, p99 1.9x (pairs 0.03-52x: the load
    decided the tails), CPU 0.95-1.01x; so the thread stays the default. The source hop
    alone (a synthetic 0.3 ms push, 10 pairs): p50 0.89x, p99 0.78x, max 1.00x.

    Where frames can be lost, and how each loss is counted:
    - a SUB socket's queue is full (`RCVHWM`, 256 messages) or the publisher's queue for
      this subscriber is: libzmq drops the newest messages silently, with no counter; they
      are counted as sequence-number holes of their stream (the summary's "lost").
    - a PULL socket never drops: a full queue stops its PUSH senders (their sends fail or
      wait, counted by them).
    - the thread reader's hand-over queue (256 messages) drops the oldest, counted as queue
      drops; the loop reader has no such queue.
    - messages still queued in libzmq when the run stops are counted as unread at stop
      (the loop reader; the thread reader closes the socket with them).
    Every message that does not become a frame is counted by kind, and an exception in
    decoding never stops the reader.
    """

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
        wanted = [n for n in address.options.get("streams", "").split(",") if n]
        for name in wanted:
            if (problem := stream_id_problem(name)) is not None:
                raise UsageError(f"{address}: streams: {problem}")
        self.subscriptions = [b""] if not wanted else [
            t for n in wanted for t in ((b"frame", b"skeleton") if stream_tag(n) is None
                                        else (f"{n}/".encode(),))]
        self.reader = address.options.get("reader", "thread")
        if self.reader not in READERS:
            raise UsageError(f"{address}: reader must be loop or thread, got {self.reader!r}")
        self.listen = listen
        self.socket: zmq.Socket[bytes] | None = None
        self.thread: threading.Thread | None = None
        self.inbox: deque[tuple[list[bytes], int]] = deque()
        self.inbox_drops = 0
        self._inbox_counted = 0
        self._scheduled = False
        self._closing = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._fd: int | None = None

    async def start(self) -> str:
        sock: zmq.Socket[bytes] = zmq.Context.instance().socket(
            zmq.SUB if self.pattern == "sub" else zmq.PULL)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.MAXMSGSIZE, MAX_MESSAGE_BYTES)
        sock.setsockopt(zmq.RCVHWM, _RCVHWM)
        endpoint = self.address.zmq_endpoint
        if self.pattern == "sub":
            for prefix in self.subscriptions:
                sock.setsockopt(zmq.SUBSCRIBE, prefix)
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
        self._loop = asyncio.get_running_loop()
        if self.reader == "loop":
            self._fd = fd = cast(int, sock.getsockopt(zmq.FD))
            self._loop.add_reader(fd, self._readable)
            self._loop.call_soon(self._readable)  # the descriptor only signals new activity
        else:
            self.thread = threading.Thread(target=self._read, name="streamkey-zmq-reader",
                                           daemon=True)
            self.thread.start()
        return f"zmq+{self.pattern} {endpoint}"

    def _readable(self) -> None:
        """Loop reader: read what waits, as much as the frame queue has room for (at most
        `_READ_BATCH` a pass; then come back after the work already queued). What does not
        fit stays in libzmq, whose own rule applies (see the class). libzmq's descriptor is
        edge-triggered: it signals only when the socket's state changes, so a pass reads
        until the socket says empty or comes back."""
        sock, loop = self.socket, self._loop
        if sock is None or loop is None or sock.closed:
            return
        queue = self.frames
        room = _READ_BATCH if not queue.maxsize else min(_READ_BATCH,
                                                         queue.maxsize - len(queue))
        try:
            for _ in range(room):
                if not _has_message(sock):
                    return
                self.handle(sock.recv_multipart(zmq.NOBLOCK), time.monotonic_ns())
            loop.call_soon(self._readable)
        except zmq.Again:  # the events said readable, the socket did not: read again later
            loop.call_soon(self._readable)
        except Exception as exc:  # the socket itself failed: the source dies and says so
            self._stop_reading()
            self.die(f"zmq source stopped: {type(exc).__name__}: {exc}")

    def _stop_reading(self) -> None:
        if self._fd is not None and self._loop is not None:
            self._loop.remove_reader(self._fd)
            self._fd = None

    def _read_rest(self) -> None:
        """At stop: what libzmq still queues goes to the frame queue, so the summary counts
        it as unread at stop (or as queue drops, past the queue's size), never as nothing."""
        sock = self.socket
        if sock is None or sock.closed:
            return
        with contextlib.suppress(zmq.ZMQError):
            while _has_message(sock):
                self.handle(sock.recv_multipart(zmq.NOBLOCK), time.monotonic_ns())

    def _read(self) -> None:
        """Reader thread: receive, stamp, hand over to the loop (never blocks the loop)."""
        assert self.socket is not None and self._loop is not None
        poller = zmq.Poller()
        poller.register(self.socket, zmq.POLLIN)
        try:
            while not self._closing.is_set():
                if not poller.poll(100):
                    continue
                parts = self.socket.recv_multipart(zmq.NOBLOCK)
                if len(self.inbox) >= _INBOX:
                    self.inbox.popleft()
                    self.inbox_drops += 1
                self.inbox.append((parts, time.monotonic_ns()))
                if not self._scheduled:
                    self._scheduled = True
                    self._loop.call_soon_threadsafe(self._drain)
        except Exception as exc:  # the socket itself failed: the source dies and says so
            if not self._closing.is_set():
                with contextlib.suppress(RuntimeError):  # the loop may be closing
                    self._loop.call_soon_threadsafe(
                        self.die, f"zmq source stopped: {type(exc).__name__}: {exc}")
        finally:
            self.socket.close(linger=0)

    def _drain(self) -> None:
        self._scheduled = False
        while self.inbox:
            parts, arrival = self.inbox.popleft()
            self.handle(parts, arrival)

    def handle(self, parts: list[bytes], arrival_ns: int | None = None) -> None:
        """Decode one multipart message; never raises (every failure counted by kind)."""
        try:
            if not parts:
                self.stats.reject("topic", "zmq: empty message")
                return
            try:
                kind, stream = parse_topic(parts[0])
            except LookupError as exc:
                self.stats.reject("topic", f"zmq: {exc}")
                return
            except ValueError as exc:
                self.stats.reject("stream_id", f"zmq: {exc}")
                return
            if kind == "skeleton":
                self._skeleton(parts, stream)
                return
            frame = decode_frame_parts(parts)
        except (ValueError, KeyError, IndexError, TypeError, RecursionError) as exc:
            self.stats.reject("malformed", f"zmq: {type(exc).__name__}: {str(exc)[:200]}")
            return
        except Exception as exc:  # a decoder bug: counted, the source goes on
            self.stats.reject("internal", f"zmq: {type(exc).__name__}: {str(exc)[:200]}")
            return
        self.stats.received += 1
        self.frames.put(frame, arrival_ns, stream)

    def _skeleton(self, parts: list[bytes], stream: str | None = None) -> None:
        if len(parts) == 2 and self.repeated_skeleton(parts[1], stream):
            return
        try:
            skeleton, fps, _ = decode_skeleton_parts(parts)
        except Exception as exc:  # any failure of a hostile skeleton: counted, ignored
            self.stats.reject("skeleton", f"zmq skeleton ignored: {type(exc).__name__}: "
                              f"{str(exc)[:200]}")
            return
        self.set_skeleton(skeleton, float(fps), stream, raw=parts[1])

    def counters(self) -> SourceStats:
        """The counters; a message the thread's hand-over queue dropped arrived (received)
        and was dropped (a queue drop), so the summary's accounting adds up."""
        fresh = self.inbox_drops - self._inbox_counted  # the reader thread only ever adds
        self._inbox_counted += fresh
        self.stats.queue_drops += fresh
        self.stats.received += fresh
        return self.stats

    async def close(self) -> None:
        await super().close()
        self._closing.set()
        if self.thread is not None:
            await asyncio.to_thread(self.thread.join, 2.0)
        elif self.socket is not None:
            self._stop_reading()
            self._read_rest()
            self.socket.close(linger=0)


def _pub_socket(address: Address, listen: str | None,
                nodrop: bool = False) -> tuple[zmq.Socket[bytes], str]:
    host = bind_host(address, listen) if address.scheme == "zmq+tcp" else ""
    sock: zmq.Socket[bytes] = zmq.Context.instance().socket(zmq.XPUB)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDHWM, 1000)
    if nodrop:
        sock.setsockopt(zmq.XPUB_NODROP, 1)
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


UNSEEN_PUB_DROPS = ("a subscriber whose queue is full (1000 messages) loses events silently: "
                    "libzmq's PUB socket keeps no drop counter (add ?nodrop=1 to count them, "
                    "at the cost that an event refused for one slow subscriber is refused for "
                    "all)")


class ZmqEventSink(Sink):
    """Events as `[b"event", JSON]` on a publisher socket (binds; subscribers connect).

    What can be known about drops: libzmq's PUB/XPUB socket drops a message silently for
    each subscriber whose queue is at its high-water mark; `send` still succeeds and there
    is no counter, no monitor event and no per-peer statistic. With `?nodrop=1`
    (`ZMQ_XPUB_NODROP`) a send that any subscriber's full queue would drop fails instead
    (EAGAIN) and is counted here, but then nobody gets that event; by default the summary
    says which drops it cannot see (`unseen_drops`).
    """

    name = "zmq"

    def __init__(self, address: Address, listen: str | None = None) -> None:
        super().__init__()
        self.address = address
        self.listen = listen
        self.nodrop = address.options.get("nodrop", "0") in ("1", "true", "yes")
        self.socket: zmq.Socket[bytes] | None = None
        self.stats.unseen_drops = "" if self.nodrop else UNSEEN_PUB_DROPS

    async def start(self) -> str:
        self.socket, endpoint = _pub_socket(self.address, self.listen, self.nodrop)
        return f"zmq+pub {endpoint}"

    def offer(self, event: Event) -> None:
        assert self.socket is not None
        try:
            self.socket.send_multipart([b"event", event_json(event, compact=False).encode()],
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

    def __init__(self, address: Address, listen: str | None = None,
                 stream: str | None = None) -> None:
        self.address = address
        self.stream = stream
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
            self.skeleton_message = (skeleton, [topic("skeleton", self.stream), body])
        self._send(self.skeleton_message[1])

    def send_frame(self, frame: Frame) -> None:
        """Publish one frame (never blocks; a full queue counts a drop)."""
        self._send(encode_frame_parts(frame, self.dtype, self.stream))

    def _send(self, parts: list[bytes]) -> None:
        try:
            self.socket.send_multipart(parts, zmq.NOBLOCK)
            self.stats.sent += 1
        except zmq.Again:
            self.stats.dropped += 1

    def close(self) -> None:
        """Close the socket."""
        self.socket.close(linger=0)
