"""Results and events: offline `Keyframes` and session `Segment`s, online `KeyframeEvent`,
`GapEvent`, `StatusEvent`, `SegmentEvent` (`streamkey.segments`), and the playable extras
(`ProvisionalEvent`, `CancelEvent`, `SignalEvent`; `streamkey.playable`).

Events are final once emitted and serialise to the versioned JSON schema documented in the
README (`to_dict()`, `"v": 2`); every event is an `Event`. Every event has an idempotent `id`:
a consumer that sees the same id twice (a resent packet, a replayed log) may drop the second.
A provisional event is the one event that is not a decision: it announces a likely key early
and is followed by exactly one final `KeyframeEvent` (`confirms` = its `pid`) or `CancelEvent`.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from .errors import UsageError

__all__ = ["Keyframes", "KeyframeEvent", "GapEvent", "StatusEvent", "ProvisionalEvent",
           "CancelEvent", "SignalEvent", "Event", "SCHEMA_VERSION", "params_digest",
           "rank_strength", "rank_strengths", "STRENGTH_WINDOW", "Segment", "SegmentEvent",
           "SegmentKind", "INPUT_STATUS"]

SCHEMA_VERSION = 2
SegmentKind = Literal["calibration", "still", "take"]
INPUT_STATUS = "input_"  # status `input_<kind>`: live input refused (what came, what was due)
STRENGTH_WINDOW = 64  # keys: a key's strength is its score's rank among this many recent keys


def rank_strength(recent: Any, score: float) -> float:
    """Mid-rank of `score` in `recent` (the scores it is ranked among, itself included):
    (number below + half the number equal) / count, in (0, 1); 0.5 for a lone key."""
    below = sum(1 for s in recent if s < score)
    equal = sum(1 for s in recent if s == score)
    return (below + 0.5 * equal) / max(len(recent), 1)


def rank_strengths(scores: Any, window: int = STRENGTH_WINDOW) -> np.ndarray:
    """Strength of each key of a sorted key list: the mid-rank of its score among itself and
    the `window - 1` keys before it (causal, the same numbers as the online keyframer's)."""
    s = np.asarray(scores, dtype=np.float64)
    head = min(len(s), window - 1)
    out = np.array([rank_strength(s[: i + 1], float(s[i])) for i in range(head)])
    if len(s) <= head:
        return out
    # the full windows at once (blocks of rows: cache-sized), rank_strength's arithmetic
    rows = np.lib.stride_tricks.sliding_window_view(s, window)
    tail = np.empty(len(rows))
    for lo in range(0, len(rows), 4096):
        w, me = rows[lo : lo + 4096], s[window - 1 + lo : window - 1 + lo + 4096, None]
        below = np.count_nonzero(w < me, axis=1)
        equal = np.count_nonzero(w == me, axis=1)
        tail[lo : lo + len(w)] = (below + 0.5 * equal) / window
    return np.concatenate([out, tail])


@dataclass
class Keyframes:
    """Offline result: sorted unique frame indices (file numbering), a score each, the params.

    `info` holds method diagnostics (candidates, thresholds, chosen sigma, ...). `strength`
    (in [0, 1], comparable across methods) defaults to `rank_strengths(scores)`.
    """

    method: str
    frames: np.ndarray
    scores: np.ndarray
    params: dict[str, Any]
    n_frames: int
    info: dict[str, Any] = field(default_factory=dict)
    strength: np.ndarray | None = None

    if TYPE_CHECKING:  # the generated __init__ also takes sequences: __post_init__ converts
        def __init__(self, method: str, frames: Sequence[int] | np.ndarray,
                     scores: Sequence[float] | np.ndarray, params: dict[str, Any], n_frames: int,
                     info: dict[str, Any] = ..., strength: Sequence[float] | np.ndarray | None
                     = None) -> None: ...

    def __post_init__(self) -> None:
        self.frames = np.asarray(self.frames, dtype=np.int64)
        self.scores = np.asarray(self.scores, dtype=np.float64)
        self.strength = (rank_strengths(self.scores) if self.strength is None
                         else np.asarray(self.strength, dtype=np.float64))
        if self.frames.shape != self.scores.shape or self.frames.shape != self.strength.shape:
            raise ValueError("frames, scores and strengths must have the same length")
        if len(self.frames) > 1 and np.any(np.diff(self.frames) <= 0):
            raise ValueError("keyframes must be sorted and unique")

    def __len__(self) -> int:
        return int(len(self.frames))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict: keyframes, scores, params (the `extract` output schema)."""
        return {"method": self.method, "keyframes": self.frames.tolist(),
                "scores": [round(float(s), 6) for s in self.scores],
                "strength": [round(float(s), 6) for s in np.asarray(self.strength)],
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


@dataclass(frozen=True, slots=True, kw_only=True)
class Event:
    """What the online keyframers and the engine emit, every kind of it about stream `stream`.

    Subclasses are frozen and keyword-only (`KeyframeEvent(stream=..., method=..., ...)`): an
    event is final once emitted. Each has an idempotent `id` and
    its documented JSON object (`to_dict()`); sinks dispatch on the subclass (`match`), and
    `streamkey.adapters.codec` encodes any of them to JSON text and OSC messages.
    """

    stream: str

    @property
    def id(self) -> str:
        """Idempotent id (a consumer that sees it twice may drop the second)."""
        raise NotImplementedError

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        raise NotImplementedError


@dataclass(frozen=True, slots=True, kw_only=True)
class KeyframeEvent(Event):
    """A final keyframe decision: frame `frame` decided when frame `decided_at` arrived.

    `strength` in [0, 1] ranks the score among the method's recent keys (comparable across
    methods); `confirms` is the `pid` of the provisional event it confirms (None: none)."""

    method: str
    frame: int
    time: float
    score: float
    decided_at: int
    lookahead: int
    params: str
    wall_latency_ms: float | None = None
    strength: float = 0.5
    confirms: int | None = None

    @property
    def latency_frames(self) -> int:
        """Frames between the key pose and the frame that decided it."""
        return self.decided_at - self.frame

    @property
    def id(self) -> str:
        """Idempotent id: stream/method/frame/params-digest."""
        return f"{self.stream}/{self.method}/{self.frame}/{self.params}"

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "keyframe", "id": self.id, "stream": self.stream,
                "method": self.method, "frame": self.frame, "time": round(self.time, 6),
                "score": round(float(self.score), 6), "strength": round(self.strength, 6),
                "decided_at": self.decided_at, "latency_frames": self.latency_frames,
                "lookahead": self.lookahead, "wall_latency_ms": self.wall_latency_ms,
                "params": self.params, "confirms": self.confirms}


@dataclass(frozen=True, slots=True, kw_only=True)
class ProvisionalEvent(Event):
    """A likely key at `frame`, announced when frame `seen_at` arrived, before the final
    decision; exactly one `KeyframeEvent` (confirms=pid) or `CancelEvent` (pid) follows."""

    method: str
    frame: int
    time: float
    strength: float
    seen_at: int
    pid: int

    @property
    def id(self) -> str:
        """Idempotent id: stream/method/provisional/pid."""
        return f"{self.stream}/{self.method}/provisional/{self.pid}"

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "provisional", "id": self.id,
                "stream": self.stream, "method": self.method, "frame": self.frame,
                "time": round(self.time, 6), "strength": round(self.strength, 6),
                "seen_at": self.seen_at, "pid": self.pid}


@dataclass(frozen=True, slots=True, kw_only=True)
class CancelEvent(Event):
    """The provisional `pid` (at `frame`) did not become a key; decided at `decided_at`."""

    method: str
    frame: int
    pid: int
    decided_at: int

    @property
    def id(self) -> str:
        """Idempotent id: stream/method/cancel/pid."""
        return f"{self.stream}/{self.method}/cancel/{self.pid}"

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "cancel", "id": self.id, "stream": self.stream,
                "method": self.method, "frame": self.frame, "pid": self.pid,
                "decided_at": self.decided_at}


@dataclass(frozen=True, slots=True, kw_only=True)
class SignalEvent(Event):
    """Continuous per-stream values at frame `seq` (opt-in): body speed, each method's
    running keyness (`streamkey.playable`)."""

    seq: int
    time: float
    values: dict[str, float] = field(default_factory=dict)

    @property
    def id(self) -> str:
        """Idempotent id: stream/signal/seq."""
        return f"{self.stream}/signal/{self.seq}"

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "signal", "id": self.id, "stream": self.stream,
                "seq": self.seq, "time": round(self.time, 6),
                "values": {k: round(float(v), 6) for k, v in self.values.items()}}


@dataclass(frozen=True, slots=True, kw_only=True)
class GapEvent(Event):
    """Frames `first`..`last` (inclusive) never arrived; `bridged` if interpolated over."""

    method: str
    first: int
    last: int
    bridged: bool

    @property
    def id(self) -> str:
        """Idempotent id: stream/gap/first seq."""
        return f"{self.stream}/gap/{self.first}"

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "gap", "id": self.id, "stream": self.stream,
                "method": self.method,
                "first": self.first, "last": self.last, "missing": self.last - self.first + 1,
                "bridged": self.bridged}


@dataclass(frozen=True, slots=True, kw_only=True)
class StatusEvent(Event):
    """Free-form status (warm-up done, restart, counters) for logs and dashboards; status
    `input_<kind>` (`INPUT_STATUS`) explains refused live input in `detail["message"]`."""

    method: str
    status: str
    detail: dict[str, Any] = field(default_factory=dict)
    seq: int | None = None

    @property
    def id(self) -> str:
        """Idempotent id: stream/status/name/seq (`seq`, else the detail's seq, else 0)."""
        seq = self.seq if self.seq is not None else self.detail.get("seq", 0)
        return f"{self.stream}/status/{self.status}/{seq}"

    def to_dict(self) -> dict[str, Any]:
        """The event as the documented JSON object."""
        return {"v": SCHEMA_VERSION, "type": "status", "id": self.id, "stream": self.stream,
                "method": self.method, "status": self.status, "detail": _jsonable(self.detail)}


@dataclass(frozen=True, slots=True)
class Segment:
    """Frames `start`..`end` (inclusive, the stream's frame numbers) of one kind; `pose` is the
    calibration pose ("T", "A", "N") of a calibration hold, else None."""

    kind: SegmentKind
    start: int
    end: int
    start_time: float
    end_time: float
    pose: str | None = None

    @property
    def frames(self) -> int:
        """Number of frames in the segment."""
        return self.end - self.start + 1

    def to_dict(self) -> dict[str, Any]:
        """The segment as a JSON object (for `extract` output)."""
        return {"kind": self.kind, "start": self.start, "end": self.end,
                "start_time": round(self.start_time, 6), "end_time": round(self.end_time, 6),
                "pose": self.pose}


@dataclass(frozen=True, slots=True, kw_only=True)
class SegmentEvent(Event):
    """A segment decision made when frame `decided_at` arrived: `end` None for an open segment
    (its start and kind known, its end not yet), else the closed, final segment."""

    kind: SegmentKind
    start: int
    end: int | None
    start_time: float
    end_time: float | None
    decided_at: int
    pose: str | None = None

    @property
    def latency_frames(self) -> int:
        """Frames between the decided boundary (the end, or the start of an open segment) and
        the frame that decided it."""
        return self.decided_at - (self.start if self.end is None else self.end)

    @property
    def id(self) -> str:
        """Idempotent id: stream/segment/kind/start/open|end."""
        tail = "open" if self.end is None else str(self.end)
        return f"{self.stream}/segment/{self.kind}/{self.start}/{tail}"

    def segment(self) -> Segment:
        """The closed segment (a `UsageError` for an open one)."""
        if self.end is None or self.end_time is None:
            raise UsageError("an open segment event has no end yet")
        return Segment(self.kind, self.start, self.end, self.start_time, self.end_time,
                       self.pose)

    def to_dict(self) -> dict[str, Any]:
        """The event as a JSON object (`"type": "segment"`)."""
        return {"v": SCHEMA_VERSION, "type": "segment", "id": self.id, "stream": self.stream,
                "kind": self.kind,
                "start": self.start, "end": self.end, "start_time": round(self.start_time, 6),
                "end_time": None if self.end_time is None else round(self.end_time, 6),
                "decided_at": self.decided_at, "latency_frames": self.latency_frames,
                "pose": self.pose}
