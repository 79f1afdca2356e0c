from __future__ import annotations

import numpy as np
import pytest
from cmu import DATA, clips, manifest

from streamkey.bvh import format_bvh, parse_bvh, read_bvh, write_bvh
from streamkey.errors import BVHError

BVH_ROWS = [r for r in manifest() if r["format"].startswith("bvh")]

SMALL = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
\tJOINT Chest
\t{
\t\tOFFSET 0 5 0
\t\tCHANNELS 3 Xrotation Zrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 3 0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.0333333
1 2 3 10 20 30 1 2 3
1 2 3 11 21 31 4 5 6
"""


@pytest.mark.parametrize("row", BVH_ROWS, ids=lambda r: r["file"])
def test_every_shared_bvh_loads_with_manifest_counts_and_round_trips(row, tmp_path):
    motion = read_bvh(DATA / row["file"])
    assert motion.n_frames == int(row["frames"])
    assert motion.skeleton.n_channels == int(row["channels"])
    assert motion.fps == pytest.approx(1 / float(row["frame_time"]), rel=1e-3)
    out = tmp_path / "rt.bvh"
    write_bvh(motion, out)
    again = read_bvh(out)
    assert again.skeleton.names == motion.skeleton.names
    assert again.skeleton.channels == motion.skeleton.channels
    np.testing.assert_allclose(again.skeleton.offsets, motion.skeleton.offsets, atol=1e-4)
    np.testing.assert_allclose(again.channels, motion.channels, atol=1e-4, rtol=0)
    assert again.first_frame == motion.first_frame


def test_reference_frame_is_detected_only_in_cgspeed_motionbuilder_files():
    for row in BVH_ROWS:
        motion = read_bvh(DATA / row["file"])
        expected = 1 if row["format"] == "bvh-cgspeed-mb" else 0
        if row["file"] == "07_12.bvh":
            expected = 2  # an all-zero dropout frame follows the reference frame
        assert motion.first_frame == expected, row["file"]
        assert np.any(motion.channels[motion.first_frame]), row["file"]


def test_variants_crlf_tabs_and_frame_time_without_leading_zero_parse_alike():
    base = parse_bvh(SMALL)
    variants = [SMALL.replace("\n", "\r\n"), SMALL.replace("\t", "    "),
                SMALL.replace("0.0333333", ".0333333"), SMALL.replace(" ", "\t")]
    for text in variants:
        m = parse_bvh(text)
        np.testing.assert_array_equal(m.channels, base.channels)
        assert m.skeleton.channels == base.skeleton.channels
    assert base.fps == pytest.approx(30.0)
    assert base.skeleton.rotation_order == [["Yrotation", "Xrotation", "Zrotation"],
                                            ["Xrotation", "Zrotation", "Yrotation"]]


def test_written_bvh_of_a_frame_subset_reloads_those_frames():
    m = read_bvh(DATA / "07_01.bvh")
    keep = np.array([1, 50, 200])
    again = parse_bvh(format_bvh(m, keep))
    np.testing.assert_allclose(again.channels, m.channels[keep], atol=1e-4)


BROKEN = {
    "no MOTION section": (SMALL.split("MOTION")[0], "MOTION"),
    "frame count mismatch": (SMALL.replace("Frames: 2", "Frames: 3"), "expected 3 frames"),
    "channel count mismatch": (SMALL.replace("4 5 6", "4 5 6 7"), "expected 9 values"),
    "non-numeric value": (SMALL.replace("11 21", "11 abc"), "got 'abc'"),
    "NaN value": (SMALL.replace("11 21", "11 nan"), "finite"),
    "truncated last line": (SMALL.replace("4 5 6\n", "4"), "truncated"),
    "unknown channel": (SMALL.replace("Xrotation Zrotation Yrotation", "Xrotation Wrotation Y"),
                        "channel name"),
    "bad frame time": (SMALL.replace("0.0333333", "fast"), "Frame Time"),
    "missing brace": (SMALL.replace("\tJOINT Chest\n\t{", "\tJOINT Chest\n"), "'{'"),
}


@pytest.mark.parametrize("case", sorted(BROKEN))
def test_bad_bvh_raises_one_bvherror_naming_file_and_line(case, tmp_path):
    text, needle = BROKEN[case]
    path = tmp_path / "bad.bvh"
    path.write_text(text)
    with pytest.raises(BVHError) as info:
        read_bvh(path)
    message = str(info.value)
    assert message.startswith(f"{path}:"), message
    assert needle in message, message


def test_missing_file_raises_bvherror():
    with pytest.raises(BVHError, match="no such file"):
        read_bvh(DATA / "does_not_exist.bvh")


def test_error_line_numbers_point_at_the_offending_line(tmp_path):
    path = tmp_path / "bad.bvh"
    path.write_text(SMALL.replace("11 21", "11 abc"))
    with pytest.raises(BVHError, match=r"bad.bvh:20: "):
        read_bvh(path)


def test_clip_list_is_not_empty():
    assert len(clips("bvh")) >= 20 and len(clips("amc")) >= 6
