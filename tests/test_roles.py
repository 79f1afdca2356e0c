"""Joint roles on any humanoid rig: built-in tables, fallbacks, `--roles FILE`, and the same
keyframes from a renamed 07_01 (Mixamo names, Axis names, arbitrary names + mapping)."""

from __future__ import annotations

import json
import random

import numpy as np
import pytest
from cmu import DATA

from streamkey.batch import extract_motion
from streamkey.bvh import read_bvh, write_bvh
from streamkey.cli import main
from streamkey.errors import RoleError
from streamkey.kinematics import point_names
from streamkey.methods import OFFLINE_METHODS, ONLINE_METHODS
from streamkey.motion import Motion, Skeleton
from streamkey.roles import ROLES, detect_rig, load_role_mapping, resolve_roles
from streamkey.streaming import run_online

CLIP = DATA / "07_01.bvh"


def _rig(spec: str, prefix: str = "") -> Skeleton:
    """A skeleton from `child parent` lines (the rig's documented joint list); a leaf gets an
    end site. Offsets are a plain stick figure: roles do not depend on them."""
    names: list[str] = []
    parents: list[int] = []
    for line in spec.split(";"):
        child, parent = (line.split() + ["-"])[:2]
        names.append(prefix + child)
        parents.append(-1 if parent == "-" else names.index(prefix + parent))
    offsets = np.array([[0.0, 0.0, 0.0]] + [[0.1, 1.0, 0.0]] * (len(names) - 1))
    channels = [["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]]
    channels += [["Zrotation", "Xrotation", "Yrotation"]] * (len(names) - 1)
    leaves = {j: np.array([0.0, 0.5, 0.0]) for j in range(len(names)) if j not in parents}
    return Skeleton(names, parents, offsets, channels, leaves)


def _sides(template: str) -> str:
    return ";".join(template.replace("{S}", s) for s in ("Left", "Right"))


_FINGERS = "".join(f";{{S}}Hand{f}1 {{S}}InHand{f};{{S}}Hand{f}2 {{S}}Hand{f}1;"
                   f"{{S}}Hand{f}3 {{S}}Hand{f}2" for f in ("Index", "Middle", "Ring", "Pinky"))
# Noitom Axis Neuron / Perception Neuron: 59 joints, legs end at Foot (Axis Neuron BVH export).
AXIS = ("Hips;" + _sides("{S}UpLeg Hips;{S}Leg {S}UpLeg;{S}Foot {S}Leg")
        + ";Spine Hips;Spine1 Spine;Spine2 Spine1;Spine3 Spine2;Neck Spine3;Head Neck;"
        + _sides("{S}Shoulder Spine3;{S}Arm {S}Shoulder;{S}ForeArm {S}Arm;{S}Hand {S}ForeArm;"
                 "{S}HandThumb1 {S}Hand;{S}HandThumb2 {S}HandThumb1;{S}HandThumb3 {S}HandThumb2;"
                 "{S}InHandIndex {S}Hand;{S}InHandMiddle {S}Hand;{S}InHandRing {S}Hand;"
                 "{S}InHandPinky {S}Hand" + _FINGERS))
# Rokoko Studio (Newton skeleton) BVH names, body only.
ROKOKO = ("Hips;" + _sides("{S}Thigh Hips;{S}Shin {S}Thigh;{S}Foot {S}Shin;{S}Toe {S}Foot")
          + ";Spine1 Hips;Spine2 Spine1;Spine3 Spine2;Spine4 Spine3;Neck Spine4;Head Neck;"
          + _sides("{S}Shoulder Spine4;{S}Arm {S}Shoulder;{S}ForeArm {S}Arm;{S}Hand {S}ForeArm"))
# Xsens MVN: the 23 segments of the MVN biomechanical model.
XSENS = ("Pelvis;L5 Pelvis;L3 L5;T12 L3;T8 T12;Neck T8;Head Neck;"
         + _sides("{S}Shoulder T8;{S}UpperArm {S}Shoulder;{S}ForeArm {S}UpperArm;"
                  "{S}Hand {S}ForeArm") + ";"
         + _sides("{S}UpperLeg Pelvis;{S}LowerLeg {S}UpperLeg;{S}Foot {S}LowerLeg;"
                  "{S}Toe {S}Foot"))
# Unity HumanBodyBones (also the VMC bone names).
UNITY = ("Hips;Spine Hips;Chest Spine;UpperChest Chest;Neck UpperChest;Head Neck;"
         + _sides("{S}Shoulder UpperChest;{S}UpperArm {S}Shoulder;{S}LowerArm {S}UpperArm;"
                  "{S}Hand {S}LowerArm;{S}ThumbProximal {S}Hand;{S}IndexProximal {S}Hand;"
                  "{S}IndexIntermediate {S}IndexProximal") + ";"
         + _sides("{S}UpperLeg Hips;{S}LowerLeg {S}UpperLeg;{S}Foot {S}LowerLeg;"
                  "{S}Toes {S}Foot"))
# Mixamo (`mixamorig:` namespace).
MIXAMO = ("Hips;Spine Hips;Spine1 Spine;Spine2 Spine1;Neck Spine2;Head Neck;HeadTop_End Head;"
          + _sides("{S}Shoulder Spine2;{S}Arm {S}Shoulder;{S}ForeArm {S}Arm;{S}Hand {S}ForeArm;"
                   "{S}HandThumb1 {S}Hand;{S}HandIndex1 {S}Hand;{S}HandIndex2 {S}HandIndex1")
          + ";" + _sides("{S}UpLeg Hips;{S}Leg {S}UpLeg;{S}Foot {S}Leg;{S}ToeBase {S}Foot;"
                         "{S}Toe_End {S}ToeBase"))


def _named(skel: Skeleton, roles: dict[str, int]) -> dict[str, str]:
    names = point_names(skel)
    return {r: names[i] for r, i in roles.items()}


def test_axis_59_joints_resolve_with_toes_at_the_foot_end_site():
    skel = _rig(AXIS)
    assert skel.n_joints == 59
    roles = _named(skel, resolve_roles(skel))
    assert roles["left_toe"] == "LeftFoot_End" and roles["right_toe"] == "RightFoot_End"
    assert roles["left_hand"] == "LeftHandIndex1" and roles["right_knee"] == "RightLeg"
    assert detect_rig(skel) == "axis"


@pytest.mark.parametrize("spec, rig, expect", [
    (ROKOKO, "rokoko", {"left_knee": "LeftShin", "right_toe": "RightToe",
                        "left_hand": "LeftHand_End", "neck": "Neck"}),
    (XSENS, "xsens", {"pelvis": "Pelvis", "left_hip": "LeftUpperLeg", "right_ankle": "RightFoot",
                      "left_hand": "LeftHand_End", "left_wrist": "LeftHand"}),
    (UNITY, "unity", {"left_elbow": "LeftLowerArm", "left_hand": "LeftIndexProximal",
                      "right_toe": "RightToes", "right_knee": "RightLowerLeg"}),
])
def test_each_built_in_table_resolves_its_documented_joint_list(spec, rig, expect):
    skel = _rig(spec)
    roles = _named(skel, resolve_roles(skel))
    assert set(roles) == set(ROLES)
    assert {r: roles[r] for r in expect} == expect
    assert detect_rig(skel) == rig


def test_mixamo_namespace_is_ignored():
    skel = _rig(MIXAMO, prefix="mixamorig:")
    roles = _named(skel, resolve_roles(skel))
    assert roles["pelvis"] == "mixamorig:Hips"
    assert roles["left_toe"] == "mixamorig:LeftToeBase"
    assert roles["right_hand"] == "mixamorig:RightHandIndex1"


def test_missing_roles_are_listed_with_the_joint_names_seen():
    skel = _rig("Base;Thing Base;Other Thing")
    with pytest.raises(RoleError) as err:
        resolve_roles(skel)
    text = str(err.value)
    assert "pelvis" in text and "left_ankle" in text and "--roles FILE" in text
    assert "joints are: Base, Thing, Other" in text
    with pytest.raises(RoleError, match="left_ankle -> 'Nope': no such joint"):
        resolve_roles(skel, {"left_ankle": "Nope"})


def test_role_mapping_file_errors_name_the_file_and_line(tmp_path):
    bad = tmp_path / "roles.json"
    bad.write_text('{"pelvis": "Hips",\n "left_ankle": }')
    with pytest.raises(RoleError, match=r"roles.json:2: expected JSON"):
        load_role_mapping(bad)
    bad.write_text('{"pelvis": "Hips", "tail": "Tail"}')
    with pytest.raises(RoleError, match=r"unknown roles \['tail'\]"):
        load_role_mapping(bad)


# --------------------------------------------------------------- renamed 07_01, same keyframes
AXIS_RENAMES = {"LeftToeBase": "LeftFootTip", "RightToeBase": "RightFootTip",
                "LeftFingerBase": "LeftInHandIndex", "RightFingerBase": "RightInHandIndex",
                "LThumb": "LeftHandThumb1", "RThumb": "RightHandThumb1", "Neck1": "Spine3"}


def _renamed(motion: Motion, rename) -> Motion:  # type: ignore[no-untyped-def]
    s = motion.skeleton
    skel = Skeleton([rename(n) for n in s.names], list(s.parents), s.offsets.copy(),
                    [list(c) for c in s.channels], dict(s.end_sites))
    return Motion(skel, motion.channels, motion.fps, motion.first_frame, motion.name)


def _frames(results: dict) -> dict[str, list[int]]:  # type: ignore[type-arg]
    return {m: k.frames.tolist() for m, k in results.items()}


@pytest.fixture(scope="module")
def reference():
    motion = read_bvh(CLIP)
    return motion, _frames(extract_motion(motion, list(OFFLINE_METHODS))), _frames(
        run_online(motion, list(ONLINE_METHODS)))


@pytest.mark.parametrize("rig", ["mixamo", "axis", "mixamo+roles", "axis+roles",
                                 "numbered+roles"])
def test_renamed_07_01_gives_the_same_keyframes_offline_and_online(reference, rig):
    motion, offline, online = reference
    names = motion.skeleton.names
    rename = {"mixamo": lambda n: "mixamorig:" + n, "axis": lambda n: AXIS_RENAMES.get(n, n),
              "numbered": lambda n: f"j{names.index(n):02d}"}[rig.split("+")[0]]
    renamed = _renamed(motion, rename)
    if rig.endswith("+roles"):  # an explicit mapping instead of the built-in tables
        original = {r: names[i] for r, i in resolve_roles(motion.skeleton).items()}
        renamed.skeleton.roles = {r: rename(n) for r, n in original.items()}
    assert resolve_roles(renamed.skeleton) == resolve_roles(motion.skeleton)
    assert _frames(extract_motion(renamed, list(OFFLINE_METHODS))) == offline
    assert _frames(run_online(renamed, list(ONLINE_METHODS))) == online


def test_toe_joints_renamed_fall_back_to_the_ankle_child():
    motion = read_bvh(CLIP)
    renamed = _renamed(motion, lambda n: AXIS_RENAMES.get(n, n))
    roles = _named(renamed.skeleton, resolve_roles(renamed.skeleton))
    assert roles["left_toe"] == "LeftFootTip" and roles["right_toe"] == "RightFootTip"


def _extract(argv: list[str], capsys) -> dict[str, list[int]]:  # type: ignore[no-untyped-def]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    return {m: r["keyframes"] for m, r in out["files"][0]["methods"].items()}


def test_cli_roles_file_on_extract_run_and_sheet(tmp_path, capsys):
    motion = read_bvh(CLIP)
    names = motion.skeleton.names
    plain, numbered = tmp_path / "plain.bvh", tmp_path / "numbered.bvh"
    write_bvh(motion, plain)
    write_bvh(_renamed(motion, lambda n: f"j{names.index(n):02d}"), numbered)
    mapping = {r: f"j{i:02d}" for r, i in resolve_roles(motion.skeleton).items()}
    roles = tmp_path / "roles.json"
    roles.write_text(json.dumps(mapping))

    assert main(["extract", str(numbered), "--method", "speed"]) == 2
    assert "could not find joints for roles" in capsys.readouterr().err
    for extra in ([], ["--online"]):
        want = _extract(["extract", str(plain), "--method", "all", *extra], capsys)
        got = _extract(["extract", str(numbered), "--method", "all", "--roles", str(roles),
                        *extra], capsys)
        assert got == want and all(want.values())

    logs = []
    for path, extra in ((plain, []), (numbered, ["--roles", str(roles)])):
        log = tmp_path / f"{path.stem}.jsonl"
        assert main(["run", "--from", str(path), "--fast", "--to", f"jsonl:{log}", *extra]) == 0
        logs.append(sorted((e["method"], e["frame"], e["decided_at"]) for e in
                           map(json.loads, log.read_text().splitlines())
                           if e["type"] == "keyframe"))
    assert logs[0] == logs[1] and len(logs[0]) > 10
    assert main(["sheet", str(numbered), "--roles", str(roles), "--method", "speed",
                 "-o", str(tmp_path / "s.png")]) == 0
    assert (tmp_path / "s.png").stat().st_size > 1000


def test_roles_reach_online_keyframers_of_a_wire_skeleton(tmp_path):
    """`run --roles` with a skeleton from the wire: the mapping rides in the method params."""
    from streamkey.cli import _online_params, build_parser
    from streamkey.online import Pipeline
    from streamkey.streaming import make_keyframers

    motion = read_bvh(CLIP)
    names = motion.skeleton.names
    numbered = _renamed(motion, lambda n: f"j{names.index(n):02d}")
    roles = tmp_path / "roles.json"
    roles.write_text(json.dumps({r: f"j{i:02d}" for r, i in
                                 resolve_roles(motion.skeleton).items()}))
    args = build_parser().parse_args(["run", "--from", "osc://127.0.0.1:9000", "--roles",
                                      str(roles)])
    events = []
    for m, params in ((motion, None), (numbered, _online_params(args))):
        pipe = Pipeline(make_keyframers(m, list(ONLINE_METHODS), params))
        events.append([(e.method, e.frame, e.score) for e in
                       pipe.push_block(m.frames()) + pipe.flush() if hasattr(e, "score")])
    assert events[0] == events[1] and len(events[0]) > 10


def test_fuzzed_role_files_exit_2_with_one_error_line(tmp_path, capsys):
    rng = random.Random(4)
    samples = [b"", b"[]", b'{"pelvis": 3}', b'{"pelvis": "Nope"}', b"\xff\xfe{", b"{" * 50]
    samples += [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 60))) for _ in range(20)]
    for i, data in enumerate(samples):
        path = tmp_path / f"r{i}.json"
        path.write_bytes(data)
        assert main(["extract", str(CLIP), "--method", "speed", "--roles", str(path)]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err
