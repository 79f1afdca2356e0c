"""The asyncio engine: one source -> N online keyframers -> M sinks (DESIGN §2).

- Frames come from the source's bounded queue (network sources drop the oldest frame when the
  engine falls behind, and count it).
- Keyframers run on the loop thread; each frame's events are stamped with the wall latency
  from the arrival of the deciding frame, written to the JSON Lines log (flushed) and then
  offered to the network sinks, whose `offer` never blocks.
- `stop()` (Ctrl-C / SIGTERM in the CLI), or `idle_exit` seconds without a frame once
  frames have flowed, ends the source; the keyframers are flushed, the
  sinks drained and closed, and a `RunSummary` is returned.
"""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .adapters.base import Sink, Source
from .keyframes import Event, KeyframeEvent, StatusEvent
from .motion import Frame
from .online import OnlineKeyframer, Pipeline

__all__ = ["Engine", "RunSummary"]


@dataclass
class RunSummary:
    """What a run did: frames, drops, gaps, events per method and sink, wall latency."""

    frames_in: int = 0
    guard: dict[str, int] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    events: Counter[str] = field(default_factory=Counter)
    sinks: dict[str, dict[str, Any]] = field(default_factory=dict)
    wall_latency_ms: list[float] = field(default_factory=list)
    seconds: float = 0.0
    errors: list[str] = field(default_factory=list)
    method_latency_ms: dict[str, list[float]] = field(default_factory=dict)

    def latency_percentiles(self) -> dict[str, float | None]:
        """p50 / p99 / max of the wall latency (ms), None before the first event."""
        if not self.wall_latency_ms:
            return {"p50": None, "p99": None, "max": None}
        lat = np.array(self.wall_latency_ms)
        return {"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                "max": float(lat.max())}

    def as_dict(self) -> dict[str, Any]:
        """The summary as a JSON-ready dict."""
        return {"frames_in": self.frames_in, "seconds": round(self.seconds, 3),
                "guard": self.guard, "source": self.source, "events": dict(self.events),
                "sinks": self.sinks, "wall_latency_ms": self.latency_percentiles(),
                "keyframer_errors": self.errors}

    def text(self) -> str:
        """A few human-readable lines for the end of a run."""
        lat = self.latency_percentiles()
        g = self.guard
        lines = [
            f"frames in: {self.frames_in} in {self.seconds:.1f} s; dropped: "
            f"{g.get('duplicates', 0)} duplicate, {g.get('out_of_order', 0)} out of order, "
            f"{g.get('invalid', 0)} invalid, {self.source.get('queue_drops', 0)} queue; "
            f"malformed: {sum(self.source.get('malformed', {}).values())}",
            f"gaps: {g.get('gaps', 0)} ({g.get('bridged_frames', 0)} frames bridged, "
            f"{g.get('restarts', 0)} restarts)",
            "events: " + (", ".join(f"{k} {v}" for k, v in sorted(self.events.items()))
                          or "none"),
        ]
        for name, st in self.sinks.items():
            lines.append(f"sink {name}: sent {st['sent']}, dropped {st['dropped']}"
                         + (f", last error: {st['last_error']}" if st.get("last_error") else ""))
        for error in self.errors[:5]:
            lines.append(f"keyframer error (window restarted): {error}")
        if lat["p50"] is not None:
            lines.append(f"wall latency: p50 {lat['p50']:.3f} ms, p99 {lat['p99']:.3f} ms, "
                         f"max {lat['max']:.3f} ms")
        return "\n".join(lines)


KeyframerFactory = Callable[[Source], list[OnlineKeyframer]]


class Engine:
    """Wire a source to keyframers and sinks; `await run()` until the source ends or `stop()`."""

    def __init__(self, source: Source, make_keyframers: KeyframerFactory, sinks: list[Sink],
                 stream: str = "default",
                 on_ready: Callable[[str], None] | None = None,
                 on_event: Callable[[dict[str, Any]], None] | None = None,
                 idle_exit: float | None = None,
                 on_frame: Callable[[Frame], None] | None = None) -> None:
        self.source = source
        self.idle_exit = idle_exit
        self.make_keyframers = make_keyframers
        # The log sinks come first: an event is on disk before any network peer sees it.
        self.sinks = sorted(sinks, key=lambda s: s.live)
        self.stream = stream
        self.on_ready = on_ready or (lambda line: None)
        self.on_event = on_event
        self.on_frame = on_frame  # called after each frame's events (the dashboard's pose view)
        self.summary = RunSummary()
        self.pipeline: Pipeline | None = None
        self._stopping = False
        self._stop_event = asyncio.Event()

    def stop(self) -> None:
        """Ask the run to end: the source stops, keyframers flush, sinks drain."""
        self._stopping = True
        self._stop_event.set()
        self.source.frames.put(None)

    async def run(self) -> RunSummary:
        """Run until the source ends or `stop()`; returns the summary."""
        started = time.monotonic()
        for sink in self.sinks:
            self.on_ready(f"sending to {await sink.start()}")
        try:
            if self.source.skeleton_ready.is_set():  # known skeleton: ready before frames flow
                self._make_pipeline()
            self.on_ready(f"listening on {await self.source.start()}")
            await self._wait_skeleton()
            if not self._stopping:
                await self._loop()
        finally:
            await self.source.close()
            if self.pipeline is not None:
                try:
                    events = self.pipeline.flush()
                except Exception as exc:
                    events = self._contain(exc, None)
                self._dispatch(events, time.monotonic_ns())
            for sink in self.sinks:
                await sink.close()
            self._finish_summary(started)
        return self.summary

    async def _wait_skeleton(self) -> None:
        waits = [asyncio.ensure_future(self._stop_event.wait()),
                 asyncio.ensure_future(self.source.skeleton_ready.wait())]
        await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
        for w in waits:
            w.cancel()
        if self.source.skeleton_ready.is_set() and not self._stopping and self.pipeline is None:
            self._make_pipeline()

    def _make_pipeline(self) -> None:
        self.pipeline = Pipeline(self.make_keyframers(self.source), stream=self.stream)
        self._warm_up()

    def _warm_up(self) -> None:
        """Push a few rest-pose frames through a throwaway copy of the keyframers, so that
        first-call costs (lazy imports, FK plans, BLAS start-up) are not paid by the first
        real decision's latency."""
        assert self.source.skeleton is not None
        spare = Pipeline(self.make_keyframers(self.source), stream=self.stream)
        rest = np.zeros(self.source.skeleton.n_channels)
        fps = self.source.fps or 120.0
        for seq in range(3):
            spare.push(Frame(seq, seq / fps, rest))
        spare.flush()

    async def _loop(self) -> None:
        assert self.pipeline is not None
        while True:
            if self.idle_exit is not None and self.summary.frames_in:
                try:
                    item = await asyncio.wait_for(self.source.get(), self.idle_exit)
                except TimeoutError:
                    return
            else:
                item = await self.source.get()
            if item is None:
                return
            frame, arrival_ns = item
            self.summary.frames_in += 1
            try:
                self.pipeline.push(frame, lambda evs, t=arrival_ns: self._dispatch(evs, t))
            except Exception as exc:  # a keyframer bug must not end the session or lose the log
                self._dispatch(self._contain(exc, frame.seq), arrival_ns)
            if self.on_frame is not None:
                self.on_frame(frame)

    def _contain(self, exc: Exception, seq: int | None) -> list[Event]:
        """Report a keyframer failure as a status event and restart the window."""
        assert self.pipeline is not None
        self.summary.errors.append(f"{type(exc).__name__}: {exc} (at seq {seq})")
        for kf in self.pipeline.keyframers:
            kf.reset()
        self.pipeline.guard.reset()
        self.pipeline.features.reset()
        return [StatusEvent(self.stream, "*", "error",
                            {"error": f"{type(exc).__name__}: {exc}", "seq": seq})]

    def _dispatch(self, events: list[Event], arrival_ns: int) -> None:
        for event in events:
            record = event.to_dict()
            if isinstance(event, KeyframeEvent):
                latency = (time.monotonic_ns() - arrival_ns) / 1e6
                record["wall_latency_ms"] = round(latency, 3)
                self.summary.wall_latency_ms.append(latency)
                self.summary.method_latency_ms.setdefault(event.method, []).append(latency)
                self.summary.events[event.method] += 1
            else:
                self.summary.events[record["type"]] += 1
            for sink in self.sinks:
                sink.offer(record)
            if self.on_event is not None:
                self.on_event(record)

    def _finish_summary(self, started: float) -> None:
        self.summary.seconds = time.monotonic() - started
        if self.pipeline is not None:
            self.summary.guard = self.pipeline.guard.counters.as_dict()
        self.summary.source = self.source.stats.as_dict()
        for sink in self.sinks:
            key = sink.name
            n = 2
            while key in self.summary.sinks:
                key, n = f"{sink.name}#{n}", n + 1
            self.summary.sinks[key] = sink.stats.as_dict()
