"""Live benchmarks of `streamkey bench`: the engine measured end to end.

- `memory`: resident memory of an accelerated one-hour stream (432,000 frames at 120 Hz,
  pushed as fast as the engine takes them) through all methods and every kind of sink;
  growth after warm-up must stay within 5 MB. `quick`: 10 minutes of stream.
- `latency`: replay and run as separate processes over OSC and over ZeroMQ at 120 Hz with
  all methods; this process is the external receiver: it gets a copy of every frame and
  every event, both stamped on arrival (kernel receive time for UDP), and reports p50/p99
  of event arrival minus the arrival of its deciding frame (`decided_at`), next to what
  the run's own summary says (arrival at its socket -> event leaves for the sinks).
- `ws_clients`: event wall latency inside the engine at 120 Hz with 0, 100 and 300
  WebSocket clients reading in another process (broadcast cost on the frame path).
"""

from __future__ import annotations

import asyncio
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
from pathlib import Path
from typing import Any

import numpy as np

from .bvh import read_bvh
from .motion import Motion

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
    from .replay.demo import demo_motion

    return demo_motion()


def bench_memory(data: Path | None, quick: bool = False) -> dict[str, Any]:
    """RSS over an accelerated stream of an hour (10 min if `quick`) with every sink."""
    from .adapters import make_sink, parse_address
    from .live import build_engine
    from .methods import ONLINE_METHODS
    from .replay.source import MotionSource

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

    def __init__(self) -> None:
        self.frames: dict[int, int] = {}
        self.events: list[tuple[int, int, str]] = []  # (decided_at, arrival_ns, method)
        self.stop = threading.Event()

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

    def zmq(self, frame_endpoint: str, event_endpoint: str) -> None:
        import zmq

        ctx = zmq.Context.instance()
        frames, events = ctx.socket(zmq.SUB), ctx.socket(zmq.SUB)
        frames.setsockopt(zmq.SUBSCRIBE, b"frame")
        events.setsockopt(zmq.SUBSCRIBE, b"event")
        for s, e in ((frames, frame_endpoint), (events, event_endpoint)):
            s.setsockopt(zmq.RCVHWM, 100_000)
            s.connect(e)
        threading.Thread(target=self._read_zmq, args=(frames, events), daemon=True).start()

    def _read_zmq(self, frames: Any, events: Any) -> None:
        import zmq

        poller = zmq.Poller()
        poller.register(frames, zmq.POLLIN)
        poller.register(events, zmq.POLLIN)
        while not self.stop.is_set():
            for sock, _ in poller.poll(100):
                parts = sock.recv_multipart()
                stamp = time.monotonic_ns()
                if sock is frames:
                    self.frames[json.loads(parts[1])["seq"]] = stamp
                else:
                    e = json.loads(parts[1])
                    if e.get("type") == "keyframe":
                        self.events.append((e["decided_at"], stamp, e["method"]))
        frames.close(linger=0)
        events.close(linger=0)


def _streamkey(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "streamkey", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_line(proc: subprocess.Popen[str], needle: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            raise RuntimeError(f"process ended before {needle!r}")
        if needle in line:
            return
    raise RuntimeError(f"no {needle!r} within {timeout} s")


def _latency_one(transport: str, clip: Path, frames: int) -> dict[str, Any]:
    receiver = _Receiver()
    with tempfile.TemporaryDirectory() as tmp:
        summary_path = Path(tmp) / "summary.json"
        if transport == "osc":
            run_port, copy_port, event_port = _free_port(), _free_port(), _free_port()
            socks = receiver.osc(copy_port, event_port)
            run = _streamkey("run", "--from", f"osc://127.0.0.1:{run_port}", "--skeleton",
                             str(clip), "--method", "all", "--to",
                             f"osc://127.0.0.1:{event_port}?layout=compact",  # parsed below
                             "--summary", str(summary_path))
            _wait_line(run, "listening on")
            targets = ["--to", f"osc://127.0.0.1:{run_port}",
                       "--to", f"osc://127.0.0.1:{copy_port}"]
        else:
            pub, events = (_free_port(socket.SOCK_STREAM) for _ in range(2))
            socks = []
            run = _streamkey("run", "--from", f"zmq+tcp://127.0.0.1:{pub}", "--method", "all",
                             "--to", f"zmq+tcp://127.0.0.1:{events}", "--summary",
                             str(summary_path))
            _wait_line(run, "listening on")
            receiver.zmq(f"tcp://127.0.0.1:{pub}", f"tcp://127.0.0.1:{events}")
            targets = ["--to", f"zmq+tcp://127.0.0.1:{pub}", "--wait", "10"]
        replay = _streamkey("replay", str(clip), "--loop", "--frames", str(frames), *targets)
        replay.wait(timeout=frames / 120 * 3 + 60)
        time.sleep(1.0)
        sent_until = time.monotonic_ns()
        run.send_signal(signal.SIGINT)
        run.communicate(timeout=60)
        receiver.stop.set()
        time.sleep(0.2)
        for s in socks:
            s.close()
        own = json.loads(summary_path.read_text())
    lat = np.array([(t - receiver.frames[d]) / 1e6 for d, t, _ in receiver.events
                    if d in receiver.frames and t < sent_until])
    return {"transport": transport, "frames_sent": frames,
            "frames_seen_by_receiver": len(receiver.frames), "events": len(lat),
            "p50_ms": round(float(np.percentile(lat, 50)), 3) if len(lat) else None,
            "p99_ms": round(float(np.percentile(lat, 99)), 3) if len(lat) else None,
            "max_ms": round(float(lat.max()), 3) if len(lat) else None,
            "run_summary_p50_ms": own["wall_latency_ms"]["p50"],
            "run_summary_p99_ms": own["wall_latency_ms"]["p99"],
            "run_frames_in": own["frames_in"], "target_p99_ms": 3.0}


def bench_latency(data: Path | None, quick: bool = False) -> dict[str, Any]:
    """External-receiver latency over OSC and ZeroMQ (replay and run as processes)."""
    clip = (data / _LATENCY_CLIP) if data is not None else None
    if clip is None or not clip.exists():
        raise RuntimeError("bench --latency needs the shared clips (--data)")
    frames = 2400 if quick else 7200  # 20 s or 60 s at 120 Hz
    return {"rows": [_latency_one(t, clip, frames) for t in ("osc", "zmq")],
            "clip": str(clip), "rate_hz": 120, "methods": "all"}


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
    from .adapters import make_sink, parse_address
    from .live import build_engine
    from .methods import ONLINE_METHODS
    from .replay.source import MotionSource

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


def run_live_bench(kind: str, data: Path | None, quick: bool) -> dict[str, Any]:
    """One live benchmark by name (see `LIVE_KINDS`)."""
    fn = {"memory": bench_memory, "latency": bench_latency, "ws_clients": bench_ws_clients}
    return fn[kind](data, quick)
