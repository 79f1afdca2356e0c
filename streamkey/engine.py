"""The asyncio engine: one source -> a pipeline of N online keyframers per stream -> M sinks
(DESIGN §2).

The path is one-way, as between `websockets`' sans-I/O protocol and its connection:

- Frames carry a stream tag; each stream gets its own `Pipeline`, built from its skeleton,
  up to `max_streams` (more are refused and counted), retired after `stream_idle` seconds
  without a frame. Due decisions first: every queued frame's `push`, of every stream, runs
  before any stream's deferred `idle`, so one stream's re-analysis burst does not delay
  another stream's due event; a stream's own order (and so its events) is unchanged.

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
import gc
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import Any

import numpy as np

from . import jit
from .errors import StreamkeyError
from .framequeue import FrameArrived, QueueItem, SkeletonAnnounced, SourceEnded
from .io import DEFAULT_MAX_STREAMS, SINK_FAILURE_LIMIT, Sink, Source, StreamSpec
from .keyframes import Event, KeyframeEvent, StatusEvent
from .motion import Frame
from .online import GuardCounters, OnlineKeyframer, Pipeline
from .summary import (
    MAX_ERRORS_KEPT,
    EngineStatistics,
    LatencyHistogram,
    RunSummary,
    StreamStats,
)

__all__ = ["Engine", "RunSummary", "StreamStats", "LatencyHistogram", "MAX_ERRORS_KEPT",
           "EngineStatistics"]



KeyframerFactory = Callable[[Any], list[OnlineKeyframer]]
"""Builds a stream's keyframers from a `StreamSpec` (`.stream`, `.skeleton`, `.fps`)."""

MAX_WAITING_FRAMES = 256     # frames a stream may hold while its skeleton has not come
MAX_STREAM_STATS = 256       # streams named in the summary; the rest are summed in "(other)"
MAX_REFUSALS_SAID = 20       # refused stream ids said on the ready channel (all are counted)




class _Stream:
    """A live stream: its pipeline and where its frames and deferred work stand."""

    def __init__(self, name: str, tag: str | None, pipeline: Pipeline,
                 stats: StreamStats) -> None:
        self.name, self.tag, self.pipeline, self.stats = name, tag, pipeline, stats
        self.last_frame = time.monotonic()
        self.last_arrival_ns = 0
        self.seq: int | None = None


class Engine:
    """Wire a source to keyframers and sinks; `await run()` until the source ends or `stop()`.

    One engine serves any number of streams (up to `max_streams`): frames carry a stream tag
    from the source (None: the unnamed stream, called `stream`); a stream's pipeline is built
    from its skeleton (or the shared one) and retired after `stream_idle` seconds without a
    frame. With `due_first` the deferred re-analysis (`Pipeline.idle`) of every stream waits
    until no frame is queued, so one stream's burst never delays another stream's due event.
    With `freeze_gc` (the CLI's `run`) the heap loaded at start-up is frozen out of the
    garbage collector for the run (`_freeze_heap`).
    """

    def __init__(self, source: Source, make_keyframers: KeyframerFactory, sinks: list[Sink],
                 stream: str = "default",
                 on_ready: Callable[[str], None] | None = None,
                 on_event: Callable[[dict[str, Any]], None] | None = None,
                 idle_exit: float | None = None,
                 on_frame: Callable[[Frame], None] | None = None,
                 reset_on_gap: bool = False, max_streams: int = DEFAULT_MAX_STREAMS,
                 stream_idle: float | None = None, due_first: bool = True,
                 freeze_gc: bool = False) -> None:
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
        self.max_streams = max_streams
        self.stream_idle = stream_idle
        self.due_first = due_first
        self.freeze_gc = freeze_gc
        source.max_streams = max_streams
        self.summary = RunSummary(max_streams=max_streams)
        self.streams: dict[str, _Stream] = {}
        self._waiting: dict[str, deque[tuple[Frame, int]]] = {}  # streams without skeleton
        self._waiting_seen: dict[str, float] = {}
        self._deferred: dict[str, _Stream] = {}  # streams whose re-analysis is pending
        self._said_refused: set[str] = set()
        self._warm = False
        self._prebuilt: tuple[tuple[Any, float], Pipeline] | None = None  # (skeleton, fps)
        self._last_frame = time.monotonic()
        self._next_retire = 0.0
        self._sink_failures: dict[int, int] = {}
        self._stopping = False

    @property
    def pipeline(self) -> Pipeline | None:
        """The pipeline of the unnamed stream (else the first live one); None before any."""
        state = self.streams.get(self.stream) or next(iter(self.streams.values()), None)
        return None if state is None else state.pipeline

    def statistics(self) -> EngineStatistics:
        """A read-only snapshot of the run's counters (for live views)."""
        src = self.source.counters()
        pipeline = self.pipeline
        return EngineStatistics(
            frames_in=self.summary.frames_in, events=dict(self.summary.events),
            source_drops=src.queue_drops + sum(src.malformed.values()),
            guard={} if pipeline is None else pipeline.guard.counters.as_dict(),
            lookahead={} if pipeline is None else {kf.method: kf.lookahead
                                                   for kf in pipeline.keyframers},
            skeleton=self.source.skeleton, fps=self.source.fps)

    def saliency_trace(self) -> tuple[tuple[int, float], ...]:
        """The per-frame saliency (seq, level) the main stream's online saliency keyframer
        keeps for live views (its last 20 s); empty without one."""
        pipeline = self.pipeline
        trace = next((getattr(kf, "trace", None) for kf in (pipeline.keyframers if pipeline
                      else []) if kf.method == "saliency"), None)
        return tuple(trace) if trace else ()

    def stop(self) -> None:
        """Ask the run to end: the source stops, keyframers flush, sinks drain."""
        self._stopping = True
        self.source.frames.end()

    async def run(self) -> RunSummary:
        """Run until the source ends or `stop()`; returns the summary."""
        started = time.monotonic()
        for sink in self.sinks:
            self.on_ready(f"sending to {await sink.start()}")
        try:
            known = self.source.skeleton_for(None)
            if known is not None:  # known skeleton: ready (and warm) before frames flow
                self._warm_up(StreamSpec(self.stream, *known))
                if not self.source.shared_skeleton:
                    self._open(self.stream, None)
                else:  # it may serve tagged streams only: built now, opened by a frame
                    self._prebuilt = (known, self._build(StreamSpec(self.stream, *known)))
            if not self._warm:  # the skeleton comes from the wire: warm up on a built-in
                self._warm_up_without_skeleton()  # rig, not while its first frames wait
            self.on_ready(f"listening on {await self.source.start()}")
            if not self._stopping:
                await self._loop()
        finally:
            if self.freeze_gc:
                gc.unfreeze()
            await self.source.close()
            for state in list(self.streams.values()):
                self._retire(state)
            for sink in self.sinks:
                try:
                    await sink.close()
                except Exception as exc:  # a sink's fault is that sink's
                    self._sink_failed(sink, exc)
            self._finish_summary(started)
        return self.summary

    # ------------------------------------------------------------------ streams

    def _stats(self, name: str) -> StreamStats:
        stats = self.summary.streams.get(name)
        if stats is None:
            if len(self.summary.streams) >= MAX_STREAM_STATS:
                name = "(other)"
            stats = self.summary.streams.setdefault(name, StreamStats())
        return stats

    def _open(self, name: str, tag: str | None, frame: bool = True) -> _Stream | None:
        """The live stream `name`, built now if its skeleton is known; None if it waits for
        its skeleton or is refused (counted either way; `frame`: a frame asked for it)."""
        state = self.streams.get(name)
        if state is not None:
            return state
        if len(self.streams) + len(self._waiting) - (name in self._waiting) >= self.max_streams:
            self._refuse(name, frame)
            self.source.forget_stream(tag)
            return None
        known = self.source.skeleton_for(tag)
        if known is None:
            self._waiting.setdefault(name, deque())
            self._waiting_seen.setdefault(name, time.monotonic())
            return None
        spec = StreamSpec(name, *known)
        prebuilt, self._prebuilt = self._prebuilt, None
        try:
            if not self._warm:
                self._warm_up(spec)
            if prebuilt is not None and tag is None and prebuilt[0][0] is known[0] and (
                    prebuilt[0][1] == known[1]):
                pipeline = prebuilt[1]
            else:
                pipeline = self._build(spec)
        except Exception as exc:
            if self.source.shared_skeleton or not isinstance(
                    exc, (StreamkeyError, ArithmeticError, ValueError, IndexError)):
                raise
            self.source.refuse_skeleton(f"{type(exc).__name__}: {exc}", tag)
            self._waiting.setdefault(name, deque())
            self._waiting_seen.setdefault(name, time.monotonic())
            return None
        state = self.streams[name] = _Stream(name, tag, pipeline, self._stats(name))
        state.stats.sessions += 1
        self._waiting_seen.pop(name, None)
        for held, arrival_ns in self._waiting.pop(name, ()):
            self._push(state, held, arrival_ns)
        return state

    def _refuse(self, name: str, frame: bool) -> None:
        self.summary.refused_frames += frame
        if name in self._said_refused:
            return
        self.summary.refused_streams += 1
        if len(self._said_refused) < MAX_REFUSALS_SAID:
            self._said_refused.add(name)
            self.on_ready(f"stream {name!r} refused: this run already serves "
                          f"{self.max_streams} streams (--max-streams); its frames are "
                          "dropped and counted")

    def _retire(self, state: _Stream) -> None:
        """End a stream: flush its pipeline, keep its counters, free its place."""
        self._deferred.pop(state.name, None)
        self._deliver(self._step(state, None, state.pipeline.flush), time.monotonic_ns(),
                      state, due=False, timed=False)
        for key, value in state.pipeline.guard.counters.as_dict().items():
            state.stats.guard[key] += value
        state.stats.retired += 1
        del self.streams[state.name]
        self.source.forget_stream(state.tag)

    def _retire_idle(self, now: float) -> None:
        if self.stream_idle is None or now < self._next_retire:
            return
        self._next_retire = now + min(0.25, self.stream_idle / 4)
        for state in [s for s in self.streams.values()
                      if now - s.last_frame > self.stream_idle]:
            self._retire(state)
            self.on_ready(f"stream {state.name!r} retired after {self.stream_idle:g} s "
                          "without a frame")
        for name in [n for n, seen in self._waiting_seen.items()
                     if now - seen > self.stream_idle]:
            self._stats(name).waiting_drops += len(self._waiting.pop(name, ()))
            del self._waiting_seen[name]

    def _warm_up(self, spec: StreamSpec) -> None:
        """Compile (or load) the numba kernels of the modules the keyframers imported and
        push a few rest-pose frames through a throwaway copy of them, so that first-call
        costs (compilation, lazy imports, FK plans, BLAS start-up) are not paid by the first
        real decision's latency."""
        self._load_kernels()
        spare = Pipeline(self.make_keyframers(spec), stream=spec.stream)
        jit.warm_up()  # modules the keyframers imported just now
        rest = np.zeros(spec.skeleton.n_channels)
        for seq in range(3):
            spare.push(Frame(seq, seq / spec.fps, rest))
        spare.flush()
        self._warm = True
        self._freeze_heap()

    def _build(self, spec: StreamSpec) -> Pipeline:
        return Pipeline(self.make_keyframers(spec), stream=spec.stream,
                        reset_on_gap=self.reset_on_gap)

    def _warm_up_without_skeleton(self) -> None:
        """Warm up before listening when the skeleton will come from the wire: on the
        built-in humanoid rig, so the method modules are imported and their kernels loaded
        before the first frames wait for them (~0.4 s with all methods). If the keyframers
        refuse that rig (a `--roles` mapping of another rig), the kernels loaded so far."""
        from .rigs import humanoid_skeleton

        try:
            self._warm_up(StreamSpec(self.stream, humanoid_skeleton(), 120.0))
        except (StreamkeyError, ValueError, KeyError, IndexError):
            self._load_kernels()
            self._freeze_heap()

    def _load_kernels(self) -> None:
        """Compile or load every numba kernel imported so far (`jit.warm_up()`), saying so
        when they compile for a new machine (once, tens of seconds) instead of pausing."""
        if jit.cache_is_cold():
            self.on_ready("compiling the numba kernels for this machine (once, up to a "
                          "minute; later runs load them from the cache)")
        jit.warm_up()

    def _freeze_heap(self) -> None:
        """With `freeze_gc`: collect once, then move every object alive now (modules,
        compiled kernels, the pipelines) out of the collector's reach, so a full collection
        during the stream scans only what the stream allocated (it took 12-14 ms with all
        methods loaded; `gc.unfreeze()` at the end of the run)."""
        if self.freeze_gc:
            gc.collect()
            gc.freeze()

    def snapshot_stream(self, name: str) -> bytes:
        """Snapshot of live stream `name`'s pipeline (`snapshot.py`); KeyError if not live."""
        return self.streams[name].pipeline.snapshot()

    def restore_stream(self, name: str, data: bytes, params: str | None = None) -> None:
        """Serve stream `name` from a snapshot from now on (a worker taking over a stream);
        a live pipeline of that name is replaced unflushed. `SnapshotError` if it does not
        fit (`params`: the digest it must carry)."""
        pipeline = Pipeline.restore(data, params)
        self._deferred.pop(name, None)
        self._waiting.pop(name, None)
        self._waiting_seen.pop(name, None)
        tag = None if name == self.stream else name
        state = self.streams[name] = _Stream(name, tag, pipeline, self._stats(name))
        state.stats.sessions += 1
        if pipeline.guard.last is not None:
            state.seq = pipeline.guard.last.seq
        if pipeline._idle_due:  # the re-analysis of its last frame had not run yet
            self._deferred[name] = state

    # ------------------------------------------------------------------ the loop

    async def _loop(self) -> None:
        queue = self.source.frames
        while True:
            if queue.empty():
                if self._deferred:  # every due decision is out: one stream's re-analysis
                    state = self._deferred.pop(next(iter(self._deferred)))
                    self._deliver(self._step(state, state.seq, state.pipeline.idle),
                                  state.last_arrival_ns, state, due=False)
                    await asyncio.sleep(0)  # let the sources queue what came meanwhile
                    continue
                item = await self._wait()
                if item is _TIMEOUT:
                    if self.idle_exit is not None and self.summary.frames_in and (
                            time.monotonic() - self._last_frame >= self.idle_exit):
                        return
                    self._retire_idle(time.monotonic())
                    continue
            else:
                item = queue.get_nowait()
            match item:
                case FrameArrived(frame=frame, arrival_ns=arrival_ns, stream=tag):
                    self._handle(frame, arrival_ns, tag)
                case SkeletonAnnounced(stream=tag):  # build the pipeline before its frames
                    name = self.stream if tag is None else tag
                    if name not in self.streams:
                        self._open(name, tag, frame=False)
                case SourceEnded():
                    return

    async def _wait(self) -> QueueItem | object:
        """The next queue item, or `_TIMEOUT` when a stream may be due for retirement or
        the run for its idle exit."""
        waits = []
        if self.idle_exit is not None and self.summary.frames_in:
            waits.append(self._last_frame + self.idle_exit - time.monotonic())
        if self.stream_idle is not None and (self.streams or self._waiting):
            waits.append(min(0.25, self.stream_idle / 4))
        if not waits:
            return await self.source.get()
        try:
            return await asyncio.wait_for(self.source.get(), max(0.0, min(waits)))
        except TimeoutError:
            return _TIMEOUT

    def _handle(self, frame: Frame, arrival_ns: int, tag: str | None) -> None:
        name = self.stream if tag is None else tag
        self.summary.frames_in += 1
        now = self._last_frame = time.monotonic()
        state = self.streams.get(name) or self._open(name, tag)
        if state is None:
            waiting = self._waiting.get(name)
            if waiting is not None:
                self._waiting_seen[name] = now
                if len(waiting) >= MAX_WAITING_FRAMES:
                    waiting.popleft()
                    self._stats(name).waiting_drops += 1
                waiting.append((frame, arrival_ns))
            self._retire_idle(now)
            return
        state.last_frame = now
        self._push(state, frame, arrival_ns)
        if self.on_frame is not None:
            self.on_frame(frame)
        self._retire_idle(now)

    def _push(self, state: _Stream, frame: Frame, arrival_ns: int) -> None:
        """One frame of a stream: the pending re-analysis of its previous frame first (the
        stream's own order), then the due decisions; this frame's re-analysis is deferred."""
        if self._deferred.pop(state.name, None) is not None:
            self._deliver(self._step(state, state.seq, state.pipeline.idle),
                          state.last_arrival_ns, state, due=False)
        state.stats.frames_in += 1
        state.seq, state.last_arrival_ns = frame.seq, arrival_ns
        self.summary.frame_wait.add((time.monotonic_ns() - arrival_ns) / 1e6)
        self._deliver(self._step(state, frame.seq, state.pipeline.push, frame), arrival_ns,
                      state, due=True)
        if self.due_first:
            self._deferred[state.name] = state
        else:
            self._deliver(self._step(state, frame.seq, state.pipeline.idle), arrival_ns,
                          state, due=False)

    def _step(self, state: _Stream, seq: int | None, call: Callable[..., list[Event]],
              *args: Any) -> list[Event]:
        """One keyframer call; a fault is reported and the stream's windows restarted."""
        try:
            return call(*args)
        except Exception as exc:  # a keyframer bug must not end the session or lose the log
            return self._contain(state, exc, seq)

    def _contain(self, state: _Stream, exc: Exception, seq: int | None) -> list[Event]:
        """Report a keyframer failure as a status event and restart the stream's window."""
        self.summary.error_count += 1
        if len(self.summary.errors) < MAX_ERRORS_KEPT:
            where = "" if len(self.summary.streams) < 2 else f" in stream {state.name!r}"
            self.summary.errors.append(f"{type(exc).__name__}: {exc} (at seq {seq}){where}")
        pipeline = state.pipeline
        for kf in pipeline.keyframers:
            kf.reset()
        pipeline.guard.reset()
        pipeline.features.reset()
        return [StatusEvent(state.name, "*", "error",
                            {"error": f"{type(exc).__name__}: {exc}", "seq": seq})]

    def _deliver(self, events: list[Event], arrival_ns: int, state: _Stream | None = None,
                 due: bool = False, timed: bool = True) -> None:
        """Stamp wall latency on keyframe events and hand every event to every sink. Events
        of a stream's end (`timed` False: no frame decided them, the flush did) are stamped
        from the flush but kept out of the latency percentiles and counted apart."""
        for event in events:
            if isinstance(event, KeyframeEvent):
                latency = (time.monotonic_ns() - arrival_ns) / 1e6
                event = dataclasses.replace(event, wall_latency_ms=round(latency, 3))
                self.summary.events[event.method] += 1
                if state is not None:
                    state.stats.events[event.method] += 1
                if timed:
                    self._time(event.method, latency, state if due else None, due)
                else:
                    self.summary.untimed_events += 1
            else:  # status, gap, provisional, cancel, signal
                self.summary.events[type(event).__name__.removesuffix("Event").lower()] += 1
            self._offer(event)
        if events:
            for sink in self.sinks:
                if not sink.stats.disabled:
                    try:
                        sink.end_batch(arrival_ns)
                    except Exception as exc:  # a sink's fault is that sink's
                        self._sink_failed(sink, exc)

    def _time(self, method: str, latency: float, state: _Stream | None, due: bool) -> None:
        self.summary.latency.add(latency)
        per_method = self.summary.method_latency.get(method)
        if per_method is None:
            per_method = self.summary.method_latency[method] = LatencyHistogram()
        per_method.add(latency)
        if due:
            self.summary.due_latency.add(latency)
        if state is not None:
            state.stats.due_latency.add(latency)

    def _offer(self, event: Event) -> None:
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
        guard: Counter[str] = Counter()
        for stats in self.summary.streams.values():
            guard.update(stats.guard)
        if self.summary.streams:
            self.summary.guard = {k: guard.get(k, 0) for k in GuardCounters().as_dict()}
        self.summary.source = self.source.counters().as_dict()
        self.summary.source_error = None if self._stopping else self.source.fatal
        self.summary.left_in_queue = self.source.frames.statistics().frames
        self.summary.waiting_at_stop = sum(len(q) for q in self._waiting.values())
        for sink in self.sinks:
            key = sink.name
            n = 2
            while key in self.summary.sinks:
                key, n = f"{sink.name}#{n}", n + 1
            self.summary.sinks[key] = sink.stats.as_dict()


_TIMEOUT = object()
