"""Durations that carry their unit, so a parameter keeps its meaning at any capture rate.

A keypose is a property of the motion, not of the recording: a smoothing scale, a window or a
lookahead defined in frames means half as much time at 60 Hz as at 120 Hz. Durations are
therefore given in seconds and converted to frames only where a stream's rate is known
(`Duration.to_frames`). A plain number passed where a `Duration` is accepted is a frame count
(the meaning every such parameter had before units were explicit), so existing calls keep
their behaviour; the CLI writes `0.5s` for seconds and `60` for frames.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Literal

from .errors import UsageError

__all__ = ["Duration", "DurationLike", "frames_of", "whole_frames", "seconds_of",
           "parse_duration"]

Unit = Literal["s", "frames"]


@dataclass(frozen=True, slots=True)
class Duration:
    """A length of time in seconds (`unit="s"`) or in frames of the stream it is applied to."""

    value: float
    unit: Unit = "s"

    @classmethod
    def seconds(cls, value: float) -> Duration:
        """`value` seconds of motion."""
        return cls(float(value), "s")

    @classmethod
    def frames(cls, value: float) -> Duration:
        """`value` frames, whatever the rate."""
        return cls(float(value), "frames")

    def to_frames(self, fps: float) -> float:
        """This duration in frames of a stream at `fps` (not rounded)."""
        return self.value * fps if self.unit == "s" else self.value

    def to_seconds(self, fps: float) -> float:
        """This duration in seconds for a stream at `fps`."""
        return self.value if self.unit == "s" else self.value / fps

    def __str__(self) -> str:
        return f"{self.value:g}s" if self.unit == "s" else f"{self.value:g} frames"


DurationLike = Duration | float | int


def frames_of(duration: DurationLike, fps: float) -> float:
    """`duration` in frames at `fps`; a plain number is already a frame count."""
    if isinstance(duration, Duration):
        return duration.to_frames(fps)
    return float(duration)


def whole_frames(duration: DurationLike, fps: float, minimum: int = 0) -> int:
    """`duration` in whole frames at `fps` (rounded half up), at least `minimum`."""
    return max(minimum, math.floor(frames_of(duration, fps) + 0.5))


def seconds_of(duration: DurationLike, fps: float) -> float:
    """`duration` in seconds at `fps`; a plain number is a frame count."""
    if isinstance(duration, Duration):
        return duration.to_seconds(fps)
    return float(duration) / fps


_DURATION = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(s|ms|frames?|f)?\s*$")


def parse_duration(text: str, *, name: str = "duration") -> Duration:
    """`0.5s`, `500ms`, `60`, `60f` or `60 frames` as a `Duration`; a `UsageError` naming
    `name` otherwise."""
    match = _DURATION.match(text)
    if not match:
        raise UsageError(f"{name}: {text!r} is not a duration; give seconds with an s suffix "
                         "(e.g. 0.5s or 500ms) or a whole number of frames (e.g. 60)")
    value, unit = float(match.group(1)), match.group(2) or "frames"
    if not math.isfinite(value):
        raise UsageError(f"{name}: {text!r} is not a finite duration")
    if unit == "s":
        return Duration.seconds(value)
    if unit == "ms":
        return Duration.seconds(value / 1000.0)
    if value != int(value):
        raise UsageError(f"{name}: {text!r} is not a whole number of frames; "
                         "add an s suffix for seconds")
    return Duration.frames(value)
