"""The asyncio engine: one source -> a pipeline of N online keyframers per stream -> M sinks.

The path is one-way, as between `websockets`' sans-I/O protocol and its connection:

- Frames carry a stream tag; each stream gets its own `Pipeline`, built from its skeleton,
  up to `max_streams` (more are refused and counted), retired after `stream_idle` seconds
  without a frame: the `StreamTable` (`streamkey.streamtable`, sans-I/O) keeps that state,
  this module is the asyncio around it. The order of work is the `Scheduler`'s
  (`streamkey.scheduler`, sans-I/O): due decisions first (every queued frame's `push`, of
  every stream, oldest arrival first, before any stream's deferred `idle`), so one stream's
  re-analysis burst does not delay another stream's due event; a stream's own order (and so
  its events) is unchanged; and work runs in turns of `turn_budget_ms`, between which the
  sources read their sockets while the engine keeps up (its queue under half full), so
  frames wait in the engine's queue (stamped with their kernel arrival) rather than
  overflow the kernel's receive buffer.

- Frames come from the source's bounded queue (network sources drop the oldest frame when
  the engine falls behind, and count it), each stamped with its arrival time (the kernel's
  receive time where the source can read it).
- `Pipeline.push` returns the events due with a frame and `Pipeline.idle` the deferred ones
  (a re-analysis); keyframer faults are caught around those calls only, reported as a
  status event and the windows restarted (`StreamTable.step`, the one fault policy).
- The engine stamps each `KeyframeEvent` with its wall latency (`dataclasses.replace`) and
  hands the typed events to the sinks (`SinkFanout`: log sinks first, a sink's fault is that
  sink's, it never touches the keyframers).
- `stop()` (Ctrl-C / SIGTERM in the CLI), `idle_exit` seconds without a frame once frames
  have flowed, or the source dying ends the run; the keyframers are flushed, the sinks
  drained and closed, and a `RunSummary` (`streamkey.summary`) is returned (`source_error`
  says why a source died).

Memory stays flat over long runs: latencies go into fixed-bin histograms, keyframer errors
into a bounded list.
"""

from __future__ import annotations

import asyncio
import dataclasses
import gc
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import jit
from .errors import StreamkeyError
from .fanout import SinkFanout
from .framequeue import FrameArrived, QueueItem, SkeletonAnnounced, SourceEnded
from .io import DEFAULT_MAX_STREAMS, Sink, Source, StreamSpec
from .keyframes import Event, KeyframeEvent
from .motion import Frame, Skeleton
from .online import GuardCounters, OnlineKeyframer, Pipeline
from .scheduler import Scheduler
from .streamtable import LiveStream, StreamTable
from .summary import (
    MAX_ERRORS_KEPT,
    EngineStatistics,
    LatencyHistogram,
    RunSummary,
    StreamStats,
)

__all__ = ["Engine", "EngineConfig", "RunSummary", "StreamStats", "LatencyHistogram",
           "MAX_ERRORS_KEPT", "EngineStatistics", "KeyframerFactory"]

KeyframerFactory = Callable[[StreamSpec], list[OnlineKeyframer]]
"""Builds a stream's keyframers from its `StreamSpec` (id, skeleton, rate)."""

MAX_REFUSALS_SAID = 20       # refused stream ids said on the ready channel (all are counted)


@dataclass(frozen=True)
class EngineConfig:
    """How an engine runs, besides its source, keyframer factory and sinks.

    `stream` names the unnamed stream; `on_ready` gets the human-readable status lines
    (ready, refused, retired, disabled sink); `on_event` every event's dict; `on_frame` each
    frame after its events (the dashboard's pose view). `idle_exit`: end the run after that
    many seconds without a frame once frames have flowed. `reset_on_gap`: a gap too long to
    bridge forgets the methods' running statistics too. `due_first`: the deferred
    re-analysis of every stream waits until no frame is queued. `freeze_gc`: freeze the heap
    loaded at start-up out of the garbage collector for the run (the CLI's `run`).
    `turn_budget_ms`: work between two passes of the event loop (the sources' reads).
    `segments`: each stream's pipeline sends segment events (calibration, still, take)."""

    stream: str = "default"
    on_ready: Callable[[str], None] | None = None
    on_event: Callable[[dict[str, Any]], None] | None = None
    idle_exit: float | None = None
    on_frame: Callable[[Frame], None] | None = None
    reset_on_gap: bool = False
    max_streams: int = DEFAULT_MAX_STREAMS
    stream_idle: float | None = None
    due_first: bool = True
    freeze_gc: bool = False
    turn_budget_ms: float = 1.0
    segments: bool = True


class Engine:
    """Wire a source to keyframers and sinks; `await run()` until the source ends or `stop()`.

    One engine serves any number of streams (up to `max_streams`): frames carry a stream tag
    from the source (None: the unnamed stream, called `stream`); a stream's pipeline is built
    from its skeleton (or the shared one) and retired after `stream_idle` seconds without a
    frame. Options: an `EngineConfig`, or its fields as keywords.
    """

    def __init__(self, source: Source, make_keyframers: KeyframerFactory, sinks: list[Sink],
                 config: EngineConfig | None = None, **options: Any) -> None:
        self.config = cfg = dataclasses.replace(config or EngineConfig(), **options)
        self.source = source
        self.make_keyframers = make_keyframers
        self._say: Callable[[str], None] = cfg.on_ready or (lambda line: None)
        self.sinks = SinkFanout(sinks, self._say)
        source.max_streams = cfg.max_streams
        self.summary = RunSummary(max_streams=cfg.max_streams)
        self.table = StreamTable(self.summary.streams, cfg.max_streams, cfg.stream_idle)
        self.scheduler: Scheduler[LiveStream] = Scheduler(int(cfg.turn_budget_ms * 1e6))
        self._warm = False
        self._prebuilt: tuple[tuple[Skeleton, float], Pipeline] | None = None
        self._last_frame = time.monotonic()
        self._next_retire = 0.0
        self._stopping = False

    @property
    def streams(self) -> dict[str, LiveStream]:
        """The live streams by name."""
        return self.table.live

    @property
    def pipeline(self) -> Pipeline | None:
        """The pipeline of the unnamed stream (else the first live one); None before any."""
        state = self.streams.get(self.config.stream) or next(iter(self.streams.values()), None)
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
        await self.sinks.start()
        try:
            self._prepare()
            self._say(f"listening on {await self.source.start()}")
            if not self._stopping:
                await self._loop()
        finally:
            if self.config.freeze_gc:
                gc.unfreeze()
            await self.source.close()
            for state in list(self.streams.values()):
                self._retire(state)
            await self.sinks.close()
            self._finish_summary(started)
        return self.summary

    def _prepare(self) -> None:
        """Warm up before listening; with a known skeleton, the unnamed stream's pipeline
        is ready before frames flow."""
        stream = self.config.stream
        known = self.source.skeleton_for(None)
        if known is not None:  # known skeleton: ready (and warm) before frames flow
            self._warm_up(StreamSpec(stream, *known))
            if not self.source.shared_skeleton:
                self._open(stream, None)
            else:  # it may serve tagged streams only: built now, opened by a frame
                self._prebuilt = (known, self._build(StreamSpec(stream, *known)))
        if not self._warm:  # the skeleton comes from the wire: warm up on a built-in
            self._warm_up_without_skeleton()  # rig, not while its first frames wait

    # ------------------------------------------------------------------ streams

    def _open(self, name: str, tag: str | None, frame: bool = True) -> LiveStream | None:
        """The live stream `name`, built now if its skeleton is known; None if it waits for
        its skeleton or is refused (counted either way; `frame`: a frame asked for it)."""
        table = self.table
        state = table.live.get(name)
        if state is not None:
            return state
        if not table.admits(name):
            if table.refuse(name, frame, MAX_REFUSALS_SAID):
                self._say(f"stream {name!r} refused: this run already serves "
                          f"{self.config.max_streams} streams (--max-streams); its frames "
                          "are dropped and counted")
            self.source.forget_stream(tag)
            return None
        known = self.source.skeleton_for(tag)
        if known is None:
            table.wait(name, time.monotonic())
            return None
        pipeline = self._pipeline_for(StreamSpec(name, *known), tag)
        if pipeline is None:
            return None
        state = table.open(name, tag, pipeline, time.monotonic())
        for held, arrival_ns in table.take_held(name):
            self._push(state, held, arrival_ns)
        return state

    def _pipeline_for(self, spec: StreamSpec, tag: str | None) -> Pipeline | None:
        """A stream's pipeline (the prebuilt one if it fits); None if the keyframers refuse
        a skeleton from the wire (counted by the source; the stream waits for another)."""
        prebuilt, self._prebuilt = self._prebuilt, None
        try:
            if not self._warm:
                self._warm_up(spec)
            if prebuilt is not None and tag is None and prebuilt[0][0] is spec.skeleton and (
                    prebuilt[0][1] == spec.fps):
                return prebuilt[1]
            return self._build(spec)
        except Exception as exc:
            if self.source.shared_skeleton or not isinstance(
                    exc, (StreamkeyError, ArithmeticError, ValueError, IndexError)):
                raise
            self.source.refuse_skeleton(f"{type(exc).__name__}: {exc}", tag)
            self.table.wait(spec.stream, time.monotonic())
            return None

    def _retire(self, state: LiveStream) -> None:
        """End a stream: flush its pipeline, keep its counters, free its place."""
        self.scheduler.drop(state.name)
        self._deliver(self.table.step(state, None, state.pipeline.flush), time.monotonic_ns(),
                      state, due=False, timed=False)
        self.table.close(state)
        self.source.forget_stream(state.tag)

    def _retire_idle(self, now: float) -> None:
        idle = self.config.stream_idle
        if idle is None or now < self._next_retire:
            return
        self._next_retire = now + min(0.25, idle / 4)
        for state in self.table.expired(now):
            self._retire(state)
            self._say(f"stream {state.name!r} retired after {idle:g} s without a frame")
        self.table.forget_stale(now)

    def _warm_up(self, spec: StreamSpec) -> None:
        """Compile (or load) the numba kernels of the modules the keyframers imported and
        push a few rest-pose frames through a throwaway copy of them, so that first-call
        costs (compilation, lazy imports, FK plans, BLAS start-up) are not paid by the first
        real decision's latency."""
        self._load_kernels()
        spare = Pipeline(self.make_keyframers(spec), stream=spec.stream,
                         segments=self.config.segments)
        jit.warm_up()  # modules the keyframers imported just now
        rest = np.zeros(spec.skeleton.n_channels)
        for seq in range(3):
            spare.push(Frame(seq, seq / spec.fps, rest))
        spare.flush()
        self._warm = True
        self._freeze_heap()

    def _build(self, spec: StreamSpec) -> Pipeline:
        return Pipeline(self.make_keyframers(spec), stream=spec.stream,
                        reset_on_gap=self.config.reset_on_gap, segments=self.config.segments)

    def _warm_up_without_skeleton(self) -> None:
        """Warm up before listening when the skeleton will come from the wire: on the
        built-in humanoid rig, so the method modules are imported and their kernels loaded
        before the first frames wait for them (~0.4 s with all methods). If the keyframers
        refuse that rig (a `--roles` mapping of another rig), the kernels loaded so far."""
        from .rigs import humanoid_skeleton

        try:
            self._warm_up(StreamSpec(self.config.stream, humanoid_skeleton(), 120.0))
        except (StreamkeyError, ValueError, KeyError, IndexError):
            self._load_kernels()
            self._freeze_heap()

    def _load_kernels(self) -> None:
        """Compile or load every numba kernel imported so far (`jit.warm_up()`), saying so
        when they compile for a new machine (once, tens of seconds) instead of pausing."""
        if jit.cache_is_cold():
            self._say("compiling the numba kernels for this machine (once, up to a "
                          "minute; later runs load them from the cache)")
        jit.warm_up()

    def _freeze_heap(self) -> None:
        """With `freeze_gc`: collect once, then move every object alive now (modules,
        compiled kernels, the pipelines) out of the collector's reach, so a full collection
        during the stream scans only what the stream allocated (it took 12-14 ms with all
        methods loaded; `gc.unfreeze()` at the end of the run)."""
        if self.config.freeze_gc:
            gc.collect()
            gc.freeze()

    def snapshot_stream(self, name: str) -> bytes:
        """Snapshot of live stream `name`'s pipeline (`snapshot.py`); KeyError if not live."""
        return self.table.snapshot(name)

    def restore_stream(self, name: str, data: bytes, params: str | None = None) -> None:
        """Serve stream `name` from a snapshot from now on (a worker taking over a stream);
        a live pipeline of that name is replaced unflushed. `SnapshotError` if it does not
        fit (`params`: the digest it must carry)."""
        self.scheduler.drop(name)
        tag = None if name == self.config.stream else name
        state = self.table.restore(name, tag, data, time.monotonic(), params)
        if state.pipeline._idle_due:  # the re-analysis of its last frame had not run yet
            self.scheduler.defer(name, state)

    # ------------------------------------------------------------------ the loop

    async def _loop(self) -> None:
        queue, sched = self.source.frames, self.scheduler
        while True:
            now = time.monotonic_ns()
            if sched.should_drain(now) and self._keeping_up(queue):
                sched.drained(now)
                await _let_sources_read()
            if queue.empty():
                state = sched.next_deferred()
                if state is not None:  # every due decision is out: one stream's re-analysis
                    sched.begin(time.monotonic_ns())
                    self._deliver(self.table.step(state, state.seq, state.pipeline.idle),
                                  state.last_arrival_ns, state, due=False)
                    continue
                sched.waiting()
                item = await self._wait()
                if item is _TIMEOUT:
                    idle_exit = self.config.idle_exit
                    if idle_exit is not None and self.summary.frames_in and (
                            time.monotonic() - self._last_frame >= idle_exit):
                        return
                    self._retire_idle(time.monotonic())
                    continue
            else:
                item = queue.get_nowait()
            sched.begin(time.monotonic_ns())
            match item:
                case FrameArrived(frame=frame, arrival_ns=arrival_ns, stream=tag):
                    self._handle(frame, arrival_ns, tag)
                case SkeletonAnnounced(stream=tag):  # build the pipeline before its frames
                    name = self.config.stream if tag is None else tag
                    if name not in self.streams:
                        self._open(name, tag, frame=False)
                case SourceEnded():
                    return

    @staticmethod
    def _keeping_up(queue: Any) -> bool:
        """True while the queue is under half full: then the sockets are read between
        turns. Behind that (no CPU to spare), reading would decode frames only for the full
        queue to drop them: the kernel's buffer holds the backlog, its drops counted."""
        return not queue.maxsize or 2 * len(queue) < queue.maxsize

    async def _wait(self) -> QueueItem | object:
        """The next queue item, or `_TIMEOUT` when a stream may be due for retirement or
        the run for its idle exit."""
        waits = []
        idle_exit, stream_idle = self.config.idle_exit, self.config.stream_idle
        if idle_exit is not None and self.summary.frames_in:
            waits.append(self._last_frame + idle_exit - time.monotonic())
        if stream_idle is not None and (self.streams or self.table.waiting):
            waits.append(min(0.25, stream_idle / 4))
        if not waits:
            return await self.source.get()
        try:
            return await asyncio.wait_for(self.source.get(), max(0.0, min(waits)))
        except TimeoutError:
            return _TIMEOUT

    def _handle(self, frame: Frame, arrival_ns: int, tag: str | None) -> None:
        name = self.config.stream if tag is None else tag
        self.summary.frames_in += 1
        self._last_frame = time.monotonic()
        # Idleness on the arrival clock: frames are handled in arrival order, so every frame
        # that arrived before this one has been handled, and a stream is idle when none of
        # its frames arrived for `stream_idle` before it, however far the run is behind.
        arrived = arrival_ns / 1e9
        state = self.streams.get(name) or self._open(name, tag)
        if state is None:  # waiting for its skeleton (held) or refused (counted)
            self.table.hold(name, frame, arrival_ns, arrived)
            self._retire_idle(arrived)
            return
        self.table.touch(state, arrived)
        self._push(state, frame, arrival_ns)
        if self.config.on_frame is not None:
            self.config.on_frame(frame)
        self._retire_idle(arrived)

    def _push(self, state: LiveStream, frame: Frame, arrival_ns: int) -> None:
        """One frame of a stream: the pending re-analysis of its previous frame first (the
        stream's own order), then the due decisions; this frame's re-analysis is deferred."""
        step = self.table.step
        if self.scheduler.take(state.name) is not None:
            self._deliver(step(state, state.seq, state.pipeline.idle),
                          state.last_arrival_ns, state, due=False)
        state.stats.frames_in += 1
        state.seq, state.last_arrival_ns = frame.seq, arrival_ns
        self.summary.frame_wait.add((time.monotonic_ns() - arrival_ns) / 1e6)
        self._deliver(step(state, frame.seq, state.pipeline.push, frame), arrival_ns,
                      state, due=True)
        if self.config.due_first:
            self.scheduler.defer(state.name, state)
        else:
            self._deliver(step(state, frame.seq, state.pipeline.idle), arrival_ns,
                          state, due=False)

    def _deliver(self, events: list[Event], arrival_ns: int, state: LiveStream | None = None,
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
            self.sinks.offer(event)
            if self.config.on_event is not None:
                self.config.on_event(event.to_dict())
        if events:
            self.sinks.end_batch(arrival_ns)

    def _time(self, method: str, latency: float, state: LiveStream | None, due: bool) -> None:
        self.summary.latency.add(latency)
        per_method = self.summary.method_latency.get(method)
        if per_method is None:
            per_method = self.summary.method_latency[method] = LatencyHistogram()
        per_method.add(latency)
        if due:
            self.summary.due_latency.add(latency)
        if state is not None:
            state.stats.due_latency.add(latency)

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
        self.summary.waiting_at_stop = self.table.held_frames()
        self.summary.refused_streams = self.table.refused_streams
        self.summary.refused_frames = self.table.refused_frames
        self.summary.errors = list(self.table.faults.messages)
        self.summary.error_count = self.table.faults.count
        self.summary.sinks.update(self.sinks.stats())
        self.summary.scheduler = self.scheduler.stats.as_dict()


async def _let_sources_read() -> None:
    """One pass of the event loop for the sources' socket readers before more work: the
    first yield puts this task in the ready queue ahead of the readers the next select
    finds, the second behind them."""
    await asyncio.sleep(0)
    await asyncio.sleep(0)


_TIMEOUT = object()
