"""What several commands share: progress lines, output, the motion of a path, the dashboard."""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..motion import Motion
from .options import online_params, roles_of

__all__ = ["progress", "write", "read", "dashboard", "Heartbeat", "HEARTBEAT_S"]


HEARTBEAT_S = 4.0  # longest silence on stderr while a file or a bench step is worked on


class Heartbeat:
    """Long work that speaks: `say(label)` prints a progress line and names what is being
    worked on; while that takes longer than `HEARTBEAT_S` without another line, a daemon
    thread prints `  ... LABEL (N s)`, so stderr is never silent for long."""

    def __init__(self, quiet: bool = False) -> None:
        self.quiet = quiet
        self.label = ""
        self.since = self.last = time.monotonic()
        self.lock = threading.Lock()
        self.running = False

    def say(self, line: str | None, label: str) -> None:
        """Print `line` (None: nothing) and work on `label` from now on."""
        with self.lock:
            self.label, self.since = label, time.monotonic()
            if line is not None and not self.quiet:
                print(line, file=sys.stderr, flush=True)
                self.last = self.since
            if not self.running and not self.quiet:
                self.running = True
                threading.Thread(target=self._beat, name="heartbeat", daemon=True).start()

    def stop(self) -> None:
        """No more lines."""
        with self.lock:
            self.quiet = True

    def _beat(self) -> None:
        while True:
            time.sleep(HEARTBEAT_S / 8)
            with self.lock:
                now = time.monotonic()
                if self.quiet:
                    return
                if now - self.last >= HEARTBEAT_S:
                    print(f"  ... {self.label} ({now - self.since:.0f} s)", file=sys.stderr,
                          flush=True)
                    self.last = now


def progress(quiet: bool, beat: Heartbeat | None = None) -> Callable[[int, int, Path], None]:
    """A progress callback: `[i/n] name` on stderr for batches of more than one file; with
    `beat`, a line every few seconds while one file takes long."""
    def report(i: int, n: int, path: Path) -> None:
        line = f"[{i + 1}/{n}] {path.name}" if not quiet and n > 1 else None
        if beat is not None:
            beat.say(line, f"{path.name} [{i + 1}/{n}]")
        elif line is not None:
            print(line, file=sys.stderr, flush=True)
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
    from .input_watch import InputWatch

    port = check_port(args.dashboard)
    log = args.log or (None if any(a.startswith("jsonl:") for a in to) else default_log())
    watch = InputWatch(quiet=getattr(args, "quiet", False))

    def watching(board: Any) -> None:  # refused input explained meanwhile (stderr, events)
        watch.engine = board.engine
        board.frame_hooks.append(watch.on_frame)
        watch.task = asyncio.get_running_loop().create_task(watch.watch())

    summary, board = asyncio.run(run_dashboard(
        source, methods, to, online_params(args), None,
        args.listen, stream, rate=rate, port=port, log=log, loop=loop,
        idle_exit=getattr(args, "idle_exit", None), on_start=watching))
    watch.check(final=True)
    print(summary.text(), file=sys.stderr)
    if (problems := watch.summary_line()) is not None:
        print(problems, file=sys.stderr)
    print(f"annotations: {board.annotator.count}", file=sys.stderr)
    if getattr(args, "summary", None):
        Path(args.summary).write_text(json.dumps(
            {**summary.as_dict(), "input_problems": dict(watch.counts)}, indent=1) + "\n")
    if summary.source_error:
        print(f"error: {getattr(args, 'source', 'source')}: {summary.source_error}",
              file=sys.stderr)
        return 2
    return 0
