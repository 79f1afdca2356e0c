from __future__ import annotations

import numpy as np
import pytest
from cmu import DATA
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message_builder import OscMessageBuilder

from streamkey.adapters.osc import (
    FRAME_ADDRESS,
    OscDecodeError,
    decode_frame,
    decode_skeleton,
    encode_event,
    encode_frame,
    encode_skeleton,
)
from streamkey.bvh import read_bvh


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
