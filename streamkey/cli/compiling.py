"""Progress while numba compiles the kernels for a new machine (a cold cache): one line per
kernel compiled, and a line at least every few seconds while a long one compiles, so a first
run never sits silent for a minute."""

from __future__ import annotations

import sys
import threading
import time
from typing import TextIO

__all__ = ["report_compilation", "HEARTBEAT_S"]

HEARTBEAT_S = 4.0  # longest silence while a kernel compiles


class _Progress:
    """Counts the kernels compiled and prints `compiling kernels N/M: name (s)` lines."""

    def __init__(self, out: TextIO | None, prefix: str = "") -> None:
        self.out = out
        self.prefix = prefix
        self.done: set[str] = set()
        self.current: list[str] = []  # names being compiled (nested: a kernel's callees)
        self.started = 0.0
        self.last_line = 0.0
        self.lock = threading.Lock()
        self.beating = False

    def __call__(self, name: str, seconds: float | None) -> None:
        from ..jit import kernel_count

        with self.lock:
            now = time.monotonic()
            if seconds is None:
                if not self.started:
                    self.started = now
                    self._say(f"compiling kernels for this machine (once; later runs load "
                              f"them from the cache in well under a second): "
                              f"{kernel_count()} kernels")
                self.current.append(name)
                self._beat()
                return
            if name not in self.current:  # its start was not ours (a refused compile)
                return
            self.current.remove(name)
            self.done.add(name)
            total = max(kernel_count(), len(self.done))
            self._say(f"compiling kernels {len(self.done)}/{total}: {name} "
                      f"({seconds:.1f} s; {now - self.started:.0f} s so far)")

    def _say(self, line: str) -> None:
        self.last_line = time.monotonic()
        print(self.prefix + line, file=self.out or sys.stderr, flush=True)

    def _beat(self) -> None:
        """A daemon thread that speaks when no line came for `HEARTBEAT_S` during a compile
        (numba's compiler is Python: it lets other threads run)."""
        if self.beating:
            return
        self.beating = True

        def beat() -> None:
            while True:
                time.sleep(HEARTBEAT_S / 4)
                with self.lock:
                    now = time.monotonic()
                    if self.current and now - self.last_line >= HEARTBEAT_S:
                        self._say(f"  still compiling {self.current[-1]} "
                                  f"({now - self.started:.0f} s so far)")

        threading.Thread(target=beat, name="compile-progress", daemon=True).start()


_INSTALLED: list[_Progress] = []


def report_compilation(out: TextIO | None = None, prefix: str = "") -> None:
    """Print compile progress on `out` (default: the current stderr) whenever kernels
    compile in this process, each line after `prefix`; once per process (later calls change
    nothing)."""
    from ..jit import watch_compilation

    if not _INSTALLED:
        _INSTALLED.append(_Progress(out, prefix))
        watch_compilation(_INSTALLED[0])
