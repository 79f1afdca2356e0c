"""What keeps a live frame from waiting: repeated skeletons are not parsed again, the numba
kernels are warm and the start-up heap is out of the garbage collector before the first
frame, and `run --realtime` changes the priority, never the events. (Latency itself is
measured by `streamkey bench --latency`, not here.)"""

from __future__ import annotations

import gc
import json
import os
import subprocess
import sys
from pathlib import Path

from cmu import DATA
from live_helpers import MS, keyframes_of, read_jsonl, streamkey

from streamkey import jit
from streamkey.adapters import osc as osc_adapter
from streamkey.adapters import parse_address
from streamkey.adapters import zmq as zmq_adapter
from streamkey.adapters.osc import OscSource, encode_frame, encode_skeleton, skeleton_header
from streamkey.adapters.zmq import ZmqSource
from streamkey.bvh import parse_bvh, read_bvh
from streamkey.framequeue import SkeletonAnnounced
from streamkey.live import PM_QOS_DEVICE, build_engine
from streamkey.replay.source import MotionSource

CLIP = DATA / "07_01.bvh"
MOTION = read_bvh(CLIP)


def counting(monkeypatch, module, name):
    """Wrap the real `module.name` so that its calls are counted."""
    real, calls = getattr(module, name), []

    def wrapper(*args, **kwargs):
        calls.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, wrapper)
    return calls


def renamed_skeleton():
    """The clip's skeleton with one joint renamed: a different skeleton on the wire."""
    text = skeleton_header(MOTION.skeleton, MOTION.fps).replace("LeftHand", "LeftPaw", 1)
    return parse_bvh(text, source="test").skeleton


def drain(source):
    items = []
    while len(source.frames):
        items.append(source.frames.get_nowait())
    return items


def test_a_repeated_osc_skeleton_is_parsed_once_until_it_is_refused(monkeypatch):
    calls = counting(monkeypatch, osc_adapter, "decode_skeleton")
    source = OscSource(parse_address("osc://127.0.0.1:9"))
    wire = encode_skeleton(MOTION.skeleton, MOTION.fps)
    for _ in range(5):  # the replay re-sends it every second
        source.receive(wire)
    assert len(calls) == 1 and source.skeleton is not None
    assert drain(source) == [SkeletonAnnounced(None)]  # announced once
    source.refuse_skeleton("the engine cannot use it")
    source.receive(wire)  # after a refusal the same bytes are looked at again
    assert len(calls) == 2 and source.skeleton is not None
    assert source.stats.malformed["skeleton"] == 1
    other = encode_skeleton(renamed_skeleton(), MOTION.fps)
    for _ in range(3):  # a different skeleton is parsed and counted every time
        source.receive(other)
    assert len(calls) == 5 and source.stats.malformed["skeleton_mismatch"] == 3
    assert source.skeleton.names == MOTION.skeleton.names


def test_a_named_streams_skeleton_is_parsed_again_after_the_stream_retired(monkeypatch):
    calls = counting(monkeypatch, osc_adapter, "decode_skeleton")
    source = OscSource(parse_address("osc://127.0.0.1:9"))
    wire = encode_skeleton(MOTION.skeleton, 60.0, "/streamkey/dancer/skeleton")
    source.receive(wire)
    source.receive(wire)
    assert len(calls) == 1 and source.skeleton_for("dancer")[1] == 60.0
    source.forget_stream("dancer")
    assert source.skeleton_for("dancer") is None
    source.receive(wire)
    assert len(calls) == 2 and source.skeleton_for("dancer") is not None
    assert [item.stream for item in drain(source)] == ["dancer", "dancer"]


def test_a_given_skeleton_repeated_on_the_wire_is_parsed_once(monkeypatch):
    calls = counting(monkeypatch, osc_adapter, "decode_skeleton")
    source = OscSource(parse_address("osc://127.0.0.1:9"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)  # `run --skeleton`: the wire's copy only matches
    for _ in range(4):
        source.receive(encode_skeleton(MOTION.skeleton, MOTION.fps))
    assert len(calls) == 1 and not source.stats.malformed


def test_a_repeated_zmq_skeleton_is_parsed_once(monkeypatch):
    calls = counting(monkeypatch, zmq_adapter, "decode_skeleton_parts")
    source = ZmqSource(parse_address("zmq+tcp://127.0.0.1:9"))
    body = json.dumps({"bvh": skeleton_header(MOTION.skeleton, MOTION.fps),
                       "fps": MOTION.fps}).encode()
    for _ in range(4):
        source.handle([b"skeleton", body])
        source.handle([b"dancer/skeleton", body])
    assert len(calls) == 2
    assert source.skeleton is not None and source.skeleton_for("dancer") is not None
    assert not source.stats.malformed


async def test_kernels_are_warm_and_the_heap_frozen_before_the_first_frame():
    seen = {"warmed": 0, "frozen_at_frames": []}

    @jit.warmer
    def probe():
        seen["warmed"] += 1

    try:
        source = MotionSource(MOTION, rate=0.0, count=300)
        engine = build_engine(source, ["simplify"], [], on_ready=lambda line: None,
                              on_frame=lambda f: seen["frozen_at_frames"].append(
                                  (seen["warmed"], gc.get_freeze_count())),
                              freeze_gc=True)
        summary = await engine.run()
    finally:
        jit._WARMERS.remove(probe)
    assert seen["warmed"] == 1
    assert len(seen["frozen_at_frames"]) == 300
    assert all(w == 1 and frozen > 10_000 for w, frozen in seen["frozen_at_frames"])
    assert gc.get_freeze_count() == 0  # unfrozen when the run ends
    assert summary.frame_wait.count == summary.frames_in == 300
    assert summary.as_dict()["frame_wait_ms"]["p50"] is not None


async def test_without_freeze_gc_the_heap_stays_with_the_collector():
    frozen = []
    engine = build_engine(MotionSource(MOTION, rate=0.0, count=50), ["simplify"], [],
                          on_ready=lambda line: None,
                          on_frame=lambda f: frozen.append(gc.get_freeze_count()))
    await engine.run()
    assert frozen == [0] * 50


def test_run_realtime_says_what_it_got_and_decides_the_same_keys(tmp_path):
    logs = []
    for extra in ([], ["--realtime"]):
        log = tmp_path / f"run{len(logs)}.jsonl"
        run = streamkey("run", "--from", str(CLIP), "--fast", "--method", "simplify",
                        "--to", f"jsonl:{log}", *extra)
        _, err = run.communicate(timeout=120 * MS)
        assert run.returncode == 0, err
        said = [line for line in err.splitlines() if line.startswith("priority: ")]
        assert len(said) == len(extra), err
        logs.append(keyframes_of(read_jsonl(log)))
    assert said[0].split(": ", 1)[1].startswith(("SCHED_RR 10", "nice -10", "normal (not"))
    assert logs[0] == logs[1] and len(logs[0]) > 10


def test_realtime_priority_is_inherited_by_threads_started_later():
    """The engine's reader threads start after `--realtime`: they get the same policy."""
    code = ("import os, threading; from streamkey.live import raise_priority; "
            "got = raise_priority(); out = []; "
            "t = threading.Thread(target=lambda: out.append(os.sched_getscheduler(0))); "
            "t.start(); t.join(); print(got, out[0] == os.sched_getscheduler(0))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60 * MS)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split()[-1] == "True"



def test_realtime_holds_a_cpu_wakeup_latency_request_while_the_process_lives():
    """PM QoS: the kernel reports the aggregate request when the device is read; the run's
    request is 0 us while its process lives and gone when it exits. Where the device cannot
    be opened, the line says so and why."""
    device = Path(PM_QOS_DEVICE)
    code = ("import sys; from streamkey.live import raise_priority; print(raise_priority(), "
            "flush=True); sys.stdin.readline()")
    proc = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        said = proc.stdout.readline()
        held = os.access(device, os.W_OK)
        if held:
            assert "CPU wake-up latency 0 us (PM QoS)" in said, said
            assert int.from_bytes(device.read_bytes()[:4], sys.byteorder) == 0
        else:
            assert f"CPU wake-up latency not held ({device}: " in said, said
    finally:
        proc.communicate("\n", timeout=60 * MS)
    assert proc.returncode == 0
    if held:  # the kernel dropped the request with the process (unless another holds one)
        if not _holders(device):
            assert int.from_bytes(device.read_bytes()[:4], sys.byteorder) > 0


def _holders(device: Path) -> list[str]:
    """Processes with `device` open (/proc/*/fd)."""
    out = []
    for fd in Path("/proc").glob("[0-9]*/fd/*"):
        try:
            if os.readlink(fd) == str(device):
                out.append(fd.parts[2])
        except OSError:
            pass
    return out


async def test_keyframes_of_a_streams_end_are_stamped_but_not_timed():
    seen = []
    engine = build_engine(MotionSource(MOTION, rate=0.0), ["speed", "simplify"], [],
                          on_ready=lambda line: None, on_event=seen.append)
    summary = await engine.run()
    keys = [e for e in seen if e["type"] == "keyframe"]
    assert all(e["wall_latency_ms"] is not None for e in keys)
    at_end = summary.as_dict()["keyframes_at_stream_end"]
    assert at_end > 0 and summary.latency.count > 0  # speed decides its tail at the end
    assert summary.latency.count + at_end == len(keys) == summary.events["speed"] + summary.events[
        "simplify"]
    assert "decided by a stream's end not timed" in summary.text()


async def test_with_a_skeleton_from_the_wire_the_keyframers_are_warm_before_listening():
    """No skeleton yet: the engine warms its keyframers up on a built-in rig before it
    listens, so the stream's first frames do not wait for imports and kernel loading."""
    seen = {"warmed": 0, "built": [], "at_listen": None}

    @jit.warmer
    def probe():
        seen["warmed"] += 1

    def ready(line):
        if line.startswith("listening on"):
            seen["at_listen"] = (seen["warmed"], list(seen["built"]))
            source.receive(encode_skeleton(MOTION.skeleton, MOTION.fps))
            for frame in MOTION.frames()[:5]:
                source.receive(encode_frame(frame.seq, frame.time, frame.channels))
            source.frames.put(None)

    try:
        source = OscSource(parse_address("osc://127.0.0.1:0"))
        engine = build_engine(source, ["saliency", "optimal"], [], on_ready=ready)
        make = engine.make_keyframers
        engine.make_keyframers = lambda spec: seen["built"].append(spec.skeleton) or make(spec)
        summary = await engine.run()
    finally:
        jit._WARMERS.remove(probe)
    warmed, built = seen["at_listen"]
    assert warmed == 1 and len(built) == 1 and built[0].names != MOTION.skeleton.names
    assert seen["warmed"] == 1  # the clip's skeleton needed no second warm-up
    assert seen["built"][-1] is source.skeleton and summary.frames_in == 5


async def test_a_given_skeletons_pipeline_is_built_before_listening_and_used():
    """`--skeleton` given: the unnamed stream's pipeline is built before listening and the
    first frame finds it ready; a tagged stream gets its own."""
    pipelines = {}

    def ready(line):
        if line.startswith("listening on"):
            pipelines["before"] = engine._prebuilt[1]
            for frame in MOTION.frames()[:5]:
                source.receive(encode_frame(frame.seq, frame.time, frame.channels))
            source.frames.put(None)

    source = OscSource(parse_address("osc://127.0.0.1:0"), skeleton=MOTION.skeleton,
                       fps=MOTION.fps)
    engine = build_engine(source, ["simplify"], [], on_ready=ready,
                          on_frame=lambda f: pipelines.setdefault("used", engine.pipeline))
    summary = await engine.run()
    assert pipelines["used"] is pipelines["before"] and summary.frames_in == 5
    assert engine._prebuilt is None


async def test_keyframers_that_refuse_the_built_in_rig_warm_up_on_the_wire_skeleton():
    """A `--roles` mapping for another rig (here the CMU skeleton's LHipJoint) makes the
    keyframers refuse the humanoid rig: the run still listens, and warms up on the real
    skeleton when it arrives, as before."""
    seen = {"built": []}

    def ready(line):
        if line.startswith("listening on"):
            seen["warm_at_listen"] = engine._warm
            source.receive(encode_skeleton(MOTION.skeleton, MOTION.fps))
            for frame in MOTION.frames()[:5]:
                source.receive(encode_frame(frame.seq, frame.time, frame.channels))
            source.frames.put(None)

    source = OscSource(parse_address("osc://127.0.0.1:0"))
    roles = {"left_hip": "LHipJoint"}
    engine = build_engine(source, ["speed"], [], params={"speed": {"role_mapping": roles}},
                          on_ready=ready)
    make = engine.make_keyframers
    engine.make_keyframers = lambda spec: seen["built"].append(spec.skeleton) or make(spec)
    summary = await engine.run()
    assert seen["warm_at_listen"] is False and seen["built"][0] is not source.skeleton
    assert seen["built"][-1] is source.skeleton and summary.frames_in == 5
    assert summary.error_count == 0
