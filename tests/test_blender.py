"""The Blender extension run headless in bpy on the shared clips: markers, reduced actions
evaluated by Blender's depsgraph against Blender's Bake Action and Decimate, bad input,
live markers from a real `streamkey run`, and the marker example."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from blender_helpers import clip_path, import_clip, require_bpy
from cmu import ROOT
from live_helpers import free_port, interrupt_if_running, read_jsonl

from streamkey.batch import extract_motion
from streamkey.bvh import read_bvh
from streamkey.export import export_keyframes_bvh
from streamkey.streaming import run_online

bpy = require_bpy()

import streamkey_blender as extension  # noqa: E402
from streamkey_blender import keys, measure, rig  # noqa: E402

CLIP = "07_01"
# Blender's BVH importer leaves its file to the garbage collector (a ResourceWarning there).
pytestmark = pytest.mark.filterwarnings(
    r"ignore:Exception ignored in. <_io.FileIO name='.*\.bvh':"
    "pytest.PytestUnraisableExceptionWarning")


@pytest.fixture(scope="module", autouse=True)
def registered() -> Any:
    """The extension registered for the module's tests."""
    extension.register()
    yield
    extension.unregister()


def _markers(method: str) -> list[int]:
    scene = bpy.context.scene
    return sorted(m.frame for m in scene.timeline_markers
                  if m.name.split(" ")[0] == method)


def test_armature_motion_has_the_files_channels() -> None:
    """The armature read back through Blender's depsgraph is the BVH file, to float32."""
    obj = import_clip(bpy, CLIP)
    motion = rig.armature_motion(bpy.context, obj)
    original = read_bvh(clip_path(CLIP))
    assert motion.skeleton.names == original.skeleton.names
    assert motion.first_frame == original.first_frame == 1
    assert np.max(np.abs(motion.channels - original.channels)) < 1e-3


def test_marks_keyposes_at_exactly_the_extracted_frames() -> None:
    """Offline methods and an online keyframer: one marker per key, at 1 + file frame."""
    import_clip(bpy, CLIP)
    original = read_bvh(clip_path(CLIP))
    expected = extract_motion(original, ["saliency", "optimal"], {"optimal": {"count": 16}})
    assert bpy.ops.streamkey.mark_keyposes(method="saliency") == {"FINISHED"}
    assert bpy.ops.streamkey.mark_keyposes(method="optimal", count=16) == {"FINISHED"}
    for method in ("saliency", "optimal"):
        assert _markers(method) == [1 + int(f) for f in expected[method].frames]
    online = run_online(original, ["speed"])["speed"]
    assert bpy.ops.streamkey.mark_keyposes(method="speed", online=True) == {"FINISHED"}
    assert _markers("speed") == [1 + int(f) for f in online.frames]
    names = [m.name for m in bpy.context.scene.timeline_markers if m.name.startswith("optimal")]
    assert all(0.0 <= float(n.split(" ")[1]) <= 1.0 for n in names)  # strength in the name
    bpy.ops.streamkey.mark_keyposes(method="optimal", count=8)  # the method's markers replaced
    assert len(_markers("optimal")) == 8


def _pose_markers(action: Any, method: str) -> list[int]:
    return sorted(m.frame for m in action.pose_markers if m.name.split(" ")[0] == method)


def test_marks_keyposes_as_pose_markers_at_exactly_the_extracted_frames() -> None:
    """Pose markers of the action (instead of, or as well as, timeline markers): one per
    key, at 1 + file frame, named by method with the strength; the method's old ones
    replaced; the timeline left alone when only pose markers are asked for."""
    obj = import_clip(bpy, "09_06")
    action = obj.animation_data.action
    original = read_bvh(clip_path("09_06"))
    expected = extract_motion(original, ["saliency", "optimal"], {"optimal": {"count": 12}})
    assert bpy.ops.streamkey.mark_keyposes(method="saliency", target="POSE") == {"FINISHED"}
    assert _pose_markers(action, "saliency") == [1 + int(f) for f in expected["saliency"].frames]
    assert _markers("saliency") == []
    assert bpy.ops.streamkey.mark_keyposes(method="optimal", count=12,
                                           target="BOTH") == {"FINISHED"}
    frames = [1 + int(f) for f in expected["optimal"].frames]
    assert _pose_markers(action, "optimal") == frames == _markers("optimal")
    strengths = [float(m.name.split(" ")[1]) for m in action.pose_markers
                 if m.name.startswith("optimal ")]
    assert len(strengths) == 12 and all(0.0 <= s <= 1.0 for s in strengths)
    assert bpy.ops.streamkey.mark_keyposes(method="optimal", count=6,
                                           target="POSE") == {"FINISHED"}
    assert len(_pose_markers(action, "optimal")) == 6  # replaced, not added
    assert len(_markers("optimal")) == 12  # the timeline's untouched
    assert len(_pose_markers(action, "saliency")) == len(expected["saliency"].frames)


def test_reduce_keys_beats_linear_auto_and_bake_action() -> None:
    """Reduce keys: a new action keyed only on the pose frames, the original untouched;
    by Blender's evaluation the fitted Bezier beats linear, auto-clamped and Bake Action's
    uniform poses at the same pose count, and streamkey's own E stays close."""
    obj = import_clip(bpy, CLIP)
    original = obj.animation_data.action
    dense = measure.keyframe_points(original)
    assert bpy.ops.streamkey.reduce_keys(method="optimal", count=16) == {"FINISHED"}
    reduced = obj.animation_data.action
    assert reduced != original and original.name in bpy.data.actions
    assert measure.keyframe_points(original) == dense  # original kept
    motion = rig.armature_motion(bpy.context, obj)  # reads the reduced action now
    obj.animation_data.action = original
    motion = rig.armature_motion(bpy.context, obj)
    found = keys.find_keys(motion, "optimal", {"count": 16})
    poses = sorted({1, *(1 + int(f) for f in found.frames)})  # the reference frame kept
    assert {round(k.co.x) for fc in reduced.fcurves for k in fc.keyframe_points} == set(poses)
    ref = measure.Reference(bpy.context, obj, motion, 1)
    err = {mode: measure.blender_error(bpy.context, obj,
                                       keys.reduce_action(original, poses, mode).action, ref)
           for mode in keys.MODES}
    assert measure.blender_error(bpy.context, obj, reduced, ref) == pytest.approx(err["FIT"])
    assert err["FIT"] < 0.1 * err["AUTO"] and err["FIT"] < 0.1 * err["LINEAR"]
    step = round((ref.frames.stop - 1 - ref.frames.start) / 15)
    baked = measure.bake_uniform(bpy.context, obj, step, ref.frames)
    assert measure.keyed_frames(baked) == 16
    assert err["FIT"] < measure.blender_error(bpy.context, obj, baked, ref)
    # measured on 07_01: 2.6e-6 (FIT), 2.0e-4 (AUTO), 2.1e-4 (LINEAR), 2.2e-4 (Bake)
    assert err["FIT"] < 5e-6


def _linear_errors(clip: str, rotate_mode: str) -> tuple[float, float, float]:
    """Blender's error of a LINEAR reduction to optimal's 16 keys, streamkey's linear and
    slerp E for the same keys."""
    from streamkey.evaluate import error_e, reconstruct

    obj = import_clip(bpy, clip, rotate_mode)
    motion = rig.armature_motion(bpy.context, obj)
    found = keys.find_keys(motion, "optimal", {"count": 16})
    ref = measure.Reference(bpy.context, obj, motion, 1)
    reduced = keys.reduce_action(obj.animation_data.action, [1 + int(f) for f in found.frames],
                                 "LINEAR")
    blender = measure.blender_error(bpy.context, obj, reduced.action, ref)
    return (blender, error_e(motion, reconstruct(motion, found, mode="linear"), normalised=True),
            error_e(motion, reconstruct(motion, found), normalised=True))


@pytest.mark.parametrize("clip", ["07_01", "09_06"])
def test_blender_error_within_ten_percent_of_streamkeys_with_quaternion_rotations(
        clip: str) -> None:
    """Imported with quaternion rotations, Blender's linear keys interpolate as streamkey's
    slerp reconstruction does (normalised lerp): the errors agree within 10 %
    (measured: 0.995x on 07_01, 0.998x on 09_06)."""
    blender, _, slerp = _linear_errors(clip, "QUATERNION")
    assert blender == pytest.approx(slerp, rel=0.1)


@pytest.mark.xfail(strict=True, reason="measured on 07_01, optimal 16 poses: Blender's LINEAR"
                   " E 2.12e-4 vs streamkey linear E 1.49e-4 (1.42x): the importer's Euler"
                   " curves are in each bone's own axes, not the file's")
def test_blender_error_within_ten_percent_of_streamkeys_with_euler_rotations() -> None:
    """Imported with the file's Euler rotations, Blender's linear keys match streamkey's
    linear E within 10 %."""
    blender, linear, _ = _linear_errors("07_01", "NATIVE")
    assert blender == pytest.approx(linear, rel=0.1)


def test_reduce_keys_beats_decimate_at_equal_points_on_pose_frames_only() -> None:
    """Against the Graph Editor's Decimate (run headless under a context override) at the
    same number of keyframe points: lower error, on 17 keyed frames instead of ~290."""
    obj = import_clip(bpy, CLIP)
    action = obj.animation_data.action
    motion = rig.armature_motion(bpy.context, obj)
    found = keys.find_keys(motion, "optimal", {"count": 16})
    reduced = keys.reduce_action(action, [1 + int(f) for f in found.frames], "FIT")
    ref = measure.Reference(bpy.context, obj, motion, 1)
    dec = measure.decimate(bpy.context, obj, action,
                           ratio=1.0 - reduced.points / measure.keyframe_points(action))
    assert measure.keyframe_points(dec) == reduced.points
    ours = measure.blender_error(bpy.context, obj, reduced.action, ref)
    theirs = measure.blender_error(bpy.context, obj, dec, ref)
    # measured: 2.6e-6 vs 3.3e-5 (0.08x) on 17 vs 289 keyed frames
    assert ours <= 1.5 * theirs
    assert measure.keyed_frames(reduced.action) * 5 <= measure.keyed_frames(dec)
    # Sparse: twice the poses, channels unkeyed where the fit holds within 0.01 (degrees or
    # file units): fewer points than Decimate's, every key still on a pose frame.
    bpy.ops.streamkey.reduce_keys(method="optimal", count=32, sparse=True, key_tolerance=0.01)
    sparse = obj.animation_data.action
    poses = {1, *(1 + int(f) for f in keys.find_keys(motion, "optimal", {"count": 32}).frames)}
    assert {round(k.co.x) for fc in sparse.fcurves for k in fc.keyframe_points} <= poses
    assert measure.keyframe_points(sparse) < reduced.points
    # measured: 1,494 points, E 4.2e-6 (Decimate at 1,632 points: 3.3e-5)
    assert measure.blender_error(bpy.context, obj, sparse, ref) <= theirs


def test_bad_input_is_reported_in_blenders_report_area() -> None:
    """No armature, no action, nothing listening, a bad address: an error report each."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with pytest.raises(RuntimeError, match="select an armature: the active object is nothing"):
        bpy.ops.streamkey.mark_keyposes()
    arm = bpy.data.objects.new("rig", bpy.data.armatures.new("rig"))
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    with pytest.raises(RuntimeError, match="armature 'rig' has no action"):
        bpy.ops.streamkey.reduce_keys()
    port = free_port(socket.SOCK_STREAM)
    with pytest.raises(RuntimeError, match=f"nothing listening at zmq\\+tcp://127.0.0.1:{port}"):
        bpy.ops.streamkey.listen(address=f"zmq+tcp://127.0.0.1:{port}")
    with pytest.raises(RuntimeError, match="expected zmq\\+tcp://HOST:PORT or osc://HOST:PORT"):
        bpy.ops.streamkey.listen(address="http://127.0.0.1:80")
    assert not extension.LISTENING.active


def _streamkey(*args: str, cwd: Path) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-P", "-m", "streamkey", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_listens_live_to_a_real_streamkey_run(tmp_path: Path) -> None:
    """A real `streamkey run` (frames from a real replay over ZeroMQ) publishes events; the
    listener places provisional markers, replaces them by the confirmed keys and stops
    cleanly: at the end exactly one marker per keyframe event, at 1 + its frame."""
    import_clip(bpy, CLIP)
    frames_port, events_port = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    log = tmp_path / "events.jsonl"
    run = _streamkey("run", "--from", f"zmq+tcp://127.0.0.1:{frames_port}", "--method",
                     "optimal", "--provisional", "--idle-exit", "2", "--to",
                     f"zmq+tcp://127.0.0.1:{events_port}", "--to", f"jsonl:{log}", cwd=tmp_path)
    replay = None
    try:
        deadline = time.monotonic() + 120
        while True:  # the run binds its publisher once it has started
            try:
                bpy.ops.streamkey.listen(address=f"zmq+tcp://127.0.0.1:{events_port}")
                break
            except RuntimeError:
                assert run.poll() is None and time.monotonic() < deadline, "run never listened"
                time.sleep(0.2)
        replay = _streamkey("replay", str(clip_path(CLIP)), "--to",
                            f"zmq+tcp://127.0.0.1:{frames_port}", "--wait", "60", "--speed", "2",
                            cwd=tmp_path)
        seen_provisional = 0
        while run.poll() is None and time.monotonic() < deadline + 120:
            extension.LISTENING.tick()  # what Blender's timer calls
            marks = [m.name for m in bpy.context.scene.timeline_markers]
            seen_provisional = max(seen_provisional, sum("?" in n for n in marks))
            time.sleep(0.02)
        extension.LISTENING.tick()
        assert bpy.ops.streamkey.listen_stop() == {"FINISHED"}
    finally:
        for proc in (replay, run):
            if proc is not None:
                interrupt_if_running(proc)
                proc.communicate(timeout=30)  # closes the pipes
    assert not extension.LISTENING.active
    events = read_jsonl(log)
    confirmed = sorted(1 + e["frame"] for e in events if e["type"] == "keyframe")
    assert len(confirmed) >= 10 and seen_provisional >= 1
    markers = bpy.context.scene.timeline_markers
    assert sorted(m.frame for m in markers) == confirmed
    assert not any("?" in m.name for m in markers)


def test_osc_events_become_markers() -> None:
    """The OSC receiver decodes streamkey's numeric layout (the codec's own encoding)."""
    from streamkey_blender import live

    from streamkey.adapters.codec import osc_messages
    from streamkey.keyframes import KeyframeEvent, ProvisionalEvent

    bpy.ops.wm.read_factory_settings(use_empty=True)
    port = free_port()
    receiver = live.make_receiver(f"osc://127.0.0.1:{port}")
    book = live.MarkerBook(offset=1)
    events = [ProvisionalEvent(stream="default", method="optimal", frame=30, time=0.25,
                               strength=0.5, seen_at=40, pid=0),
              KeyframeEvent(stream="default", method="optimal", frame=30, time=0.25, score=1.0,
                            decided_at=60, lookahead=30, params="x", strength=0.75)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
        store = bpy.context.scene.timeline_markers
        for event in events:
            for message in osc_messages(event):
                out.sendto(message, ("127.0.0.1", port))
            deadline = time.monotonic() + 5
            got: list[dict[str, Any]] = []
            while not got and time.monotonic() < deadline:
                got = receiver.poll()
            for e in got:
                book.apply(store, e)
            if isinstance(event, ProvisionalEvent):
                assert [(m.name, m.frame) for m in store] == [("optimal? 0.50", 31)]
    receiver.close()
    assert [(m.name, m.frame) for m in store] == [("optimal 0.75", 31)]


def test_marker_example_runs_through_the_extension(tmp_path: Path) -> None:
    """examples/blender_markers.py places the extract JSON's keys as the extension does."""
    import importlib.util

    import_clip(bpy, CLIP)
    original = read_bvh(clip_path(CLIP))
    found = extract_motion(original, ["saliency"])["saliency"]
    path = tmp_path / "keys.json"
    path.write_text(json.dumps({"files": [{"file": str(clip_path(CLIP)), "fps": 120.0,
                                           "methods": {"saliency": found.to_dict()}}]}))
    spec = importlib.util.spec_from_file_location("blender_markers",
                                                  ROOT / "examples" / "blender_markers.py")
    assert spec and spec.loader
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    assert example.main([str(path), "--method", "saliency"]) == 0
    assert _markers("saliency") == [1 + int(f) for f in found.frames]
    assert example.main([str(path), "--method", "saliency", "--markers", "pose"]) == 0
    action = bpy.context.active_object.animation_data.action
    assert _pose_markers(action, "saliency") == [1 + int(f) for f in found.frames]


def test_blenders_importer_reads_the_keys_only_export_frame_aligned(tmp_path: Path) -> None:
    """streamkey's keys-only BVH, imported by Blender, holds the original poses at the keys:
    imported frame 1 + i is the pose of key i (world joint positions, Blender's evaluation)."""
    obj = import_clip(bpy, CLIP)
    original = read_bvh(clip_path(CLIP))
    found = extract_motion(original, ["optimal"], {"optimal": {"count": 12}})["optimal"]
    frames = [int(f) for f in found.frames]
    full = rig.world_joint_positions(bpy.context, obj, range(1, original.n_frames + 1))
    path = tmp_path / "keys.bvh"
    export_keyframes_bvh(original, found, path)
    bpy.ops.import_anim.bvh(filepath=str(path))
    keyed = bpy.context.active_object
    n = len(rig.action_frames(keyed.animation_data.action))
    got = rig.world_joint_positions(bpy.context, keyed, range(1, n + 1))
    want = full[frames]
    if n == len(frames) + 1:  # the export keeps the reference frame first
        got = got[1:]
    assert got.shape == want.shape
    assert np.max(np.abs(got - want)) < 1e-3


def test_bench_script_measures_a_clip_against_bake_and_decimate() -> None:
    """blender/bench.py (the script behind the README's table) on 09_06 at 16 poses: FIT
    beats Bake Action, needs <= 1/5 of Decimate's keyed frames at Decimate's error, and stays
    within 1.5x of Decimate's error at equal keyframe points (measured: 7.2e-7 vs Bake 7.0e-5,
    9 vs 139 frames, 0.11x Decimate's error)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("blender_bench",
                                                  ROOT / "blender" / "bench.py")
    assert spec and spec.loader
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rows = bench.measure_clip("09_06", [16])
    (row,) = rows
    assert row["fit"] < row["bake"]
    assert row["equal_error_frames"] * 5 <= row["decimate_frames"]
    assert row["fit"] <= 1.5 * row["decimate"]
    text = bench.table(rows)
    assert "FIT beats Bake Action at the same pose count: 1 of 1 rows" in text
