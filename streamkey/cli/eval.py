"""`streamkey eval`: the thesis-style evaluation tables for a folder of clips."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .common import Heartbeat, progress

__all__ = ["add_parser", "run"]


def add_parser(sub: Any) -> None:
    """The `eval` subcommand."""
    p = sub.add_parser("eval", help="evaluation tables (thesis Table 4.1/4.2) for a folder")
    p.add_argument("folder")
    p.add_argument("-o", "--output", default="results/eval", help="output folder")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """The tables (Markdown + CSV) for every clip of the folder; a bad clip is an error line."""
    from ..batch import find_motion_files
    from ..tables import evaluate_files

    paths = find_motion_files([args.folder])
    errors: list[str] = []
    beat = Heartbeat(args.quiet)
    try:
        written = evaluate_files(paths, Path(args.output), progress=progress(args.quiet, beat),
                                 errors=errors)
    finally:
        beat.stop()
    for p in written:
        print(f"wrote {p}")
    for line in errors:
        print(f"error: {line}", file=sys.stderr)
    return 2 if errors else 0
