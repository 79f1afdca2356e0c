"""Errors of reduced actions as Blender evaluates them, and Blender's own reducers.

The error is streamkey's E (Halit 2010, "A multi scale motion saliency method for keyframe
extraction from motion capture sequences", eq. 4.1) computed from Blender's depsgraph: the
mean, over the captured frames and the pose bones, of the squared distance between the
root-relative world head positions of the original and the reduced action, divided by the
body height squared.
"""

from __future__ import annotations

from typing import Any

import bpy
import numpy as np

from streamkey.kinematics import body_height
from streamkey.motion import Motion

from .rig import world_joint_positions

__all__ = ["Reference", "blender_error", "decimate", "bake_uniform", "keyed_frames",
           "keyframe_points", "graph_editor_override"]


class Reference:
    """The original action's root-relative world joint positions over its captured frames."""

    def __init__(self, context: Any, obj: Any, motion: Motion, start: int) -> None:
        self.frames = range(start + motion.first_frame, start + motion.n_frames)
        self.height = body_height(motion.skeleton)
        self.positions = self._relative(world_joint_positions(context, obj, self.frames))

    @staticmethod
    def _relative(p: np.ndarray) -> np.ndarray:
        out: np.ndarray = p - p[:, :1]
        return out


def blender_error(context: Any, obj: Any, action: Any, ref: Reference) -> float:
    """E (body heights squared) of `action` on `obj` against the reference, by Blender."""
    old = obj.animation_data.action
    obj.animation_data.action = action
    try:
        p = Reference._relative(world_joint_positions(context, obj, ref.frames))
    finally:
        obj.animation_data.action = old
    diff = p - ref.positions
    return float(np.mean(np.sum(diff * diff, axis=-1)) / ref.height**2)


def keyframe_points(action: Any) -> int:
    """Keyframe points over every F-curve of `action`."""
    return sum(len(fc.keyframe_points) for fc in action.fcurves)


def keyed_frames(action: Any) -> int:
    """Distinct frames that carry a key on any F-curve of `action`."""
    return len({round(k.co.x, 3) for fc in action.fcurves for k in fc.keyframe_points})


def graph_editor_override(context: Any) -> dict[str, Any]:
    """Window, area and region of a Graph Editor (an area of the current screen turned
    into one), for running Graph Editor operators headless under `temp_override`."""
    window = context.window or context.window_manager.windows[0]
    areas = list(window.screen.areas)
    area = next((a for a in areas if a.type == "GRAPH_EDITOR"), None)
    if area is None:
        area = max(areas, key=lambda a: a.width * a.height)
        area.type = "GRAPH_EDITOR"
    region = next(r for r in area.regions if r.type == "WINDOW")
    return {"window": window, "screen": window.screen, "area": area, "region": region}


def decimate(context: Any, obj: Any, action: Any, *, ratio: float | None = None,
             error: float | None = None, name: str = "decimated") -> Any:
    """A copy of `action` thinned by the Graph Editor's Decimate (by ratio of keys removed,
    or by allowed error), run on every F-curve under a Graph Editor context override."""
    new = action.copy()
    new.name = name
    old = obj.animation_data.action
    obj.animation_data.action = new
    for fc in new.fcurves:
        fc.select = True
        fc.hide = False
        for k in fc.keyframe_points:
            k.select_control_point = True
    for bone in obj.data.bones:
        bone.select = True
    override = graph_editor_override(context)
    override["area"].spaces.active.dopesheet.show_only_selected = False
    with context.temp_override(active_object=obj, object=obj, **override):
        if ratio is not None:
            bpy.ops.graph.decimate(mode="RATIO", factor=ratio)
        else:
            bpy.ops.graph.decimate(mode="ERROR", remove_error_margin=float(error or 0.0))
    obj.animation_data.action = old
    return new


def bake_uniform(context: Any, obj: Any, step: int, frames: range, name: str = "baked") -> Any:
    """Blender's Bake Action (pose, visual keying) keyed every `step` frames: uniform poses."""
    old = obj.animation_data.action
    for bone in obj.data.bones:
        bone.select = True
    with context.temp_override(active_object=obj, object=obj, selected_objects=[obj]):
        bpy.ops.nla.bake(frame_start=frames.start, frame_end=frames.stop - 1, step=step,
                         only_selected=False, visual_keying=True, use_current_action=False,
                         bake_types={"POSE"})
    baked = obj.animation_data.action
    baked.name = name
    obj.animation_data.action = old
    return baked
