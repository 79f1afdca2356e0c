"""`streamkey bench --streams`: the capacity of a run, measured from outside, and the
scheduling model behind it.

The capacity (`bench_streams_external`): a sender process plays 1, 4, 8, 16, 24 and 32
streams at 120 Hz over OSC (each its own stream id, frame phases spread as independent
devices'), `streamkey run` keyframes them with every method (one worker, then one per core)
and publishes the events on ZeroMQ, and this process receives them: latency = an event's
arrival minus its deciding frame's send. A stream count is met when p99 <= 5 ms and no frame
was lost; the result names the largest met count per worker setting (and per core).

A stage: one capture system, N performers, every stream ticking at 120 Hz on the same clock
(frame i of every stream arrives at t0 + i / 120 s). Each stream replays its own shared
clip (looped) through the three-method pipeline (saliency, speed, simplify) in one engine.
A frame's arrival is stamped with its tick's deadline, as a kernel timestamp would be, so
time spent waiting behind another stream's work counts. Due events are those a frame's
`Pipeline.push` decides (not the deferred re-analysis); their wall latency is the measure.
`due_first=False` is the old order: each frame's re-analysis right after its push.

Two measurements:

- `rows` (trace-driven): every stream's pipeline is run once over its frames and the CPU
  time of each `push` and `idle` call is measured (`thread_time`); then one worker serving
  N streams is simulated with both orders, exactly as the engine schedules (a queued frame
  first, its stream's pending re-analysis before it; otherwise one stream's re-analysis).
  It isolates the scheduling question from the machine's load and timer noise.
- `live_rows`: the real engine in this process, paced by the wall clock. On a loaded
  machine it measures mostly how much CPU the process got (`cpu_per_wall`).
"""

from __future__ import annotations

import asyncio
import itertools
import os
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..bvh import read_bvh
from ..engine import Engine
from ..io import FrameQueue, Source, StreamSpec
from ..keyframes import KeyframeEvent
from ..motion import Motion
from ..online import Pipeline
from ..replay.pacing import frame_stream
from ..streaming import make_keyframers

__all__ = ["bench_streams", "readme_table", "simulate", "STREAM_COUNTS", "METHODS"]

STREAM_COUNTS = (1, 2, 4, 8, 16)
METHODS = ["saliency", "speed", "simplify"]
RATE = 120.0


class _Stage(Source):
    """N streams of looped clips ticking together at `RATE`, for `seconds`."""

    name = "stage"

    def __init__(self, motions: dict[str, Motion], seconds: float) -> None:
        super().__init__()
        self.frames = FrameQueue(self.stats, maxsize=4096)
        for name, m in motions.items():
            self.named[name] = (m.skeleton, m.fps)
        self.iters = {name: frame_stream(m, loop=True) for name, m in motions.items()}
        self.ticks = int(seconds * RATE)
        self.late_ticks = 0

    async def start(self) -> str:
        self.spawn(self._produce())
        return f"{len(self.iters)} streams at {RATE:g} Hz"

    async def _produce(self) -> None:
        t0 = time.monotonic_ns() + 50_000_000
        for i in range(self.ticks):
            deadline = t0 + int(i * 1e9 / RATE)
            delay = (deadline - time.monotonic_ns()) / 1e9
            if delay > 0:
                await asyncio.sleep(delay)
            elif delay < -1 / RATE:
                self.late_ticks += 1
            for name, frames in self.iters.items():
                self.stats.received += 1
                self.frames.put(next(frames), deadline, name)
            await asyncio.sleep(0)
        self.frames.end()


def _clips(data: Path | None, n: int) -> list[Motion]:
    if data is None:
        from ..replay.demo import demo_motion

        return [demo_motion()] * n
    paths = sorted(p for p in data.glob("*.bvh"))
    motions = [read_bvh(p) for p in paths[: max(n, 1)]]
    return [motions[i % len(motions)] for i in range(n)]


def _one(motions: list[Motion], due_first: bool, seconds: float) -> dict[str, Any]:
    named = {f"s{i:02d}": m for i, m in enumerate(motions)}
    source = _Stage(named, seconds)

    def factory(spec: StreamSpec) -> list[Any]:
        motion = Motion(spec.skeleton, np.zeros((0, spec.skeleton.n_channels)), spec.fps)
        return make_keyframers(motion, METHODS, stream=spec.stream)

    engine = Engine(source, factory, [], max_streams=len(named), due_first=due_first,
                    freeze_gc=True)  # as `run` does
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    cpu, wall = time.process_time(), time.perf_counter()
    summary = asyncio.run(engine.run())
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    due, every = summary.due_latency.summary(), summary.latency.summary()
    return {"streams": len(named), "due_first": due_first,
            "due_events": summary.due_latency.count,
            "due_p50_ms": round(due["p50"] or 0.0, 3), "due_p99_ms": round(due["p99"] or 0.0, 3),
            "all_p99_ms": round(every["p99"] or 0.0, 3),
            "frames": summary.frames_in, "queue_drops": summary.source["queue_drops"],
            "late_ticks": source.late_ticks, "cpu_per_wall": round(cpu / wall, 2),
            "load_1min": round(load, 2)}


def _trace(motion: Motion, frames: int) -> np.ndarray:
    """(frames, 3): CPU ns of `push`, CPU ns of `idle`, due keyframe events of each frame."""
    pipe = Pipeline(make_keyframers(motion, METHODS, stream="trace"))
    out = np.zeros((frames, 3), dtype=np.int64)
    clock = time.thread_time_ns
    for k, frame in enumerate(itertools.islice(frame_stream(motion, loop=True), frames)):
        t0 = clock()
        due = pipe.push(frame)
        t1 = clock()
        pipe.idle()
        out[k] = (t1 - t0, clock() - t1, sum(isinstance(e, KeyframeEvent) for e in due))
    return out


def simulate(traces: list[np.ndarray], due_first: bool) -> tuple[np.ndarray, float]:
    """Due-event latencies (ms) of one worker serving one stream per trace, all ticking at
    `RATE` together, in the engine's order; and the worker's busy fraction."""
    n, frames = len(traces), min(len(t) for t in traces)
    period = 1e9 / RATE
    now, p, total = 0.0, 0, n * frames
    deferred: OrderedDict[int, int] = OrderedDict()  # stream -> frame whose idle is pending
    latencies: list[float] = []
    while True:
        if p < total and (p // n) * period <= now:  # a queued frame: its due decisions now
            k, s = divmod(p, n)
            p += 1
            if s in deferred:  # the stream's own order: its previous re-analysis first
                now += traces[s][deferred.pop(s), 1]
            now += traces[s][k, 0]
            latencies += [(now - k * period) / 1e6] * int(traces[s][k, 2])
            if due_first:
                deferred[s] = k
            else:
                now += traces[s][k, 1]
        elif deferred:  # nothing queued: one stream's re-analysis
            s, k = deferred.popitem(last=False)
            now += traces[s][k, 1]
        elif p < total:
            now = (p // n) * period
        else:
            break
    busy = sum(float(t[:frames, :2].sum()) for t in traces) / (frames * period)
    return np.array(latencies), busy


def _simulated_rows(motions: list[Motion], seconds: float) -> list[dict[str, Any]]:
    """Both orders for every stream count, with the streams started on the same tick
    (their periodic re-analyses coincide) and staggered (stream s shifted by 7 s frames)."""
    frames = int(seconds * RATE)
    _trace(motions[0], 60)  # first-call costs (imports, FK plans) out of the traces
    together = [_trace(m, frames) for m in motions]
    staggered = [np.roll(t, -((s * 7) % 24), axis=0) for s, t in enumerate(together)]
    rows = []
    for starts, traces in (("staggered", staggered), ("together", together)):
        for n, flag in itertools.product(STREAM_COUNTS, (True, False)):
            lat, busy = simulate(traces[:n], flag)
            rows.append({"starts": starts, "streams": n, "due_first": flag,
                         "due_events": len(lat),
                         "due_p50_ms": round(float(np.percentile(lat, 50)), 3),
                         "due_p99_ms": round(float(np.percentile(lat, 99)), 3),
                         "due_max_ms": round(float(lat.max()), 3),
                         "worker_busy": round(busy, 3)})
    return rows


def bench_streams(data: Path | None, quick: bool = False,
                  say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The capacity measured outside the run (`bench_streams_external`: 1-32 streams, one
    worker and one per core), and the scheduling model's due-event p50 / p99 for 1-16
    streams, due-first on and off. `say`: a line before each external row (which of how
    many, the time left) and before the model."""
    seconds = 8.0 if quick else 20.0
    motions = _clips(data, max(STREAM_COUNTS))
    load = os.getloadavg()[0]
    external = bench_streams_external(data, quick, say=say)
    if say is not None:
        say(f"bench streams: the scheduling model, {len(STREAM_COUNTS)} stream counts, "
            f"due-first on and off, {seconds:.0f} s of frames each")
    rows = _simulated_rows(motions, seconds)
    return {**external, "rows": rows, "seconds_per_row": seconds, "rate_hz": RATE,
            "methods": METHODS,
            "cores": os.cpu_count(), "load_average_before": round(load, 2),
            "load_average_after": round(os.getloadavg()[0], 2),
            "note": "all streams tick together (one capture clock); arrival = tick deadline; "
                    "shared machine: compare rows of one run, not runs"}


def readme_table(result: dict[str, Any]) -> str:
    """The README's tables of a `bench_streams` result: the capacity measured outside the
    run, then the scheduling model (due-first against the old order)."""
    lines = ["| phases | streams | workers | due p50 / p99 / max (ms, external receiver) "
             "| frames lost | kernel drops | load before / after |",
             "|---|---|---|---|---|---|---|"]
    for r in result.get("external_rows", []):
        lines.append(f"| {r.get('phases', 'spread')} | {r['streams']} | {r['workers']} | "
                     f"{r['p50_ms']} / {r['p99_ms']} / {r['max_ms']} | {r['frames_lost']} | "
                     f"{r['kernel_drops']} | {r['load_1min_before']} / "
                     f"{r['load_1min_after']} |")
    lines.append("")
    for c in result.get("capacity", []):
        lines.append(f"- phases {c.get('phases', 'spread')}, {c['workers']} worker(s): "
                     f"{c['streams']} stream(s) at due p99 <= {TARGET_P99_MS:g} ms, max <= "
                     f"{TARGET_MAX_MS:g} ms, no frame lost ({c['streams_per_core']} per core)")
    return "\n".join(lines) + "\n\n" + _model_table(result)


def _model_table(result: dict[str, Any]) -> str:
    """The scheduling model's table (due-first against the old order)."""
    def ms(v: float) -> str:
        return f"{v:,.0f}" if v >= 100 else f"{v:.2f}" if v < 10 else f"{v:.1f}"

    def pair(rows: list[dict[str, Any]], n: int, starts: str | None = None
             ) -> tuple[dict[str, Any], dict[str, Any]]:
        a, b = (next(r for r in rows if r["streams"] == n and r["due_first"] is f
                     and r.get("starts") == starts) for f in (True, False))
        return a, b

    lines = ["| streams | staggered starts: due-first p50 / p99 | old order p50 / p99 | "
             "same-tick starts: due-first p50 / p99 | old order p50 / p99 | worker busy |",
             "|---|---|---|---|---|---|"]
    for n in sorted({r["streams"] for r in result["rows"]}):
        cells = []
        for rows, starts in ((result["rows"], "staggered"), (result["rows"], "together")):
            a, b = pair(rows, n, starts)
            cells += [f"{ms(a['due_p50_ms'])} / {ms(a['due_p99_ms'])}",
                      f"{ms(b['due_p50_ms'])} / {ms(b['due_p99_ms'])}"]
            if starts == "together":
                cells.append(f"{a['worker_busy']:.0%}")
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# ---------------------------------------------------------------------- external processes

EXTERNAL_COUNTS = (1, 4, 8, 16, 24, 32)
TARGET_P99_MS = 5.0
TARGET_MAX_MS = 20.0
PHASES = ("spread", "together")
_SENDER = "from streamkey.bench.streams import sender_main; sender_main()"


def sender_main() -> None:
    """The sender process of `external_row` (argv: port, streams, seconds, phases, clip,
    out.npy): N streams at `RATE` over OSC, each its own stream id; phases `spread` (stream
    s shifted by s / N of a period, as independent devices) or `together` (one tick); each
    frame's send time (monotonic ns) saved per stream and seq."""
    import socket
    import sys

    from ..adapters.osc import encode_frame, encode_skeleton, stream_address

    port, n, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    phases, clip, out = sys.argv[4], Path(sys.argv[5]), sys.argv[6]
    motion = read_bvh(clip)
    channels = motion.channels.astype(np.float32)
    names = [f"s{i:02d}" for i in range(n)]
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
    target = ("127.0.0.1", port)
    skeletons = [encode_skeleton(motion.skeleton, RATE, stream_address("skeleton", s))
                 for s in names]
    addresses = [stream_address("frame", s) for s in names]
    frames = int(seconds * RATE)
    sent = np.zeros((n, frames + 1), dtype=np.int64)
    for message in skeletons:
        sock.sendto(message, target)
    time.sleep(1.0)  # every stream's pipeline built before its first frame
    period = 1e9 / RATE
    offsets = [int(s * period / n) if phases == "spread" else 0 for s in range(n)]
    schedule = sorted((offsets[s], s) for s in range(n))
    t0 = time.monotonic_ns() + 20_000_000
    for i in range(frames):
        if i % int(RATE) == 0 and i:
            for message in skeletons:
                sock.sendto(message, target)
        for offset, s in schedule:
            due = t0 + int(i * period) + offset
            wait = due - time.monotonic_ns()
            if wait > 200_000:
                time.sleep((wait - 100_000) / 1e9)
            while time.monotonic_ns() < due:
                pass
            row = channels[(i + 97 * s) % len(channels)]
            sock.sendto(encode_frame(i + 1, i / RATE, row, addresses[s]), target)
            sent[s, i + 1] = time.monotonic_ns()
    np.save(out, sent)


class _EventReceiver:
    """Keyframe events from the run's ZeroMQ publisher, stamped on arrival, on a thread:
    (stream, decided_at, arrival ns)."""

    def __init__(self, endpoint: str, realtime: bool) -> None:
        import threading

        import zmq

        self.got: list[tuple[str, int, int]] = []
        self.realtime = realtime
        self.stop = threading.Event()
        self.ctx = zmq.Context()
        self.sub = self.ctx.socket(zmq.SUB)
        self.sub.setsockopt(zmq.SUBSCRIBE, b"event")
        self.sub.setsockopt(zmq.RCVHWM, 1_000_000)
        self.sub.connect(endpoint)
        self.thread = threading.Thread(target=self._receive, daemon=True)
        self.thread.start()

    def _receive(self) -> None:
        import json

        if self.realtime:
            _realtime(0)
        while not self.stop.is_set():
            if self.sub.poll(100):
                parts = self.sub.recv_multipart()
                stamp = time.monotonic_ns()
                e = json.loads(parts[1])
                if e.get("type") == "keyframe":
                    self.got.append((e["stream"], int(e["decided_at"]), stamp))

    def close(self) -> None:
        """Stop receiving and release the socket."""
        self.stop.set()
        self.thread.join(5)
        self.sub.close(linger=0)
        self.ctx.term()


def _free_port(kind: int) -> int:
    import socket

    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def external_row(streams: int, workers: int, seconds: float, clip: Path,
                 phases: str = "spread", python: str | None = None,
                 realtime: bool = False) -> dict[str, Any]:
    """One measurement with three processes: the sender (`sender_main`), `streamkey run`
    (OSC in, all methods, ZeroMQ events out, `--workers` if more than one), and this one, the
    receiver: each keyframe event's latency is its arrival here minus its deciding frame's
    send time. `python`: the interpreter of the run (another checkout's, to compare).
    `realtime`: the run with `--realtime`, the sender and the receiving thread at the same
    SCHED_RR priority (where granted): on a machine busy with other work, what the three
    processes can do when they get the CPU they ask for."""
    import json
    import socket
    import subprocess
    import sys
    import tempfile

    port, events_port = _free_port(socket.SOCK_DGRAM), _free_port(socket.SOCK_STREAM)
    with tempfile.TemporaryDirectory() as tmp:
        summary_path, sent_path = Path(tmp) / "summary.json", Path(tmp) / "sent.npy"
        run = subprocess.Popen(
            [python or sys.executable, "-P", "-m", "streamkey", "run", "--from",
             f"osc://127.0.0.1:{port}", "--method", "all", "--to",
             f"zmq+tcp://127.0.0.1:{events_port}", "--max-streams", str(max(streams, 1)),
             *(["--workers", str(workers)] if workers > 1 else []),
             *(["--realtime"] if realtime else []),
             "--idle-exit", "3", "--summary", str(summary_path)],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        assert run.stderr is not None
        for line in run.stderr:
            if "listening on" in line:
                break
        receiver = _EventReceiver(f"tcp://127.0.0.1:{events_port}", realtime)
        time.sleep(0.5)  # the subscription reaches the publisher
        load = os.getloadavg()[0]
        sender = subprocess.Popen(
            [sys.executable, "-c", _SENDER, str(port), str(streams), str(seconds), phases,
             str(clip), str(sent_path)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True)
        if realtime:
            _realtime(sender.pid)
        _, sender_err = sender.communicate(timeout=seconds * 4 + 120)
        sent_until = time.monotonic_ns()  # later events: the flush at the run's idle exit
        if sender.returncode:
            raise RuntimeError(f"sender failed: {sender_err[-500:]}")
        load_after = os.getloadavg()[0]
        _, err = run.communicate(timeout=seconds * 4 + 120)
        receiver.close()
        sent = np.load(sent_path)
        own = json.loads(summary_path.read_text())
    got = [(s, d, t) for s, d, t in receiver.got if t < sent_until]
    return {"streams": streams, "workers": workers, "phases": phases, "seconds": seconds,
            "realtime": realtime, **_latencies(got, sent, own),
            "load_1min_before": round(load, 2), "load_1min_after": round(load_after, 2),
            "run_exit": run.returncode, "run_error": err[-300:] if run.returncode else ""}


def _latencies(got: list[tuple[str, int, int]], sent: np.ndarray,
               own: dict[str, Any]) -> dict[str, Any]:
    """A row's numbers: event latencies from their deciding frame's send (events decided by
    a stream's end are not timed), frames lost, the run's own view."""
    index = {f"s{i:02d}": i for i in range(len(sent))}
    by_stream: dict[str, list[float]] = {}
    for s, d, t in got:
        if s in index and 0 < d < sent.shape[1] and sent[index[s], d]:
            by_stream.setdefault(s, []).append((t - sent[index[s], d]) / 1e6)
    lat = np.array([v for values in by_stream.values() for v in values])
    frames_sent = int((sent > 0).sum())
    lost = frames_sent - own["frames_in"]

    def pct(q: float) -> float | None:
        return round(float(np.percentile(lat, q)), 3) if len(lat) else None

    p99 = pct(99)
    return {"frames_sent": frames_sent, "frames_in": own["frames_in"], "frames_lost": lost,
            "kernel_drops": own["source"].get("kernel_drops"),
            "queue_drops": own["source"]["queue_drops"], "events": len(lat),
            "p50_ms": pct(50), "p99_ms": p99,
            "max_ms": round(float(lat.max()), 3) if len(lat) else None,
            "worst_stream_p99_ms": round(max(float(np.percentile(v, 99))
                                             for v in by_stream.values()), 3)
            if by_stream else None,
            "run_due_p99_ms": own["due_latency_ms"]["p99"],
            "run_scheduler": own.get("scheduler"),
            "met": (p99 is not None and p99 <= TARGET_P99_MS and lost == 0
                    and float(lat.max()) <= TARGET_MAX_MS)}


def _realtime(pid: int) -> None:
    """SCHED_RR at `run --realtime`'s priority for a process or this thread (0), if granted."""
    import contextlib

    from ..live import REALTIME_PRIORITY

    with contextlib.suppress(AttributeError, OSError):
        os.sched_setscheduler(pid, os.SCHED_RR, os.sched_param(REALTIME_PRIORITY))


ROW_OVERHEAD_S = 12.0  # a row's start (the run loads its kernels) and end (idle exit, flush)


def _minutes(seconds: float) -> str:
    """`45 s` or `12 min`: a time left as a person reads it."""
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def capacity(rows: list[dict[str, Any]], workers: int, phases: str = "spread"
             ) -> dict[str, Any]:
    """The largest stream count that met the target with `workers` and `phases`, and per
    core; the load averages its rows ran at."""
    mine = [r for r in rows if r["workers"] == workers and r["phases"] == phases]
    best = max((r["streams"] for r in mine if r["met"]), default=0)
    cores = min(workers, os.cpu_count() or 1)
    loads = [r[k] for r in mine for k in ("load_1min_before", "load_1min_after")]
    return {"workers": workers, "phases": phases, "streams": best,
            "streams_per_core": round(best / cores, 1),
            "load_1min_range": [min(loads), max(loads)] if loads else None}


def bench_streams_external(data: Path | None, quick: bool = False,
                           counts: tuple[int, ...] | None = None,
                           workers: tuple[int, ...] | None = None,
                           realtime: bool = False,
                           phases: tuple[str, ...] = PHASES,
                           say: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Due-event latency measured outside the run (sender, run, receiver: three processes)
    for every stream count, one worker and one per core, phases spread as independent
    devices' and all on one tick; the capacity: the largest count at p99 <= 5 ms, max <=
    20 ms, no frame lost. Counts above the first that misses are still measured (a shared
    machine is noisy). `realtime`: see `external_row`. Every row records the load average
    before and after it: on a busy machine the counts say what this process got. `say`: a
    line before each row (which of how many, the time left)."""
    seconds = 10.0 if quick else 60.0
    counts = counts or ((1, 4, 8, 16) if quick else EXTERNAL_COUNTS)
    clip = (data / "01_06.bvh") if data is not None and (data / "01_06.bvh").exists() else None
    if clip is None:
        raise FileNotFoundError("bench --streams needs --data with 01_06.bvh")
    cores = os.cpu_count() or 1
    workers = workers or tuple(sorted({1, cores}))
    load = os.getloadavg()
    plan = [(ph, w, n) for ph in phases for w in workers for n in counts]
    rows = []
    for i, (ph, w, n) in enumerate(plan, 1):
        if say is not None:
            say(f"bench streams: row {i}/{len(plan)}: {n} stream{'s' * (n != 1)}, {ph} "
                f"phases, {w} worker{'s' * (w != 1)}, {seconds:.0f} s of frames (about "
                f"{_minutes((len(plan) - i + 1) * (seconds + ROW_OVERHEAD_S))} left)")
        rows.append(external_row(n, w, seconds, clip, phases=ph, realtime=realtime))
    return {"external_rows": rows,
            "capacity": [capacity(rows, w, ph) for ph in phases for w in workers],
            "target_p99_ms": TARGET_P99_MS, "target_max_ms": TARGET_MAX_MS, "cores": cores,
            "methods": "all", "seconds_per_row": seconds,
            "load_average_at_start": [round(x, 2) for x in load],
            "note": "sender, run and receiver are separate processes on this machine; the "
                    "load average before and after each row says what else ran; latency: "
                    "a keyframe event's arrival at the receiver minus its deciding frame's "
                    "send; met: p99 <= 5 ms, max <= 20 ms, no frame lost; phases spread: "
                    "stream s sends s / N of a period after stream 0 (independent devices), "
                    "together: every stream on one tick"}
