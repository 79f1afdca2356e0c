"""Replay recorded motion as a stream: a plain generator of frames, then pacing apart.

`frame_stream` yields `Frame`s of a motion (a range, looped with ever-increasing `seq`);
`paced` spaces any frame iterable on a monotonic clock by deadlines (frame i is due at
t0 + i * interval), so lateness never accumulates into drift. Both take injectable clocks so
tests run at full speed and deterministically.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Callable, Iterable, Iterator

from streamkey.errors import UsageError
from streamkey.motion import Frame, Motion

__all__ = ["frame_stream", "paced", "apaced"]


def frame_stream(motion: Motion, start: int | None = None, end: int | None = None,
                 loop: bool = False) -> Iterator[Frame]:
    """Captured frames start..end-1 (file numbering); looping continues `seq` upward.

    The first pass carries the file's own frame numbers, so events of a replayed file name the
    same frames as the keyframers run on the file directly.
    """
    first = motion.first_frame if start is None else start
    stop = motion.n_frames if end is None else end
    if not (0 <= first < stop <= motion.n_frames):
        raise UsageError(f"frame range {first}..{stop} is not inside the motion "
                         f"(frames {motion.first_frame}..{motion.n_frames})")
    seq = first
    while True:
        for i in range(first, stop):
            yield Frame(seq, seq / motion.fps, motion.channels[i])
            seq += 1
        if not loop:
            return


MAX_INTERVAL = 10.0  # seconds between frames: 0.1 frames/s, the slowest file rate accepted


def _check_interval(interval: float) -> None:
    if not 0 <= interval <= MAX_INTERVAL:
        raise UsageError(f"frame interval must lie in 0..{MAX_INTERVAL:g} s, got {interval!r}")


def paced(frames: Iterable[Frame], interval: float,
          clock: Callable[[], float] = time.monotonic,
          sleep: Callable[[float], None] = time.sleep) -> Iterator[tuple[Frame, float]]:
    """Yield (frame, deadline) with frame i due at t0 + i * interval (no drift)."""
    _check_interval(interval)
    t0 = clock()
    for i, frame in enumerate(frames):
        deadline = t0 + i * interval
        delay = deadline - clock()
        if delay > 0:
            sleep(delay)
        yield frame, deadline


async def apaced(frames: Iterable[Frame], interval: float,
                 clock: Callable[[], float] = time.monotonic) -> AsyncIterator[tuple[Frame, float]]:
    """`paced` for an asyncio loop: awaits instead of blocking between frames."""
    _check_interval(interval)
    t0 = clock()
    for i, frame in enumerate(frames):
        deadline = t0 + i * interval
        delay = deadline - clock()
        if delay > 0:
            await asyncio.sleep(delay)
        yield frame, deadline
