"""Joint roles: which joint of a skeleton is the pelvis, the left ankle, the head, ...

Built-in name tables, detected automatically (the table that finds the most roles wins):

- `cgspeed-motionbuilder`, `cgspeed-3dsmax`, `asf`: the CMU skeletons in the shared data.
- `mixamo`: Adobe Mixamo rigs (`mixamorig:Hips`, ...; any `namespace:` prefix is ignored).
- `axis`: Noitom Axis Neuron / Axis Studio, the 59-joint Perception Neuron skeleton (each leg
  ends at `Foot`: no toe joint).
- `rokoko`: Rokoko Studio BVH (`LeftThigh`, `LeftShin`, `LeftFoot`, `LeftToe`).
- `xsens`: Xsens MVN, the 23-segment model (`Pelvis`, `LeftUpperLeg`, ..., no finger joints).
- `unity`: Unity humanoid bone names (`HumanBodyBones`), also the bone names of the VMC
  protocol (`LeftUpperArm`, `LeftLowerLeg`, `LeftToes`, ...).

Any other skeleton takes a mapping `{role: joint name}` (a JSON file, `--roles FILE`); a partial
mapping is completed from the best built-in table. A role may name a joint or an end site
(`<joint>_End`). Fallbacks where a rig lacks a joint: no toe -> the ankle's first child, else the
ankle's end site, else the ankle; no hand -> the same from the wrist; no neck -> the head's
parent. Positions are joint *start* points, as in BVH, so e.g. the knee is the start of the
shin bone. Roles resolve to indices of FK points (joints first, then end sites).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from .errors import RoleError
from .kinematics import point_names
from .motion import Skeleton

__all__ = ["ROLES", "MIURA_ROLES", "ROLE_TABLES", "resolve_roles", "load_role_mapping",
           "detect_rig"]

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

# role -> (role it falls back from, how): a missing role is found from another one.
_CHILD_FALLBACKS = {"left_hand": "left_wrist", "right_hand": "right_wrist",
                    "left_toe": "left_ankle", "right_toe": "right_ankle"}


def _table(pelvis: str, neck: str, head: str, arm: tuple[str, str, str, str | None],
           leg: tuple[str, str, str, str | None], left: str, right: str) -> dict[str, str]:
    t = {"pelvis": pelvis, "neck": neck, "head": head}
    for side, fmt in (("left", left), ("right", right)):
        for role, name in zip(("shoulder", "elbow", "wrist", "hand"), arm, strict=True):
            if name is not None:
                t[f"{side}_{role}"] = fmt.format(name)
        for role, name in zip(("hip", "knee", "ankle", "toe"), leg, strict=True):
            if name is not None:
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
    # Mixamo uses the MotionBuilder names under a `mixamorig:` namespace (stripped on lookup).
    "mixamo": _table("Hips", "Neck", "Head", ("Arm", "ForeArm", "Hand", "HandIndex1"),
                     ("UpLeg", "Leg", "Foot", "ToeBase"), "Left{}", "Right{}"),
    "axis": _table("Hips", "Neck", "Head", ("Arm", "ForeArm", "Hand", "HandIndex1"),
                   ("UpLeg", "Leg", "Foot", None), "Left{}", "Right{}"),
    "rokoko": _table("Hips", "Neck", "Head", ("Arm", "ForeArm", "Hand", None),
                     ("Thigh", "Shin", "Foot", "Toe"), "Left{}", "Right{}"),
    "xsens": _table("Pelvis", "Neck", "Head", ("UpperArm", "ForeArm", "Hand", None),
                    ("UpperLeg", "LowerLeg", "Foot", "Toe"), "Left{}", "Right{}"),
    "unity": _table("Hips", "Neck", "Head", ("UpperArm", "LowerArm", "Hand", "IndexProximal"),
                    ("UpperLeg", "LowerLeg", "Foot", "Toes"), "Left{}", "Right{}"),
}
# cgspeed puts the hand base (FingerBase / lhand) at the wrist (offset 0), so the hand role
# is the finger joint, as the ASF `lhand` bone starts beyond the wrist.
for _side, _p in (("left", "L"), ("right", "R")):
    ROLE_TABLES["cgspeed-3dsmax"][f"{_side}_hand"] = f"{_p}Fingers"


def _key(name: str) -> str:
    """Lookup key of a joint name: without any `namespace:` prefix, case-folded."""
    return name.rsplit(":", 1)[-1].casefold()


def _lookup(skeleton: Skeleton) -> dict[str, int]:
    out: dict[str, int] = {}
    for i, name in enumerate(point_names(skeleton)):
        out.setdefault(name, i)
    for i, name in enumerate(point_names(skeleton)):
        out.setdefault(_key(name), i)
    return out


def _find(lookup: dict[str, int], name: str | None) -> int | None:
    if name is None:
        return None
    return lookup.get(name, lookup.get(_key(name)))


def _fallbacks(skeleton: Skeleton, found: dict[str, int]) -> None:
    """Fill missing hand / toe / neck roles from the joints next to them."""
    n = skeleton.n_joints
    ends = sorted(skeleton.end_sites)
    for role, base in _CHILD_FALLBACKS.items():
        j = found.get(base)
        if role in found or j is None or j >= n:
            continue
        children = skeleton.children(j)
        found[role] = children[0] if children else (n + ends.index(j) if j in ends else j)
    head = found.get("head")
    if "neck" not in found and head is not None and head < n and skeleton.parents[head] >= 0:
        found["neck"] = skeleton.parents[head]


def _resolve(skeleton: Skeleton, lookup: dict[str, int], table: dict[str, str]
             ) -> dict[str, int]:
    found = {r: i for r in ROLES if (i := _find(lookup, table.get(r))) is not None}
    _fallbacks(skeleton, found)
    return found


def detect_rig(skeleton: Skeleton) -> str:
    """Name of the built-in table that finds the most roles of `skeleton`."""
    lookup = _lookup(skeleton)

    def score(table: dict[str, str]) -> tuple[int, int]:
        hits = sum(_find(lookup, name) is not None for name in table.values())
        return hits, hits - len(table)

    return max(ROLE_TABLES, key=lambda t: score(ROLE_TABLES[t]))


_RESOLVED: dict[tuple[object, ...], dict[str, int]] = {}
_MAX_RESOLVED = 64  # distinct (rig, mapping, roles) remembered; a process serves a few rigs


def resolve_roles(skeleton: Skeleton, mapping: dict[str, str] | None = None,
                  needed: tuple[str, ...] = ROLES) -> dict[str, int]:
    """Map each role in `needed` to an FK point index; raise `RoleError` listing what is
    missing. `mapping` (default: the skeleton's own `roles`) overrides the built-in tables.

    Remembered by the rig's structure (joint names, parents, end sites), the mapping and
    `needed`: every keyframer of a new stream asks for the same rig (ten times for the four
    methods, 4 ms of a stream's 6-8 ms start-up otherwise)."""
    mapping = mapping if mapping is not None else skeleton.roles
    key = (tuple(skeleton.names), tuple(skeleton.parents), tuple(sorted(skeleton.end_sites)),
           tuple(sorted((mapping or {}).items())), tuple(needed))
    known = _RESOLVED.get(key)
    if known is None:
        known = _resolve_roles(skeleton, mapping, needed)
        if len(_RESOLVED) >= _MAX_RESOLVED:
            _RESOLVED.clear()
        _RESOLVED[key] = known
    return dict(known)


def _resolve_roles(skeleton: Skeleton, mapping: dict[str, str] | None,
                   needed: tuple[str, ...]) -> dict[str, int]:
    lookup = _lookup(skeleton)
    joints = ", ".join(skeleton.names)
    for role, name in (mapping or {}).items():
        if _find(lookup, name) is None:
            raise RoleError(f"role mapping: {role} -> {name!r}: no such joint; joints are: "
                            + joints)
    best: tuple[int, str, list[str]] | None = None
    for table_name, table in ROLE_TABLES.items():
        found = _resolve(skeleton, lookup, {**table, **(mapping or {})})
        missing = [r for r in needed if r not in found]
        if not missing:
            return {r: found[r] for r in needed}
        if best is None or len(found) > best[0]:
            best = (len(found), table_name, missing)
    assert best is not None
    raise RoleError(
        "could not find joints for roles: " + ", ".join(best[2])
        + f" (closest built-in table: {best[1]}). Give a role mapping file with --roles FILE "
        "(JSON {role: joint name}); joints are: " + joints
    )


def load_role_mapping(path: str | os.PathLike[str]) -> dict[str, str]:
    """Read a JSON role mapping file `{role: joint name}`."""
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RoleError(f"{p}: no such role mapping file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise RoleError(f"{p}: cannot read the role mapping file: {exc}") from None
    except json.JSONDecodeError as exc:
        raise RoleError(
            f"{p}:{exc.lineno}: expected JSON {{role: joint name}}: {exc.msg}") from None
    if not isinstance(data, dict) or not all(isinstance(v, str) for v in data.values()):
        raise RoleError(f"{p}: expected a JSON object mapping role names to joint names")
    unknown = sorted(set(data) - set(ROLES))
    if unknown:
        raise RoleError(f"{p}: unknown roles {unknown}; known roles: {', '.join(ROLES)}")
    return data
