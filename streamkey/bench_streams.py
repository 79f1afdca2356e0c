"""`streamkey bench --streams`: due-event latency against the number of streams one process
serves, with and without due-first scheduling (issue 14 §2).

A stage: one capture system, N performers, every stream ticking at 120 Hz on the same clock
(frame i of every stream arrives at t0 + i / 120 s). Each stream replays its own shared
clip (looped) through the three-method pipeline (saliency, speed, simplify) in one engine.
A frame's arrival is stamped with its tick's deadline, as a kernel timestamp would be, so
time spent waiting behind another stream's work counts. Due events are those a frame's
`Pipeline.push` decides (not the deferred re-analysis); their wall latency is the measure.
`due_first=False` is the old order: each frame's re-analysis right after its push.
"""

from __future__ import annotations

import asyncio
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from .bvh import read_bvh
from .engine import Engine
from .io import FrameQueue, Source, StreamSpec
from .motion import Motion
from .replay.pacing import frame_stream
from .streaming import make_keyframers

__all__ = ["bench_streams", "readme_table", "STREAM_COUNTS", "METHODS"]

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
        self.frames.put(None)


def _clips(data: Path | None, n: int) -> list[Motion]:
    if data is None:
        from .replay.demo import demo_motion

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

    engine = Engine(source, factory, [], max_streams=len(named), due_first=due_first)
    cpu, wall = time.process_time(), time.perf_counter()
    summary = asyncio.run(engine.run())
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    due, every = summary.due_latency.summary(), summary.latency.summary()
    return {"streams": len(named), "due_first": due_first,
            "due_events": summary.due_latency.count,
            "due_p50_ms": round(due["p50"] or 0.0, 3), "due_p99_ms": round(due["p99"] or 0.0, 3),
            "all_p99_ms": round(every["p99"] or 0.0, 3),
            "frames": summary.frames_in, "queue_drops": summary.source["queue_drops"],
            "late_ticks": source.late_ticks, "cpu_per_wall": round(cpu / wall, 2)}


def bench_streams(data: Path | None, quick: bool = False) -> dict[str, Any]:
    """Due-event p50 / p99 for 1, 2, 4, 8, 16 streams, due-first on and off."""
    seconds = 8.0 if quick else 20.0
    motions = _clips(data, max(STREAM_COUNTS))
    load = os.getloadavg()[0]
    rows = [_one(motions[:n], flag, seconds) for n in STREAM_COUNTS for flag in (True, False)]
    return {"rows": rows, "seconds_per_row": seconds, "rate_hz": RATE, "methods": METHODS,
            "cores": os.cpu_count(), "load_average_before": round(load, 2),
            "load_average_after": round(os.getloadavg()[0], 2),
            "note": "all streams tick together (one capture clock); arrival = tick deadline; "
                    "shared machine: compare rows of one run, not runs"}


def readme_table(result: dict[str, Any]) -> str:
    """The README's table of a `bench_streams` result (due-first against the old order)."""
    def ms(v: float) -> str:
        return f"{v:,.1f}" if v >= 10 else f"{v:.2f}"

    lines = ["| streams | due-first: due p50 / p99 (ms) | old order: due p50 / p99 (ms) | "
             "due events | CPU of this process |", "|---|---|---|---|---|"]
    for n in sorted({r["streams"] for r in result["rows"]}):
        a, b = (next(r for r in result["rows"] if r["streams"] == n and r["due_first"] is f)
                for f in (True, False))
        lines.append(f"| {n} | {ms(a['due_p50_ms'])} / {ms(a['due_p99_ms'])} | "
                     f"{ms(b['due_p50_ms'])} / {ms(b['due_p99_ms'])} | {a['due_events']} | "
                     f"{a['cpu_per_wall']:.2f} / {b['cpu_per_wall']:.2f} core |")
    return "\n".join(lines)
