"""The active armature as a streamkey `Motion`, and its world joint positions by Blender.

`armature_motion` samples the armature's pose with the depsgraph (`scene.frame_set`) and
writes it as a BVH-style skeleton: every joint's rest orientation is the identity, offsets
are the rest bone heads relative to the parent's (armature space, turned from Blender's Z-up
to the Y-up of BVH files), and each joint's channels are its rotation relative to its parent
in those axes (Euler "Zrotation Yrotation Xrotation", degrees), the root's position first.
Forward kinematics of that `Motion` gives the same joint positions as Blender, so a clip
imported with Blender's BVH importer comes back with the channels of its file (to float32).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from streamkey.motion import Motion, Skeleton, detect_reference_frame

__all__ = ["armature_motion", "active_armature", "ordered_bones", "world_joint_positions",
           "ArmatureError", "Y_UP", "action_frames"]

# Blender (x, y, z) -> BVH (x, z, -y): the inverse of the BVH importer's axis conversion.
Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
_ORDER = ["Zrotation", "Yrotation", "Xrotation"]


class ArmatureError(ValueError):
    """The context has no usable armature or action (the message says which)."""


def active_armature(context: Any) -> Any:
    """The active object if it is an armature with an action; ArmatureError otherwise."""
    obj = getattr(context, "active_object", None)
    if obj is None or obj.type != "ARMATURE":
        kind = "nothing" if obj is None else f"{obj.name!r} ({obj.type.lower()})"
        raise ArmatureError(f"select an armature: the active object is {kind}")
    if obj.animation_data is None or obj.animation_data.action is None:
        raise ArmatureError(f"armature {obj.name!r} has no action to read keys from")
    return obj


def action_frames(action: Any) -> range:
    """The scene frames an action covers (its frame range, ends included)."""
    start, end = (int(round(v)) for v in action.frame_range)
    return range(start, end + 1)


def ordered_bones(obj: Any) -> list[Any]:
    """The armature's bones, every parent before its children (depth first, file order)."""
    out: list[Any] = []

    def walk(bone: Any) -> None:
        out.append(bone)
        for child in bone.children:
            walk(child)

    for bone in obj.data.bones:
        if bone.parent is None:
            walk(bone)
    return out


def _pose_matrices(obj: Any, names: list[str]) -> np.ndarray:
    """Armature-space pose matrices (n_bones x 4 x 4) of the current frame."""
    index = {b.name: i for i, b in enumerate(obj.pose.bones)}
    flat = np.empty(len(obj.pose.bones) * 16, dtype=np.float32)
    obj.pose.bones.foreach_get("matrix", flat)
    # foreach_get flattens each matrix column by column.
    mats = flat.reshape(-1, 4, 4).transpose(0, 2, 1).astype(np.float64)
    return mats[[index[n] for n in names]]


def armature_motion(context: Any, obj: Any, frames: range | None = None) -> Motion:
    """The armature's motion over `frames` (default: its action's range) as a `Motion`.

    Row i is scene frame `frames[i]`; a leading T-pose reference frame (CMU cgspeed) is found
    as `streamkey.bvh.read_bvh` finds it, so keys number rows as streamkey numbers file frames.
    """
    scene = context.scene
    frames = action_frames(obj.animation_data.action) if frames is None else frames
    if len(frames) < 2:
        raise ArmatureError(f"action of {obj.name!r} covers {len(frames)} frame; need 2 or more")
    bones = ordered_bones(obj)
    names = [b.name for b in bones]
    parent = [names.index(b.parent.name) if b.parent else -1 for b in bones]
    rest = np.array([np.array(b.matrix_local) for b in bones])
    heads = rest[:, :3, 3] @ Y_UP.T
    offsets = np.array([heads[j] - heads[p] if p >= 0 else heads[j]
                        for j, p in enumerate(parent)])
    end_sites = {j: (np.array(b.tail_local) - np.array(b.head_local)) @ Y_UP.T
                 for j, b in enumerate(bones) if not b.children}
    channels = [["Xposition", "Yposition", "Zposition"] + _ORDER if p < 0 else list(_ORDER)
                for p in parent]
    rest_rot_t = np.transpose(rest[:, :3, :3], (0, 2, 1))
    rows = []
    current = scene.frame_current
    try:
        for f in frames:
            scene.frame_set(f)
            pose = _pose_matrices(obj, names)
            rot = pose[:, :3, :3]
            rot = rot / np.linalg.norm(rot, axis=1, keepdims=True)  # drop bone scale
            glob = Y_UP @ rot @ rest_rot_t @ Y_UP.T
            local = np.array([glob[j] if p < 0 else glob[p].T @ glob[j]
                              for j, p in enumerate(parent)])
            euler = Rotation.from_matrix(local).as_euler("ZYX", degrees=True)
            root = pose[0, :3, 3] @ Y_UP.T
            rows.append(np.concatenate([root, euler.ravel()]))
    finally:
        scene.frame_set(current)
    values = np.unwrap(np.array(rows), period=360.0, axis=0)
    values[:, :3] = np.array(rows)[:, :3]
    skeleton = Skeleton(names, parent, offsets, channels, end_sites)
    first = detect_reference_frame(skeleton, np.round(values, 3))
    fps = scene.render.fps / scene.render.fps_base
    if abs(fps - round(fps)) < 0.01:
        fps = float(round(fps))
    return Motion(skeleton, values, fps, first, obj.name)


def world_joint_positions(context: Any, obj: Any, frames: range) -> np.ndarray:
    """World positions (frames x bones x 3) of every pose bone's head, evaluated by Blender's
    depsgraph at each frame (bones in `ordered_bones` order)."""
    scene = context.scene
    names = [b.name for b in ordered_bones(obj)]
    out = np.empty((len(frames), len(names), 3))
    current = scene.frame_current
    try:
        for i, f in enumerate(frames):
            scene.frame_set(f)
            world = np.array(obj.matrix_world)
            pose = _pose_matrices(obj, names)
            out[i] = pose[:, :3, 3] @ world[:3, :3].T + world[:3, 3]
    finally:
        scene.frame_set(current)
    return out


