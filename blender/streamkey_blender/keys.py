"""Keyposes of an armature's action: markers from any streamkey method, and reduced actions
whose keys sit only on the pose frames.

The reduced action keeps every F-curve of the original and keys each one at the pose frames
(the action's first and last frames always included). Three ways to fill the span between
two poses, all evaluated by Blender itself:

- ``LINEAR``: straight lines (what streamkey's linear reconstruction assumes);
- ``AUTO``: Bezier keys with Blender's auto-clamped handles (its default for new keys);
- ``FIT``: Bezier keys whose two free handles per span are fitted by least squares to the
  dense original curve of that span. The handles' frame positions are kept at 1/3 and 2/3 of
  the span, which makes Blender's Bezier a cubic polynomial in the frame, so the fit is a
  2 x 2 linear system per span and Blender evaluates exactly the fitted cubic.

``FIT`` with ``sparse=True`` also leaves a channel unkeyed at a pose frame where the cubic
through its neighbouring keys already stays within `tolerance` of the original curve (every
key still on a pose frame): fewer keyframe points for the same poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from streamkey.batch import extract_motion
from streamkey.keyframes import Keyframes
from streamkey.motion import Motion
from streamkey.streaming import run_online

__all__ = ["MODES", "find_keys", "marker_name", "set_markers", "set_pose_markers",
           "clear_markers",
           "reduce_action", "fit_span", "Reduced"]

MODES = ("LINEAR", "AUTO", "FIT")


def find_keys(motion: Motion, method: str, params: dict[str, Any] | None = None,
              online: bool = False) -> Keyframes:
    """Keys of `method` on `motion`: offline, or the online keyframer pushed every frame."""
    table = {method: dict(params or {})}
    if online:
        return run_online(motion, [method], table)[method]
    return extract_motion(motion, [method], table)[method]


def marker_name(method: str, strength: float, provisional: bool = False) -> str:
    """Marker name: the method, '?' while provisional, and the key's strength in [0, 1]."""
    return f"{method}{'?' if provisional else ''} {strength:.2f}"


def _is_mine(name: str, method: str) -> bool:
    head = name.split(" ", 1)[0]
    return head in (method, f"{method}?")


def clear_markers(scene: Any, method: str, markers: Any = None) -> int:
    """Remove the markers `set_markers` or the live listener made for `method` (from the
    scene's timeline, or from `markers`, e.g. an action's pose markers)."""
    store = scene.timeline_markers if markers is None else markers
    mine = [m for m in store if _is_mine(m.name, method)]
    for marker in mine:
        store.remove(marker)
    return len(mine)


def set_markers(scene: Any, keys: Keyframes, start: int) -> list[int]:
    """Timeline markers at `start + frame` for every key (the method's old ones replaced)."""
    clear_markers(scene, keys.method)
    strength = np.asarray(keys.strength)
    frames = [start + int(f) for f in keys.frames]
    for f, s in zip(frames, strength, strict=True):
        scene.timeline_markers.new(marker_name(keys.method, float(s)), frame=f)
    return frames


def set_pose_markers(action: Any, keys: Keyframes, start: int) -> list[int]:
    """Pose markers of `action` (its pose library / Action Editor markers) at `start + frame`
    for every key, named as the timeline markers (the method's old ones replaced): they
    travel with the action, not the scene."""
    clear_markers(None, keys.method, action.pose_markers)
    strength = np.asarray(keys.strength)
    frames = [start + int(f) for f in keys.frames]
    for f, s in zip(frames, strength, strict=True):
        marker = action.pose_markers.new(marker_name(keys.method, float(s)))
        marker.frame = f
    return frames


def fit_span(values: np.ndarray) -> tuple[float, float]:
    """Values of the two inner Bezier control points that best fit `values` (the dense curve
    from one key to the next, both keys included) with the handles at 1/3 and 2/3."""
    n = len(values) - 1
    v0, v1 = float(values[0]), float(values[-1])
    linear = (v0 + (v1 - v0) / 3.0, v0 + 2.0 * (v1 - v0) / 3.0)
    if n < 2:
        return linear
    u = np.arange(1, n) / n
    b1, b2 = 3 * u * (1 - u) ** 2, 3 * u**2 * (1 - u)
    rhs = values[1:-1] - v0 * (1 - u) ** 3 - v1 * u**3
    a = np.stack([b1, b2], axis=1)
    ridge = 1e-6 * n  # one inner sample leaves the system singular: lean to the straight line
    lhs = a.T @ a + ridge * np.eye(2)
    sol = np.linalg.solve(lhs, a.T @ rhs + ridge * np.array(linear))
    return float(sol[0]), float(sol[1])


def _bezier(v0: float, c1: float, c2: float, v1: float, n: int) -> np.ndarray:
    u = np.arange(n + 1) / n
    return (v0 * (1 - u) ** 3 + 3 * c1 * u * (1 - u) ** 2 + 3 * c2 * u**2 * (1 - u)
            + v1 * u**3)


def _sparse_keys(dense: np.ndarray, keys: np.ndarray, tolerance: float) -> np.ndarray:
    """Drop pose keys of one channel greedily while the fitted span stays within tolerance."""
    kept = list(keys)
    i = 1
    while i < len(kept) - 1:
        a, b = kept[i - 1], kept[i + 1]
        c1, c2 = fit_span(dense[a : b + 1])
        fitted = _bezier(dense[a], c1, c2, dense[b], b - a)
        if np.max(np.abs(fitted - dense[a : b + 1])) <= tolerance:
            del kept[i]
        else:
            i += 1
    return np.array(kept)


@dataclass
class Reduced:
    """What `reduce_action` made: the new action, its pose frames, its keyframe points."""

    action: Any
    frames: list[int]
    points: int


def _dense(fcurve: Any, frames: range) -> np.ndarray:
    return np.array([fcurve.evaluate(f) for f in frames])


def reduce_action(action: Any, pose_frames: Sequence[int], mode: str = "FIT",
                  sparse: bool = False, tolerance: float = 0.0, name: str | None = None) -> Reduced:
    """A copy of `action` keyed only at `pose_frames` (scene frames; its first and last frames
    added), interpolated as `mode` says (module docstring). The original is not touched."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {', '.join(MODES)}, got {mode!r}")
    start, end = (int(round(v)) for v in action.frame_range)
    frames = range(start, end + 1)
    poses = sorted({start, end, *(int(f) for f in pose_frames if start <= f <= end)})
    new = action.copy()
    new.name = name or f"{action.name}.keys"
    points = 0
    for fc_old, fc in zip(action.fcurves, new.fcurves, strict=True):
        dense = _dense(fc_old, frames)
        rows = np.array(poses) - start
        if sparse and mode == "FIT":
            rows = _sparse_keys(dense, rows, tolerance)
        _write_keys(fc, dense, rows, start, mode)
        points += len(rows)
    return Reduced(new, poses, points)


def _write_keys(fc: Any, dense: np.ndarray, rows: np.ndarray, start: int, mode: str) -> None:
    n = len(rows)
    co = np.stack([rows + start, dense[rows]], axis=1).astype(np.float32)
    left, right = co.copy(), co.copy()
    if mode == "FIT":
        for i in range(n - 1):
            a, b = int(rows[i]), int(rows[i + 1])
            c1, c2 = fit_span(dense[a : b + 1])
            third = (b - a) / 3.0
            right[i] = (start + a + third, c1)
            left[i + 1] = (start + b - third, c2)
        if n > 1:  # the outer handles continue the neighbouring inner ones
            left[0] = 2 * co[0] - right[0]
            right[-1] = 2 * co[-1] - left[-1]
    fc.keyframe_points.clear()
    fc.keyframe_points.add(n)
    kp = fc.keyframe_points
    kp.foreach_set("co", co.ravel())
    interpolation = {"LINEAR": "LINEAR", "AUTO": "BEZIER", "FIT": "BEZIER"}[mode]
    handle = {"LINEAR": "AUTO_CLAMPED", "AUTO": "AUTO_CLAMPED", "FIT": "FREE"}[mode]
    for k in kp:
        k.interpolation = interpolation
        k.handle_left_type = handle
        k.handle_right_type = handle
    if mode == "FIT":
        kp.foreach_set("handle_left", left.ravel())
        kp.foreach_set("handle_right", right.ravel())
    fc.update()
