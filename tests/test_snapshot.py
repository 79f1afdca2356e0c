"""Snapshots: versioned, refused when they do not fit, small, and a tested
determinism contract: the same frames give the same events after any snapshot/restore point."""

from __future__ import annotations

import functools
import pickle
import struct

import numpy as np
import pytest
from cmu import DATA
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from streamkey.bvh import read_bvh
from streamkey.methods import ONLINE_METHODS, online_class
from streamkey.online import OnlineKeyframer, Pipeline
from streamkey.snapshot import SnapshotError, read_header
from streamkey.streaming import make_keyframers

MOTION = read_bvh(DATA / "07_01.bvh")
FRAMES = MOTION.frames()
THREE = ["saliency", "speed", "simplify"]


def run_keyframer(kf, frames):
    return [e for f in frames for e in kf.push(f)]


@functools.cache
def uninterrupted(method: str) -> list:
    kf = online_class(method)(MOTION.skeleton, MOTION.fps)
    return run_keyframer(kf, FRAMES) + kf.flush()


@pytest.mark.parametrize("method", list(ONLINE_METHODS))
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cuts=st.lists(st.integers(0, len(FRAMES)), min_size=1, max_size=3))
def test_every_keyframer_gives_the_same_events_after_any_snapshot_point(method, cuts):
    kf = online_class(method)(MOTION.skeleton, MOTION.fps)
    events, at = [], 0
    for cut in sorted(cuts):
        events += run_keyframer(kf, FRAMES[at:cut])
        at = cut
        data = kf.snapshot()
        header, _ = read_header(data)
        assert header.params == kf.params_digest and header.kind == "keyframer"
        assert header.last_seq == (FRAMES[cut - 1].seq if cut else None)
        kf = OnlineKeyframer.restore(data, params=kf.params_digest)
    events += run_keyframer(kf, FRAMES[at:]) + kf.flush()
    assert events == uninterrupted(method)


@functools.cache
def pipeline_reference() -> list:
    pipe = Pipeline(make_keyframers(MOTION, list(ONLINE_METHODS)))
    out = []
    for f in FRAMES:
        out += pipe.push(f)
        out += pipe.idle()
    return out + pipe.flush()


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cut=st.integers(0, len(FRAMES)), before_idle=st.booleans())
def test_a_pipeline_restored_between_push_and_idle_decides_the_same(cut, before_idle):
    pipe = Pipeline(make_keyframers(MOTION, list(ONLINE_METHODS)))
    out = []
    for i, f in enumerate(FRAMES):
        out += pipe.push(f)
        if i == cut and before_idle:  # the re-analysis of frame i is still pending
            pipe = Pipeline.restore(pipe.snapshot())
        out += pipe.idle()
        if i == cut and not before_idle:
            pipe = Pipeline.restore(pipe.snapshot())
    assert out + pipe.flush() == pipeline_reference()


def test_the_three_method_pipeline_snapshot_is_at_most_8_mb_after_30_seconds():
    motion = read_bvh(DATA / "01_06.bvh")
    pipe = Pipeline(make_keyframers(motion, THREE))
    frames = motion.frames()[: int(30 * motion.fps)]
    for f in frames:
        pipe.push(f)
        pipe.idle()
    data = pipe.snapshot()
    assert len(data) <= 8 * 2**20, f"{len(data) / 2**20:.2f} MB"
    restored = Pipeline.restore(data)
    speed = next(kf for kf in restored.keyframers if kf.method == "speed")
    assert set(vars(speed._bank)) == {"lams"}  # factors: re-derived on demand, not stored
    tail = motion.frames()[len(frames) : len(frames) + 600]
    assert [e for f in tail for e in restored.push(f) + restored.idle()] == [
        e for f in tail for e in pipe.push(f) + pipe.idle()]


def test_the_four_method_pipeline_snapshot_is_at_most_8_mb_after_30_seconds():
    """Preallocated rings and unused channels are not stored (their zero slices are left
    out), so the default pipeline's snapshot stays small; restored, it decides the same."""
    motion = read_bvh(DATA / "01_06.bvh")
    pipe = Pipeline(make_keyframers(motion, list(ONLINE_METHODS)))
    frames = motion.frames()[: int(30 * motion.fps)]
    for f in frames:
        pipe.push(f)
        pipe.idle()
    data = pipe.snapshot()
    assert len(data) <= 8_000_000, f"{len(data):,} bytes"  # measured: 7,377,193 (format 7)
    assert pipe.snapshot() == data  # deterministic: the same state, the same bytes
    restored = Pipeline.restore(data)
    tail = motion.frames()[len(frames) : len(frames) + 600]
    assert [e for f in tail for e in restored.push(f) + restored.idle()] == [
        e for f in tail for e in pipe.push(f) + pipe.idle()]


def as_format(data: bytes, version: int) -> bytes:
    """A current snapshot relabelled as an earlier format (same header fields, checksum)."""
    import hashlib
    import json
    import zlib

    header, payload = read_header(data)
    assert header.version == 7
    raw = zlib.decompress(payload) if version == 4 else bytes(payload)
    info = header.as_dict() | {"version": version, "sha256": hashlib.sha256(raw).hexdigest()}
    head = json.dumps(info, sort_keys=True).encode()
    return struct.pack(">6sBI", b"SKSNAP", version, len(head)) + head + raw


@pytest.mark.parametrize("version", [4, 5, 6])
def test_a_snapshot_of_an_earlier_state_shape_is_refused_with_a_clear_error(version):
    """Formats 4-6 hold the front end without its lead-frame check and speed with its own
    first-frame hold: restored, they would half fit, so they are refused."""
    kf = online_class("speed")(MOTION.skeleton, MOTION.fps)
    run_keyframer(kf, FRAMES[:300])
    with pytest.raises(SnapshotError, match=f"version {version}, this streamkey reads "
                                            "versions 7 only; replay the stream"):
        OnlineKeyframer.restore(as_format(kf.snapshot(), version), params=kf.params_digest)


@given(shape=st.lists(st.integers(1, 40), min_size=1, max_size=3),
       density=st.sampled_from([0.0, 0.05, 0.5, 1.0]), seed=st.integers(0, 99),
       dtype=st.sampled_from(["<f8", "<f4", "|b1", "<i8", ">f8"]))
@settings(max_examples=60, deadline=None)
def test_arrays_come_back_bit_for_bit_without_their_zero_slices(shape, density, seed, dtype):
    rng = np.random.default_rng(seed)
    arr = (rng.normal(size=shape) * (rng.random(shape) < density)).astype(dtype)
    if arr.dtype.kind == "f" and arr.size:
        arr.flat[0] = -0.0  # a negative zero is a value, kept
    back = pickle.loads(_pickled(arr))
    assert back.dtype == arr.dtype and back.shape == arr.shape
    assert back.tobytes() == arr.tobytes()


def _pickled(obj) -> bytes:
    import io

    from streamkey.snapshot import _Pickler

    buf = io.BytesIO()
    _Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(obj)
    return buf.getvalue()


def test_snapshots_that_do_not_fit_are_refused_with_a_clear_error():
    kf = online_class("simplify")(MOTION.skeleton, MOTION.fps)
    run_keyframer(kf, FRAMES[:50])
    data = kf.snapshot()
    other = online_class("simplify")(MOTION.skeleton, MOTION.fps, tolerance=0.5)
    with pytest.raises(SnapshotError, match="parameters"):
        OnlineKeyframer.restore(data, params=other.params_digest)
    for version in (1, 9):  # 1: before deferred work reshaped the keyframers' state
        with pytest.raises(SnapshotError, match=f"version {version}, this streamkey reads"):
            OnlineKeyframer.restore(data[:6] + struct.pack(">B", version) + data[7:])
    with pytest.raises(SnapshotError, match="checksum"):
        OnlineKeyframer.restore(data[:-3] + bytes(3))
    with pytest.raises(SnapshotError, match="expected a Pipeline"):
        Pipeline.restore(data)
    for junk in (b"", b"SKSNAP", b"x" * 100, data[:20]):
        with pytest.raises(SnapshotError):
            OnlineKeyframer.restore(junk)
    assert OnlineKeyframer.restore(data, params=kf.params_digest).guard.last.seq == 50
