"""`streamkey demo`: the keyframers live on the embedded demo motion."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import dashboard
from .options import add_dashboard_options

__all__ = ["add_parser", "run", "compile_in_background"]


def add_parser(sub: Any) -> None:
    """The `demo` subcommand."""
    p = sub.add_parser("demo", help="run the keyframers live on the embedded demo motion")
    p.add_argument("--seconds", type=float, default=20.0)
    p.add_argument("--offline", action="store_true", help="offline methods instead of online")
    p.add_argument("--fast", action="store_true", help="as fast as possible, not at 120 Hz")
    add_dashboard_options(p)
    p.add_argument("--listen", help="dashboard: bind to this host instead of 127.0.0.1 (the "
                   "page then needs the token printed in its URL)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """The demo motion through the keyframers, events printed (or on the dashboard)."""
    from ..demo import run_demo

    if args.dashboard is not None:
        from ..methods import ONLINE_METHODS
        from ..replay.demo import demo_motion

        return dashboard(args, demo_motion(args.seconds), list(ONLINE_METHODS), [],
                         0.0 if args.fast else None, loop=True, stream="demo")
    return int(run_demo(seconds=args.seconds, offline=args.offline, fast=args.fast,
                        out=sys.stdout))


def compile_in_background() -> None:
    """Compile the kernels of every online keyframer but the preview's into numba's on-disk
    cache (`demo`'s background process on a cold cache), with progress lines on stderr."""
    from importlib import import_module

    from .. import jit
    from ..demo import PREVIEW_METHOD
    from ..methods import ONLINE_METHODS, online_class
    from ..online import Pipeline
    from ..replay.demo import demo_motion
    from ..streaming import make_keyframers
    from .compiling import report_compilation

    report_compilation(prefix="background: ")
    others = [m for m in ONLINE_METHODS if m != PREVIEW_METHOD]
    for name in others:  # imports the methods' modules (their warmers register)
        online_class(name)
    import_module("streamkey.segments")
    front = {"streamkey.kinematics", "streamkey.signal", "streamkey.filters"}
    # the methods' own kernels first: the preview compiles the front end's meanwhile
    jit.warm_up(*[w for w in jit._WARMERS if w.__module__ not in front])
    Pipeline(make_keyframers(demo_motion(0.1), others, {}))  # the rest, by now in the cache
    jit.warm_up()
