"""Joint roles: which joint of a skeleton is the pelvis, the left ankle, the head, ...

Built-in tables cover the CMU skeletons in the shared data (cgspeed MotionBuilder BVH, cgspeed
3dsMax BVH, ASF bone names). Any other skeleton needs a mapping `{role: joint name}` (a JSON
file on the command line). Joint positions are joint *start* points, as in BVH, so e.g. the
knee is the start of the shin bone.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from .errors import RoleError
from .motion import Skeleton

__all__ = ["ROLES", "MIURA_ROLES", "ROLE_TABLES", "resolve_roles", "load_role_mapping"]

ROLES = (
    "pelvis", "neck", "head",
    "left_shoulder", "left_elbow", "left_wrist", "left_hand",
    "right_shoulder", "right_elbow", "right_wrist", "right_hand",
    "left_hip", "left_knee", "left_ankle", "left_toe",
    "right_hip", "right_knee", "right_ankle", "right_toe",
)

# Miura et al. §3.1: the 16 body parts whose speed defines keyposes.
MIURA_ROLES = (
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_toe", "right_toe", "neck", "head",
)


def _table(pelvis: str, neck: str, head: str, arm: tuple[str, str, str, str],
           leg: tuple[str, str, str, str], left: str, right: str) -> dict[str, str]:
    t = {"pelvis": pelvis, "neck": neck, "head": head}
    for side, fmt in (("left", left), ("right", right)):
        for role, name in zip(("shoulder", "elbow", "wrist", "hand"), arm, strict=True):
            t[f"{side}_{role}"] = fmt.format(name)
        for role, name in zip(("hip", "knee", "ankle", "toe"), leg, strict=True):
            t[f"{side}_{role}"] = fmt.format(name)
    return t


ROLE_TABLES: dict[str, dict[str, str]] = {
    "cgspeed-motionbuilder": _table("Hips", "Neck", "Head",
                                    ("Arm", "ForeArm", "Hand", "HandIndex1"),
                                    ("UpLeg", "Leg", "Foot", "ToeBase"), "Left{}", "Right{}"),
    "cgspeed-3dsmax": _table("Hips", "lowerneck", "Head",
                             ("Shoulder", "Elbow", "Wrist", "Fingers"),
                             ("Hip", "Knee", "Ankle", "Toe"), "Left{}", "Right{}"),
    "asf": _table("root", "lowerneck", "head", ("humerus", "radius", "wrist", "hand"),
                  ("femur", "tibia", "foot", "toes"), "l{}", "r{}"),
}
# cgspeed puts the hand base (FingerBase / lhand) at the wrist (offset 0), so the hand role
# is the finger joint, as the ASF `lhand` bone starts beyond the wrist.
for _side, _p in (("left", "L"), ("right", "R")):
    ROLE_TABLES["cgspeed-3dsmax"][f"{_side}_hand"] = f"{_p}Fingers"


def resolve_roles(skeleton: Skeleton, mapping: dict[str, str] | None = None,
                  needed: tuple[str, ...] = ROLES) -> dict[str, int]:
    """Map each role in `needed` to a joint index; raise `RoleError` listing what is missing."""
    names = {n: i for i, n in enumerate(skeleton.names)}
    candidates = [mapping] if mapping else list(ROLE_TABLES.values())
    best: tuple[int, dict[str, int], list[str]] | None = None
    for table in candidates:
        found = {r: names[table[r]] for r in needed if r in table and table[r] in names}
        missing = [r for r in needed if r not in found]
        if not missing:
            return found
        if best is None or len(found) > best[0]:
            best = (len(found), found, missing)
    missing = best[2] if best else list(needed)
    raise RoleError(
        "could not find joints for roles: " + ", ".join(missing)
        + ". Give a role mapping file (JSON {role: joint name}); joints are: "
        + ", ".join(skeleton.names)
    )


def load_role_mapping(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read a JSON role mapping file `{role: joint name}`."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RoleError(f"{p}: no such role mapping file") from None
    except json.JSONDecodeError as exc:
        raise RoleError(
            f"{p}:{exc.lineno}: expected JSON {{role: joint name}}: {exc.msg}") from None
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise RoleError(f"{p}: expected a JSON object mapping role names to joint names")
    unknown = sorted(set(data) - set(ROLES))
    if unknown:
        raise RoleError(f"{p}: unknown roles {unknown}; known roles: {', '.join(ROLES)}")
    return data
