from __future__ import annotations

import numpy as np
import pytest
from cmu import DATA
from hypothesis import given, settings
from hypothesis import strategies as st
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder

from streamkey.adapters import osc as osc_adapter
from streamkey.adapters.osc import (
    FRAME_ADDRESS,
    OscDecodeError,
    OscSource,
    decode_bundle,
    decode_frame,
    decode_skeleton,
    encode_bundle,
    encode_event,
    encode_frame,
    encode_skeleton,
    event_messages,
    ntp_timetag,
    osc_name,
    timetag_seconds,
    with_layout,
)
from streamkey.bvh import read_bvh
from streamkey.keyframes import GapEvent, KeyframeEvent, StatusEvent


def python_osc_frame(seq, time, channels):
    builder = OscMessageBuilder(FRAME_ADDRESS)
    builder.add_arg(seq, "i")
    builder.add_arg(time, "d")
    for v in channels:
        builder.add_arg(float(v), "f")
    return builder.build().dgram


def test_fixed_layout_frame_encoder_is_byte_for_byte_python_osc():
    motion = read_bvh(DATA / "07_01.bvh")
    for i in (1, 100, 316):
        ours = encode_frame(i, i / 120.0, motion.channels[i])
        assert ours == python_osc_frame(i, i / 120.0, motion.channels[i])
        seq, time, channels = decode_frame(ours)
        assert (seq, time) == (i, i / 120.0)
        np.testing.assert_array_equal(channels, motion.channels[i].astype(np.float32))


def test_frames_from_other_senders_with_float_seq_and_doubles_decode():
    builder = OscMessageBuilder(FRAME_ADDRESS)
    builder.add_arg(7.0, "f")  # Pd sends every number as a float
    builder.add_arg(0.5, "f")
    for v in (1.5, 2.5, 3):
        builder.add_arg(v, "d" if isinstance(v, float) else "i")
    seq, time, channels = decode_frame(builder.build().dgram)
    assert (seq, time) == (7, 0.5)
    np.testing.assert_array_equal(channels, [1.5, 2.5, 3.0])


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.sampled_from("ihfd"), min_size=1, max_size=90), min_size=1,
                max_size=120))
def test_frames_with_many_type_tag_layouts_decode_as_python_osc_reads_them(layouts):
    """The decoder remembers layouts by type tags: a sender switching between many (more
    than it keeps) still gets every frame read exactly, and the memory stays bounded."""
    for i, tags in enumerate(layouts):
        builder = OscMessageBuilder(FRAME_ADDRESS)
        builder.add_arg(i, "i")
        builder.add_arg(i / 8, "d")
        for j, t in enumerate(tags):
            builder.add_arg(j if t in "ih" else j + 0.5, t)
        dgram = builder.build().dgram
        seq, time, channels = decode_frame(dgram)
        assert (seq, time) == (i, i / 8)
        np.testing.assert_array_equal(channels, OscMessage(dgram).params[2:])
        assert len(osc_adapter._FRAME_PLANS) <= osc_adapter._MAX_FRAME_PLANS


def bad(address="/streamkey/frame", args=(("i", 1), ("d", 0.0), ("f", 1.0))):
    builder = OscMessageBuilder(address)
    for t, v in args:
        builder.add_arg(v, t)
    return builder.build().dgram


@pytest.mark.parametrize(("packet", "kind"), [
    (bad("/other/frame"), "address"),
    (bad(args=(("i", 1), ("d", 0.0))), "arity"),
    (bad(args=(("s", "x"), ("d", 0.0), ("f", 1.0))), "types"),
    (bad(args=(("i", 1), ("d", 0.0), ("s", "x"))), "types"),
    (bad(args=(("i", 1), ("d", 0.0), ("f", float("nan")))), "nan"),
    (bad(args=(("i", 1), ("d", float("inf")), ("f", 1.0))), "nan"),
    (bad(args=[("i", 1), ("d", 0.0)] + [("f", 1.0)] * 2000), "oversize"),
    (b"\x00garbage", "parse"),
])
def test_malformed_frames_raise_one_decode_error_with_a_kind(packet, kind):
    with pytest.raises(OscDecodeError) as info:
        decode_frame(packet)
    assert info.value.kind == kind


def test_skeleton_message_round_trips():
    motion = read_bvh(DATA / "131_01.bvh")
    skeleton, fps = decode_skeleton(encode_skeleton(motion.skeleton, motion.fps))
    assert skeleton.names == motion.skeleton.names and fps == motion.fps
    assert skeleton.channels == motion.skeleton.channels
    np.testing.assert_allclose(skeleton.offsets, motion.skeleton.offsets, atol=1e-6)


def test_keyframe_event_layout_is_the_documented_one():
    event = {"stream": "s1", "method": "speed", "frame": 42, "time": 0.35, "score": 1.5,
             "latency_frames": 60}
    msg = OscMessage(encode_event(event))
    assert msg.address == "/streamkey/keyframe"
    assert msg.dgram[20:28] == b",ssiffi\x00"
    assert msg.params[:3] == ["s1", "speed", 42] and msg.params[4:] == [1.5, 60]
    assert abs(msg.params[3] - 0.35) < 1e-7
    assert OscMessage(encode_event(event, "d")).params[3] == 0.35


# -------------------------------------------------------------------------------- numeric layout

def type_tags(message: bytes) -> str:
    start = (message.index(b"\0") + 4) & ~3
    return message[start + 1 : message.index(b"\0", start)].decode()


KEY = KeyframeEvent(stream="take 1", method="speed", frame=42, time=0.35, score=1.5,
                    decided_at=162, lookahead=120, params="abcdef0123")


def test_numeric_layout_addresses_and_type_tags_are_the_documented_ones():
    (key,) = event_messages(KEY)
    msg = OscMessage(key)
    assert msg.address == "/streamkey/take_1/speed/keyframe"
    assert type_tags(key) == "iffi"
    assert msg.params[0] == 42 and msg.params[3] == 120
    assert abs(msg.params[1] - 0.35) < 1e-7
    assert 0.0 <= msg.params[2] <= 1.0
    assert OscMessage(event_messages(KEY, "d")[0]).params[1] == 0.35
    (gap,) = event_messages(GapEvent(stream="take 1", method="*", first=200, last=229,
                                          bridged=False))
    assert (OscMessage(gap).address, OscMessage(gap).params) == ("/streamkey/take_1/gap",
                                                                 [200, 229, 0])
    (status,) = event_messages(StatusEvent(stream="take 1", method="*", status="restart",
                                                detail={"last_seq": 316, "seq": 1}))
    assert (OscMessage(status).address, OscMessage(status).params) == (
        "/streamkey/take_1/status/restart", [1])


def test_new_event_types_map_by_their_dict_type():
    """Provisional, cancel and signal events map by `to_dict()["type"]`."""
    base = {"v": 2, "stream": "s", "method": "saliency", "frame": 7, "time": 0.5}
    (prov,) = event_messages({**base, "type": "provisional", "strength": 0.25, "pid": 3})
    (cancel,) = event_messages({**base, "type": "cancel", "pid": 3})
    signal = event_messages({"type": "signal", "stream": "s", "seq": 9, "time": 0.1,
                             "values": {"body speed": 1.5, "keyness": 0.2}})
    assert (OscMessage(prov).address, OscMessage(prov).params) == (
        "/streamkey/s/saliency/provisional", [7, 0.5, 0.25])
    assert type_tags(prov) == "iff" and type_tags(cancel) == "i"
    assert (OscMessage(cancel).address, OscMessage(cancel).params) == (
        "/streamkey/s/saliency/cancel", [7])
    assert [(OscMessage(m).address, OscMessage(m).params) for m in signal] == [
        ("/streamkey/s/signal/body_speed", [1.5]),
        ("/streamkey/s/signal/keyness", [pytest.approx(0.2)])]
    assert event_messages({"type": "annotation", "stream": "s"}) == []


def test_bundle_round_trips_through_our_decoder_and_python_osc():
    gap = GapEvent(stream="take 1", method="*", first=5, last=9, bridged=True)
    messages = event_messages(KEY) + event_messages(gap)
    tag = ntp_timetag(1_796_000_000.25)
    packet = encode_bundle(messages, tag)
    assert decode_bundle(packet) == (tag, messages)
    assert timetag_seconds(tag) == 1_796_000_000.25
    other = OscBundle(packet)  # an independent decoder
    assert other.timestamp == pytest.approx(1_796_000_000.25, abs=1e-6)
    assert [m.address for m in other] == ["/streamkey/take_1/speed/keyframe",
                                          "/streamkey/take_1/gap"]
    with pytest.raises(OscDecodeError):
        decode_bundle(messages[0])
    with pytest.raises(OscDecodeError):
        decode_bundle(packet[:-3])


def test_our_source_takes_a_time_tagged_bundle_of_frames():
    motion = read_bvh(DATA / "07_01.bvh")
    source = OscSource(parse_osc("osc://127.0.0.1:9"), skeleton=motion.skeleton, fps=120.0)
    frames = [encode_frame(i, i / 120, motion.channels[i]) for i in (1, 2, 3)]
    source.receive(encode_bundle(frames, ntp_timetag(1_796_000_000.0)))
    assert source.stats.received == 3 and not source.stats.malformed


def parse_osc(text):
    from streamkey.adapters import parse_address

    return parse_address(text)


def test_osc_layout_option_reaches_osc_targets_only():
    assert with_layout(["osc://127.0.0.1:9001", "jsonl:x.jsonl", "osc://h:1?time=d"],
                       "compact") == ["osc://127.0.0.1:9001?layout=compact", "jsonl:x.jsonl",
                                      "osc://h:1?time=d&layout=compact"]
    assert with_layout(["osc://h:1?layout=numeric"], "compact") == ["osc://h:1?layout=numeric"]


# Hostile names: the OSC-reserved characters, separators, controls, non-ASCII, empty, long.
HOSTILE = st.text(alphabet=st.sampled_from(list(" #*,/?[]{}\x00\n\t.:%~\u00e9\u4e2d") +
                                          list("ab09_-")), max_size=80)
RESERVED = set(" #*,/?[]{}")


@settings(max_examples=200, derandomize=True, deadline=None)
@given(stream=HOSTILE, method=HOSTILE, status=HOSTILE,
       frame=st.one_of(st.integers(-2**40, 2**40), st.none(), st.text(max_size=3)),
       value=st.floats(allow_nan=True, allow_infinity=True))
def test_hostile_names_and_values_give_legal_addresses_of_fixed_depth(stream, method, status,
                                                                      frame, value):
    events = [{"type": "keyframe", "stream": stream, "method": method, "frame": frame,
               "time": value, "strength": value, "latency_frames": frame},
              {"type": "provisional", "stream": stream, "method": method, "frame": frame,
               "time": value, "strength": None},
              {"type": "cancel", "stream": stream, "method": method, "frame": frame},
              {"type": "gap", "stream": stream, "first": frame, "last": frame, "bridged": 1},
              {"type": "status", "stream": stream, "status": status, "detail": {"seq": frame}},
              {"type": "signal", "stream": stream, "values": {status: value}}]
    depth = {"keyframe": 4, "provisional": 4, "cancel": 4, "gap": 3, "status": 4, "signal": 4}
    messages = []
    for event in events:
        for m in event_messages(event):
            address = OscMessage(m).address
            parts = address.split("/")[1:]
            assert len(parts) == depth[event["type"]], address
            assert parts[0] == "streamkey" and all(parts)
            assert not RESERVED & set(address[1:].replace("/", "")), address
            assert all(c.isascii() and c.isprintable() for c in address)
            assert len(parts[1]) <= 64
            messages.append(m)
    assert osc_name(stream) == osc_name(osc_name(stream))  # escaping is idempotent
    assert decode_bundle(encode_bundle(messages, 1)) == (1, messages)
