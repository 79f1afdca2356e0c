"""Built-in skeletons of capture systems that stream rotations without a skeleton header.

- `axis_skeleton()`: Noitom Axis Neuron / Perception Neuron, the 59-joint BVH skeleton (joint
  order and channel order `Yrotation Xrotation Zrotation` of an Axis Neuron BVH export; offsets
  of a 1.8 m T-pose in cm: give the exported BVH with `--skeleton` for the performer's own).
- `humanoid_skeleton()`: the Unity humanoid bones a VMC sender transmits (HumanBodyBones names,
  body, toes, thumb and index finger), in metres, channels `Zrotation Yrotation Xrotation`.

Both face +Z with Y up and the performer's left on +X (BVH convention).
"""

from __future__ import annotations

import numpy as np

from .motion import Skeleton

__all__ = ["axis_skeleton", "humanoid_skeleton", "AXIS_JOINTS", "HUMANOID_BONES"]

Spec = list[tuple[str, str, tuple[float, float, float]]]


def _mirror(spec: Spec) -> Spec:
    """Left-side entries (names with {S} = Left) and their mirrored Right copies."""
    out: Spec = []
    for side, sx in (("Right", -1.0), ("Left", 1.0)):
        out += [(n.format(S=side), p.format(S=side), (sx * o[0], o[1], o[2])) for n, p, o in spec]
    return out


def _build(spec: Spec, ends: dict[str, tuple[float, float, float]], order: list[str],
           ) -> Skeleton:
    names = [n for n, _, _ in spec]
    parents = [names.index(p) if p else -1 for _, p, _ in spec]
    channels = [["Xposition", "Yposition", "Zposition", *order]] + [list(order)] * (len(names) - 1)
    end_sites = {names.index(n): np.array(o, dtype=float) for n, o in ends.items()}
    return Skeleton(names, parents, np.array([o for _, _, o in spec], dtype=float), channels,
                    end_sites)


_AXIS_LEG = [("{S}UpLeg", "Hips", (9.5, 0.0, 0.0)), ("{S}Leg", "{S}UpLeg", (0.0, -42.0, 0.0)),
             ("{S}Foot", "{S}Leg", (0.0, -41.0, 0.0))]
_AXIS_SPINE = [("Spine", "Hips", (0.0, 10.0, 0.0)), ("Spine1", "Spine", (0.0, 10.0, 0.0)),
               ("Spine2", "Spine1", (0.0, 10.0, 0.0)), ("Spine3", "Spine2", (0.0, 10.0, 0.0)),
               ("Neck", "Spine3", (0.0, 12.0, 0.0)), ("Head", "Neck", (0.0, 10.0, 0.0))]
_AXIS_ARM = [("{S}Shoulder", "Spine3", (3.5, 8.0, 0.0)), ("{S}Arm", "{S}Shoulder", (14.0, 0, 0)),
             ("{S}ForeArm", "{S}Arm", (28.0, 0.0, 0.0)), ("{S}Hand", "{S}ForeArm", (26.0, 0, 0)),
             ("{S}HandThumb1", "{S}Hand", (2.5, 0.0, 3.0)),
             ("{S}HandThumb2", "{S}HandThumb1", (3.0, 0.0, 1.5)),
             ("{S}HandThumb3", "{S}HandThumb2", (2.5, 0.0, 0.0))]
for _finger, _z in (("Index", 2.0), ("Middle", 0.6), ("Ring", -0.6), ("Pinky", -1.8)):
    _AXIS_ARM += [(f"{{S}}InHand{_finger}", "{S}Hand", (3.0, 0.0, _z)),
                  (f"{{S}}Hand{_finger}1", f"{{S}}InHand{_finger}", (6.0, 0.0, _z / 4)),
                  (f"{{S}}Hand{_finger}2", f"{{S}}Hand{_finger}1", (3.5, 0.0, 0.0)),
                  (f"{{S}}Hand{_finger}3", f"{{S}}Hand{_finger}2", (2.5, 0.0, 0.0))]
_AXIS: Spec = [("Hips", "", (0.0, 0.0, 0.0))] + _mirror(_AXIS_LEG) + _AXIS_SPINE
_AXIS += [e for side in ("Right", "Left") for e in _mirror(_AXIS_ARM) if e[0].startswith(side)]
AXIS_JOINTS: tuple[str, ...] = tuple(n for n, _, _ in _AXIS)

_HUMANOID: Spec = [("Hips", "", (0.0, 0.0, 0.0))] + _mirror([
    ("{S}UpperLeg", "Hips", (0.09, -0.06, 0.0)), ("{S}LowerLeg", "{S}UpperLeg", (0, -0.42, 0)),
    ("{S}Foot", "{S}LowerLeg", (0.0, -0.41, 0.0)), ("{S}Toes", "{S}Foot", (0.0, -0.06, 0.12))])
_HUMANOID += [("Spine", "Hips", (0.0, 0.10, 0.0)), ("Chest", "Spine", (0.0, 0.12, 0.0)),
              ("UpperChest", "Chest", (0.0, 0.12, 0.0)), ("Neck", "UpperChest", (0, 0.14, 0)),
              ("Head", "Neck", (0.0, 0.10, 0.0))]
_HUMANOID += _mirror([
    ("{S}Shoulder", "UpperChest", (0.03, 0.10, 0.0)),
    ("{S}UpperArm", "{S}Shoulder", (0.13, 0.0, 0.0)),
    ("{S}LowerArm", "{S}UpperArm", (0.28, 0.0, 0.0)), ("{S}Hand", "{S}LowerArm", (0.25, 0, 0)),
    ("{S}ThumbProximal", "{S}Hand", (0.03, -0.01, 0.03)),
    ("{S}IndexProximal", "{S}Hand", (0.09, 0.0, 0.02)),
    ("{S}IndexIntermediate", "{S}IndexProximal", (0.04, 0.0, 0.0))])
HUMANOID_BONES: tuple[str, ...] = tuple(n for n, _, _ in _HUMANOID)


def axis_skeleton() -> Skeleton:
    """The 59-joint Axis Neuron skeleton (cm; without displacement channels)."""
    ends = {f"{s}{n}": (0.0, -7.0, 12.0) if n == "Foot" else (2.0 if s == "Left" else -2.0, 0, 0)
            for s in ("Left", "Right") for n in ("Foot", "HandThumb3", "HandIndex3",
                                                  "HandMiddle3", "HandRing3", "HandPinky3")}
    return _build(_AXIS, {"Head": (0.0, 18.0, 0.0), **ends},
                  ["Yrotation", "Xrotation", "Zrotation"])


def humanoid_skeleton() -> Skeleton:
    """The built-in Unity humanoid skeleton of the VMC source (metres)."""
    ends = {"Head": (0.0, 0.18, 0.0)}
    for s, sx in (("Left", 1.0), ("Right", -1.0)):
        ends |= {f"{s}Toes": (0.0, 0.0, 0.06), f"{s}ThumbProximal": (sx * 0.04, 0.0, 0.02),
                 f"{s}IndexIntermediate": (sx * 0.03, 0.0, 0.0)}
    return _build(_HUMANOID, ends, ["Zrotation", "Yrotation", "Xrotation"])
