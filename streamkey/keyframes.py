"""Results and events: offline `Keyframes`, online `KeyframeEvent`, `GapEvent`, `StatusEvent`.

Events are final once emitted (DESIGN §3) and serialise to the versioned JSON schema
documented in the README (`to_json()`).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Keyframes", "KeyframeEvent", "GapEvent", "StatusEvent", "Event", "SCHEMA_VERSION",
           "params_digest"]

SCHEMA_VERSION = 1


@dataclass
class Keyframes:
    """Offline result: sorted unique frame indices (file numbering), a score each, the params.

    `info` holds method diagnostics (candidates, thresholds, chosen sigma, ...).
    """

    method: str
    frames: np.ndarray
    scores: np.ndarray
    params: dict[str, Any]
    n_frames: int
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.frames = np.asarray(self.frames, dtype=np.int64)
        self.scores = np.asarray(self.scores, dtype=np.float64)
        if self.frames.shape != self.scores.shape:
            raise ValueError("frames and scores must have the same length")
        if len(self.frames) > 1 and np.any(np.diff(self.frames) <= 0):
            raise ValueError("keyframes must be sorted and unique")

    def __len__(self) -> int:
        return int(len(self.frames))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: keyframes, scores, params (the `extract` output schema)."""
        return {"method": self.method, "keyframes": self.frames.tolist(),
                "scores": [round(float(s), 6) for s in self.scores],
                "params": _jsonable(self.params), "n_frames": self.n_frames}


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def params_digest(params: dict[str, Any]) -> str:
    """Short stable digest of a parameter dict, carried by every event."""
    text = json.dumps(_jsonable(params), sort_keys=True)
    return hashlib.sha1(text.encode()).hexdigest()[:10]


@dataclass(frozen=True, slots=True)
class KeyframeEvent:
    """A final keyframe decision: frame `frame` decided when frame `decided_at` arrived."""

    stream: str
    method: str
    frame: int
    time: float
    score: float
    decided_at: int
    lookahead: int
    params: str
    wall_latency_ms: float | None = None

    @property
    def latency_frames(self) -> int:
        """Frames between the key pose and the frame that decided it."""
        return self.decided_at - self.frame

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "keyframe", "stream": self.stream,
                "method": self.method, "frame": self.frame, "time": round(self.time, 6),
                "score": round(float(self.score), 6), "decided_at": self.decided_at,
                "latency_frames": self.latency_frames, "lookahead": self.lookahead,
                "wall_latency_ms": self.wall_latency_ms, "params": self.params}


@dataclass(frozen=True, slots=True)
class GapEvent:
    """Frames `first`..`last` (inclusive) never arrived; `bridged` if interpolated over."""

    stream: str
    method: str
    first: int
    last: int
    bridged: bool

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "gap", "stream": self.stream, "method": self.method,
                "first": self.first, "last": self.last, "missing": self.last - self.first + 1,
                "bridged": self.bridged}


@dataclass(frozen=True, slots=True)
class StatusEvent:
    """Free-form status (warm-up done, restart, counters) for logs and dashboards."""

    stream: str
    method: str
    status: str
    detail: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "status", "stream": self.stream,
                "method": self.method, "status": self.status, "detail": _jsonable(self.detail)}


Event = KeyframeEvent | GapEvent | StatusEvent
