"""OSC over UDP: frames in (`/streamkey/frame`), skeletons in (`/streamkey/skeleton`),
keyframe events out (`/streamkey/keyframe`).

Layouts (DESIGN §7; friendly to Pd, SuperCollider, Max):

    /streamkey/frame     i seq, d time, f... channels      (seq may be i/h/f, time d/f,
                                                           channels any mix of f/d/i)
    /streamkey/skeleton  s bvh_header [, d fps]            (BVH text up to MOTION; fps 120)
    /streamkey/keyframe  s stream, s method, i frame, f time, f score, i latency_frames

The event time is `f` (float32), not DESIGN's `d`: Pd's `oscparse` (0.53) rejects `d` and
garbles the rest of the message; `i frame` carries the exact frame. Receivers that want
float64 ask for it with `osc://host:port?time=d`.

Frames are encoded with a fixed-layout encoder (~100x faster than python-osc's builder,
byte-for-byte equal to it: tested); everything else goes through python-osc.
"""

from __future__ import annotations

import asyncio
import math
import socket
import struct
from typing import Any

import numpy as np
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder

from streamkey.bvh import parse_bvh
from streamkey.errors import BVHError, InputError, UsageError
from streamkey.motion import Frame, Skeleton

from .base import MAX_CHANNELS, MAX_MESSAGE_BYTES, Address, Sink, Source, bind_host

__all__ = ["FRAME_ADDRESS", "SKELETON_ADDRESS", "KEYFRAME_ADDRESS", "encode_frame",
           "decode_frame", "encode_skeleton", "encode_event", "OscDecodeError", "OscSource",
           "OscFrameSender", "OscEventSink", "skeleton_header"]

FRAME_ADDRESS = "/streamkey/frame"
SKELETON_ADDRESS = "/streamkey/skeleton"
KEYFRAME_ADDRESS = "/streamkey/keyframe"


class OscDecodeError(InputError):
    """A malformed or unexpected OSC packet; `kind` says which counter it goes to."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def _osc_string(text: str) -> bytes:
    raw = text.encode() + b"\0"
    return raw + b"\0" * (-len(raw) % 4)


_FRAME_PREFIX: dict[int, bytes] = {}


def encode_frame(seq: int, time: float, channels: np.ndarray) -> bytes:
    """`/streamkey/frame i seq, d time, f...` as bytes (fixed layout, no python-osc)."""
    n = len(channels)
    prefix = _FRAME_PREFIX.get(n)
    if prefix is None:
        prefix = _FRAME_PREFIX[n] = _osc_string(FRAME_ADDRESS) + _osc_string(",id" + "f" * n)
    return prefix + struct.pack(">id", seq, time) + np.asarray(channels, ">f4").tobytes()


def skeleton_header(skeleton: Skeleton, fps: float) -> str:
    """BVH text of the skeleton alone (zero frames): what `/streamkey/skeleton` carries."""
    from streamkey.bvh import format_bvh
    from streamkey.motion import Motion

    return format_bvh(Motion(skeleton, np.zeros((0, skeleton.n_channels)), fps))


def encode_skeleton(skeleton: Skeleton, fps: float) -> bytes:
    """`/streamkey/skeleton s bvh, d fps`."""
    builder = OscMessageBuilder(SKELETON_ADDRESS)
    builder.add_arg(skeleton_header(skeleton, fps), "s")
    builder.add_arg(float(fps), "d")
    return builder.build().dgram


def encode_event(event: dict[str, Any], time_type: str = "f") -> bytes:
    """`/streamkey/keyframe s stream, s method, i frame, f time, f score, i latency_frames`."""
    builder = OscMessageBuilder(KEYFRAME_ADDRESS)
    builder.add_arg(str(event["stream"]), "s")
    builder.add_arg(str(event["method"]), "s")
    builder.add_arg(int(event["frame"]), "i")
    builder.add_arg(float(event["time"]), time_type)
    builder.add_arg(float(event["score"]), "f")
    builder.add_arg(int(event["latency_frames"]), "i")
    return builder.build().dgram


def _fast_frame(data: bytes) -> tuple[int, float, np.ndarray] | None:
    """Decode our own fixed layout without python-osc; None if the packet is not in it."""
    head = _osc_string(FRAME_ADDRESS)
    if not data.startswith(head + b",id"):
        return None
    tags_end = data.index(b"\0", len(head))
    tags = data[len(head) + 1 : tags_end]
    n = len(tags) - 2
    if n < 1 or tags[2:] != b"f" * n:
        return None
    start = len(head) + len(_osc_string("," + tags.decode()))
    if len(data) != start + 12 + 4 * n:
        return None
    seq, time = struct.unpack_from(">id", data, start)
    return seq, time, np.frombuffer(data, ">f4", n, start + 12).astype(np.float64)


def decode_frame(data: bytes) -> tuple[int, float, np.ndarray]:
    """Decode a `/streamkey/frame` packet; raises `OscDecodeError` saying what is wrong."""
    fast = _fast_frame(data)
    if fast is not None:
        seq, time, channels = fast
    else:
        params = _message(data, FRAME_ADDRESS).params
        if len(params) < 3:
            raise OscDecodeError("arity", f"{FRAME_ADDRESS}: expected seq, time and at least one "
                                 f"channel, got {len(params)} arguments")
        seq_value, time_value, values = params[0], params[1], params[2:]
        if isinstance(seq_value, float) and seq_value.is_integer():
            seq_value = int(seq_value)
        if not isinstance(seq_value, int) or isinstance(seq_value, bool):
            raise OscDecodeError("types", f"{FRAME_ADDRESS}: seq must be an integer (i, h), got "
                                 f"{type(seq_value).__name__}")
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                   for v in [time_value, *values]):
            raise OscDecodeError("types", f"{FRAME_ADDRESS}: time and channels must be numbers "
                                 "(f, d or i)")
        seq, time, channels = seq_value, float(time_value), np.array(values, dtype=np.float64)
    if len(channels) > MAX_CHANNELS:
        raise OscDecodeError("oversize", f"{FRAME_ADDRESS}: {len(channels)} channels, more than "
                             f"the limit of {MAX_CHANNELS}")
    if not (math.isfinite(time) and np.all(np.isfinite(channels))):
        raise OscDecodeError("nan", f"{FRAME_ADDRESS}: seq {seq}: NaN or infinite value")
    return int(seq), float(time), channels


def _message(data: bytes, address: str | None = None) -> OscMessage:
    try:
        message = OscMessage(data)
    except Exception as exc:  # python-osc raises several types for garbage
        raise OscDecodeError("parse", f"not an OSC message: {exc}") from None
    if address is not None and message.address != address:
        raise OscDecodeError("address", f"unexpected OSC address {message.address!r}")
    return message


def decode_skeleton(data: bytes) -> tuple[Skeleton, float]:
    """Decode `/streamkey/skeleton s bvh [, d fps]`."""
    params = _message(data, SKELETON_ADDRESS).params
    if not params or not isinstance(params[0], str):
        raise OscDecodeError("types", f"{SKELETON_ADDRESS}: expected s bvh_header [, d fps]")
    fps = params[1] if len(params) > 1 and isinstance(params[1], (int, float)) else 120.0
    if not (math.isfinite(fps) and 0 < fps <= 10_000):
        raise OscDecodeError("types", f"{SKELETON_ADDRESS}: fps {fps} out of range")
    try:
        motion = parse_bvh(params[0], source=SKELETON_ADDRESS)
    except BVHError as exc:
        raise OscDecodeError("skeleton", str(exc)) from None
    return motion.skeleton, float(fps)


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, source: OscSource) -> None:
        self.source = source

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.source.receive(data)

    def error_received(self, exc: Exception) -> None:
        self.source.stats.reject("socket", str(exc))


class OscSource(Source):
    """Frames from OSC over UDP (`/streamkey/frame`, bundles of them too)."""

    name = "osc"

    def __init__(self, address: Address, listen: str | None = None,
                 skeleton: Skeleton | None = None, fps: float | None = None) -> None:
        super().__init__(skeleton, fps)
        self.address = address
        self.host = bind_host(address, listen)
        self.transport: asyncio.DatagramTransport | None = None

    async def start(self) -> str:
        loop = asyncio.get_running_loop()
        try:
            self.transport, _ = await loop.create_datagram_endpoint(
                lambda: _Protocol(self), local_addr=(self.host, self.address.port),
                family=socket.AF_INET)
        except OSError as exc:
            raise InputError(f"{self.address}: cannot listen on {self.host}:"
                             f"{self.address.port}: {exc.strerror or exc}") from None
        port = self.transport.get_extra_info("sockname")[1]
        return f"osc://{self.host}:{port}"

    def receive(self, data: bytes) -> None:
        """Handle one datagram (called on the event loop); never raises."""
        try:
            if len(data) > MAX_MESSAGE_BYTES:
                raise OscDecodeError("oversize", f"packet of {len(data)} bytes, more than "
                                     f"{MAX_MESSAGE_BYTES}")
            if OscBundle.dgram_is_bundle(data):
                for item in _bundle_messages(data):
                    self.receive(item)
                return
            if data.startswith(_osc_string(SKELETON_ADDRESS)):
                self.set_skeleton(*decode_skeleton(data))
                return
            seq, time, channels = decode_frame(data)
        except OscDecodeError as exc:
            self.stats.reject(exc.kind, str(exc))
            return
        self.stats.received += 1
        self.frames.put(Frame(seq, time, channels))

    async def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


def _bundle_messages(data: bytes) -> list[bytes]:
    try:
        bundle = OscBundle(data)
    except Exception as exc:
        raise OscDecodeError("parse", f"bad OSC bundle: {exc}") from None
    out = []
    for i in range(bundle.num_contents):
        content = bundle.content(i)
        out.extend(_bundle_messages(content.dgram) if isinstance(content, OscBundle)
                   else [content.dgram])
    return out


class _UdpSender:
    """A non-blocking UDP socket to one peer; a full buffer or an absent peer counts a drop."""

    def __init__(self, address: Address, stats: Any) -> None:
        self.target = (address.host, address.port)
        self.stats = stats
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)

    def send(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.target)
            self.stats.sent += 1
        except (BlockingIOError, ConnectionRefusedError, OSError) as exc:
            self.stats.dropped += 1
            self.stats.last_error = str(exc)

    def close(self) -> None:
        self.sock.close()


class OscEventSink(Sink):
    """Keyframe events as `/streamkey/keyframe` messages to one OSC receiver."""

    name = "osc"

    def __init__(self, address: Address) -> None:
        super().__init__()
        self.address = address
        self.time_type = address.options.get("time", "f")
        if self.time_type not in ("f", "d"):
            raise UsageError(f"{address}: time must be f or d")
        self.sender = _UdpSender(address, self.stats)

    async def start(self) -> str:
        return str(self.address)

    def offer(self, event: dict[str, Any]) -> None:
        if event.get("type") == "keyframe":
            self.sender.send(encode_event(event, self.time_type))

    async def close(self) -> None:
        self.sender.close()


class OscFrameSender:
    """Frames (and the skeleton, now and then) to one OSC receiver: the replay side."""

    name = "osc"

    def __init__(self, address: Address) -> None:
        from .base import SinkStats

        self.address = address
        self.stats = SinkStats()
        self.sender = _UdpSender(address, self.stats)
        self.skeleton_message: tuple[Skeleton, bytes] | None = None

    def send_skeleton(self, skeleton: Skeleton, fps: float) -> None:
        """Announce the skeleton (receivers without `--skeleton` wait for it)."""
        if self.skeleton_message is None or self.skeleton_message[0] is not skeleton:
            self.skeleton_message = (skeleton, encode_skeleton(skeleton, fps))
        self.sender.send(self.skeleton_message[1])

    def send_frame(self, frame: Frame) -> None:
        """Send one frame (never blocks)."""
        self.sender.send(encode_frame(frame.seq, frame.time, frame.channels))

    def close(self) -> None:
        """Close the socket."""
        self.sender.close()
