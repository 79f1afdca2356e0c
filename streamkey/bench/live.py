"""Live benchmarks of `streamkey bench`: the engine measured end to end.

- `memory`: resident memory of an accelerated one-hour stream (432,000 frames at 120 Hz,
  pushed as fast as the engine takes them) through all methods and every kind of sink;
  growth after warm-up must stay within 5 MB. `quick`: 10 minutes of stream.
- `latency`: replay and run as separate processes over OSC and over ZeroMQ at 120 Hz with
  all methods, at the run's normal priority and with `run --realtime`; this process is the
  external receiver: it gets an OSC copy of every frame (kernel receive time,
  `SO_TIMESTAMPNS`) and every event, and reports p50/p99 of event arrival minus the arrival
  of its deciding frame's copy (`decided_at`), next to what the run's own summary says
  (arrival at its socket -> event leaves for the sinks; the time frames waited before
  their push). Every row carries the load average before and after it.
- `ws_clients`: event wall latency inside the engine at 120 Hz with 0, 100 and 300
  WebSocket clients reading in another process (broadcast cost on the frame path).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..bvh import read_bvh
from ..motion import Motion

__all__ = ["bench_memory", "bench_latency", "bench_ws_clients", "LIVE_KINDS", "run_live_bench"]

LIVE_KINDS = ("memory", "latency", "ws_clients")
_LATENCY_CLIP = "01_06.bvh"  # the longest shared clip (5,134 frames, 43 s), looped


def _rss_mb() -> float:
    try:
        with open("/proc/self/statm", encoding="ascii") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        import resource

        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _clip(data: Path | None) -> Motion:
    if data is not None and (data / _LATENCY_CLIP).exists():
        return read_bvh(data / _LATENCY_CLIP)
    from ..replay.demo import demo_motion

    return demo_motion()


def bench_memory(data: Path | None, quick: bool = False) -> dict[str, Any]:
    """RSS over an accelerated stream of an hour (10 min if `quick`) with every sink."""
    from ..adapters import make_sink, parse_address
    from ..live import build_engine
    from ..methods import ONLINE_METHODS
    from ..replay.source import MotionSource

    motion = _clip(data)
    total = 72_000 if quick else 432_000
    warmup = total // 6  # 10 min of a 1 h stream
    samples: list[tuple[int, float]] = []
    with tempfile.TemporaryDirectory() as tmp:
        sinks = [make_sink(parse_address(a)) for a in (
            f"jsonl:{tmp}/events.jsonl", f"osc://127.0.0.1:{_free_port()}",
            f"zmq+tcp://127.0.0.1:{_free_port(socket.SOCK_STREAM)}",
            f"ws://127.0.0.1:{_free_port(socket.SOCK_STREAM)}")]
        source = MotionSource(motion, rate=0.0, loop=True, count=total)

        def on_frame(frame: Any) -> None:
            n = engine.summary.frames_in
            if n % 6000 == 0:
                samples.append((n, round(_rss_mb(), 2)))

        engine = build_engine(source, list(ONLINE_METHODS), sinks, on_ready=lambda line: None,
                              on_frame=on_frame)
        started = time.perf_counter()
        summary = asyncio.run(engine.run())
        seconds = time.perf_counter() - started
    after = [rss for n, rss in samples if n >= warmup]
    base = after[0] if after else float("nan")
    return {"rows": [{"stream_frames": total, "stream_minutes": total / motion.fps / 60,
                      "wall_seconds": round(seconds, 1), "warmup_frames": warmup,
                      "rss_at_warmup_mb": base, "rss_max_after_warmup_mb": max(after),
                      "growth_after_warmup_mb": round(max(after) - base, 2),
                      "target_mb": 5.0}],
            "events": dict(summary.events), "rss_samples_mb": samples,
            "sinks": summary.sinks}


# ------------------------------------------------------------------ external receiver

class _Receiver:
    """Arrival stamps of frames (by seq) and events (by decided_at), in its own thread."""

    def __init__(self, realtime: bool = False) -> None:
        self.frames: dict[int, int] = {}
        self.events: list[tuple[int, int, str]] = []  # (decided_at, arrival_ns, method)
        self.stop = threading.Event()
        self.realtime = realtime

    def _thread_priority(self) -> None:
        """In the realtime rows the receiving threads run at the run's priority too."""
        if self.realtime:
            _realtime(0)

    def osc(self, frame_port: int, event_port: int) -> list[socket.socket]:
        socks = []
        for port in (frame_port, event_port):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", port))
            s.setsockopt(socket.SOL_SOCKET, 35, 1)  # SO_TIMESTAMPNS (Linux)
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            s.settimeout(0.1)
            socks.append(s)
        threading.Thread(target=self._read_osc, args=socks, daemon=True).start()
        return socks

    def _read_osc(self, frames: socket.socket, events: socket.socket) -> None:
        import selectors

        from pythonosc.osc_message import OscMessage

        self._thread_priority()
        sel = selectors.DefaultSelector()
        sel.register(frames, selectors.EVENT_READ)
        sel.register(events, selectors.EVENT_READ)
        while not self.stop.is_set():
            for key, _ in sel.select(0.1):
                sock = key.fileobj
                assert isinstance(sock, socket.socket)
                data, anc, _, _ = sock.recvmsg(70_000, 64)
                offset = time.monotonic_ns() - time.time_ns()
                stamp = time.monotonic_ns()
                for level, kind, value in anc:
                    if level == socket.SOL_SOCKET and kind == 35:
                        sec, nsec = struct.unpack_from("qq", value)
                        stamp = sec * 1_000_000_000 + nsec + offset
                if sock is frames:
                    if data.startswith(b"/streamkey/frame"):
                        tags_end = data.index(b"\0", data.index(b",id"))
                        seq = struct.unpack_from(">i", data, (tags_end + 4) & ~3)[0]
                        self.frames[seq] = stamp
                else:
                    params = OscMessage(data).params
                    self.events.append((int(params[2]) + int(params[5]), stamp, params[1]))

    def zmq(self, event_endpoint: str) -> None:
        """Events from the run's ZeroMQ publisher (frames come by OSC, see `_latency_one`)."""
        connected = threading.Event()
        threading.Thread(target=self._read_zmq, args=(event_endpoint, connected),
                         daemon=True).start()
        connected.wait(10.0)

    def _read_zmq(self, endpoint: str, connected: threading.Event) -> None:
        import zmq

        self._thread_priority()
        ctx = zmq.Context()  # its I/O thread starts here, at this thread's priority
        events = ctx.socket(zmq.SUB)
        events.setsockopt(zmq.SUBSCRIBE, b"event")
        events.setsockopt(zmq.RCVHWM, 100_000)
        events.connect(endpoint)
        connected.set()
        poller = zmq.Poller()
        poller.register(events, zmq.POLLIN)
        while not self.stop.is_set():
            for sock, _ in poller.poll(100):
                parts = sock.recv_multipart()
                stamp = time.monotonic_ns()
                e = json.loads(parts[1])
                if e.get("type") == "keyframe":
                    self.events.append((e["decided_at"], stamp, e["method"]))
        events.close(linger=0)
        ctx.term()


def _realtime(pid: int) -> None:
    """SCHED_RR at `run --realtime`'s priority for a thread or process (0: this thread)."""
    from ..live import REALTIME_PRIORITY

    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(pid, os.SCHED_RR, os.sched_param(REALTIME_PRIORITY))


def _streamkey(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "streamkey", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_line(proc: subprocess.Popen[str], needle: str, timeout: float = 60.0) -> list[str]:
    """The process's stderr lines up to the one containing `needle`."""
    deadline = time.monotonic() + timeout
    assert proc.stderr is not None
    lines = []
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            raise RuntimeError(f"process ended before {needle!r}")
        lines.append(line)
        if needle in line:
            return lines
    raise RuntimeError(f"no {needle!r} within {timeout} s")


def _load() -> float:
    """The 1-minute load average (the machine's other work; NaN where unknown)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return float("nan")


def _latency_one(transport: str, clip: Path, frames: int, realtime: bool = False,
                 workers: int = 1) -> dict[str, Any]:
    """One run: replay -> run (all methods) -> this process, over `transport`.

    The receiver's copy of every frame comes over OSC in both cases, stamped by the kernel
    when the replay sends it (right after the same frame went to the run), so each latency
    runs from the frame leaving the replay to the event reaching the receiver: the
    transport both ways is included, the receiver's own scheduling delays can only add.
    """
    receiver = _Receiver(realtime)
    load_before = _load()
    with tempfile.TemporaryDirectory() as tmp:
        summary_path = Path(tmp) / "summary.json"
        copy_port = _free_port()
        extra = (["--realtime"] if realtime else []) + ["--workers", str(workers)]
        if transport == "osc":
            run_port, event_port = _free_port(), _free_port()
            socks = receiver.osc(copy_port, event_port)
            run = _streamkey("run", "--from", f"osc://127.0.0.1:{run_port}", "--skeleton",
                             str(clip), "--method", "all", "--to",
                             f"osc://127.0.0.1:{event_port}?layout=compact",  # parsed below
                             "--summary", str(summary_path), *extra)
            said = _wait_line(run, "listening on")
            targets = ["--to", f"osc://127.0.0.1:{run_port}"]
        else:
            pub, events = (_free_port(socket.SOCK_STREAM) for _ in range(2))
            socks = receiver.osc(copy_port, _free_port())
            run = _streamkey("run", "--from", f"zmq+tcp://127.0.0.1:{pub}", "--method", "all",
                             "--to", f"zmq+tcp://127.0.0.1:{events}", "--summary",
                             str(summary_path), *extra)
            said = _wait_line(run, "listening on")
            receiver.zmq(f"tcp://127.0.0.1:{events}")
            targets = ["--to", f"zmq+tcp://127.0.0.1:{pub}", "--wait", "10"]
        targets += ["--to", f"osc://127.0.0.1:{copy_port}"]
        replay = _streamkey("replay", str(clip), "--loop", "--frames", str(frames), *targets)
        if realtime:  # the sender too (its threads start later and inherit it)
            _realtime(replay.pid)
        replay.wait(timeout=frames / 120 * 3 + 60)
        time.sleep(1.0)
        sent_until = time.monotonic_ns()
        load_after = _load()
        run.send_signal(signal.SIGINT)
        run.communicate(timeout=60)
        receiver.stop.set()
        time.sleep(0.2)
        for s in socks:
            s.close()
        own = json.loads(summary_path.read_text())
    timed = [(d, (t - receiver.frames[d]) / 1e6, method) for d, t, method in receiver.events
             if d in receiver.frames and t < sent_until]
    lat = np.array([ms for _, ms, _ in timed])
    per_method: dict[str, float] = {}
    for name in sorted({method for _, _, method in timed}):
        own_lat = np.array([ms for _, ms, method in timed if method == name])
        per_method[f"{name}_p50_ms"] = round(float(np.percentile(own_lat, 50)), 3)
        per_method[f"{name}_p99_ms"] = round(float(np.percentile(own_lat, 99)), 3)
    worst = sorted(timed, key=lambda item: -item[1])[:5]
    priority = next((line.split(":", 1)[1].strip() for line in said
                     if line.startswith("priority:")), "normal")

    def pct(q: float) -> float | None:
        return round(float(np.percentile(lat, q)), 3) if len(lat) else None

    p99 = pct(99)
    return {"transport": transport, "workers": workers, "priority": priority,
            "load_1min_before": load_before,
            "load_1min_after": load_after, "frames_sent": frames,
            "frames_seen_by_receiver": len(receiver.frames), "events": len(lat),
            "p50_ms": pct(50), "p99_ms": p99,
            "max_ms": round(float(lat.max()), 3) if len(lat) else None,
            "over_3ms": int((lat > 3.0).sum()),
            "run_summary_p50_ms": own["wall_latency_ms"]["p50"],
            "run_summary_p99_ms": own["wall_latency_ms"]["p99"],
            "run_frame_wait_p99_ms": own.get("frame_wait_ms", {}).get("p99"),
            "run_frames_in": own["frames_in"], **per_method,
            "worst_events": ", ".join(f"{method}@{d} {ms:.1f}" for d, ms, method in worst),
            "target_p99_ms": 3.0, "met": p99 is not None and p99 <= 3.0}


def bench_latency(data: Path | None, quick: bool = False,
                  say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """External-receiver latency over OSC and ZeroMQ (replay and run as processes), at the
    run's normal priority and with `run --realtime`; each row says the load average.
    `say`: a progress line per run (which run of how many, its length)."""
    clip = (data / _LATENCY_CLIP) if data is not None else None
    if clip is None or not clip.exists():
        raise RuntimeError("bench --latency needs the shared clips (--data)")
    frames = 2400 if quick else 7200  # 20 s or 60 s at 120 Hz
    runs = [(t, realtime) for realtime in (False, True) for t in ("osc", "zmq")]
    rows = []
    for i, (transport, realtime) in enumerate(runs, 1):
        if say is not None:
            say(f"bench latency: run {i}/{len(runs)}: {transport}, "
                f"{'SCHED_RR' if realtime else 'normal priority'}, {frames / 120:.0f} s of "
                f"frames (about {len(runs) - i + 1} x {frames / 120 + 5:.0f} s left)")
        rows.append(_latency_one(transport, clip, frames, realtime))
    return {"rows": rows, "clip": str(clip), "rate_hz": 120, "methods": "all",
            "cpus": os.cpu_count(),
            "note": "latency: the frame leaving the replay (kernel stamp of its OSC copy) to "
                    "the event reaching this process; load_1min: os.getloadavg() before and "
                    "after each run (the machine's other work); priority: the run's "
                    "(`run --realtime` rows: the replay and the receiving threads at the "
                    "same SCHED_RR priority); <method>_p50/p99_ms: that method's events "
                    "alone; worst_events: the five slowest as method@decided_at ms"}


# ------------------------------------------------------------------ WebSocket clients

_CLIENTS = """
import asyncio, sys
from websockets.asyncio.client import connect
async def reader(url):
    async with connect(url, max_queue=None) as ws:
        async for _ in ws:
            pass
async def main(url, n):
    await asyncio.gather(*(reader(url) for _ in range(n)), return_exceptions=True)
asyncio.run(main(sys.argv[1], int(sys.argv[2])))
"""


def _ws_run(motion: Motion, clients: int, seconds: float) -> dict[str, Any]:
    from ..adapters import make_sink, parse_address
    from ..live import build_engine
    from ..methods import ONLINE_METHODS
    from ..replay.source import MotionSource

    class Gated(MotionSource):
        gate = asyncio.Event()

        async def _produce(self) -> None:
            await self.gate.wait()
            await super()._produce()

    port = _free_port(socket.SOCK_STREAM)
    sink = make_sink(parse_address(f"ws://127.0.0.1:{port}"))
    procs: list[asyncio.subprocess.Process] = []

    async def main() -> Any:
        Gated.gate = asyncio.Event()
        source = Gated(motion, loop=True, count=int(seconds * motion.fps))
        engine = build_engine(source, list(ONLINE_METHODS), [sink], on_ready=lambda line: None)
        task = asyncio.create_task(engine.run())
        while sink.server is None:  # type: ignore[attr-defined]  # noqa: ASYNC110
            await asyncio.sleep(0.01)
        if clients:
            procs.append(await asyncio.create_subprocess_exec(
                sys.executable, "-c", _CLIENTS, f"ws://127.0.0.1:{port}", str(clients)))
        while len(sink.clients) < clients:  # type: ignore[attr-defined]  # noqa: ASYNC110
            await asyncio.sleep(0.05)
        Gated.gate.set()
        return await task

    try:
        summary = asyncio.run(main())
    finally:
        for p in procs:
            os.kill(p.pid, signal.SIGKILL)
    lat = summary.latency_percentiles()
    return {"clients": clients, "seconds": seconds, "events": sum(summary.events.values()),
            "p50_ms": round(lat["p50"], 3), "p99_ms": round(lat["p99"], 3),
            "max_ms": round(lat["max"], 3), "ws_sent": summary.sinks["ws"]["sent"],
            "ws_dropped": summary.sinks["ws"]["dropped"],
            **{f"{m}_p99_ms": round(h.percentile(99) or 0.0, 3)
               for m, h in sorted(summary.method_latency.items())}}


def bench_ws_clients(data: Path | None, quick: bool = False) -> dict[str, Any]:
    """Event wall latency at 120 Hz with 0, 100 and 300 reading WebSocket clients."""
    motion = _clip(data)
    seconds = 15.0 if quick else 45.0
    return {"rows": [_ws_run(motion, n, seconds) for n in (0, 100, 300)],
            "note": "clients read in another process on the same machine"}


def run_live_bench(kind: str, data: Path | None, quick: bool,
                   say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """One live benchmark by name (see `LIVE_KINDS`); `say`: progress lines, where the
    benchmark has steps to tell."""
    if kind == "latency":
        return bench_latency(data, quick, say)
    fn = {"memory": bench_memory, "ws_clients": bench_ws_clients}
    return fn[kind](data, quick)
