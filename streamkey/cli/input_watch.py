"""Live input that explains itself: while `run` runs, input the engine refuses or holds (a
wrong OSC address, a wrong channel count, frames before any skeleton, positions-only lines,
non-finite values) gets one line on stderr naming what arrived and what was expected, the
first time and then at most every few seconds per kind (with the count since), and a count
per kind at the end. A first frame that looks like a calibration/reference pose (a BVH's
frame-0 T-pose) is pointed out once. Reads the engine's and source's counters from outside:
the engine itself is unchanged.

Each line is also a `status` event to every sink of the engine (JSON Lines, OSC, ZeroMQ,
WebSocket, the dashboard), with the same rate limit: status `input_<kind>` (OSC
`/streamkey/<stream>/status/input_<kind> i seq`), detail `kind`, `message` (the line without
its `warning: `), `count` (refusals this line stands for) and `seq` (the stream's newest frame,
when there is one). `--quiet` silences stderr only; the events still go out."""

from __future__ import annotations

import asyncio
import sys
import time
from collections import Counter
from typing import Any, TextIO

import numpy as np

from ..keyframes import INPUT_STATUS, StatusEvent
from ..motion import Frame, detect_reference_frame

__all__ = ["InputWatch", "REPEAT_S", "POLL_S"]

REPEAT_S = 5.0  # a kind of refusal is explained again at most this often
POLL_S = 0.1    # how often the counters are read (a refusal is explained within this)

FRAME_ADDRESSES = "/streamkey/frame or /streamkey/<stream>/frame (and /streamkey/skeleton)"
_KIND_HINTS = {
    "address": f"expected {FRAME_ADDRESSES}",
    "positions": "frames must carry the skeleton's rotation channels (`channels`); solve "
                 "rotations first (an IK retargeter) and send those",
    "nan": "every channel must be a finite number",
}


class InputWatch:
    """Explains refused or held live input on `out` (stderr), rate-limited per kind."""

    def __init__(self, out: TextIO | None = None, quiet: bool = False,
                 repeat_s: float = REPEAT_S) -> None:
        self.out = out
        self.quiet = quiet
        self.repeat_s = repeat_s
        self.engine: Any = None
        self.task: asyncio.Task[None] | None = None  # `watch()` when the caller keeps it
        self.publish = True  # also send each line as a status event to the engine's sinks
        self.counts: Counter[str] = Counter()
        self._said_at: dict[str, float] = {}
        self._unsaid: Counter[str] = Counter()
        self._seen_malformed: Counter[str] = Counter()
        self._seen_invalid: dict[str, int] = {}
        self._sizes: set[int] = set()
        self._bad_size: int | None = None
        self._first: list[Frame] = []
        self._pose_checked = False
        self._first_of: tuple[str, Any] = ("", None)
        self._waiting_said: set[str] = set()

    # ------------------------------------------------------------------ hooks

    def on_frame(self, frame: Frame) -> None:
        """The engine's per-frame hook: remember a frame whose size fits no live skeleton,
        and the first two frames (for the reference-pose check)."""
        n = int(np.size(frame.channels))
        if n not in self._sizes:
            self._sizes = self._live_sizes()
            if n not in self._sizes:
                self._bad_size = n
        if not self._pose_checked and len(self._first) < 2 and n in self._sizes:
            live = list(self.engine.table.live.values())
            if len(live) != 1:  # several streams: the first frames may be of different ones
                self._pose_checked = True
                return
            self._first.append(frame)
            self._first_of = (live[0].name, live[0].pipeline.features.skeleton)

    async def watch(self) -> None:
        """Read the counters every `POLL_S` until cancelled."""
        while True:
            await asyncio.sleep(POLL_S)
            self.check()

    def check(self, final: bool = False) -> None:
        """Compare the counters with the last look; explain what grew."""
        engine = self.engine
        if engine is None:
            return
        stats = engine.source.counters()
        for kind, count in list(stats.malformed.items()):
            grew = count - self._seen_malformed[kind]
            if grew > 0:
                self._seen_malformed[kind] = count
                self._note(kind, grew, self._malformed_line(kind, stats.last_error), None,
                           final)
        for name, state in list(engine.table.live.items()):
            guard = state.pipeline.guard
            invalid = guard.counters.invalid
            grew = invalid - self._seen_invalid.get(name, 0)
            if grew > 0:
                self._seen_invalid[name] = invalid
                self._note_invalid(name, guard.n_channels, grew, final)
        for name, held in list(engine.table.waiting.items()):
            if held and name not in self._waiting_said:
                self._waiting_said.add(name)
                self._note("no_skeleton", len(held),
                           f"frames on stream {name!r} before any skeleton: send "
                           "/streamkey/skeleton (or the stdin skeleton line) first, or give "
                           "--skeleton FILE; they are held until it comes", name, final)
        self._check_first_pose(final)
        if final:
            self._flush_unsaid()

    def summary_line(self) -> str | None:
        """`input refused: KIND N, ...` for the end of the run (None if nothing was)."""
        if not self.counts:
            return None
        return "input problems: " + ", ".join(f"{k} {v}" for k, v in sorted(self.counts.items()))

    # ------------------------------------------------------------------ details

    def _live_sizes(self) -> set[int]:
        if self.engine is None:
            return set()
        return {int(s.pipeline.guard.n_channels) for s in list(self.engine.table.live.values())}

    def _malformed_line(self, kind: str, last_error: str) -> str:
        hint = _KIND_HINTS.get(kind)
        if kind == "address" or "OSC address" in last_error:
            hint = _KIND_HINTS["address"]
        if any(w in last_error for w in ("positions", "landmarks", "joints")):
            hint = _KIND_HINTS["positions"]
        return f"input refused ({kind}): {last_error}" + (f"; {hint}" if hint else "")

    def _note_invalid(self, stream: str, n_channels: int, grew: int, final: bool) -> None:
        size, self._bad_size = self._bad_size, None
        if size is not None and size != n_channels:
            self._note("channels", grew,
                       f"frame with {size} values on stream {stream!r}: its skeleton has "
                       f"{n_channels} channels (frames must carry one value per channel, in "
                       "the skeleton's order); dropped", stream, final)
        else:
            self._note("invalid", grew, f"frame on stream {stream!r} refused: expected "
                       f"{n_channels} finite channel values (one per skeleton channel) and a "
                       "usable seq/time; dropped", stream, final)

    def _check_first_pose(self, final: bool) -> None:
        if self._pose_checked or len(self._first) < 2 or self.engine is None:
            return
        self._pose_checked = True
        name, skeleton = self._first_of
        channels = np.stack([np.asarray(f.channels, dtype=np.float64) for f in self._first])
        if channels.shape[1] == skeleton.n_channels and detect_reference_frame(
                skeleton, channels) >= 1:
            self._note("reference_pose", 1,
                       f"stream {name!r}: the first frame (seq {self._first[0].seq}) "
                       "looks like a calibration/reference pose (a BVH's frame-0 T-pose: zero "
                       "root rotation, a few whole-degree joint angles), not captured motion; "
                       "the keyframers take it as motion, which can change their keys. Start "
                       "the sender at the first captured frame (`replay` does by default)",
                       name, final)

    def _note(self, kind: str, count: int, line: str, stream: str | None,
              final: bool = False) -> None:
        """Count `count` refusals of `kind`; explain them unless `kind` was explained less
        than `repeat_s` ago (`stream`: whose they are, None for the source's)."""
        self.counts[kind] += count
        now = time.monotonic()
        said = self._said_at.get(kind)
        if said is not None and now - said < self.repeat_s:
            self._unsaid[kind] += count
            return
        more = self._unsaid.pop(kind, 0)
        self._said_at[kind] = now
        message = line + (f" (+{more} more since the last warning)" if more else "")
        if not self.quiet:
            print(f"warning: {message}", file=self.out or sys.stderr, flush=True)
        if self.publish and not final:  # at the end the sinks are closed
            self._send(kind, count + more, message, stream)

    def _flush_unsaid(self) -> None:
        self._unsaid.clear()

    def _send(self, kind: str, count: int, message: str, stream: str | None) -> None:
        """The explanation as a status event to every sink of the engine, as if the engine
        had sent it (the dashboard and `on_event` included)."""
        engine = self.engine
        name = stream if stream is not None else engine.config.stream
        state = engine.table.live.get(name)
        seq = state.seq if state is not None else None
        detail: dict[str, Any] = {"kind": kind, "message": message, "count": count}
        if seq is not None:
            detail["seq"] = seq
        event = StatusEvent(stream=name, method="*", status=INPUT_STATUS + kind,
                            detail=detail, seq=seq)
        engine.summary.events["status"] += 1  # counted as the engine counts its own
        engine.sinks.offer(event)
        engine.sinks.end_batch(time.monotonic_ns())
        if engine.config.on_event is not None:
            engine.config.on_event(event.to_dict())
