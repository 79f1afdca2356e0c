"""What several commands share: progress lines, output, the motion of a path, the dashboard."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..motion import Motion
from .options import online_params, roles_of

__all__ = ["progress", "write", "read", "dashboard"]


def progress(quiet: bool) -> Callable[[int, int, Path], None]:
    """A progress callback: `[i/n] name` on stderr for batches of more than one file."""
    def report(i: int, n: int, path: Path) -> None:
        if not quiet and n > 1:
            print(f"[{i + 1}/{n}] {path.name}", file=sys.stderr, flush=True)
    return report


def write(text: str, output: str) -> None:
    """`text` to the file `output`, or to stdout for `-`."""
    # File names that are not UTF-8 come back out as the bytes they were (surrogateescape).
    data = text.encode("utf-8", "surrogateescape")
    if output != "-":
        Path(output).write_bytes(data)
    elif hasattr(sys.stdout, "buffer"):
        sys.stdout.flush()
        sys.stdout.buffer.write(data)
        sys.stdout.buffer.flush()
    else:  # a text-only stream (a StringIO in a caller's redirect)
        sys.stdout.write(data.decode("utf-8", "replace"))
        sys.stdout.flush()


def read(path: str, args: argparse.Namespace) -> Motion:
    """A motion file, its skeleton carrying the `--roles` mapping."""
    from ..batch import load_motion

    return load_motion(path, roles=roles_of(args))


def dashboard(args: argparse.Namespace, source: Any, methods: list[str], to: list[str],
              rate: float | None, loop: bool = False, stream: str = "default") -> int:
    """`--dashboard [PORT]`: the engine with the live page; annotations into the session log."""
    import asyncio
    import json

    from ..dashboard import check_port, default_log, run_dashboard

    port = check_port(args.dashboard)
    log = args.log or (None if any(a.startswith("jsonl:") for a in to) else default_log())
    summary, board = asyncio.run(run_dashboard(
        source, methods, to, online_params(args), None,
        args.listen, stream, rate=rate, port=port, log=log, loop=loop,
        idle_exit=getattr(args, "idle_exit", None)))
    print(summary.text(), file=sys.stderr)
    print(f"annotations: {board.annotator.count}", file=sys.stderr)
    if getattr(args, "summary", None):
        Path(args.summary).write_text(json.dumps(summary.as_dict(), indent=1) + "\n")
    if summary.source_error:
        print(f"error: {getattr(args, 'source', 'source')}: {summary.source_error}",
              file=sys.stderr)
        return 2
    return 0
