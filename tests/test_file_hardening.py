"""Hostile files: every class of hostile or odd file gives one named error and exit code 2.

Each test reproduces one class found by the hostile review (a traceback, a hang or a lost
batch on the code before the fix) on a mutated copy of a real CMU clip.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cmu import DATA

from streamkey.cli import main

CLIP = DATA / "07_01.bvh"
TEXT = CLIP.read_text()
TRACEBACK = "Traceback"


def mutate(tmp_path: Path, old: str, new: str, name: str = "m.bvh", count: int = 1,
           text: str = TEXT) -> Path:
    assert old in text
    out = tmp_path / name
    out.write_text(text.replace(old, new, count))
    return out


def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def assert_named_error(code: int, err: str, path: Path | str, line: int | None = None) -> None:
    assert code == 2, err
    assert TRACEBACK not in err
    errors = [e for e in err.splitlines() if e.startswith("error: ")]
    assert errors, err
    where = f"{path}:{line}:" if line is not None else f"{path}"
    assert any(e.startswith(f"error: {where}") for e in errors), err


def frames_of(n: int, start: int = 5) -> str:
    """07_01 cut to `n` rows (from row `start`)."""
    head, body = TEXT.split("MOTION\n", 1)
    rows = body.splitlines()[2:]
    return head + f"MOTION\nFrames: {n}\nFrame Time: .0083333\n" + "\n".join(
        rows[start:start + n]) + ("\n" if n else "")


# --- number grammar: str.isdigit / float() accepted non-ASCII digits ---------------------

@pytest.mark.parametrize(("old", "new", "line"), [
    ("Frames: 317", "Frames: \u00b2", 186),                     # superscript two
    ("CHANNELS 3", "CHANNELS \u00b3", 9),                         # superscript three
    ("Frames: 317", "Frames: \u0663\u0661\u0667", 186),          # Arabic-Indic 317
    ("Frame Time: .0083333", "Frame Time: 0.00_83333", 187),     # float() takes underscores
])
def test_counts_and_times_follow_an_ascii_number_grammar(tmp_path, capsys, old, new, line):
    path = mutate(tmp_path, old, new)
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path, line)


def test_frame_values_in_unicode_digits_are_refused(tmp_path, capsys):
    head, body = TEXT.split("MOTION\n", 1)
    lines = body.splitlines()
    lines[5] = lines[5].replace("0", "\u0660", 1)  # float('\u0660') == 0.0
    path = tmp_path / "u.bvh"
    path.write_text(head + "MOTION\n" + "\n".join(lines) + "\n")
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path, 191)


def test_amc_frame_numbers_follow_the_grammar(tmp_path, capsys):
    (tmp_path / "09.asf").write_text((DATA / "09.asf").read_text())
    lines = (DATA / "09_06.amc").read_text().splitlines()
    at = lines.index("2")
    lines[at] = "\u00b2"
    path = tmp_path / "09_06.amc"
    path.write_text("\n".join(lines) + "\n")
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path, at + 1)


# --- frame time and rates range-checked where they enter ---------------------------------

@pytest.mark.parametrize("value", ["5e-324", "1e300", "100", "0.00001", "-0.0083333"])
def test_frame_time_outside_1e4_to_10_seconds_is_refused(tmp_path, capsys, value):
    path = mutate(tmp_path, "Frame Time: .0083333", f"Frame Time: {value}")
    code, _, err = cli(capsys, "extract", str(path), "--method", "all")
    assert_named_error(code, err, path, 187)
    assert "0.0001 <= T <= 10 seconds" in err


def test_replay_refuses_a_file_with_frame_time_100_and_an_absurd_rate(tmp_path, capsys):
    path = mutate(tmp_path, "Frame Time: .0083333", "Frame Time: 100")
    code, _, err = cli(capsys, "replay", str(path), "--to", "osc://127.0.0.1:9")
    assert_named_error(code, err, path, 187)
    for args in (["--rate", "1e-300"], ["--rate", "nan"], ["--speed", "1e-300"],
                 ["--frames", "-1"]):
        code, _, err = cli(capsys, "replay", str(CLIP), "--to", "-", *args)
        assert code == 2 and err.startswith("error: replay") and TRACEBACK not in err, err


def test_pacing_refuses_an_interval_it_cannot_sleep():
    from streamkey.errors import UsageError
    from streamkey.replay.pacing import paced

    with pytest.raises(UsageError):
        next(paced(iter([1]), 1e300))
    with pytest.raises(UsageError):
        next(paced(iter([1]), float("nan")))


# --- structure limits: depth, channels, size ---------------------------------------------

def deep_bvh(depth: int) -> str:
    out = ["HIERARCHY", "ROOT r", "{", "OFFSET 0 0 0",
           "CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation"]
    for i in range(depth):
        out += [f"JOINT j{i}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Yrotation Xrotation"]
    out += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * (depth + 1)
    n = 6 + 3 * depth
    return "\n".join(out + ["MOTION", "Frames: 2", "Frame Time: 0.0083333", " ".join(["0"] * n),
                            " ".join(["1"] * n)]) + "\n"


def test_a_1500_deep_hierarchy_is_refused_without_recursion(tmp_path, capsys):
    path = tmp_path / "deep.bvh"
    path.write_text(deep_bvh(1500))
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path)
    assert "at most 256 nested joints" in err


def test_a_deep_but_allowed_hierarchy_round_trips(tmp_path):
    from streamkey.bvh import format_bvh, parse_bvh

    motion = parse_bvh(deep_bvh(200))
    again = parse_bvh(format_bvh(motion))
    assert again.skeleton.parents == motion.skeleton.parents
    assert np.array_equal(again.channels, motion.channels)


def test_a_joint_with_four_rotation_channels_is_refused(tmp_path, capsys):
    path = mutate(tmp_path, "CHANNELS 3 Zrotation Yrotation Xrotation",
                  "CHANNELS 4 Zrotation Yrotation Xrotation Xrotation")
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path, 9)
    assert "each at most once a joint" in err


def test_a_file_over_the_size_limit_is_refused_before_reading(tmp_path, capsys):
    from streamkey.inputs import MAX_FILE_BYTES

    path = tmp_path / "huge.bvh"
    with open(path, "wb") as fh:
        fh.truncate(MAX_FILE_BYTES + 1)  # sparse: nothing is written
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path)
    assert "MiB limit" in err


# --- degenerate skeletons refused at load (not guarded inside evaluate) --------------------

def test_all_offsets_zero_is_refused_at_load_for_eval(tmp_path, capsys):
    folder = tmp_path / "clips"
    folder.mkdir()
    path = folder / "zero.bvh"
    path.write_text(re.sub(r"OFFSET\s+\S+\s+\S+\s+\S+", "OFFSET 0 0 0", TEXT))
    code, _, err = cli(capsys, "eval", str(folder), "-o", str(tmp_path / "ev"), "-q")
    assert_named_error(code, err, "no clip could be evaluated: " + str(path))
    assert "body height" in err


def test_tiny_offsets_are_refused_at_load_for_sheet(tmp_path, capsys):
    path = tmp_path / "tiny.bvh"
    path.write_text(re.sub(r"OFFSET\s+\S+\s+\S+\s+\S+", "OFFSET 1e-300 1e-300 1e-300", TEXT))
    code, _, err = cli(capsys, "sheet", str(path), "-o", str(tmp_path / "s.png"))
    assert_named_error(code, err, path)


def test_an_asf_bone_length_of_1e308_is_refused(tmp_path, capsys):
    asf = (DATA / "09.asf").read_text()
    at = asf.index(":bonedata")
    (tmp_path / "09.asf").write_text(asf[:at] + re.sub(r"length \S+", "length 1e308",
                                                       asf[at:], count=1))
    (tmp_path / "09_06.amc").write_text((DATA / "09_06.amc").read_text())
    code, _, err = cli(capsys, "eval", str(tmp_path), "-o", str(tmp_path / "ev"), "-q")
    assert code == 2 and TRACEBACK not in err
    assert f"{tmp_path / '09.asf'}:" in err and "bone length" in err


# --- files that are not regular, and OS errors ------------------------------------------

def run_cli(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "streamkey", *args], capture_output=True,
                          text=True, timeout=timeout)


def test_a_fifo_and_a_symlink_to_dev_zero_are_refused_without_blocking(tmp_path):
    fifo = tmp_path / "f.bvh"
    os.mkfifo(fifo)
    zero = tmp_path / "zero.bvh"
    zero.symlink_to("/dev/zero")
    for path in (fifo, zero):
        done = run_cli("extract", str(path), timeout=60)
        assert done.returncode == 2 and TRACEBACK not in done.stderr
        assert f"error: {path}: is not a regular file" in done.stderr


def test_os_errors_become_one_line_naming_the_path(tmp_path, capsys):
    loop = tmp_path / "loop1.bvh"
    loop.symlink_to(tmp_path / "loop2.bvh")
    (tmp_path / "loop2.bvh").symlink_to(loop)
    through = Path(str(CLIP) + "/x.bvh")
    folder = tmp_path / "dir.bvh"
    folder.mkdir()
    (folder / "a.txt").write_text("x")
    for path, reason in ((loop, "symbolic links"), (through, "not a directory"),
                         (tmp_path / ("x" * 300 + ".bvh"), "file name too long")):
        code, _, err = cli(capsys, "extract", str(path))
        assert_named_error(code, err, path)
        assert reason in err
    code, _, err = cli(capsys, "extract", str(folder))
    assert_named_error(code, err, folder)
    code, _, err = cli(capsys, "extract", str(CLIP), "-o", str(tmp_path / "no" / "k.json"))
    assert_named_error(code, err, tmp_path / "no" / "k.json")


def test_an_os_error_while_reading_is_named(tmp_path, capsys):
    """/proc/self/mem is a regular file whose first read fails (EIO), even for root."""
    path = tmp_path / "mem.bvh"
    path.symlink_to("/proc/self/mem")
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path)
    assert "input/output error" in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files without read permission")
def test_an_unreadable_file_is_named(tmp_path, capsys):
    path = tmp_path / "locked.bvh"
    path.write_text(TEXT)
    path.chmod(0)
    code, _, err = cli(capsys, "extract", str(path))
    assert_named_error(code, err, path)
    assert "permission denied" in err


def test_non_utf8_file_names_work_in_extract_csv_eval_and_sheet(tmp_path):
    raw = os.fsencode(tmp_path) + b"/n\xff.bvh"
    os.symlink(CLIP, raw)
    name = os.fsdecode(raw)
    out = tmp_path / "k.csv"
    done = run_cli("extract", name, "--format", "csv", "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert raw in out.read_bytes()
    folder = tmp_path / "clips"
    folder.mkdir()
    os.symlink(CLIP, os.fsencode(folder) + b"/n\xff.bvh")
    done = run_cli("eval", str(folder), "-o", str(tmp_path / "ev"), "-q")
    assert done.returncode == 0, done.stderr
    assert b"n\xff.bvh" in (tmp_path / "ev" / "equal_count.md").read_bytes()
    done = run_cli("sheet", name, "-o", str(tmp_path / "s.png"))
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "s.png").stat().st_size > 1000


# --- valid but odd clips: a result or a named error -------------------------------------

def test_zero_frames_give_a_named_error_in_extract_and_run_without_hanging(tmp_path):
    path = tmp_path / "z.bvh"
    path.write_text(frames_of(0))
    done = run_cli("extract", str(path), "--method", "all")
    assert done.returncode == 2 and f"error: {path}: expected at least 1" in done.stderr
    done = run_cli("run", "--from", str(path), "--idle-exit", "1", "--fast", timeout=60)
    assert done.returncode == 2, done.stderr
    assert f"error: {path}: expected at least 1 captured frame" in done.stderr
    assert TRACEBACK not in done.stderr


@pytest.mark.parametrize("n", [1, 2, 3])
def test_one_to_three_frames_and_a_still_pose_never_trace_back(tmp_path, capsys, n):
    short = tmp_path / f"n{n}.bvh"
    short.write_text(frames_of(n))
    head, body = TEXT.split("MOTION\n", 1)
    still = tmp_path / "still.bvh"
    still.write_text(head + "MOTION\nFrames: 200\nFrame Time: .0083333\n"
                     + (body.splitlines()[7] + "\n") * 200)
    for args in (["--method", "all"], ["--online", "--method", "all"]):
        code, out, err = cli(capsys, "extract", str(short), str(still), "-q", *args)
        assert code in (0, 2) and TRACEBACK not in err
        for line in err.splitlines():
            assert line.startswith((f"error: {short}:", f"error: {still}:")), line
        assert '"file"' in out
    code, _, err = cli(capsys, "sheet", str(still), "-o", str(tmp_path / "s.png"))
    assert_named_error(code, err, still)


def test_a_still_pose_gets_every_counted_method_with_both_ends(tmp_path, capsys):
    head, body = TEXT.split("MOTION\n", 1)
    still = tmp_path / "still.bvh"
    still.write_text(head + "MOTION\nFrames: 200\nFrame Time: .0083333\n"
                     + (body.splitlines()[7] + "\n") * 200)
    code, out, err = cli(capsys, "extract", str(still), "--method", "saliency,uniform,decimate")
    assert code == 0, err

    methods = json.loads(out)["files"][0]["methods"]
    assert methods["saliency"]["keyframes"] == []
    assert methods["uniform"]["keyframes"] == [0, 199]


# --- section 2: one bad file must not lose the batch ------------------------------------

def batch_folder(tmp_path: Path) -> tuple[Path, Path, Path]:
    folder = tmp_path / "batch"
    folder.mkdir()
    for name in ("07_01.bvh", "09_06.amc", "09.asf"):
        (folder / name).write_text((DATA / name).read_text())
    bad = folder / "bad.bvh"
    bad.write_text(re.sub(r"OFFSET\s+\S+\s+\S+\s+\S+", "OFFSET 0 0 0", TEXT))
    short = folder / "short.bvh"
    short.write_text(frames_of(1))
    return folder, bad, short


@pytest.mark.parametrize("online", [False, True])
def test_extract_dir_with_broken_files_writes_the_good_results(tmp_path, capsys, online):
    folder, bad, short = batch_folder(tmp_path)
    out = tmp_path / "keys.json"
    extra = ["--online", "--method", "all"] if online else ["--method", "all"]
    code, _, err = cli(capsys, "extract", str(folder), "-q", "-o", str(out), *extra)
    assert code == 2 and TRACEBACK not in err
    files = {Path(f["file"]).name: f for f in json.loads(out.read_text())["files"]}
    assert set(files) == {"07_01.bvh", "09_06.amc", "bad.bvh", "short.bvh"}
    assert files["07_01.bvh"]["methods"]["saliency"]["keyframes"]
    assert files["09_06.amc"]["methods"]["saliency"]["keyframes"]
    assert files["bad.bvh"]["error"].startswith(f"{bad}:")
    assert f"error: {bad}:" in err
    # a 1-frame clip is valid input offline as online: its one frame is every counted
    # method's key
    assert "error" not in files["short.bvh"] and f"error: {short}" not in err
    assert files["short.bvh"]["methods"]["uniform" if not online else "simplify"][
        "keyframes"] == [0]


def test_eval_dir_with_a_broken_file_writes_the_tables_and_exits_2(tmp_path, capsys):
    folder, bad, _ = batch_folder(tmp_path)
    out = tmp_path / "ev"
    code, stdout, err = cli(capsys, "eval", str(folder), "-o", str(out), "-q")
    assert code == 2 and TRACEBACK not in err
    table = (out / "equal_count.md").read_text()
    assert "07_01.bvh" in table and "09_06.amc" in table
    assert f"error: {bad}:" in err
    assert str(bad) in (out / "errors.txt").read_text()
    assert "wrote" in stdout


def test_a_one_frame_clip_is_keyed_by_a_counted_method_as_online(tmp_path, capsys):
    """One captured frame: uniform sampling (which needs two ends) keys that frame, as the
    online keyframers do, instead of failing the clip."""
    short = tmp_path / "one.bvh"
    short.write_text(frames_of(1))
    code, out, err = cli(capsys, "extract", str(short), "--method", "uniform")
    assert code == 0 and TRACEBACK not in err and not err
    assert json.loads(out)["files"][0]["methods"]["uniform"]["keyframes"] == [0]



def test_run_from_a_file_whose_skeleton_lacks_roles_names_the_file(tmp_path, capsys):
    path = mutate(tmp_path, "LeftUpLeg", "Yyy", count=2)
    code, _, err = cli(capsys, "run", "--from", str(path), "--fast", "--to",
                       f"jsonl:{tmp_path / 'e.jsonl'}")
    assert_named_error(code, err, path)
    assert "roles" in err and not (tmp_path / "e.jsonl").exists()
