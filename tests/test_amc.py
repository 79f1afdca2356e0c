"""ASF/AMC reader: every shared AMC clip, cross-checks against the cgspeed BVH, and errors."""

from __future__ import annotations

import csv
import math
import re
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from streamkey.amc import parse_asf, read_amc, read_asf, read_motion
from streamkey.bvh import read_bvh
from streamkey.errors import AMCError, InputError, UsageError
from streamkey.features import compute_features
from streamkey.kinematics import body_height, forward_kinematics
from streamkey.motion import Motion

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "cmu"

with open(DATA / "MANIFEST.csv", newline="", encoding="utf-8") as _f:
    AMC_ROWS = [r for r in csv.DictReader(_f) if r["format"] == "amc"]
AMC_CLIPS = [Path(r["file"]).stem for r in AMC_ROWS]
PAIRED = ["05_11", "07_05", "09_06"]  # in both AMC and cgspeed BVH form

# cgspeed BVH joint -> ASF joint at the same point (both are bone START points).
LOWER_BODY = {"Hips": "root", "LeftUpLeg": "lfemur", "LeftLeg": "ltibia", "LeftFoot": "lfoot",
              "LeftToeBase": "ltoes", "RightUpLeg": "rfemur", "RightLeg": "rtibia",
              "RightFoot": "rfoot", "RightToeBase": "rtoes", "Spine": "upperback",
              "Spine1": "thorax"}
UPPER_BODY = {"LeftHand": "lwrist", "RightHand": "rwrist", "Head": "head",
              "LeftArm": "lhumerus", "RightForeArm": "rradius", "Neck1": "upperneck"}


@cache
def amc(clip: str) -> Motion:
    return read_amc(DATA / f"{clip}.amc")


@cache
def bvh(clip: str) -> Motion:
    return read_bvh(DATA / f"{clip}.bvh")


def paired_positions(clip: str) -> tuple[Motion, np.ndarray, Motion, np.ndarray]:
    """AMC frame i and BVH frame i+1 (after the cgspeed reference frame) world positions."""
    a, b = amc(clip), bvh(clip)
    fa = forward_kinematics(a.skeleton, a.channels).positions
    fb = forward_kinematics(b.skeleton, b.channels[1:]).positions
    return a, fa, b, fb


def distances(clip: str, pairs: dict[str, str], relative: bool = False) -> np.ndarray:
    """Distances (frames, pairs) between corresponding BVH and AMC joints.

    With `relative`, positions are taken from the base of the neck (ASF `lowerneck` start =
    thorax end; cgspeed `Spine1`, where its Neck and shoulders start).
    """
    a, fa, b, fb = paired_positions(clip)
    if relative:
        fa = fa - fa[:, [a.skeleton.index("lowerneck")]]
        fb = fb - fb[:, [b.skeleton.index("Spine1")]]
    ia = [a.skeleton.index(n) for n in pairs.values()]
    ib = [b.skeleton.index(n) for n in pairs]
    return np.linalg.norm(fa[:, ia] - fb[:, ib], axis=-1)


@pytest.mark.parametrize("row", AMC_ROWS, ids=AMC_CLIPS)
def test_every_shared_amc_loads_with_the_manifest_frame_count_and_62_channels(row):
    m = amc(Path(row["file"]).stem)
    assert m.channels.shape == (int(row["frames"]), int(row["channels"])) == (m.n_frames, 62)
    assert m.fps == 120.0 and m.first_frame == 0 and m.name == Path(row["file"]).stem
    assert m.skeleton.n_joints == 31 and m.skeleton.names[0] == "root"
    assert np.isfinite(m.channels).all()


@pytest.mark.parametrize("clip", PAIRED)
def test_amc_root_values_of_frame_0_equal_bvh_frame_1(clip):
    a, b = amc(clip), bvh(clip)
    assert a.n_frames == b.n_frames - 1
    sa, sb = a.skeleton, b.skeleton
    pos_a = a.channels[:, [sa.channel_index(0, c) for c in ("Xposition", "Yposition",
                                                             "Zposition")]]
    pos_b = b.channels[1:, [sb.channel_index(0, c) for c in ("Xposition", "Yposition",
                                                             "Zposition")]]
    assert np.abs(pos_a[0] - pos_b[0]).max() < 1e-3
    rot = ("Xrotation", "Yrotation", "Zrotation")
    rot_a = a.channels[:, [sa.channel_index(0, c) for c in rot]]
    rot_b = b.channels[1:, [sb.channel_index(0, c) for c in rot]]
    assert np.abs(rot_a[0] - rot_b[0]).max() < 1e-3
    # Not only frame 0: the whole root trajectory agrees to the printed precision.
    assert np.abs(pos_a - pos_b).max() < 1e-3 and np.abs(rot_a - rot_b).max() < 1e-3


@pytest.mark.parametrize("clip", PAIRED)
def test_amc_and_bvh_feet_and_legs_coincide_on_every_frame(clip):
    d = distances(clip, LOWER_BODY)
    # 2 % of body height is the acceptance bound; measured: < 1e-3 units (print precision).
    assert d.max() < 0.02 * body_height(bvh(clip).skeleton)
    assert d.max() < 1e-3


@pytest.mark.parametrize("clip", PAIRED)
def test_amc_and_bvh_hands_and_head_coincide_relative_to_the_neck_base(clip):
    # Same rotation conventions everywhere above the thorax (ASF axis C = Rz Ry Rx, C M C^T).
    d = distances(clip, UPPER_BODY, relative=True)
    assert d.max() < 0.02 * body_height(bvh(clip).skeleton)
    assert d.max() < 1e-3


@pytest.mark.xfail(strict=True, reason="measured 7.8-9.0 % of body height (2.01-2.21 units, "
                   "constant): the cgspeed BVH drops the ASF thorax bone (Spine1->Neck and "
                   "Spine1->LeftShoulder offsets are 0), so its upper body sits one thorax "
                   "length lower")
@pytest.mark.parametrize("clip", PAIRED)
def test_amc_and_bvh_hands_and_head_coincide_in_world_space(clip):
    d = distances(clip, {"LeftHand": "lwrist", "RightHand": "rwrist", "Head": "head"})
    assert d.max() < 0.02 * body_height(bvh(clip).skeleton)


def test_the_world_space_hand_and_head_gap_is_exactly_the_thorax_bone():
    a = amc("07_05")
    thorax = np.linalg.norm(a.skeleton.offsets[a.skeleton.index("lowerneck")])
    d = distances("07_05", {"LeftHand": "lwrist", "Head": "head"})
    assert np.abs(d - thorax).max() < 1e-3


@pytest.mark.parametrize("clip", AMC_CLIPS)
def test_bone_lengths_stay_constant_over_every_frame(clip):
    m = amc(clip)
    skel = m.skeleton
    fk = forward_kinematics(skel, m.channels)
    parents = np.array(skel.parents[1:] + sorted(skel.end_sites))
    children = np.arange(1, skel.n_joints + len(skel.end_sites))
    rest = np.linalg.norm(np.vstack([skel.offsets[1:]] + [skel.end_sites[j][None]
                                                          for j in sorted(skel.end_sites)]),
                          axis=1)
    lengths = np.linalg.norm(fk.positions[:, children] - fk.positions[:, parents], axis=-1)
    assert np.abs(lengths - rest).max() < 1e-9
    assert np.isclose(rest.sum(), sum(np.linalg.norm(o) for o in skel.offsets)
                      + sum(np.linalg.norm(e) for e in skel.end_sites.values()))


def test_asf_bones_map_to_joints_at_bone_starts():
    skel = read_asf(DATA / "07.asf")
    assert skel.names[:3] == ["root", "lhipjoint", "lfemur"]
    lhip = skel.index("lhipjoint")
    assert np.allclose(skel.offsets[lhip], 0)
    assert np.allclose(skel.offsets[skel.index("lfemur")],
                       2.68184 * np.array([0.692024, -0.648617, 0.316857]))
    toes = skel.index("ltoes")
    assert np.allclose(skel.end_sites[toes], [0, 0, 1.00661], atol=1e-9)
    assert skel.channels[0] == ["Xposition", "Yposition", "Zposition", "Xrotation",
                                "Yrotation", "Zrotation"]
    foot = skel.index("lfoot")
    assert skel.channels[foot] == ["Xrotation", "Zrotation"]
    assert skel.rotation_order[foot] == ["Zrotation", "Xrotation"]
    assert skel.pre_rotations[lhip] is None  # no dof, no rotation
    # lfemur `axis 0 0 20 XYZ` is Rz(20): it turns -Y onto the femur direction.
    c = skel.pre_rotations[skel.index("lfemur")]
    assert np.allclose(c @ [0, -1, 0], [0.34202, -0.939693, 0], atol=1e-6)


def test_crlf_files_read_like_lf_files(tmp_path):
    for name in ("07.asf", "07_05.amc"):
        text = (DATA / name).read_text(encoding="utf-8")
        (tmp_path / name).write_bytes(text.replace("\n", "\r\n").encode())
    m = read_amc(tmp_path / "07_05.amc")
    assert np.array_equal(m.channels, amc("07_05").channels)
    assert b"\r\n" in (DATA / "35_01.amc").read_bytes()[:200]  # a shared CRLF clip


def test_radian_units_give_the_same_motion_as_degrees(tmp_path):
    asf = (DATA / "07.asf").read_text(encoding="utf-8").replace("angle deg", "angle rad")

    def to_rad(match: re.Match[str]) -> str:
        return " ".join(f"{math.radians(float(v))!r}" for v in match.group(1).split())

    asf = re.sub(r"(?m)(?<=axis )([-\d.e+ ]+?)(?=\s+XYZ)", to_rad, asf)
    lines = (DATA / "07_05.amc").read_text(encoding="utf-8").splitlines()[:63]
    out = []
    for ln in lines:
        w = ln.split()
        if ln.startswith(":DEGREES"):
            continue  # the ASF's `angle rad` then applies
        if w and w[0] == "root":
            w[4:] = [repr(math.radians(float(v))) for v in w[4:]]
        elif w and not ln.startswith((":", "#")) and not w[0].isdigit():
            w[1:] = [repr(math.radians(float(v))) for v in w[1:]]
        out.append(" ".join(w))
    (tmp_path / "07.asf").write_text(asf, encoding="utf-8")
    (tmp_path / "07_05.amc").write_text("\n".join(out) + "\n", encoding="utf-8")
    m = read_amc(tmp_path / "07_05.amc")
    ref = amc("07_05")
    assert m.n_frames == 2
    assert np.allclose(m.channels, ref.channels[:2], atol=1e-9)
    fk = forward_kinematics(m.skeleton, m.channels).positions
    assert np.allclose(fk, forward_kinematics(ref.skeleton, ref.channels[:2]).positions)


def test_read_motion_dispatches_on_suffix(tmp_path):
    assert read_motion(DATA / "09_06.amc").n_frames == 141
    assert read_motion(DATA / "09_06.bvh").n_frames == 142
    (tmp_path / "x.c3d").write_text("", encoding="utf-8")
    with pytest.raises(InputError, match=r"x\.c3d.*\.bvh or \.amc"):
        read_motion(tmp_path / "x.c3d")


def test_features_work_on_amc_with_the_asf_role_table():
    m = amc("07_05")
    f = compute_features(m)
    names = {r: m.skeleton.names[j] for r, j in f.roles.items()}
    assert names["pelvis"] == "root" and names["left_ankle"] == "lfoot"
    assert names["left_wrist"] == "lwrist" and names["head"] == "head"
    assert f.rotations.shape == (m.n_frames, 59)
    # Feet of a walk touch the ground: ankle heights span a few units, same as the BVH (raw:
    # the BVH's noise filter also sees its frame-0 T-pose, which the AMC does not have).
    raw, b = compute_features(m, noise_cutoff_hz=None), compute_features(bvh("07_05"), None,
                                                                          noise_cutoff_hz=None)
    assert np.abs(raw.foot_heights - b.foot_heights[1:]).max() < 1e-3


def test_read_amc_rejects_a_bad_fps():
    with pytest.raises(UsageError):
        read_amc(DATA / "07_05.amc", fps=0)


# --- errors: each names the file and line, and says what was expected -----------------------

ASF_TEXT = (DATA / "07.asf").read_text(encoding="utf-8")
AMC_LINES = (DATA / "07_05.amc").read_text(encoding="utf-8").splitlines()[:93]  # 3 frames


def write_clip(tmp_path: Path, amc_lines: list[str], asf_text: str = ASF_TEXT) -> Path:
    (tmp_path / "07.asf").write_text(asf_text, encoding="utf-8")
    path = tmp_path / "07_05.amc"
    path.write_text("\n".join(amc_lines) + "\n", encoding="utf-8")
    return path


def expect_error(path: Path, pattern: str, line: int | None = None, name: str = "") -> None:
    with pytest.raises(AMCError) as info:
        read_amc(path)
    msg = str(info.value)
    assert msg.startswith(str(path.with_name(name) if name else path)), msg
    if line is not None:
        assert f":{line}: " in msg, msg
    assert re.search(pattern, msg), msg
    assert "Traceback" not in msg


def test_the_three_frame_fixture_is_valid(tmp_path):
    assert read_amc(write_clip(tmp_path, AMC_LINES)).n_frames == 3


def test_missing_amc_file_is_an_amc_error(tmp_path):
    (tmp_path / "07.asf").write_text(ASF_TEXT, encoding="utf-8")
    expect_error(tmp_path / "07_05.amc", "no such file")


def test_missing_asf_beside_the_amc_is_an_amc_error(tmp_path):
    path = tmp_path / "07_05.amc"
    path.write_text("\n".join(AMC_LINES), encoding="utf-8")
    expect_error(path, r"07\.asf beside it")
    with pytest.raises(AMCError, match=r"other\.asf: no such file"):
        read_amc(path, tmp_path / "other.asf")


def test_missing_bonedata_section_is_an_amc_error(tmp_path):
    asf = ASF_TEXT.split(":bonedata")[0]
    n = len(asf.splitlines())
    expect_error(write_clip(tmp_path, AMC_LINES, asf), "expected a :bonedata section",
                 line=n, name="07.asf")


def test_missing_hierarchy_section_is_an_amc_error(tmp_path):
    asf = ASF_TEXT.split(":hierarchy")[0]
    expect_error(write_clip(tmp_path, AMC_LINES, asf), "expected a :hierarchy section",
                 name="07.asf")


def test_unknown_bone_in_hierarchy_is_an_amc_error(tmp_path):
    asf = ASF_TEXT.replace("lfoot ltoes", "lfoot ltoez")
    line = ASF_TEXT[: ASF_TEXT.index("lfoot ltoes")].count("\n") + 1
    expect_error(write_clip(tmp_path, AMC_LINES, asf), "'ltoez'", line=line, name="07.asf")


def test_bad_number_in_asf_is_an_amc_error(tmp_path):
    asf = ASF_TEXT.replace("length 6.92462", "length six")
    line = ASF_TEXT[: ASF_TEXT.index("length 6.92462")].count("\n") + 1
    expect_error(write_clip(tmp_path, AMC_LINES, asf), "expected a number for the bone length",
                 line=line, name="07.asf")


def test_unknown_bone_in_an_amc_frame_is_an_amc_error(tmp_path):
    lines = list(AMC_LINES)
    lines[10] = lines[10].replace("head", "hed")
    expect_error(write_clip(tmp_path, lines), r"expected a bone .*'hed'", line=11)


def test_wrong_number_of_values_for_a_bone_is_an_amc_error(tmp_path):
    lines = list(AMC_LINES)
    assert lines[40].split()[0] == "head"  # of frame 2: 3 values
    lines[40] += " 1.0"
    expect_error(write_clip(tmp_path, lines), "expected 3 values for bone 'head', got 4", line=41)


@pytest.mark.parametrize("bad", ["abc", "nan", "inf"])
def test_non_numeric_or_nan_values_are_an_amc_error(tmp_path, bad):
    lines = list(AMC_LINES)
    words = lines[70].split()
    words[1] = bad
    lines[70] = " ".join(words)
    expect_error(write_clip(tmp_path, lines), f"expected a finite number, got '{bad}'", line=71)


def test_frame_numbers_out_of_sequence_are_an_amc_error(tmp_path):
    lines = list(AMC_LINES)
    second = lines.index("2")
    lines[second] = "4"
    expect_error(write_clip(tmp_path, lines), "expected frame number 2, got 4", line=second + 1)


def test_truncated_last_frame_is_an_amc_error(tmp_path):
    lines = AMC_LINES[:-5]
    expect_error(write_clip(tmp_path, lines), r"lfemur.*in frame 3.*truncated last frame",
                 line=len(lines))


def test_amc_without_frames_is_an_amc_error(tmp_path):
    expect_error(write_clip(tmp_path, AMC_LINES[:3]), "at least one numbered frame", line=3)


def test_parse_asf_names_the_source_in_errors():
    with pytest.raises(AMCError, match=r"^mem\.asf:1: expected an ASF keyword"):
        parse_asf("begin\n", "mem.asf")
