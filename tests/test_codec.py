"""The one event codec (`adapters.codec`): typed events encode to the same JSON text and OSC
bytes as their documented JSON records, on the real events of a CMU clip (every kind)."""

from __future__ import annotations

import json

import numpy as np
from cmu import DATA
from pythonosc.osc_message import OscMessage

from streamkey.adapters.codec import (
    compact_message,
    encode_event,
    event_id,
    event_json,
    osc_messages,
    record_json,
    record_messages,
)
from streamkey.bvh import read_bvh
from streamkey.keyframes import Event, GapEvent, KeyframeEvent, StatusEvent
from streamkey.methods import ONLINE_METHODS
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers


def clip_events() -> list[Event]:
    """Every method's events on 09_01 with provisional and signal events, plus a gap and the
    status of a restart (a hole of 30 frames, then the stream starting over)."""
    motion = read_bvh(DATA / "09_01.bvh")
    params = {"*": {"provisional": True, "signal": 1}}
    frames = motion.frames()
    whole = Pipeline(make_keyframers(motion, list(ONLINE_METHODS), params))
    holed = Pipeline(make_keyframers(motion, list(ONLINE_METHODS), params))
    return (whole.push_block(frames) + whole.flush() + holed.push_block(frames[:60] + frames[90:])
            + holed.push_block(frames[:20]) + holed.flush())


def test_typed_events_encode_as_their_json_records_do() -> None:
    events = clip_events()
    kinds = {type(e).__name__ for e in events}
    assert {"KeyframeEvent", "ProvisionalEvent", "CancelEvent", "SignalEvent", "GapEvent",
            "StatusEvent"} <= kinds, kinds
    for event in events:
        record = event.to_dict()
        assert event_json(event) == json.dumps(record, separators=(",", ":"))
        assert event_json(event, compact=False) == json.dumps(record)
        assert record_json(record) == event_json(event)
        assert event_id(event) == event_id(record) == event.id
        for time_type in ("f", "d"):
            assert osc_messages(event, time_type) == record_messages(record, time_type), event
        if isinstance(event, KeyframeEvent):
            assert compact_message(event) == encode_event(record)
            assert compact_message(event, "d") == encode_event(record, "d")


def test_osc_carries_the_numbers_of_the_json_object() -> None:
    """Times and strengths are rounded to 6 decimals as in the JSON, then sent as float32."""
    event = KeyframeEvent(stream="s", method="speed", frame=42, time=1 / 3, score=1.5,
                          decided_at=162, lookahead=120, params="p", strength=2 / 3)
    (message,) = osc_messages(event, "d")
    args = OscMessage(message).params
    assert args[:3] == [42, round(1 / 3, 6), float(np.float32(round(2 / 3, 6)))]
    gap, status = (GapEvent(stream="s", method="*", first=5, last=9, bridged=True),
                   StatusEvent(stream="s", method="*", status="error", detail={"seq": 3}))
    assert OscMessage(osc_messages(gap)[0]).params == [5, 9, 1]
    assert OscMessage(osc_messages(status)[0]).address == "/streamkey/s/status/error"
