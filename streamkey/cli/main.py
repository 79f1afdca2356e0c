"""The `streamkey` command line: a thin layer over the library, one module per command.

Every input error becomes one `error: ...` line on stderr and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence

from .. import __version__
from ..errors import StreamkeyError
from . import bench, cluster, demo, eval, extract, figures, replay, run
from .compiling import report_compilation

__all__ = ["main", "build_parser", "busy_port"]

_BUSY = re.compile(r"(cannot listen on \S+?:\d+): .*\bin use\b.*$", re.I | re.S)
BUSY_HINT = "the port is in use (give another port, or 0 for a free one)"


def busy_port(message: str) -> str:
    """One wording for a busy port, whichever listener (OSC, WebSocket, ZeroMQ, dashboard)
    and library said it."""
    return _BUSY.sub(lambda m: f"{m.group(1)}: {BUSY_HINT}", message)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(prog="streamkey", description=__doc__)
    parser.add_argument("--version", action="version", version=f"streamkey {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    extract.add_parser(sub)
    replay.add_parser(sub)
    run.add_parser(sub)
    eval.add_parser(sub)
    demo.add_parser(sub)
    figures.add_parsers(sub)
    cluster.add_parser(sub)
    bench.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI; returns the exit code (2 for input and usage errors)."""
    args = build_parser().parse_args(argv)
    report_compilation()  # a cold kernel cache: progress lines, not a silent minute
    try:
        return int(args.func(args))
    except StreamkeyError as exc:
        print(f"error: {busy_port(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # live commands stop on Ctrl-C themselves (exit 0)
        print(f"interrupted: {args.command} stopped by Ctrl-C before it finished",
              file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:  # the environment, not the data: an output path, a port, a disk
        from ..inputs import os_reason

        where = exc.filename if exc.filename is not None else args.command
        print(f"error: {where}: {os_reason(exc)}", file=sys.stderr)
        return 2
