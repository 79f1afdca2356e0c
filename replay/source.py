"""In-process frame source: a motion replayed (paced or as fast as possible) into the engine."""

from __future__ import annotations

import asyncio
import itertools
import time

from streamkey.framequeue import FrameArrived, SourceEnded
from streamkey.io import Source
from streamkey.motion import Motion

from .pacing import apaced, frame_stream

__all__ = ["MotionSource"]


class MotionSource(Source):
    """Frames of a motion, paced at `rate * speed` frames per second (0: unpaced)."""

    name = "replay"

    def __init__(self, motion: Motion, rate: float | None = None, speed: float = 1.0,
                 loop: bool = False, start: int | None = None, end: int | None = None,
                 count: int | None = None) -> None:
        super().__init__(motion.skeleton, motion.fps, queue_size=8)
        self.motion = motion
        self.rate = motion.fps if rate is None else rate
        self.speed = speed
        self.frames_iter = itertools.islice(frame_stream(motion, start, end, loop), count)
        self.task: asyncio.Task[None] | None = None

    async def start(self) -> str:
        self.task = self.spawn(self._produce())
        return f"replay of {self.motion.name or 'motion'} at {self.rate * self.speed:g} frames/s"

    async def _produce(self) -> None:
        interval = 1.0 / (self.rate * self.speed) if self.rate > 0 else 0.0
        async for frame, _ in apaced(self.frames_iter, interval):
            self.stats.received += 1
            # in-process: backpressure instead of drops
            await self.frames.send(FrameArrived(frame, time.monotonic_ns()))
        await self.frames.send(SourceEnded())

