"""`run --workers N`: one source, one set of sinks, one summary, the streams' keyframers
spread over N worker processes (every core of the machine, not one).

::

    source (this process) --frames of stream s--> worker k (placed by load) --events-->
    this process: the sinks, the merged summary

This process reads the source (its sockets, its queue and counters as in a one-process run)
and places each stream id on the worker serving the fewest streams (ties: the one given the
fewest so far, then the first); a stream keeps its worker until it is retired, so its frames stay in
order and its events are exactly a one-process run's. Frames go to their worker in one
message per batch read from the queue, stamped with their arrival time (the monotonic clock
is the machine's, shared by the processes). Each worker is an ordinary `Engine` (its own
scheduler: due first, drain before compute) whose source is the pipe from here and whose
one sink is the pipe back; this process hands the events to the sinks and times them again
there (`wall latency` in the summary: arrival to the sinks, the pipe hops included; the due
p99 / max per stream are measured in the workers, up to their hand-off).

Shutdown: on the source's end, `stop()` (Ctrl-C / SIGTERM) or `idle_exit`, every worker is
told to end, flushes its streams, sends their last events and its summary, and exits; the
sinks are drained and closed after the last worker's summary came. Workers ignore SIGINT
(the terminal sends it to the whole process group): the parent ends them in order.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import os
import signal
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from types import SimpleNamespace
from typing import Any

from .engine import Engine, EngineConfig
from .errors import StreamkeyError
from .fanout import SinkFanout
from .framequeue import FrameArrived, SkeletonAnnounced, SourceEnded
from .io import DEFAULT_MAX_STREAMS, Sink, Source, StreamSpec
from .keyframes import Event, KeyframeEvent
from .motion import Frame, Skeleton
from .online import GuardCounters, OnlineKeyframer
from .summary import LatencyHistogram, RunSummary, StreamStats

__all__ = ["WorkerPool", "WorkerConfig", "default_workers", "merge_summaries", "run_workers"]

BATCH = 256          # queue items routed per pass before the batches are sent
READY_TIMEOUT = 300.0  # seconds a worker may take to start (numba kernels compiling)


def default_workers() -> int:
    """The machine's cores (the CPUs this process may run on)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


@dataclass
class WorkerConfig:
    """What a worker process needs to build its engine (pickled to it)."""

    methods: list[str]
    params: dict[str, dict[str, Any]] = field(default_factory=dict)
    lookahead: int | None = None
    stream: str = "default"
    reset_on_gap: bool = False
    max_streams: int = DEFAULT_MAX_STREAMS
    stream_idle: float | None = None
    freeze_gc: bool = True
    skeleton: Skeleton | None = None  # a skeleton given up front serves every stream
    fps: float | None = None
    segments: bool = True  # send segment events
    # makes a worker's explainer of refused input (`cli.input_watch.InputWatch`, given by
    # the caller so the library does not import the CLI): it watches the streams' guards
    input_watch: Callable[[], Any] | None = None


# ---------------------------------------------------------------------- worker side


class _PipeSource(Source):
    """A worker's source: frames and skeletons from the parent's pipe."""

    name = "worker"

    def __init__(self, conn: Connection, cfg: WorkerConfig) -> None:
        super().__init__(cfg.skeleton, cfg.fps, queue_size=4096)
        self.conn = conn

    async def start(self) -> str:
        asyncio.get_running_loop().add_reader(self.conn.fileno(), self._readable)
        self.conn.send(("ready", os.getpid()))
        return "the parent's pipe"

    def _readable(self) -> None:
        try:
            while self.conn.poll():
                self._handle(self.conn.recv())
        except (EOFError, OSError):  # the parent is gone: end the run (flush, exit)
            asyncio.get_running_loop().remove_reader(self.conn.fileno())
            self.frames.end()

    def _handle(self, message: tuple[Any, ...]) -> None:
        kind = message[0]
        if kind == "frames":
            for tag, frame, arrival_ns in message[1]:
                self.stats.received += 1
                self.frames.put(frame, arrival_ns, tag)
        elif kind == "skeleton":
            _, tag, skeleton, fps = message
            self.set_skeleton(skeleton, fps, tag)
        elif kind == "end":
            asyncio.get_running_loop().remove_reader(self.conn.fileno())
            self.frames.end()

    def forget_stream(self, stream: str | None) -> None:
        super().forget_stream(stream)
        with contextlib.suppress(OSError):
            self.conn.send(("retired", stream))


class _PipeSink(Sink):
    """A worker's sink: each frame's events to the parent in one message."""

    name = "parent"

    def __init__(self, conn: Connection) -> None:
        super().__init__()
        self.conn = conn
        self.batch: list[Event] = []

    def offer(self, event: Event) -> None:
        self.batch.append(event)

    def end_batch(self, arrival_ns: int) -> None:
        if self.batch:
            self.conn.send(("events", self.batch, arrival_ns))
            self.stats.sent += len(self.batch)
            self.batch = []


def _worker_main(conn: Connection, cfg: WorkerConfig) -> None:
    """A worker process: an engine from the pipe to the pipe, then its summary."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    from .streamtable import keyframers_for

    def keyframers(spec: StreamSpec) -> list[OnlineKeyframer]:
        return keyframers_for(spec, cfg.methods, cfg.params, cfg.lookahead)

    def say(line: str) -> None:
        if not line.startswith("listening on"):
            conn.send(("say", line))

    source = _PipeSource(conn, cfg)
    watch = cfg.input_watch() if cfg.input_watch is not None else None
    engine = Engine(source, keyframers, [_PipeSink(conn)], EngineConfig(
        stream=cfg.stream, on_ready=say, reset_on_gap=cfg.reset_on_gap,
        max_streams=cfg.max_streams, stream_idle=cfg.stream_idle, freeze_gc=cfg.freeze_gc,
        segments=cfg.segments, on_frame=watch.on_frame if watch is not None else None))
    summary = asyncio.run(_watched(engine, watch))
    summary.sinks = {}
    summary.scheduler["cpu_seconds"] = round(time.process_time(), 3)
    with contextlib.suppress(OSError):
        if watch is not None:
            conn.send(("input", dict(watch.counts)))
        conn.send(("summary", summary))
    conn.close()


async def _watched(engine: Engine, watch: Any) -> RunSummary:
    """`engine.run()` with `watch` (an input explainer, or None) reading its counters."""
    if watch is None:
        return await engine.run()
    watch.engine = engine
    task = asyncio.create_task(watch.watch())
    try:
        return await engine.run()
    finally:
        task.cancel()
        watch.check(final=True)


class _SourceView:
    """What an input explainer reads of an engine, for the workers' parent: the source's
    counters (refused packets, wrong addresses); the streams' guards are in the workers,
    whose own explainers watch them. Its status events go to the parent's sinks."""

    def __init__(self, pool: WorkerPool) -> None:
        self.source = pool.source
        self.sinks = pool.sinks
        self.table = SimpleNamespace(live={}, waiting={})
        self.config = SimpleNamespace(stream=pool.cfg.stream, on_event=None)
        self.summary = SimpleNamespace(events=pool.input_events)


# ---------------------------------------------------------------------- parent side


@dataclass
class _Worker:
    """A worker process as the parent sees it."""

    process: Any
    conn: Connection
    outbox: list[tuple[str | None, Frame, int]] = field(default_factory=list)
    streams: set[str] = field(default_factory=set)
    placed: int = 0
    ready: bool = False
    summary: RunSummary | None = None
    cpu_seconds: float = 0.0


class WorkerPool:
    """Run a source through `workers` worker processes to `sinks` (see the module);
    `await run()` until the source ends, `stop()` or `idle_exit`; returns the merged
    summary."""

    def __init__(self, source: Source, sinks: list[Sink], cfg: WorkerConfig, workers: int,
                 on_ready: Any = None, idle_exit: float | None = None,
                 input_watch: Any = None) -> None:
        self.source, self.cfg, self.n = source, cfg, workers
        self.watch = input_watch  # explains the source's refusals; counts the workers' too
        self.input_events: Counter[str] = Counter()  # its status events, for the summary
        self._say = on_ready or (lambda line: None)
        self.sinks = SinkFanout(sinks, self._say)
        self.idle_exit = idle_exit
        self.workers: list[_Worker] = []
        self.placement: dict[str, int] = {}
        self.latency = LatencyHistogram()
        self.events: Counter[str] = Counter()
        self.refused: set[str] = set()
        self.refused_frames = 0
        self._stopping = False
        self._all_ready = asyncio.Event()
        self._all_done = asyncio.Event()
        self._last_frame: float | None = None
        self._failed: str | None = None
        source.max_streams = cfg.max_streams

    def stop(self) -> None:
        """End the run: the source stops, the workers flush, the sinks drain."""
        self._stopping = True
        self.source.frames.end()

    async def run(self) -> RunSummary:
        """Start the workers, route the source's frames, end cleanly; the merged summary."""
        started = time.monotonic()
        self._start_workers()
        watching: asyncio.Task[None] | None = None
        try:
            await self.sinks.start()
            await asyncio.wait_for(self._all_ready.wait(), READY_TIMEOUT)
            if self._failed:
                raise StreamkeyError(f"run --workers {self.n}: {self._failed}")
            self._say(f"{self.n} workers ready (pids "
                      f"{', '.join(str(w.process.pid) for w in self.workers)})")
            self._say(f"listening on {await self.source.start()}")
            if self.watch is not None:
                self.watch.engine = _SourceView(self)
                watching = asyncio.create_task(self.watch.watch())
            if not self._stopping:
                await self._route()
        finally:
            if watching is not None:
                watching.cancel()
                self.watch.check(final=True)
            await self.source.close()
            await self._end_workers()
            await self.sinks.close()
        return self._summary(time.monotonic() - started)

    def _start_workers(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        loop = asyncio.get_running_loop()
        for i in range(self.n):
            parent, child = ctx.Pipe(duplex=True)
            proc = ctx.Process(target=_worker_main, args=(child, self.cfg),
                               name=f"streamkey-worker-{i}", daemon=True)
            proc.start()
            child.close()
            self.workers.append(_Worker(proc, parent))
            loop.add_reader(parent.fileno(), self._from_worker, i)

    def _from_worker(self, i: int) -> None:
        w = self.workers[i]
        try:
            while w.conn.poll():
                self._handle(w, w.conn.recv())
        except (EOFError, OSError):  # the worker ended (or died): no more from it
            asyncio.get_running_loop().remove_reader(w.conn.fileno())
            if w.summary is None:
                self._say(f"worker {i} (pid {w.process.pid}) ended without its summary")
                w.summary = RunSummary()
            if not w.ready:
                self._failed = f"worker {i} ended before it was ready"
                self._all_ready.set()
            self._check_done()

    def _handle(self, w: _Worker, message: tuple[Any, ...]) -> None:
        kind = message[0]
        if kind == "events":
            self._deliver(message[1], message[2])
        elif kind == "ready":
            w.ready = True
            if all(x.ready for x in self.workers):
                self._all_ready.set()
        elif kind == "retired":
            name = self.cfg.stream if message[1] is None else message[1]
            if self.placement.pop(name, None) is not None:
                w.streams.discard(name)
                self.source.forget_stream(message[1])  # it may come back with its skeleton
        elif kind == "say":
            self._say(message[1])
        elif kind == "input" and self.watch is not None:
            self.watch.counts.update(message[1])
        elif kind == "summary":
            w.summary = message[1]
            self._check_done()

    def _check_done(self) -> None:
        if all(w.summary is not None for w in self.workers):
            self._all_done.set()

    def _deliver(self, events: list[Event], arrival_ns: int) -> None:
        now = time.monotonic_ns()
        for event in events:
            if isinstance(event, KeyframeEvent):
                self.latency.add((now - arrival_ns) / 1e6)
                self.events[event.method] += 1
            else:
                self.events[type(event).__name__.removesuffix("Event").lower()] += 1
            self.sinks.offer(event)
        self.sinks.end_batch(arrival_ns)

    # ------------------------------------------------------------------ routing

    def _place(self, name: str, tag: str | None) -> _Worker | None:
        """The worker of stream `name`, placed now on the least loaded if new; None if the
        run's `max_streams` are placed (refused, counted)."""
        index = self.placement.get(name)
        if index is not None:
            return self.workers[index]
        if len(self.placement) >= self.cfg.max_streams:
            if name not in self.refused:
                self.refused.add(name)
                self._say(f"stream {name!r} refused: this run already serves "
                          f"{self.cfg.max_streams} streams (--max-streams)")
            return None
        index = min(range(self.n), key=lambda k: (len(self.workers[k].streams),
                                                   self.workers[k].placed, k))
        w = self.workers[index]
        self.placement[name] = index
        w.streams.add(name)
        w.placed += 1
        known = None if self.source.shared_skeleton else self.source.skeleton_for(tag)
        if known is not None:  # from the wire: the worker learns it before the frames
            w.conn.send(("skeleton", tag, *known))
        return w

    async def _route(self) -> None:
        queue = self.source.frames
        while True:
            item = await self._next()
            if item is None:
                return
            items = [item]
            while len(items) < BATCH and not queue.empty():
                items.append(queue.get_nowait())
            ended = False
            for it in items:
                match it:
                    case FrameArrived(frame=frame, arrival_ns=arrival_ns, stream=tag):
                        self._last_frame = time.monotonic()
                        w = self._place(self.cfg.stream if tag is None else tag, tag)
                        if w is None:
                            self.refused_frames += 1
                        else:
                            w.outbox.append((tag, frame, arrival_ns))
                    case SkeletonAnnounced(stream=tag):
                        name = self.cfg.stream if tag is None else tag
                        index = self.placement.get(name)
                        if index is None:
                            self._place(name, tag)
                        elif (known := self.source.skeleton_for(tag)) is not None:
                            self.workers[index].conn.send(("skeleton", tag, *known))
                    case SourceEnded():
                        ended = True
            for w in self.workers:
                if w.outbox:
                    w.conn.send(("frames", w.outbox))
                    w.outbox = []
            if ended:
                return

    async def _next(self) -> Any:
        """The next queue item; None when `idle_exit` seconds passed without a frame."""
        if self.idle_exit is None or self._last_frame is None:
            return await self.source.get()
        while True:
            left = self._last_frame + self.idle_exit - time.monotonic()
            if left <= 0:
                return None
            with contextlib.suppress(TimeoutError):
                return await asyncio.wait_for(self.source.get(), left)

    async def _end_workers(self) -> None:
        for w in self.workers:
            with contextlib.suppress(OSError):
                w.conn.send(("end",))
        if self.workers:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._all_done.wait(), 60.0)
        loop = asyncio.get_running_loop()
        for w in self.workers:
            with contextlib.suppress(Exception):
                loop.remove_reader(w.conn.fileno())
            await asyncio.to_thread(w.process.join, 10.0)
            if w.process.is_alive():
                w.process.kill()
            w.conn.close()

    def _summary(self, seconds: float) -> RunSummary:
        parts = [w.summary or RunSummary() for w in self.workers]
        out = merge_summaries(parts)
        out.seconds = seconds
        out.latency = self.latency
        source = self.source.counters().as_dict()
        source["queue_drops"] += sum(p.source.get("queue_drops", 0) for p in parts)
        out.source = source
        out.source_error = None if self._stopping else self.source.fatal
        out.left_in_queue += self.source.frames.statistics().frames
        out.refused_streams += len(self.refused)
        out.refused_frames += self.refused_frames
        out.max_streams = self.cfg.max_streams
        out.events.update(self.input_events)
        out.sinks = self.sinks.stats()
        out.scheduler["workers"] = [
            {"pid": w.process.pid, "streams_placed": w.placed, "frames_in": p.frames_in,
             "cpu_seconds": p.scheduler.get("cpu_seconds", 0.0),
             "due_latency_ms": p.due_latency.summary()}
            for w, p in zip(self.workers, parts, strict=True)]
        return out


def merge_summaries(parts: list[RunSummary]) -> RunSummary:
    """One summary of several engines' (each stream served by one of them)."""
    out = RunSummary()
    guard: Counter[str] = Counter()
    for p in parts:
        out.frames_in += p.frames_in
        out.events.update(p.events)
        guard.update(p.guard)
        out.latency.merge(p.latency)
        out.due_latency.merge(p.due_latency)
        out.frame_wait.merge(p.frame_wait)
        for method, hist in p.method_latency.items():
            out.method_latency.setdefault(method, LatencyHistogram()).merge(hist)
        for name, stats in p.streams.items():
            mine = out.streams.setdefault(name, StreamStats())
            mine.merge(stats)
        out.errors += p.errors
        out.error_count += p.error_count
        out.left_in_queue += p.left_in_queue
        out.refused_streams += p.refused_streams
        out.refused_frames += p.refused_frames
        out.waiting_at_stop += p.waiting_at_stop
        out.untimed_events += p.untimed_events
        for key, value in p.scheduler.items():
            if not isinstance(value, (int, float)):
                continue
            if key == "longest_turn_ms":
                out.scheduler[key] = max(out.scheduler.get(key, 0.0), value)
            else:
                out.scheduler[key] = out.scheduler.get(key, 0) + value
    if parts:
        out.guard = {k: guard.get(k, 0) for k in GuardCounters().as_dict()}
    return out


async def run_workers(source: Source, methods: list[str], to: list[str], workers: int,
                      params: dict[str, dict[str, Any]] | None = None,
                      lookahead: int | None = None, listen: str | None = None,
                      stream: str = "default", idle_exit: float | None = None,
                      reset_on_gap: bool = False, max_streams: int = DEFAULT_MAX_STREAMS,
                      stream_idle: float | None = None,
                      on_ready: Any = None, segments: bool = True,
                      input_watch: Any = None,
                      worker_watch: Callable[[], Any] | None = None) -> RunSummary:
    """`run --workers N` from a listening `source` to the sinks at `to` until the source
    ends, `idle_exit`, SIGINT or SIGTERM; the merged summary. `input_watch`: an explainer of
    the source's refused input (`cli.input_watch.InputWatch`); `worker_watch`: makes one per
    worker, for the streams' guards."""
    from .adapters import make_sink, parse_address
    from .live import _ready

    sinks = [make_sink(parse_address(a), listen) for a in to]
    cfg = WorkerConfig(methods, params or {}, lookahead, stream, reset_on_gap, max_streams,
                       stream_idle, True, source.skeleton if source.shared_skeleton else None,
                       source.fps if source.shared_skeleton else None, segments, worker_watch)
    pool = WorkerPool(source, sinks, cfg, workers, on_ready or _ready, idle_exit, input_watch)
    loop = asyncio.get_running_loop()
    handled = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, pool.stop)
            handled.append(sig)
        except (NotImplementedError, RuntimeError):  # not the main thread
            pass
    try:
        return await pool.run()
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)
