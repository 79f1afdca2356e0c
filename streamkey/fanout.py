"""The sinks of a run: every event to every sink, log sinks first, each sink's faults its own.

An event is on disk (the JSON Lines log) before any network peer sees it. A sink that raises
is counted in its `SinkStats` and disabled after `SINK_FAILURE_LIMIT` failures in a row; the
other sinks and the keyframers never notice.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .io import SINK_FAILURE_LIMIT, Sink
from .keyframes import Event

__all__ = ["SinkFanout"]


class SinkFanout:
    """Hand events to sinks (`offer`, `end_batch`), contain their faults, close them."""

    def __init__(self, sinks: list[Sink], say: Callable[[str], None]) -> None:
        self.sinks = sorted(sinks, key=lambda s: s.live)  # log sinks first
        self._say = say
        self._failures: dict[int, int] = {}

    async def start(self) -> None:
        """Open every sink, saying where each one sends."""
        for sink in self.sinks:
            self._say(f"sending to {await sink.start()}")

    def offer(self, event: Event) -> None:
        """One event to every sink (a disabled sink counts it as dropped)."""
        for sink in self.sinks:
            if sink.stats.disabled:
                sink.stats.dropped += 1
                continue
            try:
                sink.offer(event)
                self._failures[id(sink)] = 0
            except Exception as exc:  # a sink's fault is that sink's
                self.failed(sink, exc)

    def end_batch(self, arrival_ns: int) -> None:
        """The events offered since the last call belong to the frame that arrived at
        `arrival_ns` (sinks that bundle them send now)."""
        for sink in self.sinks:
            if not sink.stats.disabled:
                try:
                    sink.end_batch(arrival_ns)
                except Exception as exc:  # a sink's fault is that sink's
                    self.failed(sink, exc)

    async def close(self) -> None:
        """Drain and close every sink."""
        for sink in self.sinks:
            try:
                await sink.close()
            except Exception as exc:  # a sink's fault is that sink's
                self.failed(sink, exc)

    def failed(self, sink: Sink, exc: Exception) -> None:
        """Count a sink's failure; disable it after `SINK_FAILURE_LIMIT` in a row."""
        stats = sink.stats
        stats.errors += 1
        stats.dropped += 1
        stats.last_error = f"{type(exc).__name__}: {exc}"
        failures = self._failures[id(sink)] = self._failures.get(id(sink), 0) + 1
        if failures >= SINK_FAILURE_LIMIT and not stats.disabled:
            stats.disabled = True
            self._say(f"sink {sink.name} disabled after {failures} failures in a row: "
                      f"{stats.last_error}")

    def stats(self) -> dict[str, dict[str, Any]]:
        """Each sink's counters by name (`name#2`, ... for a second sink of a kind)."""
        out: dict[str, dict[str, Any]] = {}
        for sink in self.sinks:
            key, n = sink.name, 2
            while key in out:
                key, n = f"{sink.name}#{n}", n + 1
            out[key] = sink.stats.as_dict()
        return out
