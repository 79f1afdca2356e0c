"""`streamkey bench`: speed and memory of the methods, written to JSON and Markdown files.

Offline: each method on a long motion (shared CMU clips concatenated, or the demo motion
tiled when the data is absent), features timed apart. Online: per-frame cost of `push`
(mean, p50, p99, max; frames per second) for each keyframer with its own feature stage, and
for all of them on one pipeline; peak memory growth over a long looped stream.
"""

from __future__ import annotations

import gc
import json
import os
import platform
import time
import tracemalloc
from collections.abc import Callable, Iterable, Sequence
from functools import partial
from pathlib import Path
from typing import Any, cast

import numpy as np

from ..bvh import read_bvh
from ..motion import Motion

__all__ = ["run_bench", "long_motion", "default_data_dir", "BenchInterrupted", "QUICK"]

Say = Callable[[str], None]

# --quick: every benchmark shortened so that the default run stays under two minutes.
QUICK = {"frames": 20_000, "stream_frames": 24_000}


class BenchInterrupted(Exception):
    """Ctrl-C during a benchmark; `written` lists the files with the results so far."""

    def __init__(self, written: list[Path]) -> None:
        super().__init__("interrupted")
        self.written = written


def _quiet(message: str) -> None:
    """Default progress sink: say nothing."""


def default_data_dir() -> Path | None:
    """../shared/data/cmu relative to the working directory, if it exists."""
    p = Path("..") / "shared" / "data" / "cmu"
    return p if p.is_dir() else None


def long_motion(frames: int, data: Path | None) -> tuple[Motion, str]:
    """A motion of `frames` frames: cgspeed clips of the data folder looped, or the demo."""
    clips: list[Motion] = []
    if data is not None:
        for path in sorted(data.glob("*.bvh")):
            m = read_bvh(path)
            if m.first_frame == 1:  # cgspeed MotionBuilder release: one skeleton layout
                clips.append(m.captured())
    if clips:
        source = f"{len(clips)} cgspeed clips from {data}, looped"
    else:
        from ..replay.demo import demo_motion

        clips = [demo_motion()]
        source = "embedded demo motion, looped"
    rows, total = [], 0
    while total < frames:
        for m in clips:
            rows.append(m.channels[: frames - total])
            total += len(rows[-1])
            if total >= frames:
                break
    return Motion(clips[0].skeleton, np.concatenate(rows), clips[0].fps, 0, "bench"), source


def _measure(fn: Callable[[], Any]) -> tuple[float, float, Any]:
    """Seconds of one plain run, then peak traced memory (MB) of a second, traced run:
    tracemalloc slows allocation-heavy Python code several times over."""
    gc.collect()
    t0 = time.perf_counter()
    result = fn()
    seconds = time.perf_counter() - t0
    gc.collect()
    tracemalloc.start()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return seconds, peak / 2**20, result


def bench_offline(frames: int, data: Path | None, rows: list[dict[str, Any]] | None = None,
                  say: Say = _quiet) -> dict[str, Any]:
    """Time and peak memory of every offline method on one long motion (rows appended to
    `rows` as they finish, each reported to `say`)."""
    from ..features import compute_features
    from ..methods import offline_method

    motion, source = long_motion(frames, data)
    table = _Rows(rows, say, "offline", "seconds")
    seconds, peak, feats = _measure(lambda: compute_features(motion))
    table.append({"method": "features (FK, once)", "seconds": seconds, "peak_mb": peak})
    count = None
    for name in ("saliency", "speed", "simplify", "uniform", "decimate"):
        fn = offline_method(name)
        kwargs: dict[str, Any] = ({"count": count} if name in ("uniform", "decimate")
                                  else {"features": feats})
        if name == "decimate":
            kwargs["features"] = feats  # positions space: the shared FK, as the others
        seconds, peak, keys = _measure(partial(fn, motion, **kwargs))
        if name == "saliency":
            count = len(keys)
        table.append({"method": name, "seconds": seconds, "peak_mb": peak, "keyframes": len(keys)})
    for label, kwargs in (("optimal --rate 6 (one lambda)", {"rate": 6.0}),
                          ("optimal --tolerance 1e-4 (one pass)", {"tolerance": 1e-4}),
                          ("optimal --count 5 %", {"count": frames // 20})):
        fn = offline_method("optimal")
        seconds, peak, keys = _measure(partial(fn, motion, features=feats, **kwargs))
        table.append({"method": label, "seconds": seconds, "peak_mb": peak, "keyframes": len(keys),
                     "solver": keys.info.get("solver", "")})
    # ISODATA (Zhang et al. 2013) and Hermite curve fitting (Önder et al. 2008) are slower by
    # nature: timed on the first 10,000 frames.
    short = Motion(motion.skeleton, motion.channels[:10_000], motion.fps, 0, "bench-10k")
    short_feats = compute_features(short)
    for name in ("isodata", "curvefit"):
        fn = offline_method(name)
        seconds, peak, keys = _measure(partial(fn, short, features=short_feats))
        table.append({"method": f"{name} (10,000 frames)", "seconds": seconds, "peak_mb": peak,
                     "keyframes": len(keys)})
    return {"frames": motion.n_frames, "source": source, "rows": table.rows}


class _Rows:
    """Result rows kept in the caller's list (so Ctrl-C still finds them), each one reported
    to `say` as it lands."""

    def __init__(self, rows: list[dict[str, Any]] | None, say: Say, kind: str,
                 value: str) -> None:
        self.rows = [] if rows is None else rows
        self.say, self.kind, self.value = say, kind, value

    def append(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        name = row.get("method", row.get("target", "?"))
        value = row.get(self.value)
        shown = f"{value:.4g}" if isinstance(value, float) else str(value)
        self.say(f"bench {self.kind}: {name}: {self.value} {shown}")


def _push_costs(make: Callable[[], Any], frames: list[Any]) -> dict[str, float]:
    target = make()
    costs = np.empty(len(frames))
    clock = time.perf_counter_ns
    for i, frame in enumerate(frames):
        t0 = clock()
        target.push(frame)
        costs[i] = clock() - t0
    target.flush()
    us = costs / 1000.0
    return {"mean_us": float(us.mean()), "p50_us": float(np.percentile(us, 50)),
            "p99_us": float(np.percentile(us, 99)), "max_us": float(us.max()),
            "frames_per_s": float(1e6 / us.mean())}


def bench_online(data: Path | None, stream_frames: int = 432_000,
                 frames_long: int = 100_000, rows: list[dict[str, Any]] | None = None,
                 say: Say = _quiet) -> dict[str, Any]:
    """Per-frame push cost of each online keyframer and memory over a long looped stream."""
    from ..methods import ONLINE_METHODS, online_class
    from ..online import Pipeline

    clip_path = data / "05_06.bvh" if data is not None else None
    if clip_path is not None and clip_path.exists():
        motion, source = read_bvh(clip_path), str(clip_path)
    else:
        from ..replay.demo import demo_motion

        motion, source = demo_motion(), "embedded demo motion"
    frames = motion.frames()
    table = _Rows(rows, say, "online", "mean_us")
    for name in ONLINE_METHODS:
        cls = online_class(name)
        row = _push_costs(partial(cls, motion.skeleton, motion.fps), frames)
        table.append({"method": name, **row})

    def pipeline() -> Pipeline:
        return Pipeline([online_class(m)(motion.skeleton, motion.fps) for m in ONLINE_METHODS])

    table.append({"method": "all (one pipeline)", **_push_costs(pipeline, frames)})
    table.append({"method": "feature stage only (guard + unwrap; FK only when a keyframer "
                            "reads it)",
                  **_push_costs(lambda: _FeaturesOnly(motion.skeleton, motion.fps), frames)})
    long, _ = long_motion(frames_long, data)
    long_frames = long.frames()
    for name, make in (("optimal", lambda: online_class("optimal")(long.skeleton, long.fps)),
                       ("feature stage only", lambda: _FeaturesOnly(long.skeleton, long.fps)),
                       ("feature stage + FK positions (what optimal reads)",
                        lambda: _FeaturesOnly(long.skeleton, long.fps, positions=True))):
        table.append({"method": f"{name} ({len(long_frames):,} frames)",
                     **_push_costs(make, long_frames)})
    say(f"bench online: memory over a {stream_frames:,}-frame looped stream ...")
    memory = _stream_memory(pipeline, motion, stream_frames, say)
    memory.update(methods=list(ONLINE_METHODS), rate_hz=motion.fps)  # what the stream was
    say(f"bench online: growth after warm-up {memory['growth_after_warmup_mb']:.3g} MB; "
        "engine latency at 120 Hz ...")
    seconds = 60.0 if stream_frames >= 100_000 else 15.0
    return {"clip": source, "frames": len(frames), "rows": table.rows, "memory": memory,
            "engine_live": _engine_latency(motion, seconds)}


class _FeaturesOnly:
    """Baseline of the per-frame cost: the guard and the shared feature stage, no method."""

    def __init__(self, skeleton: Any, fps: float, positions: bool = False) -> None:
        from ..online import FeatureStage, StreamGuard

        self.guard = StreamGuard(skeleton.n_channels)
        self.stage = FeatureStage(skeleton, fps)
        self.positions = positions  # also read the FK positions (computed on first access)

    def push(self, frame: Any) -> None:
        clean, _, _ = self.guard.accept(frame)
        if clean:
            block = self.stage.compute(clean)
            if self.positions:
                block.positions  # noqa: B018 - computes FK

    def flush(self) -> None:
        self.guard.reset()
        self.stage.reset()


def _engine_latency(motion: Motion, seconds: float = 60.0) -> dict[str, Any]:
    """Wall latency inside the engine at the capture rate: arrival of the deciding frame to
    the event leaving for the sinks (every online keyframer, a JSON Lines sink)."""
    import asyncio
    import tempfile

    from ..live import run_live
    from ..methods import ONLINE_METHODS
    from ..replay.source import MotionSource

    with tempfile.TemporaryDirectory() as tmp:
        source = MotionSource(motion, loop=True, count=int(seconds * motion.fps))
        summary = asyncio.run(run_live(source, list(ONLINE_METHODS), [f"jsonl:{tmp}/e.jsonl"],
                                       on_ready=lambda line: None))
    lat = summary.latency_percentiles()
    per_method = {m: {"events": h.count, **h.summary()}
                  for m, h in summary.method_latency.items()}
    return {"seconds": seconds, "rate_hz": motion.fps, "frames": summary.frames_in,
            "events": sum(summary.events.values()), "wall_latency_ms": lat,
            "per_method": per_method}


def _stream_memory(make: Callable[[], Any], motion: Motion, total: int,
                   say: Say = _quiet) -> dict[str, Any]:
    from ..motion import Frame

    target = make()
    rows = motion.captured().channels
    warmup = min(total // 10, 12_000)
    gc.collect()
    tracemalloc.start()
    samples = []
    t0 = time.perf_counter()
    for seq in range(total):
        target.push(Frame(seq, seq / motion.fps, rows[seq % len(rows)]))
        if seq == warmup:
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
        if seq > warmup and seq % 12_000 == 0:
            samples.append((seq, tracemalloc.get_traced_memory()[0] / 2**20))
            if seq % 48_000 == 0:
                spent = time.perf_counter() - t0
                say(f"bench online: memory stream {seq:,}/{total:,} frames, about "
                    f"{spent * (total - seq) / seq:.0f} s left")
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return {"stream_frames": total, "warmup_frames": warmup,
            "seconds": time.perf_counter() - t0,
            "growth_after_warmup_mb": (peak - base) / 2**20,
            "current_mb_samples": samples}


def _bench_agreement(data: Path | None, output: Path) -> list[Path]:
    """F1 of online against offline for each method and lookahead over every shared clip."""
    import sys

    from ..agreement import LOOKAHEADS, lookahead_table, write_lookahead_table
    from ..amc import read_motion
    from ..errors import UsageError

    if data is None:
        raise UsageError("bench --agreement needs the CMU clips (--data DIR)")
    motions = [read_motion(p) for p in sorted(data.iterdir()) if p.suffix in (".bvh", ".amc")]
    # Saliency at the thesis' low-dynamic preset on both sides, so the table measures the
    # lookahead alone (the `auto` preset adds its own 2 s decision).
    lookaheads = cast(dict[str, Sequence[int]], LOOKAHEADS)  # read only: tuples will do
    rows = lookahead_table(motions, lookaheads, {"saliency": {"sigma": 10.0, "k": 7}},
                           progress=lambda msg: print(msg, file=sys.stderr, flush=True))
    md, js = output / "agreement_lookahead.md", output / "agreement_lookahead.json"
    write_lookahead_table(rows, md)
    js.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return [md, js]


def _markdown(kind: str, result: dict[str, Any]) -> str:
    lines = [f"# streamkey bench --{kind}", "", f"machine: {platform.machine()}, "
             f"{platform.python_implementation()} {platform.python_version()}", ""]
    rows = result["rows"]
    keys = list(rows[0].keys())
    for k in rows[1:]:
        keys += [c for c in k if c not in keys]
    lines += ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for row in rows:
        cells = [f"{row[k]:.4g}" if isinstance(row.get(k), float) else str(row.get(k, ""))
                 for k in keys]
        lines.append("| " + " | ".join(cells) + " |")
    extra = {k: v for k, v in result.items() if k != "rows"}
    lines += ["", "```", json.dumps(extra, indent=1), "```", ""]
    return "\n".join(lines)


def run_bench(kinds: list[str], output: Path, frames: int = 100_000,
              data: str | None = None, stream_frames: int = 432_000,
              quick: bool = False, say: Say = _quiet) -> list[Path]:
    """Run the chosen benchmarks; write `bench_<kind>.json` and `.md` into `output`.

    `quick` shortens every benchmark (`QUICK`). Progress goes to `say`. On Ctrl-C the rows
    measured so far are written (marked `"partial": true`) and `BenchInterrupted` is raised."""
    from .live import LIVE_KINDS, run_live_bench

    if quick:
        frames, stream_frames = min(frames, QUICK["frames"]), min(stream_frames,
                                                                  QUICK["stream_frames"])
    data_dir = Path(data) if data else default_data_dir()
    output.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    for kind in kinds:
        say(f"bench {kind}: started ({time.strftime('%H:%M:%S')})")
        rows: list[dict[str, Any]] = []
        try:
            if kind == "agreement":
                written += _bench_agreement(data_dir, output)
                continue
            if kind in LIVE_KINDS:  # live engine benches (memory, latency, ws_clients)
                result = run_live_bench(kind, data_dir, quick, say)
            elif kind == "streams":  # many streams in one engine, due-first on and off
                from .streams import bench_streams

                result = bench_streams(data_dir, quick, say)
            elif kind == "offline":
                result = bench_offline(frames, data_dir, rows, say)
            elif kind == "perf":
                result = bench_perf(frames, data_dir, rows, say)
            else:
                result = bench_online(data_dir, stream_frames, frames, rows, say)
        except KeyboardInterrupt:
            if rows:
                written += _write_result(output, kind, {"rows": rows, "partial": True})
            raise BenchInterrupted(written) from None
        written += _write_result(output, kind, result)
        say(f"bench {kind}: done")
    return written


def _write_result(output: Path, kind: str, result: dict[str, Any]) -> list[Path]:
    result["date"] = time.strftime("%Y-%m-%d %H:%M:%S")
    paths = []
    for suffix, text in (("json", json.dumps(result, indent=1)),
                         ("md", _markdown(kind, result))):
        path = output / f"bench_{kind}.{suffix}"
        path.write_text(text + "\n", encoding="utf-8")
        paths.append(path)
    return paths


# --- bench --perf: per-frame and per-clip targets (CPU time, long stream, growth exponents) -

PERF_ONLINE_GOALS = {"feature stage": (40.0, 1000.0), "saliency": (80.0, 1000.0),
                     "speed": (80.0, 1000.0), "simplify": (80.0, 1000.0),
                     "optimal": (80.0, 1000.0),
                     "saliency + speed + simplify (one pipeline)": (150.0, 1000.0),
                     "all four (one pipeline)": (150.0, 1000.0)}
PERF_BURST_GOALS = (1000.0, 2000.0)  # µs a push, p99.9 and max: no push holds a loop turn up
PIPELINE_OF_THREE = ("saliency", "speed", "simplify")  # the pipeline of three (no optimal)
PERF_OFFLINE_GOALS = {"features": 0.5, "saliency": 0.5, "speed": 1.0, "simplify": 0.5,
                      "decimate": 2.0, "isodata": 1.0, "curvefit": 10.0}


def _cpu_push_costs(make: Callable[[], Any], frames: list[Any], push: str = "push"
                    ) -> dict[str, float]:
    """Per-push CPU time of the calling thread (µs): mean, p50, p99, p99.9, max."""
    from ..jit import warm_up

    target = make()
    warm_up()  # every kernel imported so far compiled (or loaded) before the clock runs
    step = getattr(target, push)
    costs = np.empty(len(frames))
    clock = time.thread_time_ns
    gc.collect()
    for i, frame in enumerate(frames):
        t0 = clock()
        step(frame)
        costs[i] = clock() - t0
    us = costs / 1000.0
    return {"mean_us": float(us.mean()), "p50_us": float(np.percentile(us, 50)),
            "p99_us": float(np.percentile(us, 99)), "p999_us": float(np.percentile(us, 99.9)),
            "max_us": float(us.max())}


def bench_perf_online(frames: int, data: Path | None, methods: list[str] | None = None,
                      rows: list[dict[str, Any]] | None = None, say: Say = _quiet
                      ) -> dict[str, Any]:
    """One frame per push on a long stream of the shared clips concatenated (CPU time)."""
    from ..methods import ONLINE_METHODS, online_class
    from ..online import FeatureStage, Pipeline

    motion, source = long_motion(frames, data)
    stream = motion.frames()
    names = methods or list(ONLINE_METHODS)

    def stage() -> Any:
        st = FeatureStage(motion.skeleton, motion.fps)
        return lambda f: st.compute([f]).materialise()

    out = _Rows(rows, say, f"perf online ({len(stream):,} frames)", "mean_us")

    def add(target: str, costs: dict[str, float]) -> None:
        mean_goal, p99_goal = PERF_ONLINE_GOALS[target]
        out.append({"target": target, **costs, "streams_per_core": 1e6 / motion.fps
                    / costs["mean_us"],
                    "goal": f"mean <= {mean_goal:g}, p99 <= {p99_goal:g}, p99.9 <= "
                            f"{PERF_BURST_GOALS[0]:g}, max <= {PERF_BURST_GOALS[1]:g}",
                    "met": costs["mean_us"] <= mean_goal and costs["p99_us"] <= p99_goal
                    and costs["p999_us"] <= PERF_BURST_GOALS[0]
                    and costs["max_us"] <= PERF_BURST_GOALS[1],
                    "load_average": round(os.getloadavg()[0], 2)})

    def pipeline_of(group: Iterable[str]) -> Pipeline:
        return Pipeline([online_class(m)(motion.skeleton, motion.fps) for m in group])

    add("feature stage", _cpu_push_costs(stage, stream, "__call__"))
    for name in names:
        cls = online_class(name)
        add(name, _cpu_push_costs(partial(cls, motion.skeleton, motion.fps), stream))
    if methods is None:
        for target, group in (("saliency + speed + simplify (one pipeline)", PIPELINE_OF_THREE),
                              ("all four (one pipeline)", ONLINE_METHODS)):
            add(target, _cpu_push_costs(partial(pipeline_of, group), stream))
    return {"frames": len(stream), "source": source, "rows": out.rows}


def bench_perf_offline(sizes: list[int], data: Path | None,
                       methods: list[str] | None = None,
                       rows: list[dict[str, Any]] | None = None, say: Say = _quiet,
                       repeats: int = 2) -> dict[str, Any]:
    """CPU seconds of every offline method at each size; exponent of the growth fitted.

    Each timing is the least of `repeats` runs (the arithmetic's cost); the first run's is
    kept beside it (`first_s@N`): it also pays for first touching fresh memory, which this
    project's 2-core VM charges at ~10 ms per MB (against ~0.1 ms on bare metal), and a
    batch over a library pays only on its first clip. Rows land in `rows` once every size is
    done; each timing is reported to `say`."""
    from ..features import compute_features
    from ..methods import offline_method

    names = methods or [m for m in PERF_OFFLINE_GOALS if m != "features"]
    motion, source = long_motion(max(sizes), data)
    times: dict[str, list[float]] = {m: [] for m in ["features", *names]}
    first: dict[str, list[float]] = {m: [] for m in times}
    warm = Motion(motion.skeleton, motion.channels[:2_000], motion.fps, 0, "warm-up")
    warm_feats = compute_features(warm)  # imports, plans and compiled kernels: not timed
    for name in names:
        offline_method(name)(warm, **({"count": 20} if name == "decimate"
                                      else {"features": warm_feats}))

    def timed(name: str, n: int, fn: Callable[[], Any]) -> Any:
        runs = []
        for _ in range(max(1, repeats)):
            gc.collect()
            t0 = time.process_time()
            out = fn()
            runs.append(time.process_time() - t0)
            del out
        first[name].append(runs[0])
        times[name].append(min(runs))
        say(f"bench perf offline: {name} at {n:,} frames: {min(runs):.3g} s "
            f"(first run {runs[0]:.3g} s)")

    for n in sizes:
        part = Motion(motion.skeleton, motion.channels[:n], motion.fps, 0, f"bench-{n}")
        timed("features", n, partial(compute_features, part))
        feats = compute_features(part)
        count = len(offline_method("saliency")(part, features=feats))
        for name in names:
            fn = offline_method(name)
            kwargs: dict[str, Any] = {"count": count} if name == "decimate" else {
                "features": feats}
            timed(name, n, partial(fn, part, **kwargs))
        del feats
    rows = [] if rows is None else rows
    for name, secs in times.items():
        slope = float(np.polyfit(np.log(sizes), np.log(secs), 1)[0]) if len(sizes) > 1 else 0.0
        goal = PERF_OFFLINE_GOALS.get(name, float("inf"))
        rows.append({"target": name, **{f"s@{n}": s for n, s in zip(sizes, secs, strict=True)},
                     **{f"first_s@{n}": s for n, s in zip(sizes, first[name], strict=True)},
                     "exponent": slope, "goal": f"<= {goal:g} s at 100k, exponent <= ~1.1",
                     "met": sizes[-1] >= 100_000 and secs[-1] <= goal and slope <= 1.15})
    return {"sizes": sizes, "source": source, "rows": rows}


def bench_perf(frames: int, data: Path | None, rows: list[dict[str, Any]] | None = None,
               say: Say = _quiet) -> dict[str, Any]:
    """The performance targets: online per-frame CPU time, offline growth from frames/10."""
    rows = [] if rows is None else rows
    online = bench_perf_online(frames, data, rows=rows, say=say)
    memory = bench_perf_memory(data, frames=min(36_000, frames), rows=rows, say=say)
    sizes = [frames // 10, frames // 10 * 3, frames]
    bench_perf_offline(sizes, data, rows=rows, say=say)
    return {"rows": rows, "source": online["source"], "stream_frames": online["frames"],
            "memory_frames": memory["frames"], "offline_sizes": sizes}


def bench_perf_memory(data: Path | None, frames: int = 36_000,
                      rows: list[dict[str, Any]] | None = None, say: Say = _quiet
                      ) -> dict[str, Any]:
    """Traced memory (MB) held by each online keyframer after `frames` frames (every window
    and history full) and its peak growth over the last half (flat: near zero)."""
    from ..methods import ONLINE_METHODS, online_class

    motion, _ = long_motion(frames, data)
    stream = motion.frames()
    out = _Rows(rows, say, f"perf memory ({frames:,} frames)", "state_mb")
    for name in ONLINE_METHODS:
        online_class(name)(motion.skeleton, motion.fps).push(stream[0])  # imports, plans
        gc.collect()
        tracemalloc.start()
        kf = online_class(name)(motion.skeleton, motion.fps)
        for frame in stream[: frames // 2]:
            kf.push(frame)
        half = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        for frame in stream[frames // 2 :]:
            kf.push(frame)
        now, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        out.append({"target": f"memory {name}", "state_mb": now / 2**20,
                    "growth_mb": (now - half) / 2**20, "peak_mb": peak / 2**20,
                    "goal": "state <= 20 MB", "met": now / 2**20 <= 20.0})
    return {"frames": frames, "rows": out.rows}
