"""`streamkey run`: live keyframes from a source through the keyframers to the sinks."""

from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path
from typing import Any

from .common import dashboard, read
from .input_watch import InputWatch
from .options import (
    add_dashboard_options,
    add_method_options,
    add_playable_options,
    add_roles_option,
    online_params,
    roles_of,
)

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    """The `run` subcommand."""
    p = sub.add_parser("run", help="live keyframes: a source -> keyframers -> sinks")
    p.add_argument("--from", dest="source", required=True, metavar="ADDR",
                   help="osc://HOST:PORT, zmq+tcp://HOST:PORT[?pattern=pull], a file, - "
                        "(JSON Lines on stdin), axis+tcp://HOST:7001 (Axis Neuron), "
                        "vmc://127.0.0.1:39539 (VMC)")
    p.add_argument("--skeleton", help="BVH/AMC file with the stream's skeleton (else it comes "
                   "from a /streamkey/skeleton message, the stdin skeleton line, or the "
                   "built-in Axis / humanoid table)")
    p.add_argument("--method", default="all",
                   help="saliency, speed, simplify, optimal, a list, or all")
    p.add_argument("--to", action="append", metavar="ADDR",
                   help="osc://, zmq+tcp://, ws://, jsonl:PATH or - (default: -)")
    p.add_argument("--listen", help="let listeners bind to this host instead of 127.0.0.1")
    p.add_argument("--stream", default="default",
                   help="name of the unnamed stream (frames without a stream id)")
    p.add_argument("--max-streams", type=int, default=64, metavar="N",
                   help="serve at most N streams at once; frames of more are refused and "
                        "counted (default 64)")
    p.add_argument("--stream-idle", type=float, metavar="SECONDS",
                   help="retire a stream (flush its keyframers) after SECONDS without a "
                        "frame; it starts afresh if it comes back (default: never)")
    p.add_argument("--osc-layout", choices=("numeric", "compact"),
                   help="osc:// sinks: numeric (default: /streamkey/STREAM/METHOD/keyframe "
                        "i f f i, one bundle per frame) or compact (/streamkey/keyframe "
                        "s s i f f i); same as osc://HOST:PORT?layout=...")
    p.add_argument("--summary", help="also write the run summary as JSON to this file")
    p.add_argument("--reset-on-gap", action="store_true",
                   help="a gap too long to bridge (or a source restart) forgets the methods' "
                        "running statistics too (default: only the windows restart)")
    p.add_argument("--fast", action="store_true", help="file source: as fast as possible")
    p.add_argument("--idle-exit", type=float, metavar="SECONDS",
                   help="stop once frames have flowed and then none came for SECONDS "
                        "(default: run until Ctrl-C / SIGTERM)")
    p.add_argument("-q", "--quiet", action="store_true",
                   help="no warnings about refused input while running (still counted in "
                        "the summary)")
    p.add_argument("--no-segments", action="store_true",
                   help="send no segment events (calibration holds, still stretches, takes)")
    p.add_argument("--workers", type=_workers, default=1, metavar="N",
                   help="spread the streams over N worker processes (auto: one per core; "
                        "network sources; default 1: this process, as a worker's extra "
                        "process hop costs one stream about 1 ms of latency)")
    p.add_argument("--realtime", action="store_true",
                   help="run ahead of ordinary processes (SCHED_RR 10 where allowed, else "
                        "nice -10) and keep idle CPUs quick to wake (a 0 us PM QoS request "
                        "where allowed), so frames do not wait for a busy machine's other "
                        "work or for a sleeping core")
    add_playable_options(p)
    add_dashboard_options(p)
    add_roles_option(p)
    add_method_options(p, online=True)
    p.set_defaults(func=run)


def _source(args: argparse.Namespace, methods: list[str], skeleton: Any) -> Any:
    """The frame source: a file read and checked before the engine starts, or a listener
    (with the `--skeleton` motion, if given)."""
    from ..adapters import make_source, parse_address

    _check_source_address(args.source)
    if Path(args.source).suffix.lower() in (".bvh", ".amc"):
        motion = read(args.source, args)
        _check_keyframers(motion, methods, args)
        return motion
    return make_source(parse_address(args.source), args.listen,
                       skeleton.skeleton if skeleton else None,
                       skeleton.fps if skeleton else None)


def run(args: argparse.Namespace) -> int:
    """Live keyframes until the source ends, `--idle-exit`, Ctrl-C or SIGTERM."""
    import asyncio
    import json

    from ..adapters.osc import with_layout
    from ..amc import bvh_equivalent, read_motion
    from ..methods import parse_methods
    from ..motion import Motion
    from ..streaming import check_online_params

    args.to = with_layout(args.to or [], args.osc_layout) or None
    methods = parse_methods(args.method, online=True)
    # Frames on the wire come from `replay`, which sends AMC clips as their BVH equivalent.
    skeleton = bvh_equivalent(read_motion(args.skeleton)) if args.skeleton else None
    if skeleton is not None:
        skeleton.skeleton.roles = roles_of(args) or skeleton.skeleton.roles
    check_online_params(methods, online_params(args))
    source = _source(args, methods, skeleton)
    if args.realtime:
        from ..live import raise_priority

        print(f"priority: {raise_priority()}", file=sys.stderr, flush=True)
    if args.dashboard is not None:
        return dashboard(args, source, methods, args.to or [], 0.0 if args.fast else None,
                         stream=args.stream)
    _check_streams(args)
    watch = InputWatch(quiet=args.quiet)
    if args.workers > 1 and not isinstance(source, Motion):
        from ..workers import run_workers

        summary = asyncio.run(run_workers(
            source, methods, args.to or ["-"], args.workers, online_params(args), None,
            args.listen, args.stream, idle_exit=args.idle_exit, reset_on_gap=args.reset_on_gap,
            max_streams=args.max_streams, stream_idle=args.stream_idle,
            segments=not args.no_segments, input_watch=watch,
            worker_watch=functools.partial(InputWatch, quiet=args.quiet)))
    else:
        summary = asyncio.run(_run_watched(args, source, methods, watch))
    print(summary.text(), file=sys.stderr)
    if (problems := watch.summary_line()) is not None:
        print(problems, file=sys.stderr)
    if args.summary:
        Path(args.summary).write_text(json.dumps(
            {**summary.as_dict(), "input_problems": dict(watch.counts)}, indent=1) + "\n")
    if summary.source_error:  # the source died: say so and fail, never idle on
        print(f"error: {args.source}: {summary.source_error}", file=sys.stderr)
        return 2
    return 0


def _ready(line: str) -> None:
    """The engine's status lines on stderr, but its one-line compile notice: the progress
    lines (`cli/compiling.py`) say when kernels really compile, and how far along."""
    if not line.startswith("compiling the numba kernels"):
        print(line, file=sys.stderr, flush=True)


async def _run_watched(args: argparse.Namespace, source: Any, methods: list[str],
                       watch: InputWatch) -> Any:
    """The engine (as `run_live` builds it) with `watch` reading its counters meanwhile."""
    import asyncio

    from ..adapters import make_sink, parse_address
    from ..live import build_engine, run_engine

    sinks = [make_sink(parse_address(a), args.listen) for a in args.to or ["-"]]
    engine = build_engine(source, methods, sinks, online_params(args), None, args.stream,
                          rate=0.0 if args.fast else None, idle_exit=args.idle_exit,
                          on_frame=watch.on_frame, reset_on_gap=args.reset_on_gap,
                          max_streams=args.max_streams, stream_idle=args.stream_idle,
                          freeze_gc=True, on_ready=_ready, segments=not args.no_segments)
    watch.engine = engine
    task = asyncio.create_task(watch.watch())
    try:
        return await run_engine(engine)
    finally:
        task.cancel()
        watch.check(final=True)


LIVE_SOURCES = ("osc://HOST:PORT, zmq+tcp://HOST:PORT, zmq+ipc://PATH, axis+tcp://HOST:PORT, "
                "vmc://HOST:PORT or - (JSON Lines on stdin)")


def _check_source_address(source: str) -> None:
    """A `--from` that is neither a BVH/AMC file nor an address gets told what would be:
    a file of another kind, or an address with one slash."""
    import re

    from ..errors import UsageError

    if source == "-" or "://" in source:
        return
    if (m := re.match(r"([a-z][a-z0-9+]*):/?([^/].*)", source)) and not Path(source).exists():
        raise UsageError(f"run --from {source}: an address needs two slashes: "
                         f"{m.group(1)}://{m.group(2)}")
    if Path(source).suffix.lower() not in (".bvh", ".amc"):
        what = ("not a BVH (.bvh) or AMC (.amc) file" if Path(source).exists()
                else "neither a file nor an address")
        raise UsageError(f"run --from {source}: {what}; run replays a BVH or AMC file, or "
                         f"listens on a live source: {LIVE_SOURCES}")


def _workers(text: str) -> int:
    """`--workers N|auto`: 1..256 worker processes (auto: the machine's cores)."""
    if text == "auto":
        from ..workers import default_workers

        return default_workers()
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number or auto, got {text!r}") from None
    if not 1 <= value <= 256:
        raise argparse.ArgumentTypeError(f"expected 1..256 workers, got {value}")
    return value


def _check_streams(args: argparse.Namespace) -> None:
    """`--max-streams / --stream-idle` in range, or a usage error."""
    from ..errors import UsageError

    if not 1 <= args.max_streams <= 10_000:
        raise UsageError(f"run --max-streams must lie in 1..10000, got {args.max_streams}")
    if args.stream_idle is not None and not 0.01 <= args.stream_idle <= 86_400:
        raise UsageError(f"run --stream-idle must lie in 0.01..86400 seconds, got "
                         f"{args.stream_idle:g}")


def _check_keyframers(motion: Any, methods: list[str], args: argparse.Namespace) -> None:
    """The keyframers can be built on this file's skeleton (roles, parameters), or its error."""
    from ..batch import naming
    from ..streaming import make_keyframers

    with naming(args.source):
        make_keyframers(motion, methods, online_params(args))
