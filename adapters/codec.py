"""Events on the wire, in one place: JSON text and OSC messages of every engine `Event`, for
every sink (JSON Lines, stdout, WebSocket and the dashboard, ZeroMQ, OSC, the cluster's Redis
event log).

Typed events are encoded from their fields (`event_json`, `osc_messages`,
`compact_message`), dispatched on their class. OSC carries the numbers of the JSON object
(times, scores and strengths rounded to 6 decimals), so a receiver of either sees the same
values. Records that are not engine events (operator annotations, events read back from a log
written by an older version) go through `record_messages` / `record_id`, which read the
documented JSON fields and tolerate missing ones.

OSC layouts (documented in `adapters.osc`): `numeric` (`NUMERIC_LAYOUT`, one message per event,
numbers only, stream and method in the address) and `compact` (`/streamkey/keyframe`, one
message per keyframe).

A session segment (`SegmentEvent`, `"type": "segment"`) is, in the `numeric` layout,

    /streamkey/<stream>/segment/<kind>  i open, i start, i end, f start_time, f end_time,
                                        i latency_frames

with `<kind>` `calibration`, `still` or `take`; `open` 1 when the segment starts (its end not
known yet: `end` and `end_time` are -1), 0 when it is closed (final); `latency_frames` as in
the JSON. The times follow the sink's time type (`f`, or `d` with `?time=d`). The calibration
pose ("T", "A", "N") is in the JSON only.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from pythonosc.osc_message_builder import OscMessageBuilder

from streamkey.keyframes import (
    CancelEvent,
    Event,
    GapEvent,
    KeyframeEvent,
    ProvisionalEvent,
    SegmentEvent,
    SignalEvent,
    StatusEvent,
)

__all__ = ["event_json", "record_json", "osc_messages", "record_messages", "event_messages",
           "compact_message", "encode_event", "event_id", "osc_name", "osc_string",
           "encode_message", "NUMERIC_LAYOUT", "KEYFRAME_ADDRESS", "NAME_LIMIT"]

KEYFRAME_ADDRESS = "/streamkey/keyframe"
NUMERIC_LAYOUT = {  # event type -> (address under /streamkey/<stream>/, OSC type tags)
    "keyframe": ("<method>/keyframe", "ifif"),
    "provisional": ("<method>/provisional", "iff"),
    "cancel": ("<method>/cancel", "i"),
    "gap": ("gap", "iii"),
    "status": ("status/<status>", "i"),
    "signal": ("signal/<name>", "f"),
    "segment": ("segment/<kind>", "iiiffi"),
}
NAME_LIMIT = 64
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_NAME_OK = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-")
_COMPACT = (",", ":")


# ------------------------------------------------------------------ JSON


def event_json(event: Event, *, compact: bool = True) -> str:
    """The event's documented JSON object as text (`compact`: no spaces; else `json.dumps`'
    default separators, what the ZeroMQ and Redis event payloads have always carried)."""
    return record_json(event.to_dict(), compact=compact)


def record_json(record: Mapping[str, Any], *, compact: bool = True) -> str:
    """A JSON record (an event's dict, an annotation, a dashboard message) as text."""
    return json.dumps(record, separators=_COMPACT) if compact else json.dumps(record)


def event_id(event: Event | Mapping[str, Any]) -> str | None:
    """The idempotent id of an event or of a logged record (schema v2 `id`): keyframes
    `stream/method/frame/params-digest`, gaps `stream/gap/<first seq>`, segments
    `stream/segment/<kind>/<start>/<end or open>`, status
    `stream/status/<name>/<seq>`; None for a record without one (a status without a seq).
    A record's own `id` wins; the same string is computed for records that lack it."""
    if isinstance(event, Event):
        return event.id
    if isinstance(event.get("id"), str):
        return str(event["id"])
    kind, stream = event.get("type"), event.get("stream")
    if kind == "keyframe":
        return f"{stream}/{event.get('method')}/{event.get('frame')}/{event.get('params')}"
    if kind == "gap":
        return f"{stream}/gap/{event.get('first')}"
    if kind == "segment":
        end = event.get("end")
        return (f"{stream}/segment/{event.get('kind')}/{event.get('start')}/"
                f"{'open' if end is None else end}")
    detail = event.get("detail")
    if kind == "status" and isinstance(detail, dict) and detail.get("seq") is not None:
        return f"{stream}/status/{event.get('status')}/{detail['seq']}"
    return None


# ------------------------------------------------------------------ OSC


def osc_string(text: str) -> bytes:
    """An OSC string: UTF-8, NUL-terminated, padded to 4 bytes."""
    raw = text.encode() + b"\0"
    return raw + b"\0" * (-len(raw) % 4)


def osc_name(name: object) -> str:
    """One address part from a stream/method/status/signal name: characters outside
    `A-Z a-z 0-9 _ -` become `_`, empty becomes `_`, at most 64 characters."""
    text = str(name)[:NAME_LIMIT]
    return "".join(c if c in _NAME_OK else "_" for c in text) or "_"


def encode_message(address: str, tags: str, args: Sequence[float]) -> bytes:
    """One OSC message with numeric arguments (`i`, `f`, `d`), fixed layout; a float
    beyond float32 range is sent as an infinity of its sign."""
    values = [math.copysign(math.inf, a) if t == "f" and abs(a) > _FLOAT32_MAX else a
              for t, a in zip(tags, args, strict=True)]
    return osc_string(address) + osc_string("," + tags) + struct.pack(">" + tags, *values)


def _int32(value: Any, default: int = -1) -> int:
    """An int for an `i` argument (out of range or not a number: `default`)."""
    try:
        number = int(value)
    except (TypeError, ValueError, OverflowError):
        return default
    return number if -(2**31) <= number < 2**31 else default


def _float(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError, OverflowError):
        return float("nan")


def _r6(value: Any) -> float:
    """A number as `to_dict()` rounds it (6 decimals, by the value's own `round`)."""
    return _float(round(value, 6))


def osc_messages(event: Event, time_type: str = "f") -> list[bytes]:
    """The `numeric` layout messages of one event (none for a kind that has none)."""
    root = f"/streamkey/{osc_name(event.stream)}"
    match event:
        case KeyframeEvent():
            return [encode_message(f"{root}/{osc_name(event.method)}/keyframe",
                                   f"i{time_type}fi",
                                   (_int32(event.frame), _r6(event.time), _r6(event.strength),
                                    _int32(event.latency_frames)))]
        case ProvisionalEvent():
            return [encode_message(f"{root}/{osc_name(event.method)}/provisional",
                                   f"i{time_type}f",
                                   (_int32(event.frame), _r6(event.time), _r6(event.strength)))]
        case CancelEvent():
            return [encode_message(f"{root}/{osc_name(event.method)}/cancel", "i",
                                   (_int32(event.frame),))]
        case GapEvent():
            return [encode_message(f"{root}/gap", "iii", (
                _int32(event.first), _int32(event.last), int(bool(event.bridged))))]
        case StatusEvent():
            return [encode_message(f"{root}/status/{osc_name(event.status)}", "i",
                                   (_int32(event.detail.get("seq", -1)),))]
        case SignalEvent():
            return [encode_message(f"{root}/signal/{osc_name(name)}", "f",
                                   (_r6(float(value)),))
                    for name, value in event.values.items()]
        case SegmentEvent():
            return [_segment_message(root, event.kind, event.start, event.end,
                                     event.start_time, event.end_time, event.latency_frames,
                                     time_type)]
    return []


def _segment_message(root: str, kind: Any, start: Any, end: Any, start_time: Any,
                     end_time: Any, latency: Any, time_type: str) -> bytes:
    """`/streamkey/<stream>/segment/<kind>`: open, start, end, start_time, end_time, latency
    (an open segment: end and end_time -1)."""
    closed = end is not None
    return encode_message(f"{root}/segment/{osc_name(kind)}", f"iii{time_type}{time_type}i", (
        int(not closed), _int32(start), _int32(end) if closed else -1, _r6(_float(start_time)),
        _r6(_float(end_time)) if closed else -1.0, _int32(latency)))


def record_messages(record: Mapping[str, Any], time_type: str = "f") -> list[bytes]:
    """The `numeric` layout messages of a JSON record, by its `type` (none for a type it
    has no message for, e.g. an annotation); a keyframe without a `strength` (events before
    strengths were added) sends 1.0."""
    d, kind = record, record.get("type")
    root = f"/streamkey/{osc_name(d.get('stream', 'default'))}"
    method = f"{root}/{osc_name(d.get('method', '_'))}"
    strength = d.get("strength")
    strength = 1.0 if strength is None else _float(strength)
    if kind == "keyframe":
        return [encode_message(f"{method}/keyframe", f"i{time_type}fi", (
            _int32(d.get("frame")), _float(d.get("time")), strength,
            _int32(d.get("latency_frames"))))]
    if kind == "provisional":
        return [encode_message(f"{method}/provisional", f"i{time_type}f", (
            _int32(d.get("frame")), _float(d.get("time")), strength))]
    if kind == "cancel":
        return [encode_message(f"{method}/cancel", "i", (_int32(d.get("frame")),))]
    if kind == "gap":
        return [encode_message(f"{root}/gap", "iii", (
            _int32(d.get("first")), _int32(d.get("last")), int(bool(d.get("bridged")))))]
    if kind == "status":
        detail = d.get("detail") or {}
        seq = detail.get("seq", -1) if isinstance(detail, dict) else -1
        return [encode_message(f"{root}/status/{osc_name(d.get('status', '_'))}", "i",
                               (_int32(seq),))]
    if kind == "segment":
        return [_segment_message(root, d.get("kind", "_"), d.get("start"), d.get("end"),
                                 d.get("start_time"), d.get("end_time"),
                                 d.get("latency_frames"), time_type)]
    if kind == "signal":
        values = d.get("values") or {}
        return [encode_message(f"{root}/signal/{osc_name(name)}", "f", (_float(value),))
                for name, value in (values.items() if isinstance(values, dict) else ())]
    return []


def event_messages(event: Event | Mapping[str, Any], time_type: str = "f") -> list[bytes]:
    """`osc_messages` of an event, `record_messages` of a JSON record."""
    if isinstance(event, Event):
        return osc_messages(event, time_type)
    return record_messages(event, time_type)


def compact_message(event: KeyframeEvent, time_type: str = "f") -> bytes:
    """`/streamkey/keyframe s stream, s method, i frame, f time, f score, i latency_frames`."""
    return _compact(event.stream, event.method, event.frame, round(event.time, 6),
                    round(float(event.score), 6), event.latency_frames, time_type)


def encode_event(event: KeyframeEvent | Mapping[str, Any], time_type: str = "f") -> bytes:
    """The `compact` layout message of a keyframe event or of its JSON record."""
    if isinstance(event, KeyframeEvent):
        return compact_message(event, time_type)
    return _compact(event["stream"], event["method"], event["frame"], event["time"],
                    event["score"], event["latency_frames"], time_type)


def _compact(stream: Any, method: Any, frame: Any, time: Any, score: Any, latency: Any,
             time_type: str) -> bytes:
    builder = OscMessageBuilder(KEYFRAME_ADDRESS)
    builder.add_arg(str(stream), "s")
    builder.add_arg(str(method), "s")
    builder.add_arg(int(frame), "i")
    builder.add_arg(float(time), time_type)
    builder.add_arg(float(score), "f")
    builder.add_arg(int(latency), "i")
    return bytes(builder.build().dgram)
