"""Playable events: strength, `--min-interval` debounce, provisional events and
the continuous signal. Sans-I/O: wrappers around any online keyframer, and the same rules as
functions over offline `Keyframes`.

- **Strength** (every key, online and offline): the mid-rank of the key's score among the
  method's last `STRENGTH_WINDOW` (64) keys, itself included: (keys below + half the keys
  equal) / keys, in (0, 1). A rank, so it reads the same for every method whatever its score's
  unit (saliency 0.01–82, speed 0.5–68, simplify 0–0.5): 0.9 is "stronger than 90 % of this
  method's recent keys". Causal: online it is computed when the key is sent
  (`OnlineKeyframer.event`), offline over the keys in frame order (`rank_strengths`); with
  an unbounded lookahead the keys, their order and so their strengths are identical. The
  first key of a stream has 0.5; keys inserted by `--max-gap` have 0. The ranking history
  survives a restart inside a stream (a long gap) and starts afresh at a flush.
- **Debounce** (`--min-interval SECONDS`, per method): of keys closer than the interval, keep
  the stronger (higher score; a tie keeps the earlier). Greedy in frame order: a held key is
  replaced by a stronger key less than the interval after it, and sent once a key at least the
  interval after it arrives or once no such key can come any more. Online (`MinInterval`) the
  latter is known when the inner keyframer has decided every frame up to held + interval - 1,
  i.e. at most `interval - 1` frames after its own deadline: the wrapper's lookahead is the
  inner one plus the interval. Same keys offline (`debounce`) and online, whatever the
  lookahead, given the same inner keys.
- **Provisional events** (`--provisional`, opt-in): every method exposes `candidates()`, the
  keys it expects among its undecided frames right now (speed: the window's speed minima whose
  current intensity clears the current cut-off, recomputed every `hop` frames; saliency: the
  clusters that the frames not yet classified point to with this moment's statistics, from
  their final maps or, for frames younger than the support, from early maps computed 2 sigma
  frames after the frame with windows cut there, every 4 frames; simplify: the window
  recursion's keys and the witness; optimal: the keys of the best chain after the decided
  part). `Playable` asks after every frame: a candidate with no open provisional within
  `radius` frames (0.05 s) gets a `ProvisionalEvent`; an open one follows its nearest
  candidate; a candidate at a key just sent is not announced again. A final key confirms the
  nearest open provisional within `radius` (its `confirms` is that `pid`), else a provisional
  is sent right before it (lead 0), so every final key confirms exactly one provisional. An
  open provisional whose frame + `radius` has been decided without a key gets a `CancelEvent`;
  at the end of a stream or a window every open one is resolved. The final events are the
  inner keyframer's, unchanged but for `confirms`. Opt-in because it doubles the event count
  and asks the consumer to handle take-backs; the final-only stream stays what existing sinks
  and scripts expect.
- **Signal** (`--signal [N]`, opt-in): one `SignalEvent` per stream every N frames (seq % N
  == 0) with `body_speed` (mean speed of Miura's 16 body parts in the pelvis frame, body
  heights per second, smoothed causally with a 50 ms time constant) and per method its
  running keyness: the strength of its strongest candidate in view (0 when it has none).
  The last keyframer of the pipeline sends it, reading the others' per-frame keyness.

The wrappers `MinInterval` and `Playable` live in `streamkey.playable_online` (this module
stays light for the command line). `Playable` runs its inner keyframer frame by frame (block
slices), so provisional and signal events are the same whatever the block split. Restarts (a
long gap, a source starting over) and flushes resolve every open provisional; after a
keyframer fault the engine resets the windows without a flush, and the open provisionals of
that moment are dropped (the `error` status event says so).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import UsageError
from .keyframes import Keyframes
from .methods import OFFLINE_METHODS

__all__ = ["debounce", "debounce_rows", "Debouncer", "parse_min_interval", "interval_frames",
           "debounce_results", "RADIUS_SECONDS",
           "SIGNAL_SMOOTHING_SECONDS"]

RADIUS_SECONDS = 0.05  # a provisional and a final key this close are the same key
SIGNAL_SMOOTHING_SECONDS = 0.05  # time constant of the body-speed smoothing


# --------------------------------------------------------------------------- debounce

def interval_frames(seconds: float, fps: float) -> int:
    """A minimum interval in frames (at least 1)."""
    if not (isinstance(seconds, int | float) and math.isfinite(seconds) and seconds >= 0):
        raise UsageError(f"min-interval must be a number of seconds >= 0, got {seconds!r}")
    return max(1, int(round(seconds * fps)))


class Debouncer:
    """The debounce rule over keys arriving in frame order (shared offline and online)."""

    def __init__(self, gap: int) -> None:
        self.gap = int(gap)
        self.held: tuple[int, float, Any] | None = None  # (frame, score, item)

    def offer(self, frame: int, score: float, item: Any) -> list[Any]:
        """A new key; returns the held item it releases (if any)."""
        held = self.held
        if held is not None and frame - held[0] < self.gap:
            if score > held[1]:
                self.held = (frame, score, item)
            return []
        self.held = (frame, score, item)
        return [] if held is None else [held[2]]

    def due(self, final: int) -> list[Any]:
        """Frames <= `final` carry no further key: release the held key if none can reach it."""
        if self.held is not None and self.held[0] + self.gap - 1 <= final:
            item, self.held = self.held[2], None
            return [item]
        return []

    def finish(self) -> list[Any]:
        """End of stream: release the held key."""
        item, self.held = (None if self.held is None else self.held[2]), None
        return [] if item is None else [item]


def debounce_rows(frames: np.ndarray, scores: np.ndarray, gap: int) -> np.ndarray:
    """Indices of the keys kept by the debounce rule (frames sorted)."""
    d = Debouncer(gap)
    kept: list[int] = []
    for i, (f, s) in enumerate(zip(np.asarray(frames).tolist(), np.asarray(scores).tolist(),
                                   strict=True)):
        kept += d.offer(int(f), float(s), i)
    kept += d.finish()
    return np.array(kept, dtype=np.int64)


def debounce(keys: Keyframes, seconds: float, fps: float) -> Keyframes:
    """`keys` without keys closer than `seconds` to a stronger one (module docstring)."""
    keep = debounce_rows(keys.frames, keys.scores, interval_frames(seconds, fps))
    strength = np.asarray(keys.strength)
    info = {**keys.info, "min_interval_dropped": int(len(keys) - len(keep))}
    return Keyframes(keys.method, keys.frames[keep], keys.scores[keep],
                     {**keys.params, "min_interval": seconds}, keys.n_frames, info,
                     strength=strength[keep] if len(keep) else np.zeros(0))


def parse_min_interval(text: str | None) -> dict[str, float] | None:
    """`0.15` (every method) or `simplify=0.2,speed=0.1` -> {method or "*": seconds}."""
    if text is None:
        return None
    out: dict[str, float] = {}
    for part in (p.strip() for p in text.split(",")):
        name, _, value = part.rpartition("=")
        try:
            seconds = float(value)
        except ValueError:
            seconds = math.nan
        if not part or not math.isfinite(seconds) or seconds < 0:
            raise UsageError(f"--min-interval: expected SECONDS or METHOD=SECONDS[,...], "
                             f"got {text!r}")
        name = name.strip() or "*"
        if name != "*" and name not in OFFLINE_METHODS:
            raise UsageError(f"--min-interval: unknown method {name!r}; choose from "
                             f"{', '.join(OFFLINE_METHODS)}")
        out[name] = seconds
    return out


def debounce_results(results: list[Any], text: str | None) -> None:
    """`extract --min-interval`: debounce every offline result in place (`FileResult`s)."""
    intervals = parse_min_interval(text)
    if not intervals:
        return
    for r in results:
        if r.motion is None:
            continue
        for name, keys in r.results.items():
            seconds = intervals.get(name, intervals.get("*"))
            if seconds:
                r.results[name] = debounce(keys, seconds, r.motion.fps)
