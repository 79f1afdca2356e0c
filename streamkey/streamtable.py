"""The stream table: which streams a keyframer host serves, and the one fault policy.

Sans-I/O, like the keyframers: no asyncio, no sockets, no clock (the caller passes `now`, in
seconds of any monotonic clock). The asyncio engine (`streamkey.engine`) and the cluster's
shard worker (`streamkey.cluster.live`) both keep their streams here and do the I/O around it.

A stream id goes through these states:

- **live** (`open`): its `Pipeline` was built from its skeleton; `touch` on every frame.
- **waiting** (`wait`, `hold`): a frame came before the stream's skeleton; up to
  `MAX_WAITING_FRAMES` of its frames are held (the oldest dropped and counted) until it
  opens (`take_held`), or forgotten after `idle` seconds (`forget_stale`).
- **refused** (`admits` false, then `refuse`): `max_streams` streams are live or waiting; its
  frames are counted, never held.
- **retired** (`expired`, then `close`): idle longer than `idle` seconds; the caller flushes
  the pipeline, `close` keeps its guard counters in its `StreamStats` and frees its place. It
  may come back: a new session, from a fresh pipeline.

Fault policy: `step` runs one pipeline call (`push`, `idle`, `flush`); if it raises, the
fault is counted (`faults`), the stream's windows restart (every keyframer, the guard and the
feature stage are reset: the stream goes on from its next frame) and the call's result is a
`StatusEvent` "error" carrying the message and the seq, so the event log says where and why.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .io import StreamSpec
from .keyframes import Event, StatusEvent
from .motion import Frame, Motion
from .online import OnlineKeyframer, Pipeline
from .summary import MAX_ERRORS_KEPT, StreamStats

__all__ = ["StreamTable", "LiveStream", "FaultLog", "keyframers_for", "MAX_WAITING_FRAMES",
           "MAX_STREAM_STATS"]

MAX_WAITING_FRAMES = 256     # frames a stream may hold while its skeleton has not come
MAX_STREAM_STATS = 256       # streams named in the stats; the rest are summed in "(other)"


def keyframers_for(spec: StreamSpec, methods: list[str],
                   params: dict[str, dict[str, Any]] | None = None,
                   lookahead: int | None = None) -> list[OnlineKeyframer]:
    """The online keyframers of one stream, from its spec (id, skeleton, rate)."""
    from .streaming import make_keyframers

    motion = Motion(spec.skeleton, np.zeros((0, spec.skeleton.n_channels)), spec.fps)
    return make_keyframers(motion, methods, params, lookahead, spec.stream)


@dataclass
class LiveStream:
    """A live stream: its pipeline, its counters, and where its frames stand."""

    name: str
    tag: str | None          # the source's tag (None: the unnamed stream)
    pipeline: Pipeline
    stats: StreamStats
    last_frame: float        # `now` of its last frame (or of its opening)
    last_arrival_ns: int = 0
    seq: int | None = None   # seq of its last frame pushed


@dataclass
class FaultLog:
    """Keyframer faults contained so far: how many, and the first `MAX_ERRORS_KEPT`."""

    count: int = 0
    messages: list[str] = field(default_factory=list)


class StreamTable:
    """Live, waiting and refused streams of one host, and their counters (see the module)."""

    def __init__(self, stats: dict[str, StreamStats] | None = None,
                 max_streams: int | None = None, idle: float | None = None) -> None:
        self.live: dict[str, LiveStream] = {}
        self.stats = {} if stats is None else stats
        self.max_streams = max_streams
        self.idle = idle
        self.waiting: dict[str, deque[tuple[Frame, int]]] = {}
        self.waiting_seen: dict[str, float] = {}
        self.refused_streams = 0
        self.refused_frames = 0
        self.said_refused: set[str] = set()
        self.faults = FaultLog()

    # ------------------------------------------------------------------ lifecycle

    def stats_of(self, name: str) -> StreamStats:
        """The counters of stream `name` over the run (beyond `MAX_STREAM_STATS` names:
        the shared "(other)" entry)."""
        stats = self.stats.get(name)
        if stats is None:
            if len(self.stats) >= MAX_STREAM_STATS:
                name = "(other)"
            stats = self.stats.setdefault(name, StreamStats())
        return stats

    def admits(self, name: str) -> bool:
        """True if `name` may open or wait: a place is free, or it holds one already."""
        if name in self.live or self.max_streams is None:
            return True
        return len(self.live) + len(self.waiting) - (name in self.waiting) < self.max_streams

    def refuse(self, name: str, frame: bool, say_limit: int) -> bool:
        """Count a refusal of `name` (`frame`: a frame was dropped); True the first time
        (for the first `say_limit` ids), when the caller should say so."""
        self.refused_frames += frame
        if name in self.said_refused:
            return False
        self.refused_streams += 1
        if len(self.said_refused) < say_limit:
            self.said_refused.add(name)
            return True
        return False

    def wait(self, name: str, now: float) -> None:
        """`name` waits for its skeleton (from `now`, if it was not waiting already)."""
        self.waiting.setdefault(name, deque())
        self.waiting_seen.setdefault(name, now)

    def hold(self, name: str, frame: Frame, arrival_ns: int, now: float) -> None:
        """Keep a frame of a waiting stream (nothing if `name` is not waiting)."""
        waiting = self.waiting.get(name)
        if waiting is None:
            return
        self.waiting_seen[name] = now
        if len(waiting) >= MAX_WAITING_FRAMES:
            waiting.popleft()
            self.stats_of(name).waiting_drops += 1
        waiting.append((frame, arrival_ns))

    def open(self, name: str, tag: str | None, pipeline: Pipeline, now: float) -> LiveStream:
        """Stream `name` is live from now on with `pipeline` (a new session)."""
        state = self.live[name] = LiveStream(name, tag, pipeline, self.stats_of(name), now)
        state.stats.sessions += 1
        self.waiting_seen.pop(name, None)
        return state

    def take_held(self, name: str) -> Sequence[tuple[Frame, int]]:
        """The frames held for `name` while it waited (oldest first), no longer held."""
        return self.waiting.pop(name, ())

    def touch(self, state: LiveStream, now: float) -> None:
        """A frame of `state` arrived at `now`."""
        state.last_frame = now

    def expired(self, now: float) -> list[LiveStream]:
        """Live streams without a frame for longer than `idle` seconds (none if no `idle`)."""
        if self.idle is None:
            return []
        return [s for s in self.live.values() if now - s.last_frame > self.idle]

    def forget_stale(self, now: float) -> None:
        """Drop the streams that waited longer than `idle` seconds for a skeleton (their
        held frames counted as `waiting_drops`)."""
        if self.idle is None:
            return
        for name in [n for n, seen in self.waiting_seen.items() if now - seen > self.idle]:
            self.stats_of(name).waiting_drops += len(self.waiting.pop(name, ()))
            del self.waiting_seen[name]

    def close(self, state: LiveStream) -> None:
        """Retire a live stream (its pipeline flushed by the caller): its guard counters go
        to its stats, its place is free."""
        for key, value in state.pipeline.guard.counters.as_dict().items():
            state.stats.guard[key] += value
        state.stats.retired += 1
        del self.live[state.name]

    def forget(self, name: str) -> None:
        """Stream `name` neither waits nor holds frames any more."""
        self.waiting.pop(name, None)
        self.waiting_seen.pop(name, None)

    def held_frames(self) -> int:
        """Frames held, all waiting streams together."""
        return sum(len(q) for q in self.waiting.values())

    # ------------------------------------------------------------------ faults

    def step(self, state: LiveStream, seq: int | None, call: Callable[..., list[Event]],
             *args: Any) -> list[Event]:
        """One pipeline call of `state`; a fault is contained (see the module)."""
        try:
            return call(*args)
        except Exception as exc:  # a keyframer bug must not end the session or lose the log
            return self.contain(state, exc, seq)

    def contain(self, state: LiveStream, exc: Exception, seq: int | None) -> list[Event]:
        """Count a keyframer fault, restart the stream's windows, report it as an event."""
        self.faults.count += 1
        if len(self.faults.messages) < MAX_ERRORS_KEPT:
            where = "" if len(self.stats) < 2 else f" in stream {state.name!r}"
            self.faults.messages.append(f"{type(exc).__name__}: {exc} (at seq {seq}){where}")
        pipeline = state.pipeline
        for kf in pipeline.keyframers:
            kf.reset()
        pipeline.guard.reset()
        pipeline.features.reset()
        if pipeline.segments is not None:
            pipeline.segments.reset()
        return [StatusEvent(stream=state.name, method="*", status="error",
                            detail={"error": f"{type(exc).__name__}: {exc}", "seq": seq})]

    # ------------------------------------------------------------------ snapshots

    def snapshot(self, name: str) -> bytes:
        """Snapshot of live stream `name`'s pipeline (`snapshot.py`); KeyError if not live."""
        return self.live[name].pipeline.snapshot()

    def restore(self, name: str, tag: str | None, data: bytes, now: float,
                params: str | None = None) -> LiveStream:
        """Serve stream `name` from a snapshot from now on (a live pipeline of that name is
        replaced unflushed); `SnapshotError` if it does not fit (`params`: the digest it must
        carry)."""
        pipeline = Pipeline.restore(data, params)
        self.forget(name)
        state = self.open(name, tag, pipeline, now)
        if pipeline.guard.last is not None:
            state.seq = pipeline.guard.last.seq
        return state
