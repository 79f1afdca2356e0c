"""`streamkey replay`: a recorded file sent as a paced frame stream."""

from __future__ import annotations

import argparse
import sys
from typing import Any

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    """The `replay` subcommand."""
    p = sub.add_parser("replay", help="send a BVH/AMC file as a paced frame stream")
    p.add_argument("file")
    p.add_argument("--to", action="append", required=True, metavar="ADDR",
                   help="osc://HOST:PORT, zmq+tcp://HOST:PORT (binds a publisher) or -")
    p.add_argument("--rate", type=float, help="frames per second (default: the file's)")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor")
    p.add_argument("--loop", action="store_true", help="start over at the end, seq continuing")
    p.add_argument("--start", type=int, help="first frame (file numbering)")
    p.add_argument("--end", type=int, help="frame to stop before (file numbering)")
    p.add_argument("--frames", type=int, help="stop after sending this many frames")
    p.add_argument("--listen", help="bind publishers to this host instead of 127.0.0.1")
    p.add_argument("--wait", type=float, default=2.0,
                   help="ZeroMQ: seconds to wait for a subscriber before sending")
    p.add_argument("--stream", metavar="NAME",
                   help="stream id on the wire (OSC /streamkey/NAME/frame, ZeroMQ topic "
                        "NAME/frame, JSON Lines \"stream\"); default: the unnamed stream")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Send the file's frames at its rate (or `--rate`, `--speed`) to every `--to`."""
    from ..amc import bvh_equivalent
    from ..batch import load_motion
    from ..errors import UsageError
    from ..live import replay

    for name, low, high in (("--rate", 0.1, 1e5), ("--speed", 1e-3, 1e6)):
        value = getattr(args, name[2:])
        if value is not None and not low <= value <= high:
            raise UsageError(f"replay {name} must lie in {low:g}..{high:g}, got {value:g}")
    if args.frames is not None and args.frames < 0 or not 0 <= args.wait <= 3600:
        raise UsageError("replay --frames must be >= 0 and --wait in 0..3600 seconds")
    motion = bvh_equivalent(load_motion(args.file))
    if (args.rate or motion.fps) * args.speed < 0.1:
        raise UsageError(f"replay: {(args.rate or motion.fps) * args.speed:g} frames/s is too"
                         " slow (at least 0.1 frames/s; give --rate or --speed)")
    result = replay(motion, args.to, rate=args.rate, speed=args.speed, loop=args.loop,
                    start=args.start, end=args.end, listen=args.listen,
                    wait_subscribers=args.wait, count=args.frames, stream=args.stream)
    print(f"sent {result['frames']} frames", file=sys.stderr)
    return 0
