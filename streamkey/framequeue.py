"""The frame queue between a source and the engine, and the three things that travel on it.

A source puts `FrameArrived` (a frame, its arrival time, its stream tag), `SkeletonAnnounced`
(a stream's skeleton came from the wire: the engine builds its pipeline before its first
frame) and, once, `SourceEnded`. The engine takes them in order with `get` / `get_nowait`.

Two ways in: `offer` (and its shorthands `put`, `announce`, `end`) never waits and drops the
oldest item when the queue is full (network sources: a real-time keyframer wants the newest
frames, not a backlog, and big buffers only make frames stale); `send` waits for room (a pipe
or an in-process replay: backpressure instead of drops).
"""

from __future__ import annotations

import asyncio
import time
from dataclasses import dataclass
from typing import Protocol

from .motion import Frame

__all__ = ["FrameArrived", "SkeletonAnnounced", "SourceEnded", "QueueItem", "FrameQueue",
           "QueueStatistics", "DEFAULT_QUEUE_SIZE"]

DEFAULT_QUEUE_SIZE = 256


@dataclass(frozen=True, slots=True)
class FrameArrived:
    """A frame of stream `stream` (None: the unnamed stream), received at `arrival_ns`
    (monotonic ns; the kernel's receive time where the source can read it)."""

    frame: Frame
    arrival_ns: int
    stream: str | None = None


@dataclass(frozen=True, slots=True)
class SkeletonAnnounced:
    """Stream `stream` (None: the unnamed stream) now has a skeleton."""

    stream: str | None = None


@dataclass(frozen=True, slots=True)
class SourceEnded:
    """No item follows: the source ended, died (`reason`) or the run was stopped."""

    reason: str | None = None


QueueItem = FrameArrived | SkeletonAnnounced | SourceEnded


@dataclass(frozen=True, slots=True)
class QueueStatistics:
    """What the queue holds now and what it dropped so far."""

    items: int          # queued items of every kind
    frames: int         # of which frames
    maxsize: int        # 0: unbounded
    drops: int          # items dropped to make room (by `put` and `end`)


class _Counters(Protocol):
    queue_drops: int


class FrameQueue:
    """A bounded FIFO of `QueueItem`s; `drops` go to the source's `queue_drops` counter."""

    def __init__(self, stats: _Counters, maxsize: int = DEFAULT_QUEUE_SIZE) -> None:
        self._items: asyncio.Queue[QueueItem] = asyncio.Queue(maxsize)
        self._frames = 0
        self.stats = stats

    def __len__(self) -> int:
        return self._items.qsize()

    @property
    def maxsize(self) -> int:
        """Capacity (0: unbounded)."""
        return self._items.maxsize

    def empty(self) -> bool:
        """True if no item is queued."""
        return self._items.empty()

    def offer(self, item: QueueItem) -> int:
        """Queue `item` without waiting, dropping the oldest items to make room; returns how
        many were dropped."""
        dropped = 0
        while True:
            try:
                self._items.put_nowait(item)
                break
            except asyncio.QueueFull:
                self._took(self._items.get_nowait())
                dropped += 1
        self._frames += isinstance(item, FrameArrived)
        return dropped

    async def send(self, item: QueueItem) -> None:
        """Queue `item`, waiting for room (backpressure instead of drops)."""
        await self._items.put(item)
        self._frames += isinstance(item, FrameArrived)

    def put(self, frame: Frame | None, arrival_ns: int | None = None,
            stream: str | None = None) -> None:
        """Offer a frame stamped with its arrival (monotonic ns; now if not given) and its
        stream tag (None: the unnamed stream); drops are counted. `frame` None: `end()`."""
        if frame is None:
            self.end()
            return
        arrival = time.monotonic_ns() if arrival_ns is None else arrival_ns
        self.stats.queue_drops += self.offer(FrameArrived(frame, arrival, stream))

    def announce(self, stream: str | None) -> None:
        """Offer `SkeletonAnnounced(stream)`."""
        self.offer(SkeletonAnnounced(stream))

    def end(self, reason: str | None = None) -> None:
        """Offer `SourceEnded(reason)`; drops are counted."""
        self.stats.queue_drops += self.offer(SourceEnded(reason))

    async def get(self) -> QueueItem:
        """The next item, waiting for one."""
        return self._took(await self._items.get())

    def get_nowait(self) -> QueueItem:
        """The next item; `asyncio.QueueEmpty` if there is none."""
        return self._took(self._items.get_nowait())

    def statistics(self) -> QueueStatistics:
        """A snapshot of the queue's state."""
        return QueueStatistics(len(self), self._frames, self.maxsize, self.stats.queue_drops)

    def _took(self, item: QueueItem) -> QueueItem:
        self._frames -= isinstance(item, FrameArrived)
        return item
