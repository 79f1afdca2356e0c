"""Input edges a fuzzer found in files: a UTF-8 byte-order mark at the start of a BVH, ASF or
AMC file (was refused), a still clip (was "1 captured frame" offline, so `extract
--method all` refused it while `--online` took it), and a reference frame plus one captured
frame (uniform and decimate refused it offline, exit 2, while `--online` gave its key, exit
0). Real CMU clips, mutated copies."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cmu import DATA

from streamkey.amc import read_amc, read_asf
from streamkey.bvh import read_bvh
from streamkey.cli import main

BOM = "\ufeff"


def with_bom(src: Path, dst: Path) -> Path:
    dst.write_text(BOM + src.read_text(encoding="utf-8"), encoding="utf-8")
    assert dst.read_bytes().startswith(b"\xef\xbb\xbf")
    return dst


def extract(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, dict, str]:
    code = main(["extract", *args, "-q"])
    out, err = capsys.readouterr()
    return code, json.loads(out) if code == 0 else {}, err


def test_a_bvh_with_a_byte_order_mark_reads_as_without(tmp_path, capsys):
    plain = read_bvh(DATA / "07_01.bvh")
    marked = with_bom(DATA / "07_01.bvh", tmp_path / "07_01.bvh")
    motion = read_bvh(marked)
    assert motion.skeleton.names == plain.skeleton.names
    assert np.array_equal(motion.channels, plain.channels)
    assert (motion.fps, motion.first_frame) == (plain.fps, plain.first_frame)
    code, out, err = extract(capsys, str(marked), "--method", "simplify")
    assert code == 0 and "Traceback" not in err, err
    want = extract(capsys, str(DATA / "07_01.bvh"), "--method", "simplify")[1]
    assert out["files"][0]["methods"] == want["files"][0]["methods"]


def test_asf_and_amc_with_byte_order_marks_read_as_without(tmp_path, capsys):
    asf = with_bom(DATA / "07.asf", tmp_path / "07.asf")
    amc = with_bom(DATA / "07_05.amc", tmp_path / "07_05.amc")
    assert read_asf(asf).names == read_asf(DATA / "07.asf").names
    plain, motion = read_amc(DATA / "07_05.amc"), read_amc(amc)
    assert np.array_equal(motion.channels, plain.channels)
    code, out, err = extract(capsys, str(amc), "--method", "simplify")
    assert code == 0 and "Traceback" not in err, err
    assert out["files"][0]["frames"] == plain.n_frames


def _still(tmp_path: Path, row: str | None, name: str) -> Path:
    """07_01's skeleton with 100 copies of one frame (`row`; None: every channel zero)."""
    head, body = (DATA / "07_01.bvh").read_text().split("MOTION\n", 1)
    rows = body.splitlines()[2:]
    frame = row if row is not None else " ".join("0" for _ in rows[0].split())
    path = tmp_path / name
    path.write_text(head + "MOTION\nFrames: 100\nFrame Time: .0083333\n"
                    + (frame + "\n") * 100)
    return path


@pytest.mark.parametrize("pose", ["rest", "captured"])
def test_a_still_clip_is_valid_input_offline_and_online_alike(tmp_path, capsys, pose):
    rows = (DATA / "07_01.bvh").read_text().split("MOTION\n", 1)[1].splitlines()[2:]
    path = _still(tmp_path, None if pose == "rest" else rows[50], f"still_{pose}.bvh")
    motion = read_bvh(path)
    assert (motion.n_frames, motion.first_frame) == (100, 0)  # not "1 captured frame"
    code, offline, err = extract(capsys, str(path), "--method", "all")
    assert code == 0 and "Traceback" not in err, err
    code, online, err = extract(capsys, str(path), "--online", "--method", "all")
    assert code == 0 and "Traceback" not in err, err
    off, on = offline["files"][0]["methods"], online["files"][0]["methods"]
    for name, result in off.items():  # empty, the two ends, or evenly spread (isodata)
        keys = result["keyframes"]
        assert keys == sorted(set(keys)) and all(0 <= k < 100 for k in keys), (name, keys)
    assert off["saliency"]["keyframes"] == off["speed"]["keyframes"] == []  # nothing moves
    assert off["simplify"]["keyframes"] == off["optimal"]["keyframes"] == [0, 99]
    assert {m: r["keyframes"] for m, r in on.items()} == {
        m: off[m]["keyframes"] for m in on}


def test_a_reference_frame_plus_one_captured_frame_is_one_key_offline_and_online(
        tmp_path, capsys):
    """07_05's T-pose reference frame and its first captured frame: every method that keys
    the ends gives that frame, both ways, exit 0 (as for a still clip)."""
    head, body = (DATA / "07_05.bvh").read_text().split("MOTION\n", 1)
    lines = body.splitlines()
    path = tmp_path / "07_05_one.bvh"
    path.write_text(head + "MOTION\nFrames: 2\n" + lines[1] + "\n" + "\n".join(lines[2:4])
                    + "\n")
    motion = read_bvh(path)
    assert (motion.n_frames, motion.first_frame) == (2, 1)  # one captured frame
    code, offline, err = extract(capsys, str(path), "--method", "all")
    assert code == 0 and "error" not in err, err
    code, online, err = extract(capsys, str(path), "--online", "--method", "all")
    assert code == 0 and "error" not in err, err
    off, on = offline["files"][0]["methods"], online["files"][0]["methods"]
    assert {m: r["keyframes"] for m, r in off.items()} == {
        "saliency": [], "speed": [], "simplify": [1], "uniform": [1], "decimate": [1],
        "isodata": [1], "curvefit": [1], "optimal": [1]}
    assert {m: r["keyframes"] for m, r in on.items()} == {m: off[m]["keyframes"] for m in on}


@pytest.mark.parametrize(("address", "said"), [
    ("out.jsonl", "a file is not an address (for a JSON Lines file of the events write "
                  "jsonl:out.jsonl)"),
    ("README.md", "a file is not an address"),
    ("127.0.0.1:9000", "the scheme is missing (osc://127.0.0.1:9000, zmq+tcp://127.0.0.1:9000"),
    ("osc:/127.0.0.1:9000", "an address needs two slashes: osc://127.0.0.1:9000"),
    ("foo://127.0.0.1:9000", "unknown scheme 'foo'"),
])
def test_an_address_that_is_a_file_or_lacks_a_scheme_is_told_what_it_looks_like(
        capsys, address, said):
    code = main(["replay", str(DATA / "07_01.bvh"), "--to", address])
    err = capsys.readouterr().err
    assert code == 2 and said in err and "Traceback" not in err, err
    assert err.startswith(f"error: address {address!r}: ")
