"""What a run did and what a running engine shows: `RunSummary` (frames, drops, gaps, events
per method and sink, wall latency; its `text()` ends a run), `StreamStats` per stream,
`LatencyHistogram` (percentiles in fixed memory, so long runs stay flat), and
`EngineStatistics`, the read-only snapshot live views (the dashboard) read instead of the
engine's internals.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .io import DEFAULT_MAX_STREAMS
from .motion import Skeleton

__all__ = ["RunSummary", "RunLatency", "StreamStats", "LatencyHistogram", "EngineStatistics",
           "MAX_ERRORS_KEPT"]

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

    def merge(self, other: LatencyHistogram) -> None:
        """Count `other`'s values too (same bins: another process's histogram)."""
        if other.n_bins != self.n_bins or other.step != self.step or other.low != self.low:
            raise ValueError("latency histograms of different bins cannot be merged")
        self.counts += other.counts
        self.count += other.count
        self.max = max(self.max, other.max)

    def summary(self) -> dict[str, float | None]:
        """p50 / p99 / max (ms), None before the first value."""
        return {"p50": self.percentile(50), "p99": self.percentile(99),
                "max": self.max if self.count else None}


@dataclass
class RunLatency:
    """The wall latency of a run's keyframe events (ms, from the arrival of the frame whose
    push decided each), and what it leaves out: keys decided by a stream's end."""

    events: LatencyHistogram = field(default_factory=LatencyHistogram)  # every timed key
    by_method: dict[str, LatencyHistogram] = field(default_factory=dict)
    due: LatencyHistogram = field(default_factory=LatencyHistogram)  # decided by the push
    frame_wait: LatencyHistogram = field(default_factory=LatencyHistogram)  # before a push
    untimed: int = 0  # keyframes decided by a stream's end, not by a frame


@dataclass
class RunSummary:
    """What a run did: frames, drops, gaps, events per method and sink, wall latency
    (`timing`; its histograms are also readable and settable under their older names,
    `latency`, `method_latency`, `due_latency`, `frame_wait`, `untimed_events`)."""

    frames_in: int = 0
    guard: dict[str, int] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    events: Counter[str] = field(default_factory=Counter)
    sinks: dict[str, dict[str, Any]] = field(default_factory=dict)
    timing: RunLatency = field(default_factory=RunLatency)
    seconds: float = 0.0
    errors: list[str] = field(default_factory=list)
    error_count: int = 0
    source_error: str | None = None
    left_in_queue: int = 0
    streams: dict[str, StreamStats] = field(default_factory=dict)
    max_streams: int = DEFAULT_MAX_STREAMS
    refused_streams: int = 0
    refused_frames: int = 0
    waiting_at_stop: int = 0
    # `TurnStats.as_dict()`; with `run --workers`, "workers": each worker's counters
    scheduler: dict[str, Any] = field(default_factory=dict)

    @property
    def latency(self) -> LatencyHistogram:
        """Wall latency of every timed keyframe event (`timing.events`)."""
        return self.timing.events

    @latency.setter
    def latency(self, value: LatencyHistogram) -> None:
        self.timing.events = value

    @property
    def method_latency(self) -> dict[str, LatencyHistogram]:
        """Wall latency per method (`timing.by_method`)."""
        return self.timing.by_method

    @method_latency.setter
    def method_latency(self, value: dict[str, LatencyHistogram]) -> None:
        self.timing.by_method = value

    @property
    def due_latency(self) -> LatencyHistogram:
        """Wall latency of the keys a push decided (`timing.due`)."""
        return self.timing.due

    @due_latency.setter
    def due_latency(self, value: LatencyHistogram) -> None:
        self.timing.due = value

    @property
    def frame_wait(self) -> LatencyHistogram:
        """How long frames waited before their push (`timing.frame_wait`)."""
        return self.timing.frame_wait

    @frame_wait.setter
    def frame_wait(self, value: LatencyHistogram) -> None:
        self.timing.frame_wait = value

    @property
    def untimed_events(self) -> int:
        """Keyframes decided by a stream's end, not timed (`timing.untimed`)."""
        return self.timing.untimed

    @untimed_events.setter
    def untimed_events(self, value: int) -> None:
        self.timing.untimed = value

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
            "kernel_drops": s.get("kernel_drops"), "refused_streams": self.refused_frames,
            "waiting_for_skeleton": self.waiting_at_stop + sum(
                st.waiting_drops for st in self.streams.values())}

    def as_dict(self) -> dict[str, Any]:
        """The summary as a JSON-ready dict."""
        return {"frames_in": self.frames_in, "frames_lost": self.guard.get("lost", 0),
                "seconds": round(self.seconds, 3),
                "guard": self.guard, "source": self.source, "events": dict(self.events),
                "sinks": self.sinks, "wall_latency_ms": self.latency_percentiles(),
                "wall_latency_by_method": {m: h.summary()
                                           for m, h in self.method_latency.items()},
                "accounting": self.accounting(), "keyframer_errors": self.errors,
                "keyframer_error_count": self.error_count, "source_error": self.source_error,
                "due_latency_ms": self.due_latency.summary(),
                "frame_wait_ms": self.frame_wait.summary(),
                "keyframes_at_stream_end": self.untimed_events,
                "streams": {n: st.as_dict() for n, st in self.streams.items()},
                "scheduler": self.scheduler,
                "max_streams": self.max_streams, "refused_streams": self.refused_streams,
                "refused_frames": self.refused_frames, "waiting_at_stop": self.waiting_at_stop}

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
            + (f"{a['refused_streams']} of refused streams + " if a["refused_streams"] else "")
            + (f"{a['waiting_for_skeleton']} waiting for a skeleton + "
               if a["waiting_for_skeleton"] else "")
            + f"{a['processed']} processed; {a['never_arrived']} frames never arrived "
            f"(seq holes); kernel receive drops: {kernel}",
            "events: " + (", ".join(f"{k} {v}" for k, v in sorted(self.events.items()))
                          or "none"),
        ]
        for name, st in self.sinks.items():
            lines.append(f"sink {name}: sent {st['sent']}, dropped {st['dropped']}"
                         + (f", errors {st['errors']}" if st.get("errors") else "")
                         + (f", duplicates skipped {st['duplicates']}" if st.get("duplicates")
                            else "")
                         + (" (disabled)" if st.get("disabled") else "")
                         + (f", last error: {st['last_error']}" if st.get("last_error") else "")
                         + (f"; not counted: {st['unseen_drops']}" if st.get("unseen_drops")
                            else ""))
        if len(self.streams) > 1 or self.refused_streams:
            lines.append(f"streams: {len(self.streams)} served, {self.refused_streams} refused "
                         f"({self.refused_frames} frames; --max-streams {self.max_streams})")
            for name, ss in list(self.streams.items())[:16]:
                due = ss.due_latency.summary()
                lines.append(f"stream {name}: frames in {ss.frames_in}, events "
                             + (", ".join(f"{k} {v}" for k, v in sorted(ss.events.items()))
                                or "none")
                             + f", gaps {ss.guard.get('gaps', 0)}, sessions {ss.sessions}"
                             + (f", due p99 {due['p99']:.2f} ms, max {due['max']:.2f} ms"
                                if due["p99"] is not None else "")
                             + (f", {ss.waiting_drops} dropped waiting for its skeleton"
                                if ss.waiting_drops else ""))
            if len(self.streams) > 16:
                lines.append(f"... {len(self.streams) - 16} more streams (see --summary)")
        for i, w in enumerate(self.scheduler.get("workers", [])):
            due = w["due_latency_ms"]
            lines.append(f"worker {i} (pid {w['pid']}): {w['streams_placed']} streams placed, "
                         f"frames in {w['frames_in']}, CPU {w['cpu_seconds']:.1f} s"
                         + (f", due p99 {due['p99']:.2f} ms, max {due['max']:.2f} ms"
                            if due["p99"] is not None else ""))
        for error in self.errors[:5]:
            lines.append(f"keyframer error (window restarted): {error}")
        if self.error_count > 5:
            lines.append(f"... {self.error_count - 5} more keyframer errors")
        if lat["p50"] is not None:
            wait = self.frame_wait.summary()
            lines.append(f"wall latency (from the deciding frame's arrival): "
                         f"p50 {lat['p50']:.3f} ms, p99 {lat['p99']:.3f} ms, "
                         f"max {lat['max']:.3f} ms; frames waited before their push: "
                         f"p50 {wait['p50'] or 0:.3f} ms, p99 {wait['p99'] or 0:.3f} ms"
                         + (f" ({self.untimed_events} keyframes decided by a stream's end "
                            "not timed)" if self.untimed_events else ""))
        if self.source_error:
            lines.append(f"source died: {self.source_error}")
        return "\n".join(lines)


@dataclass
class StreamStats:
    """Counters of one stream over the run (all its sessions: a retired stream may return)."""

    frames_in: int = 0
    sessions: int = 0
    retired: int = 0
    waiting_drops: int = 0
    events: Counter[str] = field(default_factory=Counter)
    guard: Counter[str] = field(default_factory=Counter)
    due_latency: LatencyHistogram = field(default_factory=LatencyHistogram)

    def merge(self, other: StreamStats) -> None:
        """Add `other`'s counters (the same stream id served by another process)."""
        self.frames_in += other.frames_in
        self.sessions += other.sessions
        self.retired += other.retired
        self.waiting_drops += other.waiting_drops
        self.events.update(other.events)
        self.guard.update(other.guard)
        self.due_latency.merge(other.due_latency)

    def as_dict(self) -> dict[str, Any]:
        """Counters as a plain dict (latency: the due events' p50 / p99 / max, ms)."""
        return {"frames_in": self.frames_in, "sessions": self.sessions,
                "retired": self.retired, "waiting_drops": self.waiting_drops,
                "events": dict(self.events), "guard": dict(self.guard),
                "due_latency_ms": self.due_latency.summary()}

@dataclass(frozen=True, slots=True)
class EngineStatistics:
    """A snapshot of a running engine (`Engine.statistics()`): counters copied at the call,
    so a reader never holds or changes the engine's own state.

    `guard` and `lookahead` are of the engine's main stream (the unnamed one, else the first
    live one; empty before any); `skeleton` / `fps` the source's (the unnamed stream's or the
    shared one), None until known."""

    frames_in: int
    events: Mapping[str, int]
    source_drops: int               # frames dropped by the queue + malformed messages
    guard: Mapping[str, int]        # `GuardCounters.as_dict()` of the main stream
    lookahead: Mapping[str, int]    # method -> frames of lookahead, main stream
    skeleton: Skeleton | None
    fps: float | None
