"""Local sinks: the JSON Lines session log (never drops) and stdout."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any, TextIO

from streamkey.errors import InputError
from streamkey.keyframes import Event

from .base import Address, Sink

__all__ = ["JsonlSink", "StdoutSink"]


class JsonlSink(Sink):
    """Append every event as one JSON line, flushed before any network sink sees it.

    The file is fsynced on close. It never drops by itself; a write error (disk full) raises,
    and the engine counts it against this sink (and disables it after repeated failures)
    without touching the keyframers or the other sinks.
    """

    name = "jsonl"
    live = False

    def __init__(self, address: Address) -> None:
        super().__init__()
        self.path = Path(address.path)
        try:
            self.file: TextIO = open(self.path, "a", encoding="utf-8")  # noqa: SIM115
        except OSError as exc:
            raise InputError(f"{self.path}: cannot open the log for appending: "
                             f"{exc.strerror}") from None

    async def start(self) -> str:
        return f"jsonl:{self.path}"

    def offer(self, event: Event) -> None:
        self.write(event.to_dict())

    def write(self, record: dict[str, Any]) -> None:
        """Append one JSON record (an event, or an operator annotation) and flush."""
        self.file.write(json.dumps(record, separators=(",", ":")) + "\n")
        self.file.flush()
        self.stats.sent += 1

    async def close(self) -> None:
        if self.file.closed:
            return
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
        finally:
            try:
                self.file.close()
            except OSError:  # the unwritable tail was reported by flush (or by offer)
                pass


class StdoutSink(Sink):
    """Events as JSON lines on stdout (`-`)."""

    name = "stdout"
    live = False

    def offer(self, event: Event) -> None:
        try:
            sys.stdout.write(json.dumps(event.to_dict(), separators=(",", ":")) + "\n")
            sys.stdout.flush()
            self.stats.sent += 1
        except BrokenPipeError:
            self.stats.dropped += 1
