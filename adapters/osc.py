"""OSC over UDP: frames in (`/streamkey/frame`), skeletons in (`/streamkey/skeleton`),
events out.

Streams: `/streamkey/<stream>/frame` and `/streamkey/<stream>/skeleton` carry stream
<stream> (same arguments); `/streamkey/frame` is the unnamed stream (`default`).

Layouts in (friendly to Pd, SuperCollider, Max):

    /streamkey/frame     i seq, d time, f... channels      (seq may be i/h/f, time d/f,
                                                           channels any mix of f/d/i)
    /streamkey/skeleton  s bvh_header [, d fps]            (BVH text up to MOTION; fps 120)

Events out, `numeric` layout (the default; numbers only, stream and method in the address,
so Pd routes on the address, TouchDesigner's OSC In CHOP takes every value, SuperCollider's
OSCdef matches a path); the events of one frame leave as ONE bundle whose time tag is the
wall-clock arrival of the frame that decided them (`NUMERIC_LAYOUT` lists the messages):

    /streamkey/<stream>/<method>/keyframe     i frame, f time, f strength, i latency_frames
    /streamkey/<stream>/<method>/provisional  i frame, f time, f strength
    /streamkey/<stream>/<method>/cancel       i frame
    /streamkey/<stream>/gap                   i first, i last, i bridged
    /streamkey/<stream>/status/<status>       i seq
    /streamkey/<stream>/signal/<name>         f value
    /streamkey/<stream>/segment/<kind>        i open, i start, i end, f start_time,
                                              f end_time, i latency_frames
                                              (<kind>: calibration, still, take; open 1
                                              with end and end_time -1, closed 0)

`compact` layout (`osc://host:port?layout=compact`, `run --osc-layout compact`; the earlier
layout, one message per keyframe, no bundle, other events not sent):

    /streamkey/keyframe  s stream, s method, i frame, f time, f score, i latency_frames

Stream, method, status and signal names become address parts through `osc_name`: every
character outside `A-Z a-z 0-9 _ -` (the OSC-reserved ` #*,/?[]{}`, dots, non-ASCII, ...)
becomes `_`, an empty name `_`, and names are cut to 64 characters; so no name can add an
address level or a pattern character, and TouchDesigner keeps the channel name as sent.

The event time is `f` (float32), not `d` (double): Pd's `oscparse` (0.53) rejects `d` and
garbles the rest of the message; `i frame` carries the exact frame. Receivers that want
float64 ask for it with `osc://host:port?time=d`.

Frames are encoded with a fixed-layout encoder (~100x faster than python-osc's builder,
byte-for-byte equal to it: tested); everything else goes through python-osc.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import socket
import struct
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder

from streamkey.bvh import parse_bvh
from streamkey.errors import BVHError, InputError, UsageError
from streamkey.io import stream_id_problem, stream_tag
from streamkey.keyframes import Event, KeyframeEvent
from streamkey.motion import Frame, Skeleton

from .base import (
    LOOPBACK,
    MAX_CHANNELS,
    MAX_MESSAGE_BYTES,
    Address,
    Sink,
    Source,
    SourceStats,
    bind_host,
    fps_problem,
    frame_numbers_problem,
    is_loopback,
)
from .codec import (
    KEYFRAME_ADDRESS,
    NUMERIC_LAYOUT,
    compact_message,
    encode_event,
    encode_message,
    event_messages,
    osc_messages,
    osc_name,
    osc_string,
)
from .udp_listen import refresh_kernel_drops

__all__ = ["FRAME_ADDRESS", "SKELETON_ADDRESS", "KEYFRAME_ADDRESS", "encode_frame",
           "decode_frame", "encode_skeleton", "encode_event", "OscDecodeError", "OscSource",
           "OscFrameSender", "OscEventSink", "skeleton_header", "OSC_LAYOUTS", "NUMERIC_LAYOUT",
           "osc_name", "event_messages", "encode_message", "encode_bundle", "decode_bundle",
           "ntp_timetag", "timetag_seconds", "with_layout", "stream_address",
           "stream_of_address"]

FRAME_ADDRESS = "/streamkey/frame"
SKELETON_ADDRESS = "/streamkey/skeleton"


class OscDecodeError(InputError):
    """A malformed or unexpected OSC packet; `kind` says which counter it goes to."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


_FRAME_PREFIX: dict[tuple[str, int], bytes] = {}


def stream_address(kind: str, stream: str | None = None) -> str:
    """`/streamkey/<stream>/frame` or `/skeleton` (None or `default`: `/streamkey/<kind>`)."""
    tag = stream_tag(stream)
    return f"/streamkey/{kind}" if tag is None else f"/streamkey/{tag}/{kind}"


def encode_frame(seq: int, time: float, channels: np.ndarray,
                 address: str = FRAME_ADDRESS) -> bytes:
    """`/streamkey/frame i seq, d time, f...` as bytes (fixed layout, no python-osc)."""
    n = len(channels)
    prefix = _FRAME_PREFIX.get((address, n))
    if prefix is None:
        if len(_FRAME_PREFIX) > 256:
            _FRAME_PREFIX.clear()
        prefix = _FRAME_PREFIX[(address, n)] = (osc_string(address)
                                                + osc_string(",id" + "f" * n))
    return prefix + struct.pack(">id", seq, time) + np.asarray(channels, ">f4").tobytes()


def skeleton_header(skeleton: Skeleton, fps: float) -> str:
    """BVH text of the skeleton alone (zero frames): what `/streamkey/skeleton` carries."""
    from streamkey.bvh import format_bvh
    from streamkey.motion import Motion

    return format_bvh(Motion(skeleton, np.zeros((0, skeleton.n_channels)), fps))


def encode_skeleton(skeleton: Skeleton, fps: float, address: str = SKELETON_ADDRESS) -> bytes:
    """`/streamkey/skeleton s bvh, d fps`."""
    builder = OscMessageBuilder(address)
    builder.add_arg(skeleton_header(skeleton, fps), "s")
    builder.add_arg(float(fps), "d")
    return builder.build().dgram


OSC_LAYOUTS = ("numeric", "compact")
_NTP_UNIX_OFFSET = 2_208_988_800  # seconds from 1900-01-01 (NTP era 0) to 1970-01-01
_BUNDLE_ROOM = 8192  # bytes per bundle: well inside one datagram on any path


def with_layout(targets: Sequence[str], layout: str | None) -> list[str]:
    """`--osc-layout`: add `layout=LAYOUT` to every `osc://` target that does not set one."""
    if layout is None:
        return list(targets)
    if layout not in OSC_LAYOUTS:
        raise UsageError(f"--osc-layout must be one of {', '.join(OSC_LAYOUTS)}, got {layout!r}")
    out = []
    for target in targets:
        if target.startswith("osc://") and "layout=" not in target:
            target += ("&" if "?" in target else "?") + f"layout={layout}"
        out.append(target)
    return out


def ntp_timetag(unix_seconds: float) -> int:
    """OSC time tag (NTP 32.32 fixed point) of a Unix time in seconds."""
    whole = math.floor(unix_seconds)
    frac = min(int((unix_seconds - whole) * 2**32), 2**32 - 1)
    return ((whole + _NTP_UNIX_OFFSET) % 2**32) << 32 | frac


def timetag_seconds(tag: int) -> float:
    """Unix time in seconds of an OSC time tag (NTP era 0); 1 ("immediately") gives 0.0."""
    if tag == 1:
        return 0.0
    return (tag >> 32) - _NTP_UNIX_OFFSET + (tag & 0xFFFFFFFF) / 2**32


def encode_bundle(messages: Sequence[bytes], timetag: int) -> bytes:
    """`#bundle`, the time tag, then each message with its size (OSC 1.0 §Bundles)."""
    parts = [_BUNDLE_HEAD, struct.pack(">Q", timetag)]
    for message in messages:
        parts.append(struct.pack(">i", len(message)))
        parts.append(message)
    return b"".join(parts)


def decode_bundle(data: bytes) -> tuple[int, list[bytes]]:
    """(time tag, elements) of an OSC bundle; a malformed one is an `OscDecodeError`."""
    if not data.startswith(_BUNDLE_HEAD):
        raise OscDecodeError("bundle", "not an OSC bundle: no #bundle header")
    elements = _bundle_elements(data, 0)
    return struct.unpack_from(">Q", data, 8)[0], elements


_ARG_FORMATS = {ord("i"): "i", ord("h"): "q", ord("f"): "f", ord("d"): "d"}
_FRAME_HEAD = osc_string(FRAME_ADDRESS)


def _address_of(data: bytes) -> str:
    """The address pattern of an OSC message, for error messages; raises on garbage."""
    end = data.find(b"\0")
    if end <= 0 or not data.startswith(b"/"):
        raise OscDecodeError("parse", "not an OSC message: no address pattern")
    return data[:end].decode("ascii", "replace")


def stream_of_address(address: str) -> tuple[str, str | None]:
    """(kind, stream tag) of `/streamkey/frame`, `/streamkey/skeleton` or
    `/streamkey/<stream>/frame|skeleton`; `OscDecodeError` (address or stream_id) if not."""
    if address in (FRAME_ADDRESS, SKELETON_ADDRESS):
        return address.rsplit("/", 1)[1], None
    parts = address.split("/")
    if len(parts) != 4 or parts[:2] != ["", "streamkey"] or parts[3] not in ("frame",
                                                                              "skeleton"):
        raise OscDecodeError("address", f"unexpected OSC address {address[:80]!r}")
    problem = stream_id_problem(parts[2])
    if problem is not None:
        raise OscDecodeError("stream_id", f"{address[:80]!r}: {problem}")
    return parts[3], stream_tag(parts[2])


def decode_frame(data: bytes, address: str = FRAME_ADDRESS) -> tuple[int, float, np.ndarray]:
    """Decode a `/streamkey/frame` packet (or one to `address`, a stream's frame address)
    exactly (every byte accounted for); raises `OscDecodeError` with a kind: parse,
    address, types, arity, oversize, truncated, trailing, nan, range."""
    frame_head = _FRAME_HEAD if address == FRAME_ADDRESS else osc_string(address)
    if not data.startswith(frame_head):
        raise OscDecodeError("address", f"unexpected OSC address {_address_of(data)!r}")
    head = len(frame_head)
    tags_end = data.find(b"\0", head)
    if tags_end < 0 or data[head : head + 1] != b",":
        raise OscDecodeError("parse", f"{FRAME_ADDRESS}: no type tag string")
    tags = data[head + 1 : tags_end]
    plan = _FRAME_PLANS.get(tags)
    if plan is None:
        plan = _frame_plan(tags)
    layout, head_layout, n = plan
    start = (tags_end + 4) & ~3
    if len(data) != start + layout.size:
        kind = "truncated" if len(data) < start + layout.size else "trailing"
        raise OscDecodeError(kind, f"{FRAME_ADDRESS}: {len(data)} bytes, the type tags "
                             f"{tags[:40].decode('ascii')!r} need {start + layout.size}")
    if head_layout is not None:  # our own layout (and most senders'): one vectorised read
        seq_value, time_value = head_layout.unpack_from(data, start)
        channels = np.frombuffer(data, ">f4", n, start + head_layout.size).astype(np.float64)
    else:
        seq_value, time_value, *values = layout.unpack_from(data, start)
        channels = np.array(values, dtype=np.float64)
    if not (math.isfinite(time_value) and np.all(np.isfinite(channels))):
        raise OscDecodeError("nan", f"{FRAME_ADDRESS}: NaN or infinite value")
    problem = frame_numbers_problem(seq_value, time_value)
    if problem is not None:
        raise OscDecodeError("range", f"{FRAME_ADDRESS}: {problem}")
    return int(seq_value), float(time_value), channels


_FRAME_PLANS: dict[bytes, tuple[struct.Struct, struct.Struct | None, int]] = {}
_MAX_FRAME_PLANS = 64  # distinct type-tag strings remembered (a sender uses one or two)


def _frame_plan(tags: bytes) -> tuple[struct.Struct, struct.Struct | None, int]:
    """How to read a frame with these type tags: the whole layout, the (seq, time) head
    when every channel is a float32 (else None), the channel count; remembered, so a
    stream's frames after its first skip this (the tags repeat frame after frame)."""
    formats = [_ARG_FORMATS.get(t) for t in tags]
    if None in formats:
        raise OscDecodeError("types", f"{FRAME_ADDRESS}: seq, time and channels must be "
                             f"numbers (i, h, f, d), got type tags {tags[:40]!r}")
    if len(formats) < 3:
        raise OscDecodeError("arity", f"{FRAME_ADDRESS}: expected seq, time and at least one "
                             f"channel, got {len(formats)} arguments")
    n = len(formats) - 2
    if n > MAX_CHANNELS:
        raise OscDecodeError("oversize", f"{FRAME_ADDRESS}: {n} channels, more than the limit "
                             f"of {MAX_CHANNELS}")
    layout = struct.Struct(">" + "".join(f for f in formats if f))
    head = struct.Struct(f">{formats[0]}{formats[1]}") if tags[2:] == b"f" * n else None
    if len(_FRAME_PLANS) >= _MAX_FRAME_PLANS:
        _FRAME_PLANS.clear()
    plan = _FRAME_PLANS[tags] = (layout, head, n)
    return plan


_KNOWN_TAGS = frozenset(b"ihfdsbrmtTFN[]")  # python-osc logs a warning for any other tag


def _message(data: bytes, address: str | None = None) -> OscMessage:
    at = (data.find(b"\0") // 4 + 1) * 4  # the type tags after the padded address
    if data[at : at + 1] == b",":
        end = data.find(b"\0", at)
        odd = set(data[at + 1 : end if end >= 0 else len(data)]) - _KNOWN_TAGS
        if odd:
            raise OscDecodeError("types", f"type tag {chr(min(odd))!r} in an OSC message: "
                                 "not one streamkey reads")
    try:
        message = OscMessage(data)
    except Exception as exc:  # python-osc raises several types for garbage
        raise OscDecodeError("parse", f"not an OSC message: {exc}") from None
    if address is not None and message.address != address:
        raise OscDecodeError("address", f"unexpected OSC address {message.address!r}")
    return message


def decode_skeleton(data: bytes, address: str = SKELETON_ADDRESS) -> tuple[Skeleton, float]:
    """Decode `/streamkey/skeleton s bvh [, d fps]`; any failure is an `OscDecodeError`."""
    params = _message(data, address).params
    if not params or not isinstance(params[0], str):
        raise OscDecodeError("types", f"{SKELETON_ADDRESS}: expected s bvh_header [, d fps]")
    fps = params[1] if len(params) > 1 and isinstance(params[1], (int, float)) else 120.0
    problem = fps_problem(fps)
    if problem is not None:
        raise OscDecodeError("skeleton", f"{SKELETON_ADDRESS}: {problem}")
    try:
        motion = parse_bvh(params[0], source=SKELETON_ADDRESS)
    except BVHError as exc:
        raise OscDecodeError("skeleton", str(exc)) from None
    except Exception as exc:  # a hostile header must not reach the loop (RecursionError, ...)
        raise OscDecodeError("skeleton", f"{SKELETON_ADDRESS}: {type(exc).__name__}: "
                             f"{str(exc)[:200]}") from None
    return motion.skeleton, float(fps)


_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35 if sys.platform == "linux" else None)
_SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40 if sys.platform == "linux" else None)
_READ_BURST = 64  # datagrams read per wake-up before the loop gets its turn back


def _enable(sock: socket.socket, option: int | None) -> bool:
    if option is None:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, option, 1)
    except OSError:
        return False
    return True


class OscSource(Source):
    """Frames from OSC over UDP (`/streamkey/frame`, bundles of them too).

    The socket is read with `recvmsg`: on Linux every datagram carries the kernel's receive
    time (`SO_TIMESTAMPNS`), so the wall latency counts the time a frame waited in the socket
    while the loop was busy, and the kernel's count of datagrams it dropped because the
    receive buffer was full (`SO_RXQ_OVFL`). Elsewhere the arrival is stamped when read and
    kernel drops stay unknown (None in the summary, said so in its text).
    """

    name = "osc"

    def __init__(self, address: Address, listen: str | None = None,
                 skeleton: Skeleton | None = None, fps: float | None = None) -> None:
        super().__init__(skeleton, fps)
        self.address = address
        self.host = bind_host(address, listen)
        self.sock: socket.socket | None = None
        self.kernel_stamps = False

    async def start(self) -> str:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        try:
            sock.bind((self.host, self.address.port))
        except OSError as exc:
            sock.close()
            raise InputError(f"{self.address}: cannot listen on {self.host}:"
                             f"{self.address.port}: {exc.strerror or exc}") from None
        self.kernel_stamps = _enable(sock, _SO_TIMESTAMPNS)
        if _enable(sock, _SO_RXQ_OVFL):
            self.stats.kernel_drops = 0
        self.sock = sock
        asyncio.get_running_loop().add_reader(sock.fileno(), self._readable)
        return f"osc://{self.host}:{sock.getsockname()[1]}"

    def _readable(self) -> None:
        assert self.sock is not None
        space = socket.CMSG_SPACE(16) + socket.CMSG_SPACE(4)
        offset: int | None = None
        for _ in range(_READ_BURST):
            try:
                data, ancillary, flags, _ = self.sock.recvmsg(MAX_MESSAGE_BYTES + 1, space)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # an ICMP error reported on the socket
                self.stats.reject("socket", str(exc))
                continue
            arrival: int | None = None
            for level, kind, value in ancillary:
                if level != socket.SOL_SOCKET:
                    continue
                if kind == _SO_TIMESTAMPNS and len(value) >= 16:
                    sec, nsec = struct.unpack_from("qq", value)
                    if offset is None:  # realtime -> monotonic, one clock pair per burst
                        offset = time.monotonic_ns() - time.time_ns()
                    arrival = sec * 1_000_000_000 + nsec + offset
                elif kind == _SO_RXQ_OVFL and len(value) >= 4:
                    self.stats.kernel_drops = struct.unpack_from("I", value)[0]
            if flags & socket.MSG_TRUNC:
                self.stats.reject("oversize", f"datagram larger than {MAX_MESSAGE_BYTES} bytes")
                continue
            self.receive(data, arrival)

    def receive(self, data: bytes, arrival_ns: int | None = None, depth: int = 0) -> None:
        """Handle one datagram (called on the event loop); never raises: every packet that
        does not become a frame is counted by kind."""
        try:
            if len(data) > MAX_MESSAGE_BYTES:
                raise OscDecodeError("oversize", f"packet of {len(data)} bytes, more than "
                                     f"{MAX_MESSAGE_BYTES}")
            if data.startswith(_BUNDLE_HEAD):
                for item in _bundle_elements(data, depth):
                    self.receive(item, arrival_ns, depth + 1)
                return
            if data.startswith(osc_string(SKELETON_ADDRESS)):
                if not self.repeated_skeleton(data):
                    self.set_skeleton(*decode_skeleton(data), raw=data)
                return
            stream = None
            if not data.startswith(_FRAME_HEAD):  # a stream's own address, or garbage
                address = _address_of(data)
                kind, stream = stream_of_address(address)
                if kind == "skeleton":
                    if not self.repeated_skeleton(data, stream):
                        self.set_skeleton(*decode_skeleton(data, address), stream, raw=data)
                    return
                seq, time_s, channels = decode_frame(data, address)
            else:
                seq, time_s, channels = decode_frame(data)
        except OscDecodeError as exc:
            self.stats.reject(exc.kind, str(exc))
            return
        except Exception as exc:  # a decoder bug: counted, the source goes on
            self.stats.reject("internal", f"{type(exc).__name__}: {str(exc)[:200]}")
            return
        self.stats.received += 1
        self.frames.put(Frame(seq, time_s, channels), arrival_ns, stream)

    def counters(self) -> SourceStats:
        """Counters, with the kernel's drop count for this socket from /proc/net/udp (the
        ancillary count only arrives with the next datagram after a drop)."""
        return refresh_kernel_drops(self.stats, self.sock)

    async def close(self) -> None:
        self.counters()
        await super().close()
        if self.sock is not None:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self.sock.fileno())
            self.sock.close()


_BUNDLE_HEAD = b"#bundle\0"
MAX_BUNDLE_DEPTH = 8


def _bundle_elements(data: bytes, depth: int) -> list[bytes]:
    """The elements of an OSC bundle (size-prefixed, each a multiple of 4 bytes, non-empty,
    inside the packet); a malformed bundle is an `OscDecodeError` of kind `bundle`."""
    if depth >= MAX_BUNDLE_DEPTH:
        raise OscDecodeError("bundle", f"bundles nested deeper than {MAX_BUNDLE_DEPTH}")
    if len(data) < 16:
        raise OscDecodeError("bundle", "bundle shorter than its header and time tag")
    out, at = [], 16
    while at < len(data):
        if at + 4 > len(data):
            raise OscDecodeError("bundle", f"bundle element size cut off at byte {at}")
        (size,) = struct.unpack_from(">i", data, at)
        at += 4
        if size <= 0 or size % 4 or at + size > len(data):
            raise OscDecodeError("bundle", f"bundle element of size {size} at byte {at - 4} "
                                 f"(must be a positive multiple of 4 inside the packet)")
        out.append(data[at : at + size])
        at += size
    return out


class _UdpSender:
    """A non-blocking UDP socket to one peer; a full buffer or an absent peer counts a drop.

    The socket is bound to the loopback (or to `listen`) when the peer is on loopback, and
    connect()ed to the peer, so it never listens on every interface and takes datagrams from
    the peer only.
    """

    def __init__(self, address: Address, stats: Any, listen: str | None = None) -> None:
        self.target = (address.host, address.port)
        self.stats = stats
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        try:
            if listen or is_loopback(address.host):
                self.sock.bind((listen or LOOPBACK, 0))
            self.sock.connect(self.target)
        except OSError as exc:
            self.sock.close()
            raise InputError(f"{address}: cannot send to {address.host}:{address.port}: "
                             f"{exc.strerror or exc}") from None

    def send(self, data: bytes, events: int = 1) -> None:
        """Send one datagram carrying `events` events (a bundle: several); counted as such."""
        try:
            self.sock.send(data)
            self.stats.sent += events
        except OSError as exc:  # full buffer, absent peer (ICMP refused), unreachable
            self.stats.dropped += events
            self.stats.last_error = str(exc)

    def close(self) -> None:
        self.sock.close()


class OscEventSink(Sink):
    """Events to one OSC receiver: the `numeric` layout (default; one bundle per frame, time
    tag = that frame's arrival) or the `compact` one (`?layout=compact`)."""

    name = "osc"

    def __init__(self, address: Address, listen: str | None = None) -> None:
        super().__init__()
        self.address = address
        self.time_type = address.options.get("time", "f")
        if self.time_type not in ("f", "d"):
            raise UsageError(f"{address}: time must be f or d")
        self.layout = address.options.get("layout", "numeric")
        if self.layout not in OSC_LAYOUTS:
            raise UsageError(f"{address}: layout must be one of {', '.join(OSC_LAYOUTS)}, "
                             f"got {self.layout!r}")
        self.sender = _UdpSender(address, self.stats, listen)
        self.pending: list[bytes] = []
        self.pending_bytes = 0
        self.pending_events = 0
        self._clock_offset = time.time_ns() - time.monotonic_ns()

    async def start(self) -> str:
        return str(self.address)

    def offer(self, event: Event) -> None:
        if self.layout == "compact":
            match event:
                case KeyframeEvent():
                    self.sender.send(compact_message(event, self.time_type))
            return  # gaps, status and the rest have no compact message
        messages = osc_messages(event, self.time_type)
        size = sum(len(m) + 4 for m in messages)
        if self.pending and self.pending_bytes + size > _BUNDLE_ROOM:
            self._send_bundle(time.monotonic_ns())  # a huge frame: split, never truncate
        if messages:
            self.pending.extend(messages)
            self.pending_bytes += size
            self.pending_events += 1

    def end_batch(self, arrival_ns: int) -> None:
        """The events offered since the last call belong to the frame that arrived at
        `arrival_ns` (monotonic): send them as one bundle time-tagged with that arrival."""
        if self.pending:
            self._send_bundle(arrival_ns)

    def _send_bundle(self, arrival_ns: int) -> None:
        tag = ntp_timetag((arrival_ns + self._clock_offset) / 1e9)
        self.sender.send(encode_bundle(self.pending, tag), self.pending_events)
        self.pending, self.pending_bytes, self.pending_events = [], 0, 0

    async def close(self) -> None:
        if self.pending:  # offered after the last batch (a caller without end_batch)
            self._send_bundle(time.monotonic_ns())
        self.sender.close()


class OscFrameSender:
    """Frames (and the skeleton, now and then) to one OSC receiver: the replay side."""

    name = "osc"

    def __init__(self, address: Address, listen: str | None = None,
                 stream: str | None = None) -> None:
        from .base import SinkStats

        self.address = address
        self.stats = SinkStats()
        self.sender = _UdpSender(address, self.stats, listen)
        self.skeleton_message: tuple[Skeleton, bytes] | None = None
        self.frame_address = stream_address("frame", stream)
        self.skeleton_address = stream_address("skeleton", stream)

    def send_skeleton(self, skeleton: Skeleton, fps: float) -> None:
        """Announce the skeleton (receivers without `--skeleton` wait for it)."""
        if self.skeleton_message is None or self.skeleton_message[0] is not skeleton:
            self.skeleton_message = (skeleton, encode_skeleton(skeleton, fps,
                                                               self.skeleton_address))
        self.sender.send(self.skeleton_message[1])

    def send_frame(self, frame: Frame) -> None:
        """Send one frame (never blocks)."""
        self.sender.send(encode_frame(frame.seq, frame.time, frame.channels,
                                      self.frame_address))

    def close(self) -> None:
        """Close the socket."""
        self.sender.close()
