"""JSON Lines frames on stdin (`run --from -`): the format `replay --to -` writes.

One JSON object a line (UTF-8)::

    {"type": "skeleton", "bvh": "HIERARCHY ... MOTION ...", "fps": 120}   (first, unless --skeleton)
    {"seq": 12, "time": 0.1, "channels": [0.0, 93.2, ...]}                  (one frame)

`time` is optional (default `seq / fps`). Blank lines are skipped. An optional `"stream":
"ID"` on a frame line names its stream (none: the unnamed stream, `default`); a later
skeleton line with a `stream` gives that stream its own skeleton (before its first frame),
else the first skeleton serves every stream. A line that is not such an
object (bad JSON, missing or mistyped field, longer than `MAX_LINE_BYTES`) is dropped and
counted in the source's `malformed` counters; frames with the wrong channel count or non-finite
values are dropped and counted by the stream guard. Reading blocks when the engine falls
behind (backpressure through the pipe), so a file piped in is never thinned out.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import json
import sys
import threading
import time
from typing import IO, Any

import numpy as np

from streamkey.errors import BVHError, InputError
from streamkey.framequeue import FrameArrived, SourceEnded
from streamkey.motion import Frame, Skeleton

from .base import (
    MAX_CHANNELS,
    Source,
    fps_problem,
    frame_numbers_problem,
    stream_id_problem,
    stream_tag,
)

__all__ = ["StdinSource", "read_skeleton_line", "decode_frame_line", "decode_stream_line",
           "MAX_LINE_BYTES",
           "POSITIONS_ONLY"]

MAX_LINE_BYTES = 1 << 20  # a skeleton header of a few hundred joints fits easily
POSITIONS_ONLY = ("positions-only frames (joint positions, no joint rotations) cannot drive "
                  "streamkey: every method reads the rotation channels of a skeleton (README: "
                  "Positions-only sources); solve rotations first (IK) and send channels")
_POSITION_KEYS = ("positions", "joints", "landmarks", "keypoints", "points")


class PositionsOnlyError(ValueError):
    """A frame that carries joint positions instead of rotation channels."""


class StreamIdError(ValueError):
    """A line whose `stream` is not a usable stream id."""


def _positions_only(obj: Any) -> bool:
    return isinstance(obj, dict) and "channels" not in obj and any(
        k in obj for k in _POSITION_KEYS)


def read_skeleton_line(stream: IO[bytes], where: str = "stdin") -> tuple[Skeleton, float]:
    """Read lines up to the first non-blank one, which must be a skeleton line."""
    from streamkey.bvh import parse_bvh

    number = 0
    while True:
        line = stream.readline(MAX_LINE_BYTES)
        number += 1
        if not line:
            raise InputError(f"{where}: ended before a skeleton line; expected "
                             '{"type": "skeleton", "bvh": ..., "fps": ...} first, or --skeleton')
        if line.strip():
            break
    try:
        info = json.loads(line)
        if _positions_only(info):
            raise InputError(f"{where}:{number}: {POSITIONS_ONLY}")
        if not isinstance(info, dict) or info.get("type") != "skeleton":
            raise ValueError("not a skeleton line")
        fps = float(info.get("fps", 120.0))
        if (problem := fps_problem(fps)) is not None:
            raise ValueError(problem)
        skeleton = parse_bvh(str(info["bvh"]), source=f"{where} skeleton").skeleton
    except (ValueError, KeyError, TypeError, BVHError) as exc:
        raise InputError(f"{where}:{number}: expected a skeleton line "
                         '{"type": "skeleton", "bvh": BVH header text, "fps": number} '
                         f"(or give --skeleton FILE): {exc}") from None
    return skeleton, fps


def decode_frame_line(line: bytes, fps: float) -> Frame | dict[str, Any] | None:
    """A frame, a skeleton announcement (dict), or None for a blank line; ValueError if bad."""
    return decode_stream_line(line, fps)[0]


def decode_stream_line(line: bytes, fps: float
                       ) -> tuple[Frame | dict[str, Any] | None, str | None]:
    """`decode_frame_line` and the line's stream tag (None: the unnamed stream)."""
    if not line.strip():
        return None, None
    try:
        obj = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"not JSON: {type(exc).__name__}: {exc}") from None
    if not isinstance(obj, dict):
        raise ValueError("expected a JSON object")
    stream = obj.get("stream")
    if stream is not None and (problem := stream_id_problem(stream)) is not None:
        raise StreamIdError(problem)
    stream = stream_tag(stream)
    if obj.get("type") == "skeleton":
        return obj, stream
    if _positions_only(obj):
        raise PositionsOnlyError(POSITIONS_ONLY)
    seq, channels = obj.get("seq"), obj.get("channels")
    if isinstance(seq, bool) or not isinstance(seq, int):
        raise ValueError("expected an integer seq")
    if not isinstance(channels, list) or not 0 < len(channels) <= MAX_CHANNELS:
        raise ValueError(f"expected channels: a list of 1..{MAX_CHANNELS} numbers")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in channels):
        raise ValueError("expected channels: numbers only")
    time = obj.get("time", seq / fps)
    if isinstance(time, bool) or not isinstance(time, (int, float)):
        raise ValueError("expected a numeric time")
    problem = frame_numbers_problem(seq, time)
    if problem is not None:
        raise ValueError(problem)
    return Frame(seq, float(time), np.array(channels, dtype=np.float64)), stream


class StdinSource(Source):
    """Frames as JSON Lines from a byte stream (stdin by default), read on a thread."""

    name = "stdin"

    def __init__(self, skeleton: Skeleton, fps: float, stream: IO[bytes] | None = None) -> None:
        super().__init__(skeleton, fps)  # a pipe: `send` waits (backpressure, no drops)
        self.stream = stream if stream is not None else sys.stdin.buffer
        self.line = 0
        self.thread: threading.Thread | None = None
        self.closed = False

    async def start(self) -> str:
        loop = asyncio.get_running_loop()
        self.thread = threading.Thread(target=self._read, args=(loop,), daemon=True,
                                       name="streamkey-stdin")
        self.thread.start()
        return "stdin (JSON Lines frames)"

    def _read(self, loop: asyncio.AbstractEventLoop) -> None:
        try:
            while not self.closed:
                line = self.stream.readline(MAX_LINE_BYTES)
                if not line:
                    break
                too_long = not line.endswith(b"\n") and len(line) >= MAX_LINE_BYTES
                while too_long and (rest := self.stream.readline(MAX_LINE_BYTES)) and (
                        not rest.endswith(b"\n")):
                    pass
                item = b"" if too_long else line
                asyncio.run_coroutine_threadsafe(self.accept(item, too_long), loop).result()
        except (RuntimeError, concurrent.futures.CancelledError):  # the loop stopped under us
            return
        except Exception as exc:  # noqa: BLE001 - a reader that stops ends the run, loudly
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(self.die, f"stdin: {type(exc).__name__}: {exc}")
            return
        try:
            asyncio.run_coroutine_threadsafe(self.frames.send(SourceEnded()), loop).result()
        except RuntimeError:
            pass

    async def accept(self, line: bytes, too_long: bool = False) -> None:
        """Decode one line and queue its frame (waits for room); never raises."""
        self.line += 1
        if too_long:
            self.stats.reject("too_long", f"stdin:{self.line}: line longer than "
                              f"{MAX_LINE_BYTES} bytes")
            return
        assert self.fps is not None
        try:
            item, stream = decode_stream_line(line, self.fps)
        except ValueError as exc:
            kind = ("positions_only" if isinstance(exc, PositionsOnlyError) else
                    "stream_id" if isinstance(exc, StreamIdError) else "malformed")
            self.stats.reject(kind, f"stdin:{self.line}: {exc}")
            return
        if item is None:
            return  # blank line
        if isinstance(item, dict):  # a skeleton: the first one repeated, or a stream's own
            if stream is not None:
                self._stream_skeleton(item, stream)
            return
        self.stats.received += 1
        await self.frames.send(FrameArrived(item, time.monotonic_ns(), stream))

    def _stream_skeleton(self, info: dict[str, Any], stream: str) -> None:
        from streamkey.bvh import parse_bvh

        try:
            fps = info.get("fps", 120.0)
            if (problem := fps_problem(fps)) is not None:
                raise ValueError(problem)
            skeleton = parse_bvh(str(info["bvh"]), source=f"stdin:{self.line} skeleton").skeleton
        except Exception as exc:  # any failure of a hostile skeleton: counted, ignored
            self.stats.reject("skeleton", f"stdin:{self.line}: skeleton of stream {stream!r} "
                              f"ignored: {type(exc).__name__}: {str(exc)[:200]}")
            return
        self.set_skeleton(skeleton, float(fps), stream)

    async def close(self) -> None:
        self.closed = True

