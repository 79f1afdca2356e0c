"""`streamkey demo`: the embedded demo motion through the keyframers, with no data or network."""

from __future__ import annotations

from typing import Any, TextIO

from .replay.demo import demo_motion

__all__ = ["run_demo", "PREVIEW_METHOD"]

PREVIEW_METHOD = "simplify"  # its kernels (and the front end's) compile first, in seconds


def run_demo(seconds: float = 20.0, offline: bool = False, fast: bool = False,
             out: TextIO | None = None, staged: bool = True) -> int:
    """Run the keyframers on the demo motion (live at 120 Hz unless `fast`), printing events.
    On a machine whose kernel cache is cold (the first run) and with `staged`, `simplify`
    (whose kernels compile in seconds) runs alone while the others compile in a background
    process; then the four run from the start."""
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

    if not fast and staged and _kernels_cold():
        if not _preview_while_compiling(motion, out):
            return 0  # stopped (Ctrl-C) during the preview
    counts = dict.fromkeys(ONLINE_METHODS, 0)
    summary = asyncio.run(run_live(
        motion, list(ONLINE_METHODS), [], stream="demo", rate=0.0 if fast else None,
        on_event=lambda e: _print_event(e, counts, out),
        on_ready=lambda line: None))  # compiling: the progress lines say it (cli/compiling)
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


def _kernels_cold() -> bool:
    """True when the preview keyframer's kernels (and the front end's) are not in numba's
    cache yet: the first run on a machine. Imports only that keyframer's modules, so the
    preview compiles nothing of the others."""
    from . import jit
    from .online import Pipeline
    from .replay.demo import demo_motion
    from .streaming import make_keyframers

    jit._WATCHERS.insert(0, _refuse_compiling)  # before any progress line
    try:  # a cold kernel stops the build before it compiles
        Pipeline(make_keyframers(demo_motion(0.1), [PREVIEW_METHOD], {}))
    except _Cold:
        return True
    finally:
        jit._WATCHERS.remove(_refuse_compiling)
    return False


class _Cold(Exception):
    """A kernel was about to compile (`_kernels_cold` asks without compiling)."""


def _refuse_compiling(name: str, seconds: float | None) -> None:
    if seconds is None:
        raise _Cold(name)


def _preview_while_compiling(motion: Any, out: TextIO) -> bool:
    """`simplify` alone on the looped demo motion while a background process compiles the
    other keyframers' kernels into the cache; False if the user stopped it (Ctrl-C)."""
    import asyncio
    import subprocess
    import sys

    from .live import build_engine, run_engine

    background = subprocess.Popen(
        [sys.executable, "-c", "from streamkey.cli.demo import compile_in_background as c; c()"])
    print(f"first run on this machine: numba compiles the kernels once (about a minute); "
          f"meanwhile {PREVIEW_METHOD} runs alone, the other keyframers compile in the "
          "background", file=sys.stderr, flush=True)
    counts: dict[str, int] = {}

    async def preview() -> bool:
        engine = build_engine(motion, [PREVIEW_METHOD], [], stream="demo", loop=True,
                              on_event=lambda e: _print_event(e, counts, out),
                              on_ready=lambda line: None)
        done = False

        async def until_compiled() -> None:
            nonlocal done
            await asyncio.to_thread(background.wait)
            done = True
            engine.stop()

        task = asyncio.create_task(until_compiled())
        try:
            await run_engine(engine)
        finally:
            task.cancel()
            if background.poll() is None:  # stopped first: end the waiting thread too
                background.terminate()
                background.wait()
        return done

    if not asyncio.run(preview()):
        return False
    print("all kernels ready: the four keyframers on the demo motion from the start",
          file=sys.stderr, flush=True)
    return True
