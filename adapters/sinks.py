"""Local sinks: the JSON Lines session log (never drops) and stdout."""

from __future__ import annotations

import json
import os
import sys
from collections import deque
from pathlib import Path
from typing import Any, TextIO

from streamkey.errors import InputError
from streamkey.keyframes import Event

from .base import Address, Sink
from .codec import event_id, event_json, record_json

__all__ = ["JsonlSink", "StdoutSink", "event_id", "DEDUPE_TAIL"]

DEDUPE_TAIL = 100_000  # ids of the last events of an existing log checked against on restart


def _ids_in(path: Path) -> set[str]:
    """Ids of the last `DEDUPE_TAIL` events already in a log (unreadable lines skipped)."""
    tail: deque[str] = deque(maxlen=DEDUPE_TAIL)
    try:
        with open(path, "rb") as fh:
            for line in fh:
                try:
                    record = json.loads(line)
                except ValueError:
                    continue
                if isinstance(record, dict) and (key := event_id(record)) is not None:
                    tail.append(key)
    except OSError:
        return set()
    return set(tail)


class JsonlSink(Sink):
    """Append every event as one JSON line, flushed before any network sink sees it.

    The file is fsynced on close. It never drops by itself; a write error (disk full) raises,
    and the engine counts it against this sink (and disables it after repeated failures)
    without touching the keyframers or the other sinks.

    Appending to an existing log (a restarted run, a stream restored from a snapshot and
    replayed) skips the events whose id is already in it (the last `DEDUPE_TAIL`), counted
    as `duplicates`; events of this run are never skipped.
    """

    name = "jsonl"
    live = False

    def __init__(self, address: Address) -> None:
        super().__init__()
        self.path = Path(address.path)
        self.logged = _ids_in(self.path) if self.path.is_file() else set()
        try:
            self.file: TextIO = open(self.path, "a", encoding="utf-8")  # noqa: SIM115
        except OSError as exc:
            raise InputError(f"{self.path}: cannot open the log for appending: "
                             f"{exc.strerror}") from None

    async def start(self) -> str:
        return f"jsonl:{self.path}"

    def offer(self, event: Event) -> None:
        if self.logged and event.id in self.logged:
            self.stats.duplicates += 1
            return
        self._append(event_json(event))

    def write(self, record: dict[str, Any]) -> None:
        """Append one JSON record (an operator annotation) and flush."""
        self._append(record_json(record))

    def _append(self, text: str) -> None:
        self.file.write(text + "\n")
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
            sys.stdout.write(event_json(event) + "\n")
            sys.stdout.flush()
            self.stats.sent += 1
        except BrokenPipeError:
            self.stats.dropped += 1
