"""The asyncio engine: one source -> N online keyframers -> M sinks (DESIGN §2).

The path is one-way, as between `websockets`' sans-I/O protocol and its connection:

- Frames come from the source's bounded queue (network sources drop the oldest frame when
  the engine falls behind, and count it), each stamped with its arrival time (the kernel's
  receive time where the source can read it).
- `Pipeline.push` returns the events due with a frame and `Pipeline.idle` the deferred ones
  (a re-analysis); keyframer faults are caught around those two calls only, reported as a
  status event and the windows restarted.
- The engine stamps each `KeyframeEvent` with its wall latency (`dataclasses.replace`) and
  hands the typed events to the sinks, log sinks first (an event is on disk before any
  network peer sees it). A sink's fault is that sink's: counted in its stats, and the sink
  disabled after `SINK_FAILURE_LIMIT` failures in a row; it never touches the keyframers.
- `stop()` (Ctrl-C / SIGTERM in the CLI), `idle_exit` seconds without a frame once frames
  have flowed, or the source dying ends the run; the keyframers are flushed, the sinks
  drained and closed, and a `RunSummary` is returned (`source_error` says why a source died).

Memory stays flat over long runs: latencies go into fixed-bin histograms, keyframer errors
into a bounded list.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import StreamkeyError
from .io import SINK_FAILURE_LIMIT, Sink, Source
from .keyframes import Event, KeyframeEvent, StatusEvent
from .motion import Frame
from .online import OnlineKeyframer, Pipeline

__all__ = ["Engine", "RunSummary", "LatencyHistogram", "MAX_ERRORS_KEPT"]

MAX_ERRORS_KEPT = 20


class LatencyHistogram:
    """Streaming percentiles in fixed memory: log-spaced bins of ratio `1 + 2 * rel_error`
    from `low` to `high` ms (plus an underflow and an overflow bin). A percentile is the
    geometric centre of its bin, so it is within `rel_error` (0.5 %) of a value of that bin;
    max and count are exact. 1,850 bins, 15 KB, whatever the run length."""

    def __init__(self, low: float = 1e-3, high: float = 1e5, rel_error: float = 0.005) -> None:
        self.low = low
        self.step = math.log1p(2 * rel_error)
        self.n_bins = int(math.ceil(math.log(high / low) / self.step)) + 2
        self.counts = np.zeros(self.n_bins, dtype=np.int64)
        self.count = 0
        self.max = -math.inf

    def add(self, value: float) -> None:
        """Count one value (ms)."""
        if value < self.low:
            index = 0
        else:
            index = min(self.n_bins - 1, 1 + int(math.log(value / self.low) / self.step))
        self.counts[index] += 1
        self.count += 1
        self.max = max(self.max, value)

    def percentile(self, q: float) -> float | None:
        """The q-th percentile (0..100) within the bin error; None when empty."""
        if not self.count:
            return None
        rank = max(1, math.ceil(q / 100 * self.count))
        index = int(np.searchsorted(np.cumsum(self.counts), rank))
        if index == 0:
            return min(self.low, self.max)
        centre = self.low * math.exp((index - 0.5) * self.step)
        return min(centre, self.max)

    def summary(self) -> dict[str, float | None]:
        """p50 / p99 / max (ms), None before the first value."""
        return {"p50": self.percentile(50), "p99": self.percentile(99),
                "max": self.max if self.count else None}


@dataclass
class RunSummary:
    """What a run did: frames, drops, gaps, events per method and sink, wall latency."""

    frames_in: int = 0
    guard: dict[str, int] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    events: Counter[str] = field(default_factory=Counter)
    sinks: dict[str, dict[str, Any]] = field(default_factory=dict)
    latency: LatencyHistogram = field(default_factory=LatencyHistogram)
    method_latency: dict[str, LatencyHistogram] = field(default_factory=dict)
    seconds: float = 0.0
    errors: list[str] = field(default_factory=list)
    error_count: int = 0
    source_error: str | None = None
    left_in_queue: int = 0

    def latency_percentiles(self) -> dict[str, float | None]:
        """p50 / p99 / max of the wall latency (ms), None before the first event."""
        return self.latency.summary()

    def accounting(self) -> dict[str, Any]:
        """Where every frame that reached the source went (and what is known of the rest)."""
        g, s = self.guard, self.source
        return {
            "arrived": s.get("received", 0) + sum(s.get("malformed", {}).values()),
            "malformed": dict(s.get("malformed", {})), "queue_drops": s.get("queue_drops", 0),
            "left_in_queue": self.left_in_queue, "engine_in": self.frames_in,
            "duplicates": g.get("duplicates", 0), "out_of_order": g.get("out_of_order", 0),
            "invalid": g.get("invalid", 0), "processed": g.get("accepted", 0),
            "never_arrived": g.get("lost", 0), "bridged": g.get("bridged_frames", 0),
            "gaps": g.get("gaps", 0), "restarts": g.get("restarts", 0),
            "kernel_drops": s.get("kernel_drops")}

    def as_dict(self) -> dict[str, Any]:
        """The summary as a JSON-ready dict."""
        return {"frames_in": self.frames_in, "frames_lost": self.guard.get("lost", 0),
                "seconds": round(self.seconds, 3),
                "guard": self.guard, "source": self.source, "events": dict(self.events),
                "sinks": self.sinks, "wall_latency_ms": self.latency_percentiles(),
                "wall_latency_by_method": {m: h.summary()
                                           for m, h in self.method_latency.items()},
                "accounting": self.accounting(), "keyframer_errors": self.errors,
                "keyframer_error_count": self.error_count, "source_error": self.source_error}

    def text(self) -> str:
        """A few human-readable lines for the end of a run."""
        lat = self.latency_percentiles()
        a = self.accounting()
        malformed = ", ".join(f"{k} {v}" for k, v in sorted(a["malformed"].items()))
        kernel = ("not counted (this source is not a UDP socket on Linux)"
                  if a["kernel_drops"] is None else str(a["kernel_drops"]))
        lines = [
            f"frames in: {self.frames_in} in {self.seconds:.1f} s; "
            f"lost: {a['never_arrived']} (seq holes in {a['gaps']} gaps); dropped: "
            f"{a['duplicates']} duplicate, {a['out_of_order']} out of order, "
            f"{a['invalid']} invalid, {a['queue_drops']} queue; "
            f"malformed: {sum(a['malformed'].values())}" + (f" ({malformed})" if malformed
                                                            else ""),
            f"gaps: {a['gaps']} ({a['bridged']} frames bridged, {a['restarts']} restarts)",
            f"accounting: {a['arrived']} frames or packets arrived = "
            f"{sum(a['malformed'].values())} malformed + {a['queue_drops']} queue drops + "
            f"{a['left_in_queue']} unread at stop + {a['duplicates']} duplicate + "
            f"{a['out_of_order']} out of order + {a['invalid']} invalid + "
            f"{a['processed']} processed; {a['never_arrived']} frames never arrived "
            f"(seq holes); kernel receive drops: {kernel}",
            "events: " + (", ".join(f"{k} {v}" for k, v in sorted(self.events.items()))
                          or "none"),
        ]
        for name, st in self.sinks.items():
            lines.append(f"sink {name}: sent {st['sent']}, dropped {st['dropped']}"
                         + (f", errors {st['errors']}" if st.get("errors") else "")
                         + (" (disabled)" if st.get("disabled") else "")
                         + (f", last error: {st['last_error']}" if st.get("last_error") else "")
                         + (f"; not counted: {st['unseen_drops']}" if st.get("unseen_drops")
                            else ""))
        for error in self.errors[:5]:
            lines.append(f"keyframer error (window restarted): {error}")
        if self.error_count > 5:
            lines.append(f"... {self.error_count - 5} more keyframer errors")
        if lat["p50"] is not None:
            lines.append(f"wall latency (from the deciding frame's arrival): "
                         f"p50 {lat['p50']:.3f} ms, p99 {lat['p99']:.3f} ms, "
                         f"max {lat['max']:.3f} ms")
        if self.source_error:
            lines.append(f"source died: {self.source_error}")
        return "\n".join(lines)


KeyframerFactory = Callable[[Source], list[OnlineKeyframer]]


class Engine:
    """Wire a source to keyframers and sinks; `await run()` until the source ends or `stop()`."""

    def __init__(self, source: Source, make_keyframers: KeyframerFactory, sinks: list[Sink],
                 stream: str = "default",
                 on_ready: Callable[[str], None] | None = None,
                 on_event: Callable[[dict[str, Any]], None] | None = None,
                 idle_exit: float | None = None,
                 on_frame: Callable[[Frame], None] | None = None,
                 reset_on_gap: bool = False) -> None:
        self.source = source
        self.reset_on_gap = reset_on_gap  # a long gap forgets running statistics too
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
        self._skeleton_given = source.skeleton is not None
        self._sink_failures: dict[int, int] = {}
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
            if not self._stopping and self.pipeline is not None:
                await self._loop()
        finally:
            await self.source.close()
            if self.pipeline is not None:
                self._deliver(self._step(None, self.pipeline.flush), time.monotonic_ns())
            for sink in self.sinks:
                try:
                    await sink.close()
                except Exception as exc:  # a sink's fault is that sink's
                    self._sink_failed(sink, exc)
            self._finish_summary(started)
        return self.summary

    async def _wait_skeleton(self) -> None:
        """Wait for a usable skeleton (a bad one is counted and the next awaited), `stop()`
        or the source dying."""
        while self.pipeline is None and not self._stopping and self.source.fatal is None:
            waits = [asyncio.ensure_future(self._stop_event.wait()),
                     asyncio.ensure_future(self.source.skeleton_ready.wait()),
                     asyncio.ensure_future(self.source.dead.wait())]
            await asyncio.wait(waits, return_when=asyncio.FIRST_COMPLETED)
            for w in waits:
                w.cancel()
            if self.source.skeleton_ready.is_set() and not self._stopping:
                self._make_pipeline()

    def _make_pipeline(self) -> None:
        try:
            self.pipeline = Pipeline(self.make_keyframers(self.source), stream=self.stream,
                                     reset_on_gap=self.reset_on_gap)
            self._warm_up()
        except Exception as exc:
            self.pipeline = None
            if self._skeleton_given or not isinstance(exc, (StreamkeyError, ArithmeticError,
                                                            ValueError, IndexError)):
                raise
            self.source.refuse_skeleton(f"{type(exc).__name__}: {exc}")

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

    async def _next(self) -> tuple[Frame, int] | None:
        if self.idle_exit is not None and self.summary.frames_in:
            try:
                return await asyncio.wait_for(self.source.get(), self.idle_exit)
            except TimeoutError:
                return None
        return await self.source.get()

    async def _loop(self) -> None:
        assert self.pipeline is not None
        while (item := await self._next()) is not None:
            frame, arrival_ns = item
            self.summary.frames_in += 1
            self._deliver(self._step(frame.seq, self.pipeline.push, frame), arrival_ns)
            self._deliver(self._step(frame.seq, self.pipeline.idle), arrival_ns)
            if self.on_frame is not None:
                self.on_frame(frame)

    def _step(self, seq: int | None, call: Callable[..., list[Event]], *args: Any
              ) -> list[Event]:
        """One keyframer call; a fault is reported and the windows restarted."""
        try:
            return call(*args)
        except Exception as exc:  # a keyframer bug must not end the session or lose the log
            return self._contain(exc, seq)

    def _contain(self, exc: Exception, seq: int | None) -> list[Event]:
        """Report a keyframer failure as a status event and restart the window."""
        assert self.pipeline is not None
        self.summary.error_count += 1
        if len(self.summary.errors) < MAX_ERRORS_KEPT:
            self.summary.errors.append(f"{type(exc).__name__}: {exc} (at seq {seq})")
        for kf in self.pipeline.keyframers:
            kf.reset()
        self.pipeline.guard.reset()
        self.pipeline.features.reset()
        return [StatusEvent(self.stream, "*", "error",
                            {"error": f"{type(exc).__name__}: {exc}", "seq": seq})]

    def _deliver(self, events: list[Event], arrival_ns: int) -> None:
        """Stamp wall latency on keyframe events and hand every event to every sink."""
        for event in events:
            if isinstance(event, KeyframeEvent):
                latency = (time.monotonic_ns() - arrival_ns) / 1e6
                event = dataclasses.replace(event, wall_latency_ms=round(latency, 3))
                self.summary.latency.add(latency)
                per_method = self.summary.method_latency.get(event.method)
                if per_method is None:
                    per_method = self.summary.method_latency[event.method] = LatencyHistogram()
                per_method.add(latency)
                self.summary.events[event.method] += 1
            else:  # status, gap, provisional, cancel, signal
                self.summary.events[type(event).__name__.removesuffix("Event").lower()] += 1
            for sink in self.sinks:
                if sink.stats.disabled:
                    sink.stats.dropped += 1
                    continue
                try:
                    sink.offer(event)
                    self._sink_failures[id(sink)] = 0
                except Exception as exc:  # a sink's fault is that sink's
                    self._sink_failed(sink, exc)
            if self.on_event is not None:
                self.on_event(event.to_dict())
        if events:
            for sink in self.sinks:
                if not sink.stats.disabled:
                    try:
                        sink.end_batch(arrival_ns)
                    except Exception as exc:  # a sink's fault is that sink's
                        self._sink_failed(sink, exc)

    def _sink_failed(self, sink: Sink, exc: Exception) -> None:
        stats = sink.stats
        stats.errors += 1
        stats.dropped += 1
        stats.last_error = f"{type(exc).__name__}: {exc}"
        failures = self._sink_failures[id(sink)] = self._sink_failures.get(id(sink), 0) + 1
        if failures >= SINK_FAILURE_LIMIT and not stats.disabled:
            stats.disabled = True
            self.on_ready(f"sink {sink.name} disabled after {failures} failures in a row: "
                          f"{stats.last_error}")

    def _finish_summary(self, started: float) -> None:
        self.summary.seconds = time.monotonic() - started
        if self.pipeline is not None:
            self.summary.guard = self.pipeline.guard.counters.as_dict()
        self.summary.source = self.source.counters().as_dict()
        self.summary.source_error = None if self._stopping else self.source.fatal
        self.summary.left_in_queue = sum(1 for item in self.source.frames.queue._queue
                                         if item is not None)
        for sink in self.sinks:
            key = sink.name
            n = 2
            while key in self.summary.sinks:
                key, n = f"{sink.name}#{n}", n + 1
            self.summary.sinks[key] = sink.stats.as_dict()
