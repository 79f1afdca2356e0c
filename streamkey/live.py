"""The library side of `streamkey run`, `replay` and the live `demo`."""

from __future__ import annotations

import asyncio
import itertools
import json
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

from .adapters import make_sink, parse_address
from .adapters.base import Sink, Source
from .engine import Engine, EngineConfig
from .errors import UsageError
from .io import DEFAULT_MAX_STREAMS, StreamSpec, stream_id_problem, stream_tag
from .motion import Frame, Motion
from .online import OnlineKeyframer
from .replay.pacing import frame_stream, paced
from .replay.source import MotionSource
from .streamtable import keyframers_for
from .summary import RunSummary

__all__ = ["run_live", "build_engine", "run_engine", "replay", "FRAME_TARGETS",
           "raise_priority", "REALTIME_PRIORITY", "hold_cpu_wakeup_latency", "PM_QOS_DEVICE"]

FRAME_TARGETS = ("osc", "zmq+tcp", "zmq+ipc", "-")
REALTIME_PRIORITY = 10  # SCHED_RR 1..99: above every ordinary process, below kernel threads
PM_QOS_DEVICE = "/dev/cpu_dma_latency"  # Linux PM QoS: the CPUs' wake-up latency bound, in µs
_pm_qos_request: int | None = None  # the open request (held while the process lives)


def raise_priority() -> str:
    """`run --realtime`: run this process, and the threads it starts afterwards (sources'
    readers, libzmq's I/O threads), ahead of ordinary work: SCHED_RR at `REALTIME_PRIORITY`
    where the OS grants it, else nice -10, and keep the CPUs out of deep idle states
    (`hold_cpu_wakeup_latency`); returns what was granted. The engine is paced by its input,
    and Linux keeps 5 % of each core for ordinary processes whatever happens
    (`sched_rt_runtime_us`)."""
    return f"{_scheduling()}, {hold_cpu_wakeup_latency()}"


def _scheduling() -> str:
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(REALTIME_PRIORITY))
        return f"SCHED_RR {REALTIME_PRIORITY}"
    except (AttributeError, OSError):
        pass
    try:
        os.setpriority(os.PRIO_PROCESS, 0, -10)
        return "nice -10"
    except (AttributeError, OSError) as exc:
        return f"normal (not granted: {_reason(exc)})"


def hold_cpu_wakeup_latency(device: str = PM_QOS_DEVICE) -> str:
    """Ask Linux PM QoS for a CPU wake-up latency of 0 µs while this process lives (the
    request is an open file; the kernel drops it when the process exits): idle CPUs poll
    instead of entering states that take long to leave. A run at 120 Hz sleeps ~8 ms between
    frames, and code that runs right after such a sleep ran 3-20x slower on the measuring
    machine (a KVM guest whose idle CPUs halt): a frame's decode took 108 µs instead of 5,
    and 29 µs with the request held. Costs power on an idle machine, so only with
    `--realtime`; writing the device needs root (or a udev rule). Returns what was granted."""
    global _pm_qos_request
    if _pm_qos_request is None:
        fd = None
        try:
            fd = os.open(device, os.O_WRONLY | os.O_CLOEXEC)
            os.write(fd, (0).to_bytes(4, sys.byteorder))
        except OSError as exc:
            if fd is not None:
                os.close(fd)
            return f"CPU wake-up latency not held ({device}: {_reason(exc)})"
        _pm_qos_request = fd
    return "CPU wake-up latency 0 us (PM QoS)"


def _reason(exc: BaseException) -> str:
    return str(getattr(exc, "strerror", None) or exc)


def _ready(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def build_engine(source: Source | Motion, methods: list[str], sinks: list[Sink],
                 params: dict[str, dict[str, Any]] | None = None,
                 lookahead: int | None = None, stream: str = "default",
                 rate: float | None = None, loop: bool = False,
                 on_event: Callable[[dict[str, Any]], None] | None = None,
                 on_ready: Callable[[str], None] = _ready, idle_exit: float | None = None,
                 on_frame: Callable[[Frame], None] | None = None,
                 reset_on_gap: bool = False, max_streams: int = DEFAULT_MAX_STREAMS,
                 stream_idle: float | None = None, due_first: bool = True,
                 freeze_gc: bool = False, segments: bool = True) -> Engine:
    """The engine for a source (a Motion is replayed at `rate`, default its fps; 0: unpaced);
    every stream of the source gets its own keyframers (`Engine`); `segments`: send segment
    events."""
    if isinstance(source, Motion):
        source = MotionSource(source, rate=rate, loop=loop)

    def keyframers(spec: StreamSpec) -> list[OnlineKeyframer]:
        return keyframers_for(spec, methods, params, lookahead)

    return Engine(source, keyframers, sinks, EngineConfig(
        stream=stream, on_ready=on_ready, on_event=on_event, idle_exit=idle_exit,
        on_frame=on_frame, reset_on_gap=reset_on_gap, max_streams=max_streams,
        stream_idle=stream_idle, due_first=due_first, freeze_gc=freeze_gc,
        segments=segments))


async def run_engine(engine: Engine) -> RunSummary:
    """Run until the source ends or SIGINT/SIGTERM (which flush and drain); the summary."""
    loop = asyncio.get_running_loop()
    handled = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, engine.stop)
            handled.append(sig)
        except (NotImplementedError, RuntimeError):  # not the main thread
            pass
    try:
        return await engine.run()
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)


async def run_live(source: Source | Motion, methods: list[str], to: list[str],
                   params: dict[str, dict[str, Any]] | None = None,
                   lookahead: int | None = None, listen: str | None = None,
                   stream: str = "default", rate: float | None = None,
                   on_event: Callable[[dict[str, Any]], None] | None = None,
                   on_ready: Callable[[str], None] = _ready,
                   idle_exit: float | None = None, reset_on_gap: bool = False,
                   max_streams: int = DEFAULT_MAX_STREAMS,
                   stream_idle: float | None = None, freeze_gc: bool = True) -> RunSummary:
    """Run the engine from `source` to the sinks at `to`; returns the summary (`freeze_gc`:
    see `Engine`)."""
    sinks = [make_sink(parse_address(a), listen) for a in to]
    return await run_engine(build_engine(source, methods, sinks, params, lookahead, stream,
                                         rate, on_event=on_event, on_ready=on_ready,
                                         idle_exit=idle_exit, reset_on_gap=reset_on_gap,
                                         max_streams=max_streams, stream_idle=stream_idle,
                                         freeze_gc=freeze_gc))


def replay(motion: Motion, to: list[str], rate: float | None = None, speed: float = 1.0,
           loop: bool = False, start: int | None = None, end: int | None = None,
           listen: str | None = None, wait_subscribers: float = 2.0,
           count: int | None = None, stream: str | None = None) -> dict[str, Any]:
    """Send a motion as a paced frame stream to OSC / ZeroMQ / stdout; returns counters.
    `stream`: the stream id on the wire (None: the unnamed stream, `default`)."""
    if stream is not None and (problem := stream_id_problem(stream)) is not None:
        raise UsageError(f"replay --stream: {problem}")
    targets = [parse_address(a) for a in to]
    bad = [str(a) for a in targets if a.scheme not in FRAME_TARGETS]
    if bad:
        raise UsageError(f"replay sends frames to osc://, zmq+tcp://, zmq+ipc:// or -; "
                         f"not {', '.join(bad)}")
    if speed <= 0 or (rate is not None and rate <= 0):
        raise UsageError("--rate and --speed must be positive")
    senders = [_frame_sender(a, listen, stream) for a in targets]
    fps = motion.fps
    for s in senders:
        if hasattr(s, "subscribers") and wait_subscribers > 0:
            s.subscribers(wait_subscribers)
        s.send_skeleton(motion.skeleton, fps)
    interval = 1.0 / ((rate or fps) * speed)
    _ready(f"replaying {motion.name or 'motion'} to {', '.join(str(a) for a in targets)} "
           f"at {1 / interval:g} frames/s")
    sent = 0
    frames = itertools.islice(frame_stream(motion, start, end, loop), count)
    try:
        for frame, _ in paced(frames, interval):
            for s in senders:
                if sent % max(1, round(fps)) == 0 and sent:
                    s.send_skeleton(motion.skeleton, fps)
                s.send_frame(frame)
            sent += 1
    except KeyboardInterrupt:
        pass
    finally:
        for s in senders:
            s.close()
    return {"frames": sent, "senders": {s.name: s.stats.as_dict() for s in senders}}


class _StdoutFrames:
    name = "stdout"

    def __init__(self, stream: str | None = None) -> None:
        from .adapters.base import SinkStats

        self.stats = SinkStats()
        self.tag = {} if stream_tag(stream) is None else {"stream": stream}

    def send_skeleton(self, skeleton: Any, fps: float) -> None:
        if self.stats.sent == 0:  # once, first: what `run --from -` reads before any frame
            from .adapters.osc import skeleton_header

            sys.stdout.write(json.dumps({"type": "skeleton", "fps": fps, **self.tag,
                                         "bvh": skeleton_header(skeleton, fps)}) + "\n")

    def send_frame(self, frame: Frame) -> None:
        # Full float precision: `replay --to - | run --from -` equals `run --from FILE`.
        sys.stdout.write(json.dumps({"seq": frame.seq, "time": frame.time, **self.tag,
                                     "channels": frame.channels.tolist()}) + "\n")
        self.stats.sent += 1

    def close(self) -> None:
        sys.stdout.flush()


def _frame_sender(address: Any, listen: str | None, stream: str | None = None) -> Any:
    if address.scheme == "osc":
        from .adapters.osc import OscFrameSender

        return OscFrameSender(address, listen, stream=stream)
    if address.scheme in ("zmq+tcp", "zmq+ipc"):
        from .adapters.zmq import ZmqFrameSender

        return ZmqFrameSender(address, listen, stream=stream)
    return _StdoutFrames(stream)
