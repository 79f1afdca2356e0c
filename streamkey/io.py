"""The engine's edges: the `Source` and `Sink` interfaces, their counters and the frame queue.

A source delivers `FrameArrived` items (a frame, its arrival time, its stream tag) through
its `FrameQueue` (`streamkey.framequeue`), then `SourceEnded`, and may learn skeletons from
the wire (`skeleton_ready` for the unnamed stream, `named` for the others, each announced to
the engine through the queue as `SkeletonAnnounced`). Stream ids follow `stream_id_problem`;
`stream_tag` maps the name `default` to the unnamed stream. Every task a source runs goes
through `spawn`: an exception inside it is counted and, if the task ends, the source `die`s,
which ends the stream with a reason (`fatal`) instead of leaving the engine waiting forever.

A sink takes typed events (`KeyframeEvent`, `GapEvent`, `StatusEvent`) with `offer()`,
which never blocks: live sinks drop the oldest pending message when they fall behind and
count it; the JSON Lines sink never drops. A sink that raises is that sink's fault: the
engine counts it in the sink's `SinkStats` and disables the sink after
`SINK_FAILURE_LIMIT` failures in a row; the keyframers never see it.
"""

from __future__ import annotations

import asyncio
import math
import re
from collections import Counter
from collections.abc import Coroutine
from dataclasses import dataclass, field
from typing import Any

from .framequeue import DEFAULT_QUEUE_SIZE, FrameQueue, QueueItem
from .keyframes import Event
from .motion import Skeleton

__all__ = ["Source", "Sink", "SourceStats", "SinkStats", "FrameQueue",
           "frame_numbers_problem", "fps_problem", "MAX_SEQ", "MAX_TIME", "MIN_FPS", "MAX_FPS",
           "SINK_FAILURE_LIMIT", "stream_id_problem", "stream_tag", "StreamSpec",
           "DEFAULT_MAX_STREAMS", "MAX_STREAM_ID"]

MAX_SEQ = 2**53 - 1          # exact in a float64 and an int64: JSON and NumPy agree on it
MAX_TIME = 1e9               # seconds (31 years of stream)
MIN_FPS, MAX_FPS = 0.1, 10_000.0   # frame time 1e-4 .. 10 s
SINK_FAILURE_LIMIT = 10      # consecutive failures before a sink is disabled
DEFAULT_MAX_STREAMS = 64     # streams one run serves at once (`run --max-streams`)
MAX_STREAM_ID = 64           # characters of a stream id
_STREAM_ID = re.compile(rf"[A-Za-z0-9][A-Za-z0-9_.-]{{0,{MAX_STREAM_ID - 1}}}", re.ASCII)


def stream_id_problem(name: Any) -> str | None:
    """Why `name` cannot be a stream id (None if it can): 1..64 ASCII letters, digits, `_`,
    `.` or `-`, starting with a letter or digit (no `/`: it separates the id from the kind
    in OSC addresses and ZeroMQ topics)."""
    if isinstance(name, str) and _STREAM_ID.fullmatch(name):
        return None
    return (f"a stream id must be 1..{MAX_STREAM_ID} ASCII letters, digits, '_', '.' or '-' "
            f"starting with a letter or digit, got {str(name)[:40]!r}")


def stream_tag(name: str | None) -> str | None:
    """The tag a source puts on a frame of stream `name`: None for the unnamed stream (the
    legacy addresses, and the name `default`), which the engine calls by its `--stream`."""
    return None if name in (None, "default") else name


@dataclass(frozen=True)
class StreamSpec:
    """What a keyframer factory needs to know of one stream: its id, skeleton and rate."""

    stream: str
    skeleton: Skeleton
    fps: float


def frame_numbers_problem(seq: Any, time_s: Any) -> str | None:
    """Why a frame's seq / time cannot be used (None if they can): seq an integer in
    0..MAX_SEQ, time a finite number of seconds in -MAX_TIME..MAX_TIME."""
    if isinstance(seq, float) and math.isfinite(seq) and seq.is_integer():
        seq = int(seq)
    if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= MAX_SEQ:
        return f"seq must be an integer in 0..{MAX_SEQ}, got {str(seq)[:40]}"
    if isinstance(time_s, bool) or not isinstance(time_s, (int, float)) or not (
            math.isfinite(time_s) and abs(time_s) <= MAX_TIME):
        return f"time must be a finite number of seconds (|t| <= {MAX_TIME:g}), got " \
               f"{str(time_s)[:40]}"
    return None


def fps_problem(fps: Any) -> str | None:
    """Why a frame rate cannot be used (None if it can): a number in MIN_FPS..MAX_FPS."""
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (
            math.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        return f"fps must be a number in {MIN_FPS:g}..{MAX_FPS:g}, got {str(fps)[:40]}"
    return None


@dataclass
class SourceStats:
    """Counters of a source: frames received, dropped (queue full), malformed by kind, the
    kernel's receive-buffer drops (None where the platform does not say), the last error."""

    received: int = 0
    queue_drops: int = 0
    malformed: Counter[str] = field(default_factory=Counter)
    last_error: str = ""
    kernel_drops: int | None = None
    task_errors: int = 0

    def reject(self, kind: str, message: str) -> None:
        """Count a malformed message of `kind` and remember why."""
        self.malformed[kind] += 1
        self.last_error = message[:300]

    def as_dict(self) -> dict[str, Any]:
        """Counters as a plain dict."""
        return {"received": self.received, "queue_drops": self.queue_drops,
                "malformed": dict(self.malformed), "last_error": self.last_error,
                "kernel_drops": self.kernel_drops, "task_errors": self.task_errors}


@dataclass
class SinkStats:
    """Counters of a sink: events sent, dropped (slow or absent peer), errors, disabled."""

    sent: int = 0
    dropped: int = 0
    errors: int = 0
    last_error: str = ""
    disabled: bool = False
    unseen_drops: str = ""   # drops this sink cannot count, and why (empty: it counts all)
    duplicates: int = 0      # events skipped because their id was delivered before

    def as_dict(self) -> dict[str, Any]:
        """Counters as a plain dict."""
        return dict(self.__dict__)


class Source:
    """Base of frame sources: a queue, counters, and the skeleton (given or from the wire)."""

    name = "source"

    def __init__(self, skeleton: Skeleton | None = None, fps: float | None = None,
                 queue_size: int = DEFAULT_QUEUE_SIZE) -> None:
        self.stats = SourceStats()
        self.frames = FrameQueue(self.stats, queue_size)
        self.skeleton = skeleton
        self.fps = fps
        self.skeleton_ready = asyncio.Event()
        self.fatal: str | None = None
        self.dead = asyncio.Event()
        self.tasks: set[asyncio.Task[Any]] = set()
        # A skeleton given up front (`--skeleton`) serves every stream; one from the wire
        # serves its own stream (`self.skeleton`: the unnamed one; `named`: the others).
        self.shared_skeleton = skeleton is not None
        self.named: dict[str, tuple[Skeleton, float]] = {}
        self.max_streams = DEFAULT_MAX_STREAMS  # the engine sets its cap here
        self._skeleton_raw: dict[str | None, bytes] = {}  # wire form of each held skeleton
        if skeleton is not None:
            self.skeleton_ready.set()

    def repeated_skeleton(self, raw: bytes, stream: str | None = None) -> bool:
        """True if `raw` is the wire form of the skeleton `stream` holds now: senders repeat
        it every second, and parsing it again (~1 ms) would delay the next frame."""
        return self._skeleton_raw.get(stream) == raw and self.skeleton_for(stream) is not None

    def set_skeleton(self, skeleton: Skeleton, fps: float, stream: str | None = None,
                     raw: bytes | None = None) -> None:
        """Adopt a skeleton announced on the wire for `stream` (None: the unnamed stream;
        first good one wins; a bad or changed one is counted and ignored). `raw`: its wire
        form, remembered so that repeats are recognised (`repeated_skeleton`)."""
        problem = fps_problem(fps)
        if problem is not None:
            self.stats.reject("skeleton", f"skeleton ignored: {problem}")
            return
        if stream is not None:
            held = self.named.get(stream)
            if held is None and len(self.named) >= self.max_streams:
                self.stats.reject("stream_limit", f"skeleton of stream {stream!r} ignored: "
                                  f"{self.max_streams} streams already announced")
            elif held is None:
                self.named[stream] = (skeleton, float(fps))
                self._remember_raw(stream, raw)
                self.frames.announce(stream)
            else:
                self._mismatch(skeleton, held[0], stream, raw)
        elif self.skeleton is None:
            self.skeleton, self.fps = skeleton, float(fps)
            self._remember_raw(None, raw)
            self.skeleton_ready.set()
            self.frames.announce(None)
        else:
            self._mismatch(skeleton, self.skeleton, None, raw)

    def _remember_raw(self, stream: str | None, raw: bytes | None) -> None:
        if raw is not None:
            self._skeleton_raw[stream] = raw

    def _mismatch(self, skeleton: Skeleton, held: Skeleton, stream: str | None,
                  raw: bytes | None) -> None:
        if skeleton.names == held.names and skeleton.channels == held.channels:
            self._remember_raw(stream, raw)  # the held skeleton again: repeats need no parse
        else:
            self.stats.reject("skeleton_mismatch",
                              f"another skeleton ({len(skeleton.names)} joints, "
                              f"{skeleton.n_channels} channels) ignored; the stream keeps its "
                              f"first ({len(held.names)} joints, {held.n_channels} channels)")

    def skeleton_for(self, stream: str | None) -> tuple[Skeleton, float] | None:
        """Skeleton and fps of a stream: its own, else the shared one; None if unknown yet."""
        own = self.named.get(stream) if stream is not None else None
        if own is not None:
            return own
        if (stream is None or self.shared_skeleton) and self.skeleton is not None:
            return self.skeleton, float(self.fps or 120.0)
        return None

    def forget_stream(self, stream: str | None) -> None:
        """A stream was retired: its skeleton no longer takes a place (it may come back with
        its skeleton)."""
        if stream is not None:
            self.named.pop(stream, None)
            self._skeleton_raw.pop(stream, None)

    def refuse_skeleton(self, why: str, stream: str | None = None) -> None:
        """The engine cannot use the adopted skeleton: count it and wait for another."""
        self.stats.reject("skeleton", f"skeleton ignored: {why}")
        self._skeleton_raw.pop(stream, None)
        if stream is not None:
            self.named.pop(stream, None)
            return
        self.skeleton, self.fps = None, None
        self.skeleton_ready.clear()

    def spawn(self, coro: Coroutine[Any, Any, None]) -> asyncio.Task[None]:
        """Run a source task; if it ends by an exception the source dies saying why."""
        task = asyncio.create_task(coro)
        self.tasks.add(task)
        task.add_done_callback(self._task_done)
        return task

    def _task_done(self, task: asyncio.Task[Any]) -> None:
        self.tasks.discard(task)
        if not task.cancelled() and task.exception() is not None:
            exc = task.exception()
            self.stats.task_errors += 1
            self.die(f"{self.name} source stopped: {type(exc).__name__}: {exc}")

    def die(self, why: str) -> None:
        """End the stream because the source cannot go on (the run reports `why`)."""
        if self.fatal is None:
            self.fatal = why
        self.dead.set()
        self.frames.end(why)

    async def start(self) -> str:
        """Open the transport; returns a description for the ready line."""
        raise NotImplementedError

    async def get(self) -> QueueItem:
        """The next item of the queue (a frame, a skeleton announced, the end)."""
        return await self.frames.get()

    async def close(self) -> None:
        """Release the transport and stop the source's tasks."""
        for task in list(self.tasks):
            task.cancel()

    def counters(self) -> SourceStats:
        """The counters, refreshed from the transport where it keeps its own (kernel drops)."""
        return self.stats


class Sink:
    """Base of event sinks. `offer` must never block the engine."""

    name = "sink"
    live = True  # live sinks may drop under backpressure; the log sink never does

    def __init__(self) -> None:
        self.stats = SinkStats()

    async def start(self) -> str:
        """Open the transport; returns a description for the ready line."""
        return self.name

    def offer(self, event: Event) -> None:
        """Hand over one typed event; must not block (may raise: the engine counts it)."""
        raise NotImplementedError

    def end_batch(self, arrival_ns: int) -> None:
        """The events offered since the last call were decided by the frame that arrived at
        `arrival_ns` (monotonic ns); a sink that groups them (OSC bundles) sends now."""

    async def close(self) -> None:
        """Drain (bounded time) and release the transport."""
