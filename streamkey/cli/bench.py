"""`streamkey bench`: speed, memory and latency of the methods and the engine, to files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import Heartbeat

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    """The `bench` subcommand."""
    p = sub.add_parser("bench", help="benchmark speed and memory; results written to files")
    p.add_argument("--offline", action="store_true",
                   help="offline methods: seconds and peak memory on a --frames-long motion "
                        "(the default bench, with --online)")
    p.add_argument("--online", action="store_true",
                   help="online keyframers: per-frame push cost, memory over a 1-hour looped "
                        "stream, engine latency at 120 Hz (the default bench, with --offline; "
                        "several minutes)")
    p.add_argument("--agreement", action="store_true",
                   help="online vs offline at the default settings of both sides, on every "
                        "clip of --data and on sessions (each subject's takes back to back, "
                        "1-2 minutes): F1 within ±4 frames, key-count ratio, optimal's E at "
                        "the same key count, sessions also after their first 10 s (2-3 CPU-min)")
    p.add_argument("--sessions", help="agreement: comma-separated subjects whose takes make "
                   "the sessions (default: every subject with two or more BVH takes; "
                   "'none': clips only)")
    p.add_argument("--lookahead-sweep", dest="lookahead_sweep", action="store_true",
                   help="with --agreement: F1 against lookahead per method instead (slow)")
    p.add_argument("--memory", action="store_true",
                   help="live: RSS over an accelerated 1-hour stream with every sink")
    p.add_argument("--latency", action="store_true", help="live: replay and run as processes, "
                   "an external receiver, OSC and ZeroMQ at 120 Hz, all methods")
    p.add_argument("--ws-clients", dest="ws_clients", action="store_true",
                   help="live: event latency with 0, 100 and 300 WebSocket clients")
    p.add_argument("--streams", action="store_true", help="live: due-event latency for 1-16 "
                   "streams in one process, due-first scheduling on and off")
    p.add_argument("--quick", action="store_true",
                   help="shorter runs: 20,000-frame motion and stream (default benches under "
                        "2 minutes), shorter live benches")
    p.add_argument("--engines", action="store_true", help="extract DIR on local, Ray and "
                   "Dask: wall and CPU (needs streamkey[cluster])")
    p.add_argument("--playable", action="store_true", help="provisional lead, cancel share "
                   "and pose-to-event delay per online method over every clip of --data")
    p.add_argument("--perf", action="store_true",
                   help="per-frame CPU time on a long stream and offline growth exponents")
    p.add_argument("--robustness", action="store_true",
                   help="keys of resampled, noisy, padded, lossy and mistimed variants of each "
                        "clip against the clean take's, offline and online")
    p.add_argument("--clips", help="robustness, agreement: comma-separated clip names or "
                   "files (default: every .bvh of --data; agreement: and every .amc)")
    p.add_argument("--variants", help="robustness: comma-separated variant names "
                   "(default: all; e.g. '30 Hz,noise 0.3°,1%% dropped')")
    p.add_argument("--frames", type=int, default=100_000, help="offline motion length")
    p.add_argument("--data", help="folder of CMU clips (default: ../shared/data/cmu if present)")
    p.add_argument("-o", "--output", default="results", help="output folder")
    p.set_defaults(func=run)


def _wrote(paths: list[Path]) -> None:
    for path in paths:
        print(f"wrote {path}")


def run(args: argparse.Namespace) -> int:
    """Run the chosen benches (default: offline and online) and name the files written."""
    from ..bench import BenchInterrupted, run_bench

    if args.robustness:
        from ..bench.robustness import main as bench_robustness

        return bench_robustness(args.data, args.clips, args.variants, args.output)
    if args.agreement and not args.lookahead_sweep:
        from ..bench.agreement import main as bench_agreement

        return bench_agreement(args.data, args.clips, args.sessions, args.output)
    data = Path(args.data or "../shared/data/cmu")
    if args.playable:
        from ..bench.playable import bench_playable

        _wrote(bench_playable(data, Path(args.output)))
        return 0
    kinds = [k for k in ("offline", "online", "agreement", "perf") if getattr(args, k)]
    kinds += [k for k in ("memory", "latency", "ws_clients") if getattr(args, k)]
    kinds += ["streams"] if args.streams else []
    if args.engines:  # extract on local / Ray / Dask
        from ..bench.engines import bench_engines

        _wrote(bench_engines(data, Path(args.output)))
        if not kinds:
            return 0
    beat = Heartbeat()
    try:
        written = run_bench(kinds or ["offline", "online"], Path(args.output),
                            frames=args.frames, data=args.data, quick=args.quick,
                            say=lambda line: beat.say(line, line.rstrip(" .")))
    except BenchInterrupted as stop:
        _wrote(stop.written)
        print("interrupted: the results above are what was measured before Ctrl-C "
              "(partial ones are marked \"partial\": true)", file=sys.stderr)
        return 130
    finally:
        beat.stop()
    _wrote(written)
    return 0
