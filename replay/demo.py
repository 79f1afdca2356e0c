"""The embedded demo motion: a deterministic synthetic performance on a CMU-like skeleton.

`streamkey demo` needs motion on a fresh machine with no data and no network, and the CMU
clips may not be shipped, so the demo generates one: a walk, a stop with the arms raised and
held, a turn on the spot, a crouch and a walk away. Joint names follow the cgspeed
MotionBuilder release, so every role and method works on it unchanged.
"""

from __future__ import annotations

import numpy as np

from streamkey.motion import Motion, Skeleton

__all__ = ["demo_skeleton", "demo_motion"]

_ZYX = ["Zrotation", "Yrotation", "Xrotation"]


def demo_skeleton() -> Skeleton:
    """A 19-joint humanoid with cgspeed joint names (units: CMU inches / 0.45)."""
    joints: list[tuple[str, int, tuple[float, float, float]]] = [("Hips", -1, (0, 0, 0))]

    def add(name: str, parent: str, offset: tuple[float, float, float]) -> None:
        joints.append((name, [j[0] for j in joints].index(parent), offset))

    for side, x in (("Left", 1.0), ("Right", -1.0)):
        add(f"{side}UpLeg", "Hips", (1.8 * x, -1.7, 0.0))
        add(f"{side}Leg", f"{side}UpLeg", (0.0, -7.0, 0.0))
        add(f"{side}Foot", f"{side}Leg", (0.0, -7.2, 0.0))
    add("Spine", "Hips", (0.0, 4.5, 0.0))
    add("Neck", "Spine", (0.0, 4.5, 0.0))
    add("Head", "Neck", (0.0, 1.6, 0.0))
    for side, x in (("Left", 1.0), ("Right", -1.0)):
        add(f"{side}Arm", "Neck", (3.0 * x, -0.6, 0.0))
        add(f"{side}ForeArm", f"{side}Arm", (5.0 * x, 0.0, 0.0))
        add(f"{side}Hand", f"{side}ForeArm", (4.6 * x, 0.0, 0.0))
    for side in ("Left", "Right"):
        add(f"{side}ToeBase", f"{side}Foot", (0.0, -0.6, 2.0))
        x = 1.0 if side == "Left" else -1.0
        add(f"{side}HandIndex1", f"{side}Hand", (1.4 * x, 0.0, 0.0))
    order = sorted(range(len(joints)), key=lambda j: _depth(joints, j))
    remap = {old: new for new, old in enumerate(order)}
    names = [joints[j][0] for j in order]
    parents = [remap[joints[j][1]] if joints[j][1] >= 0 else -1 for j in order]
    offsets = np.array([joints[j][2] for j in order], dtype=float)
    channels = [["Xposition", "Yposition", "Zposition", *_ZYX]] + [list(_ZYX)] * (len(names) - 1)
    ends = {names.index(n): np.array(o) for n, o in (
        ("Head", (0.0, 2.0, 0.0)), ("LeftToeBase", (0.0, 0.0, 1.0)),
        ("RightToeBase", (0.0, 0.0, 1.0)), ("LeftHandIndex1", (0.8, 0.0, 0.0)),
        ("RightHandIndex1", (-0.8, 0.0, 0.0)))}
    return Skeleton(names, parents, offsets, channels, end_sites=ends)


def _depth(joints: list[tuple[str, int, tuple[float, float, float]]], j: int) -> int:
    return 0 if joints[j][1] < 0 else 1 + _depth(joints, joints[j][1])


def _smooth(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """0 before a, 1 after b, a smooth (C1) ramp between."""
    x = np.clip((t - a) / (b - a), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def demo_motion(seconds: float = 20.0, fps: float = 120.0) -> Motion:
    """The demo performance; deterministic (no randomness), any length and rate."""
    skel = demo_skeleton()
    t = np.arange(int(round(seconds * fps))) / fps
    span = seconds / 20.0
    walking = (1 - _smooth(t, 6 * span, 6.6 * span)) + _smooth(t, 15 * span, 15.6 * span)
    arms_up = _smooth(t, 7 * span, 7.8 * span) * (1 - _smooth(t, 10 * span, 10.8 * span))
    turn = _smooth(t, 11 * span, 12.5 * span)
    crouch = _smooth(t, 13 * span, 13.6 * span) * (1 - _smooth(t, 14.2 * span, 14.8 * span))
    phase = 2 * np.pi * np.cumsum(walking) / fps / 1.1  # one stride per 1.1 s of walking
    step = np.sin(phase)
    values = np.zeros((len(t), skel.n_channels))

    def put(joint: str, channel: str, v: np.ndarray) -> None:
        col = skel.channel_index(skel.index(joint), channel)
        assert col is not None
        values[:, col] = v

    heading = 180.0 * turn
    speed = 2.2 * walking
    direction = np.deg2rad(heading)
    put("Hips", "Xposition", np.cumsum(speed * np.sin(direction)) / fps * 6.0)
    put("Hips", "Zposition", np.cumsum(speed * np.cos(direction)) / fps * 6.0)
    put("Hips", "Yposition", 17.0 + 0.3 * walking * np.cos(2 * phase) - 4.0 * crouch)
    put("Hips", "Yrotation", heading + 4.0 * walking * step)
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        swing = sign * step
        put(f"{side}UpLeg", "Xrotation", -28.0 * walking * swing - 70.0 * crouch)
        knee = 35.0 * walking * np.clip(np.sin(phase + sign * 0.5 * np.pi), 0, None)
        put(f"{side}Leg", "Xrotation", knee + 110.0 * crouch)
        put(f"{side}Foot", "Xrotation", -12.0 * walking * swing - 40.0 * crouch)
        put(f"{side}Arm", "Xrotation", 30.0 * walking * swing)
        put(f"{side}Arm", "Zrotation", sign * (70.0 - 150.0 * arms_up))
        put(f"{side}ForeArm", "Yrotation", -sign * (20.0 * walking + 60.0 * arms_up))
        put(f"{side}Hand", "Zrotation", sign * 25.0 * arms_up * np.sin(2 * np.pi * t / 1.5))
    put("Spine", "Xrotation", 5.0 * walking + 25.0 * crouch)
    put("Head", "Yrotation", 30.0 * np.sin(2 * np.pi * t / 7.0) * (1 - walking))
    return Motion(skel, values, fps, 0, "demo")
