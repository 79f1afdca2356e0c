"""The stream table (sans-I/O): lifecycle of stream ids and the one fault policy, on a real
clip's pipelines; and it does no I/O (no asyncio, sockets, clocks)."""

from __future__ import annotations

import ast

import pytest
from cmu import DATA, ROOT

from streamkey.bvh import read_bvh
from streamkey.io import StreamSpec
from streamkey.keyframes import Event, KeyframeEvent, StatusEvent
from streamkey.online import Pipeline
from streamkey.streamtable import MAX_WAITING_FRAMES, StreamTable, keyframers_for

MOTION = read_bvh(DATA / "07_01.bvh")
SPEC = StreamSpec("a", MOTION.skeleton, MOTION.fps)


def pipeline(name: str = "a") -> Pipeline:
    return Pipeline(keyframers_for(StreamSpec(name, MOTION.skeleton, MOTION.fps), ["speed"]),
                    stream=name)


def test_the_table_module_does_no_io() -> None:
    tree = ast.parse((ROOT / "streamkey" / "streamtable.py").read_text())
    imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)
                for a in n.names}
    imported |= {(n.module or "").split(".")[0] for n in ast.walk(tree)
                 if isinstance(n, ast.ImportFrom) and n.level == 0}
    assert not imported & {"asyncio", "socket", "time", "zmq", "threading", "selectors"}


def test_streams_open_wait_hold_are_refused_and_retire_by_the_time_passed_in() -> None:
    table = StreamTable(max_streams=2, idle=1.0)
    a = table.open("a", "a", pipeline("a"), now=0.0)
    table.wait("b", now=0.0)
    frames = MOTION.frames()
    for i in range(MAX_WAITING_FRAMES + 3):
        table.hold("b", frames[i % len(frames)], i, now=0.5)
    assert table.stats_of("b").waiting_drops == 3
    assert not table.admits("c") and table.admits("b") and table.admits("a")
    assert table.refuse("c", frame=True, say_limit=20)
    assert not table.refuse("c", frame=True, say_limit=20)  # said once, counted twice
    assert (table.refused_streams, table.refused_frames) == (1, 2)
    held = table.take_held("b")
    assert len(held) == MAX_WAITING_FRAMES and held[0][1] == 3
    table.touch(a, now=0.9)
    assert table.expired(now=1.5) == [] and table.expired(now=2.0) == [a]
    table.close(a)
    assert "a" not in table.live and table.stats_of("a").retired == 1
    table.wait("d", now=0.0)
    table.forget_stale(now=5.0)
    assert "d" not in table.waiting


def test_a_keyframer_fault_restarts_the_windows_and_is_reported_as_an_event() -> None:
    table = StreamTable()
    state = table.open("a", None, pipeline(), now=0.0)
    frames = MOTION.frames()
    for frame in frames[:100]:
        table.step(state, frame.seq, state.pipeline.push, frame)

    def broken(*_: object) -> list[Event]:
        raise ZeroDivisionError("injected")

    (event,) = table.step(state, 100, broken)
    assert isinstance(event, StatusEvent) and event.status == "error"
    assert event.detail == {"error": "ZeroDivisionError: injected", "seq": 100}
    assert table.faults.count == 1 and "injected (at seq 100)" in table.faults.messages[0]
    assert state.pipeline.guard.last is None  # windows restarted
    events: list[Event] = []
    for frame in frames[100:]:  # the stream goes on
        events += table.step(state, frame.seq, state.pipeline.push, frame)
    events += table.step(state, None, state.pipeline.flush)
    assert any(isinstance(e, KeyframeEvent) and e.frame > 100 for e in events)


def test_a_snapshot_restores_into_a_new_session() -> None:
    table = StreamTable()
    state = table.open("a", None, pipeline(), now=0.0)
    for frame in MOTION.frames()[:50]:
        table.step(state, frame.seq, state.pipeline.push, frame)
    data = table.snapshot("a")
    other = StreamTable()
    restored = other.restore("a", None, data, now=1.0)
    assert restored.seq == MOTION.frames()[49].seq and restored.stats.sessions == 1
    with pytest.raises(KeyError):
        table.snapshot("nope")
