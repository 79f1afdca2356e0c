"""streamkey for Blender: keypose markers, key reduction on pose frames, live markers.

Operators (View3D sidebar, tab "streamkey"):

- `streamkey.mark_keyposes`: run a streamkey method (offline, or its online keyframer as if
  streamed) on the active armature's action; timeline markers `method strength` at the keys,
  or the action's pose markers, or both.
- `streamkey.reduce_keys`: a new action keyed only on the method's pose frames (LINEAR, AUTO
  or FIT Bezier handles), assigned to the armature; the original kept; reports the error as
  Blender evaluates it.
- `streamkey.listen` / `streamkey.listen_stop`: markers from a running `streamkey run`
  (ZeroMQ or OSC on loopback), provisional ones replaced by the confirmed keys.
"""

from __future__ import annotations

from typing import Any

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from streamkey.errors import StreamkeyError
from streamkey.methods import OFFLINE_METHODS, ONLINE_METHODS

from . import keys, live, measure, rig

__all__ = ["register", "unregister", "LISTENING"]

_METHODS = [(m, m, f"streamkey method {m}") for m in OFFLINE_METHODS]
_MODES = [("FIT", "Fitted Bezier", "Bezier handles fitted to the original curve"),
          ("AUTO", "Auto-clamped Bezier", "Blender's default handles"),
          ("LINEAR", "Linear", "Straight lines between pose keys")]
_TARGETS = [("TIMELINE", "Timeline", "Markers on the scene's timeline"),
            ("POSE", "Pose", "Pose markers of the action (shown in the Action Editor)"),
            ("BOTH", "Both", "Timeline markers and the action's pose markers")]
TIMER_SECONDS = 0.05


def _prefs(context: Any) -> Any:
    addon = context.preferences.addons.get(__package__)
    return addon.preferences if addon else None


def _default(context: Any, name: str, fallback: Any) -> Any:
    prefs = _prefs(context)
    return getattr(prefs, name, fallback) if prefs else fallback


class StreamkeyPreferences(bpy.types.AddonPreferences):  # type: ignore[misc]
    """Where to listen, and the defaults of the operators."""

    bl_idname = __package__

    address: StringProperty(name="Listen address", default="zmq+tcp://127.0.0.1:5556",  # type: ignore[valid-type]
                            description="zmq+tcp://HOST:PORT of a `streamkey run --to` sink,"
                                        " or osc://HOST:PORT to receive its OSC")
    method: EnumProperty(name="Default method", items=_METHODS, default="optimal")  # type: ignore[valid-type]
    frame_offset: IntProperty(name="Frame offset", default=1,  # type: ignore[valid-type]
                              description="Scene frame of stream frame 0 (the BVH importer's"
                                          " Start Frame)")
    interpolation: EnumProperty(name="Interpolation", items=_MODES, default="FIT")  # type: ignore[valid-type]

    def draw(self, context: Any) -> None:
        """Preferences panel."""
        for name in ("address", "method", "frame_offset", "interpolation"):
            self.layout.prop(self, name)


def _method_params(method: str, count: int, rate: float, tolerance: float) -> dict[str, Any]:
    if count > 0:
        return {"count": count}
    if method == "optimal" and rate > 0:
        return {"rate": rate}
    if method == "optimal" and tolerance > 0:
        return {"tolerance": tolerance}
    return {}


def _show_pose_markers(context: Any) -> None:
    """Let the open Action Editors show pose markers (they show timeline markers otherwise)."""
    screen = getattr(context, "screen", None)
    for area in screen.areas if screen else ():
        if area.type == "DOPESHEET_EDITOR":
            area.spaces.active.show_pose_markers = True


class _KeyOperator:
    """Shared properties: the method and its count / rate / tolerance."""

    method: EnumProperty(name="Method", items=_METHODS, default="optimal")  # type: ignore[valid-type]
    count: IntProperty(name="Count", default=0, min=0,  # type: ignore[valid-type]
                       description="Number of pose keys (0: the method's own choice)")
    rate: FloatProperty(name="Rate", default=0.0, min=0.0,  # type: ignore[valid-type]
                        description="optimal: keys per second (0: default)")
    tolerance: FloatProperty(name="Tolerance", default=0.0, min=0.0,  # type: ignore[valid-type]
                             description="optimal: allowed error (0: default)")

    def _keys(self, context: Any, online: bool = False) -> tuple[Any, Any, Any, int]:
        obj = rig.active_armature(context)
        motion = rig.armature_motion(context, obj)
        params = _method_params(self.method, self.count, self.rate, self.tolerance)
        found = keys.find_keys(motion, self.method, params, online=online)
        start = rig.action_frames(obj.animation_data.action).start
        return obj, motion, found, start


class STREAMKEY_OT_mark_keyposes(_KeyOperator, bpy.types.Operator):  # type: ignore[misc]
    """Timeline markers at the keyposes streamkey finds in the active armature's action"""

    bl_idname = "streamkey.mark_keyposes"
    bl_label = "Mark Keyposes"
    bl_options = {"REGISTER", "UNDO"}

    online: BoolProperty(name="Online", default=False,  # type: ignore[valid-type]
                         description="Run the online keyframer as if the action were streamed")
    target: EnumProperty(name="Markers", items=_TARGETS, default="TIMELINE")  # type: ignore[valid-type]

    def execute(self, context: Any) -> set[str]:
        """Find the keys and place the markers."""
        if self.online and self.method not in ONLINE_METHODS:
            self.report({"ERROR"}, f"{self.method} has no online version; choose from"
                                   f" {', '.join(ONLINE_METHODS)}")
            return {"CANCELLED"}
        try:
            obj, _, found, start = self._keys(context, self.online)
        except (rig.ArmatureError, StreamkeyError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if self.target in ("TIMELINE", "BOTH"):
            frames = keys.set_markers(context.scene, found, start)
        if self.target in ("POSE", "BOTH"):
            frames = keys.set_pose_markers(obj.animation_data.action, found, start)
            _show_pose_markers(context)
        where = {"TIMELINE": "timeline", "POSE": "pose", "BOTH": "timeline and pose"}
        self.report({"INFO"}, f"{self.method}: {len(frames)} keypose {where[self.target]}"
                              " markers")
        return {"FINISHED"}


class STREAMKEY_OT_reduce_keys(_KeyOperator, bpy.types.Operator):  # type: ignore[misc]
    """A new action keyed only on the keypose frames; the original action is kept"""

    bl_idname = "streamkey.reduce_keys"
    bl_label = "Reduce Keys"
    bl_options = {"REGISTER", "UNDO"}

    interpolation: EnumProperty(name="Interpolation", items=_MODES, default="FIT")  # type: ignore[valid-type]
    sparse: BoolProperty(name="Sparse", default=False,  # type: ignore[valid-type]
                         description="FIT: leave a channel unkeyed at a pose frame where its"
                                     " fitted curve stays within the key tolerance")
    key_tolerance: FloatProperty(name="Key tolerance", default=0.01, min=0.0,  # type: ignore[valid-type]
                                 description="Sparse: largest change of a channel's curve"
                                             " (degrees or scene units) a dropped key may make")
    report_error: BoolProperty(name="Report error", default=True,  # type: ignore[valid-type]
                               description="Evaluate both actions and report the error")

    def execute(self, context: Any) -> set[str]:
        """Reduce, assign the new action, report the error."""
        try:
            obj, motion, found, start = self._keys(context)
        except (rig.ArmatureError, StreamkeyError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        original = obj.animation_data.action
        original.use_fake_user = True
        reduced = keys.reduce_action(original, [start + int(f) for f in found.frames],
                                     self.interpolation, sparse=self.sparse,
                                     tolerance=self.key_tolerance,
                                     name=f"{original.name}.{self.method}")
        text = (f"{self.method}: {len(reduced.frames)} pose frames, {reduced.points} keys"
                f" ({self.interpolation.lower()}); original kept as {original.name!r}")
        if self.report_error:
            ref = measure.Reference(context, obj, motion, start)
            err = measure.blender_error(context, obj, reduced.action, ref)
            text += f"; E = {err:.3g} body heights² (Blender's evaluation)"
        obj.animation_data.action = reduced.action
        self.report({"INFO"}, text)
        return {"FINISHED"}


class _Listening:
    """The running live session (one at a time)."""

    def __init__(self) -> None:
        self.receiver: live.ZmqReceiver | live.OscReceiver | None = None
        self.book = live.MarkerBook()
        self.scene_name = ""

    @property
    def active(self) -> bool:
        """True while a receiver is open."""
        return self.receiver is not None

    def tick(self) -> float | None:
        """Timer callback: apply what arrived; None (stop the timer) once stopped."""
        if self.receiver is None:
            return None
        scene = bpy.data.scenes.get(self.scene_name)
        if scene is None:
            self.stop()
            return None
        for event in self.receiver.poll():
            self.book.apply(scene.timeline_markers, event)
        return TIMER_SECONDS

    def stop(self) -> None:
        """Close the receiver, remove the provisional markers left, stop the timer."""
        if self.receiver is not None:
            scene = bpy.data.scenes.get(self.scene_name)
            if scene is not None:
                self.tick_final(scene)
            self.receiver.close()
            self.receiver = None
        if bpy.app.timers.is_registered(self.tick):
            bpy.app.timers.unregister(self.tick)

    def tick_final(self, scene: Any) -> None:
        """Apply the last events, then drop the provisional markers still waiting."""
        assert self.receiver is not None
        for event in self.receiver.poll():
            self.book.apply(scene.timeline_markers, event)
        self.book.clear_provisional(scene.timeline_markers)


LISTENING = _Listening()


class STREAMKEY_OT_listen(bpy.types.Operator):  # type: ignore[misc]
    """Place markers at the keyposes a running `streamkey run` sends"""

    bl_idname = "streamkey.listen"
    bl_label = "Listen Live"

    address: StringProperty(name="Address", default="",  # type: ignore[valid-type]
                            description="zmq+tcp://HOST:PORT or osc://HOST:PORT (empty:"
                                        " the preferences')")

    def execute(self, context: Any) -> set[str]:
        """Open the receiver and start the timer."""
        if LISTENING.active:
            self.report({"WARNING"}, "already listening; stop first")
            return {"CANCELLED"}
        address = self.address or _default(context, "address", "zmq+tcp://127.0.0.1:5556")
        try:
            LISTENING.receiver = live.make_receiver(address)
        except live.ListenError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        LISTENING.book = live.MarkerBook(offset=_default(context, "frame_offset", 1))
        LISTENING.scene_name = context.scene.name
        bpy.app.timers.register(LISTENING.tick, first_interval=TIMER_SECONDS)
        self.report({"INFO"}, f"listening at {address}")
        return {"FINISHED"}


class STREAMKEY_OT_listen_stop(bpy.types.Operator):  # type: ignore[misc]
    """Stop listening (the confirmed markers stay)"""

    bl_idname = "streamkey.listen_stop"
    bl_label = "Stop Listening"

    def execute(self, context: Any) -> set[str]:
        """Stop the live session."""
        if not LISTENING.active:
            self.report({"WARNING"}, "not listening")
            return {"CANCELLED"}
        LISTENING.stop()
        book = LISTENING.book
        self.report({"INFO"}, f"stopped: {book.confirmed} keys, {book.cancelled} cancelled")
        return {"FINISHED"}


class STREAMKEY_PT_panel(bpy.types.Panel):  # type: ignore[misc]
    """The sidebar panel."""

    bl_label = "streamkey"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "streamkey"

    def draw(self, context: Any) -> None:
        """Buttons for the operators."""
        col = self.layout.column()
        col.operator(STREAMKEY_OT_mark_keyposes.bl_idname)
        col.operator(STREAMKEY_OT_reduce_keys.bl_idname)
        if LISTENING.active:
            col.operator(STREAMKEY_OT_listen_stop.bl_idname)
        else:
            col.operator(STREAMKEY_OT_listen.bl_idname)


_CLASSES = (StreamkeyPreferences, STREAMKEY_OT_mark_keyposes, STREAMKEY_OT_reduce_keys,
            STREAMKEY_OT_listen, STREAMKEY_OT_listen_stop, STREAMKEY_PT_panel)


def register() -> None:
    """Register the classes with Blender."""
    for cls in _CLASSES:
        bpy.utils.register_class(cls)


def unregister() -> None:
    """Stop listening and unregister the classes."""
    LISTENING.stop()
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
