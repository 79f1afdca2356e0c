"""`streamkey demo`: the embedded demo motion through the keyframers, with no data or network."""

from __future__ import annotations

from typing import Any, TextIO

from .replay.demo import demo_motion

__all__ = ["run_demo"]


def run_demo(seconds: float = 20.0, offline: bool = False, fast: bool = False,
             out: TextIO | None = None) -> int:
    """Run the keyframers on the demo motion (live at 120 Hz unless `fast`), printing events."""
    import sys

    out = out or sys.stdout
    motion = demo_motion(seconds)
    print(f"demo motion: {motion.n_frames} frames at {motion.fps:g} fps "
          f"({motion.skeleton.n_joints} joints, {motion.skeleton.n_channels} channels)", file=out)
    if offline:
        from .batch import extract_motion

        for name, keys in extract_motion(motion, ["saliency", "speed", "simplify", "uniform",
                                                  "decimate"]).items():
            print(f"{name:>9}: {len(keys):3d} keyframes {keys.frames.tolist()}", file=out)
        return 0
    import asyncio

    from .live import run_live
    from .methods import ONLINE_METHODS

    counts = dict.fromkeys(ONLINE_METHODS, 0)
    summary = asyncio.run(run_live(
        motion, list(ONLINE_METHODS), [], stream="demo", rate=0.0 if fast else None,
        on_event=lambda e: _print_event(e, counts, out),
        on_ready=lambda line: print(line, file=sys.stderr, flush=True)
        if line.startswith("compiling") else None))
    lat = summary.latency_percentiles()
    print(f"done: {summary.frames_in} frames, keyframes per method: "
          + ", ".join(f"{m} {n}" for m, n in counts.items())
          + (f"; wall latency p50 {lat['p50']:.2f} ms, p99 {lat['p99']:.2f} ms"
             if lat["p50"] is not None else ""), file=out)
    return 0


def _print_event(event: dict[str, Any], counts: dict[str, int], out: TextIO) -> None:
    if event["type"] == "keyframe":
        counts[event["method"]] = counts.get(event["method"], 0) + 1
        print(f"t={event['time']:7.3f}s  {event['method']:>8}  keyframe {event['frame']:5d}  "
              f"score {event['score']:9.4g}  decided at {event['decided_at']:5d} "
              f"(+{event['latency_frames']} frames, lookahead {event['lookahead']}, "
              f"{event['wall_latency_ms']:.2f} ms)", file=out, flush=True)
