"""Noitom Axis Neuron / Axis Studio "BVH data broadcasting" in (`--from axis+tcp://HOST:7001`,
`axis+udp://HOST:PORT`).

Protocol, as published by Noitom:

- Axis Neuron user manual, "BVH data broadcasting": Axis Neuron serves the frames on TCP
  (port 7001 by default; the NeuronDataReader SDK samples connect there) or sends UDP
  datagrams. Each frame carries the rotations (and, with "displacement", the positions) of
  every joint in the channel order of the Axis skeleton's BVH header, optionally prefixed by a
  "reference" bone (6 values). Two encodings: **String**:
  ``<avatar index> <avatar name> <value> <value> ... ||`` (ASCII, one frame per message, `||`
  ends the frame); **Binary**: a 64-byte header, then `DataCount` float32 values.
- NeuronDataReader SDK (Noitom, "Neuron Data Reader Runtime API Documentation", b12, 2014),
  `DataType.h`, `#pragma pack(1) struct _BvhDataHeader`: `uint16 Token1 = 0xDDFF`,
  `uint32 DataVersion`, `uint16 DataCount`, `uint8 WithDisp`, `uint8 WithReference`,
  `uint32 AvatarIndex`, `char AvatarName[32]`, `uint32 FrameIndex`, `uint32 Reserved[3]`,
  `uint16 Token2 = 0xEEFF` (64 bytes, little-endian). "Calculation data" (`0x88FF`, port
  7003) is not read: it is not BVH data.

Values per frame for a skeleton with C channels and J joints: C (plain), C + 6 (reference
first), 6 J (displacement: every joint `Xposition Yposition Zposition` + its rotations; only
the root keeps its positions), 6 J + 6 (both). The skeleton is `--skeleton FILE.bvh` (the BVH
Axis exports) or the built-in 59-joint table (`streamkey.rigs.axis_skeleton`).

The string encoding has no frame number: frames are numbered as they arrive (continuing across
reconnections). The binary one carries `FrameIndex`, used as `seq`. Frames of other avatars
than the first seen (or `?avatar=N`) are dropped and counted (`other_avatar`); anything that
is not a frame is dropped and counted by kind, and the reader resynchronises on the next
`0xDDFF` token or `||`. The TCP client reconnects (backoff up to 1 s) when the server goes
away; a UDP listener binds 127.0.0.1 unless `--listen` allows another interface.
"""

from __future__ import annotations

import asyncio
import struct
from dataclasses import dataclass

import numpy as np

from streamkey.errors import UsageError
from streamkey.motion import Frame, Skeleton

from .base import MAX_CHANNELS, Address, SourceStats, bind_host, frame_numbers_problem
from .udp_listen import DatagramSource

__all__ = ["AxisSource", "AxisParser", "AxisLayout", "AxisPacket", "HEADER", "TOKEN1", "TOKEN2",
           "encode_binary", "encode_text"]

HEADER = struct.Struct("<HIHBBI32sIIIIH")  # _BvhDataHeader, packed, little-endian: 64 bytes
TOKEN1, TOKEN2 = 0xDDFF, 0xEEFF
_TOKEN1_BYTES = struct.pack("<H", TOKEN1)
MAX_TEXT_FRAME = 64_000  # a text frame of MAX_CHANNELS values fits; more is garbage
assert HEADER.size == 64


@dataclass(frozen=True)
class AxisPacket:
    """One decoded frame: avatar, frame index (binary only), the values as sent."""

    avatar: int
    name: str
    frame_index: int | None
    values: np.ndarray


def encode_text(avatar: int, name: str, values: np.ndarray) -> bytes:
    """A string-format frame (what Axis Neuron sends with "String" selected)."""
    return (f"{avatar} {name} " + " ".join(repr(float(v)) for v in values) + " ||\n").encode()


def encode_binary(avatar: int, name: str, frame_index: int, values: np.ndarray,
                  with_disp: bool = False, with_reference: bool = False) -> bytes:
    """A binary-format frame: `_BvhDataHeader` then float32 values."""
    head = HEADER.pack(TOKEN1, 0x01000002, len(values), int(with_disp), int(with_reference),
                       avatar, name.encode()[:32], frame_index, 0, 0, 0, TOKEN2)
    return head + np.asarray(values, dtype="<f4").tobytes()


class AxisParser:
    """Byte stream (TCP) or datagrams (UDP) -> `AxisPacket`s; never raises, counts drops."""

    def __init__(self, stats: SourceStats) -> None:
        self.stats = stats
        self.buffer = bytearray()

    def feed(self, data: bytes) -> list[AxisPacket]:
        """Append received bytes; return every complete frame now in the buffer."""
        self.buffer += data
        out: list[AxisPacket] = []
        while self.buffer:
            if self.buffer[:2] == _TOKEN1_BYTES:
                if len(self.buffer) < HEADER.size:
                    break
                packet, size = self._binary()
                if size == 0:
                    break
                del self.buffer[:size]
            else:
                end = self.buffer.find(b"||")
                token = self.buffer.find(_TOKEN1_BYTES)
                if token > 0 and (end < 0 or token < end):
                    self._reject_text(bytes(self.buffer[:token]))
                    del self.buffer[:token]
                    continue
                if end < 0:
                    if len(self.buffer) > MAX_TEXT_FRAME:
                        self.stats.reject("text", f"axis: {len(self.buffer)} bytes without ||")
                        self.buffer.clear()
                    break
                packet = self._text(bytes(self.buffer[:end]))
                del self.buffer[: end + 2]
            if packet is not None:
                out.append(packet)
        return out

    def end_of_message(self) -> None:
        """A datagram ended (or the connection closed): a partial frame left over is dropped."""
        self._reject_text(bytes(self.buffer))
        self.buffer.clear()

    def _reject_text(self, data: bytes) -> None:
        if data.strip():
            self.stats.reject("text", f"axis: {len(data)} bytes that are no frame")

    def _binary(self) -> tuple[AxisPacket | None, int]:
        (_, _, count, _, _, avatar, name, frame_index, _, _, _, token2) = HEADER.unpack_from(
            self.buffer)
        if token2 != TOKEN2 or count > MAX_CHANNELS:
            self.stats.reject("binary", f"axis: bad binary header (token2 {token2:#06x}, "
                              f"{count} values)")
            return None, 2  # skip the token and resynchronise
        size = HEADER.size + 4 * count
        if len(self.buffer) < size:
            return None, 0
        with np.errstate(invalid="ignore"):  # a NaN payload: the stream guard counts it
            values = np.frombuffer(bytes(self.buffer[HEADER.size:size]), "<f4").astype(float)
        text = name.split(b"\0", 1)[0].decode("utf-8", "replace")
        return AxisPacket(int(avatar), text, int(frame_index), values), size

    def _text(self, chunk: bytes) -> AxisPacket | None:
        try:
            tokens = chunk.decode("ascii").split()
            if len(tokens) < 3:
                raise ValueError("expected <avatar index> <avatar name> <values> ||")
            if len(tokens) - 2 > MAX_CHANNELS:
                raise ValueError(f"more than {MAX_CHANNELS} values")
            values = np.array([float(t) for t in tokens[2:]])
            return AxisPacket(int(tokens[0]), tokens[1], None, values)
        except (UnicodeDecodeError, ValueError) as exc:
            self.stats.reject("text", f"axis: {str(exc)[:120]}")
            return None


class AxisLayout:
    """Values of an Axis frame -> the skeleton's channels (see the module docstring)."""

    def __init__(self, skeleton: Skeleton) -> None:
        self.skeleton = skeleton
        n = skeleton.n_joints
        picks: list[int] = []
        for j, chans in enumerate(skeleton.channels):
            rot = len([c for c in chans if c.endswith("rotation")])
            block = list(range(6 * j, 6 * j + 6))
            picks += block if len(chans) == 6 else block[6 - rot:] if len(chans) == rot else []
        self.displacement = np.array(picks) if len(picks) == skeleton.n_channels else None
        self.sizes = {skeleton.n_channels: "plain", skeleton.n_channels + 6: "reference",
                      6 * n: "displacement", 6 * n + 6: "reference+displacement"}

    def channels(self, values: np.ndarray) -> np.ndarray:
        """The skeleton's channel vector; ValueError if the count fits no layout."""
        kind = self.sizes.get(len(values))
        if kind is None or (kind.endswith("displacement") and self.displacement is None):
            raise ValueError(f"{len(values)} values fit no layout of this skeleton "
                             f"({', '.join(f'{k} {v}' for k, v in self.sizes.items())})")
        if kind.startswith("reference"):
            values = values[6:]
        if kind.endswith("displacement") and len(values) != self.skeleton.n_channels:
            assert self.displacement is not None
            values = values[self.displacement]
        return values


class AxisSource(DatagramSource):
    """Frames from Axis Neuron's BVH broadcast: a TCP client (reconnecting) or UDP listener."""

    name = "axis"

    def __init__(self, address: Address, listen: str | None = None,
                 skeleton: Skeleton | None = None, fps: float | None = None) -> None:
        if skeleton is None:
            from streamkey.rigs import axis_skeleton

            skeleton = axis_skeleton()
        super().__init__(address, skeleton, fps)
        self.udp = address.scheme == "axis+udp"
        self.host = bind_host(address, listen) if self.udp else address.host
        try:
            self.avatar: int | None = (int(address.options["avatar"])
                                       if "avatar" in address.options else None)
        except ValueError:
            raise UsageError(f"{address}: avatar must be an integer") from None
        self.layout = AxisLayout(skeleton)
        self.parser = AxisParser(self.stats)
        self.counter = 0
        self.connections = 0

    async def start(self) -> str:
        if self.udp:
            port = await self.listen(self.host, lambda data: self.receive(data, end=True))
            return f"axis+udp {self.host}:{port}"
        self.spawn(self._connect_loop())
        return f"axis+tcp client of {self.host}:{self.address.port}"

    async def _connect_loop(self) -> None:
        delay = 0.05
        while True:
            try:
                reader, writer = await asyncio.open_connection(self.host, self.address.port)
            except OSError as exc:
                self.stats.last_error = f"axis: connect {self.host}:{self.address.port}: {exc}"
                await asyncio.sleep(delay)
                delay = min(1.0, delay * 2)
                continue
            delay = 0.05
            self.connections += 1
            try:
                while data := await reader.read(65536):
                    self.receive(data)
            except OSError as exc:
                self.stats.last_error = f"axis: connection lost: {exc}"
            finally:
                self.parser.end_of_message()
                writer.close()

    def receive(self, data: bytes, end: bool = False) -> None:
        """Decode received bytes (a datagram when `end`) and queue the frames; never raises."""
        packets = self.parser.feed(data)
        if end:
            self.parser.end_of_message()
        for packet in packets:
            if self.avatar is None:
                self.avatar = packet.avatar
            if packet.avatar != self.avatar:
                self.stats.reject("other_avatar", f"axis: frame of avatar {packet.avatar} "
                                  f"({packet.name}) ignored; following avatar {self.avatar}")
                continue
            try:
                channels = self.layout.channels(packet.values)
            except ValueError as exc:
                self.stats.reject("channel_count", f"axis: {exc}")
                continue
            self.counter += 1
            seq = packet.frame_index if packet.frame_index is not None else self.counter
            assert self.fps is not None
            problem = frame_numbers_problem(seq, seq / self.fps)
            if problem is not None:
                self.stats.reject("range", f"axis: {problem}")
                continue
            self.stats.received += 1
            self.frames.put(Frame(seq, seq / self.fps, channels))
