"""`streamkey bench --streams`: due-event latency against the number of streams one process
serves, with and without due-first scheduling.

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


def bench_streams(data: Path | None, quick: bool = False) -> dict[str, Any]:
    """Due-event p50 / p99 for 1, 2, 4, 8, 16 streams, due-first on and off."""
    seconds = 8.0 if quick else 20.0
    motions = _clips(data, max(STREAM_COUNTS))
    load = os.getloadavg()[0]
    rows = _simulated_rows(motions, seconds)
    live = [_one(motions[:n], flag, seconds) for n in STREAM_COUNTS for flag in (True, False)]
    return {"rows": rows, "live_rows": live, "seconds_per_row": seconds, "rate_hz": RATE,
            "methods": METHODS,
            "cores": os.cpu_count(), "load_average_before": round(load, 2),
            "load_average_after": round(os.getloadavg()[0], 2),
            "note": "all streams tick together (one capture clock); arrival = tick deadline; "
                    "shared machine: compare rows of one run, not runs"}


def readme_table(result: dict[str, Any]) -> str:
    """The README's table of a `bench_streams` result (due-first against the old order)."""
    def ms(v: float) -> str:
        return f"{v:,.0f}" if v >= 100 else f"{v:.2f}" if v < 10 else f"{v:.1f}"

    def pair(rows: list[dict[str, Any]], n: int, starts: str | None = None
             ) -> tuple[dict[str, Any], dict[str, Any]]:
        a, b = (next(r for r in rows if r["streams"] == n and r["due_first"] is f
                     and r.get("starts") == starts) for f in (True, False))
        return a, b

    lines = ["| streams | staggered starts: due-first p50 / p99 | old order p50 / p99 | "
             "same-tick starts: due-first p50 / p99 | old order p50 / p99 | worker busy | "
             "live here: due-first p50 / p99 | old order p50 / p99 | CPU it got |",
             "|---|---|---|---|---|---|---|---|---|"]
    for n in sorted({r["streams"] for r in result["rows"]}):
        cells = []
        for rows, starts in ((result["rows"], "staggered"), (result["rows"], "together"),
                             (result["live_rows"], None)):
            a, b = pair(rows, n, starts)
            cells += [f"{ms(a['due_p50_ms'])} / {ms(a['due_p99_ms'])}",
                      f"{ms(b['due_p50_ms'])} / {ms(b['due_p99_ms'])}"]
            if starts == "together":
                cells.append(f"{a['worker_busy']:.0%}")
        cpu = pair(result["live_rows"], n)[0]["cpu_per_wall"]
        lines.append(f"| {n} | " + " | ".join(cells) + f" | {cpu:.2f} core |")
    return "\n".join(lines)
