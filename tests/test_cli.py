from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest
from cmu import DATA

from streamkey.cli import main


def test_extract_writes_the_documented_json_schema(tmp_path, capsys):
    out = tmp_path / "keys.json"
    code = main(["extract", str(DATA / "07_01.bvh"), str(DATA / "07_05.amc"), "--method", "all",
                 "-o", str(out), "-q"])
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc["schema"] == 2
    assert [f["file"] for f in doc["files"]] == [str(DATA / "07_01.bvh"), str(DATA / "07_05.amc")]
    for entry in doc["files"]:
        assert set(entry["methods"]) == {"saliency", "speed", "simplify", "uniform", "decimate",
                                         "isodata", "curvefit", "optimal"}
        for name, result in entry["methods"].items():
            keys = result["keyframes"]
            assert keys == sorted(set(keys)) and len(keys) == len(result["scores"]) > 0, name
            assert len(result["strength"]) == len(keys)
            assert all(0.0 <= s <= 1.0 for s in result["strength"]), name
            assert all(entry["first_frame"] <= k < entry["frames"] for k in keys)
            assert isinstance(result["params"], dict)
        sal = len(entry["methods"]["saliency"]["keyframes"])
        assert len(entry["methods"]["uniform"]["keyframes"]) == sal
        assert len(entry["methods"]["decimate"]["keyframes"]) == sal


def test_extract_csv_has_one_row_per_keyframe(tmp_path):
    out = tmp_path / "keys.csv"
    assert main(["extract", str(DATA / "07_01.bvh"), "--method", "speed", "--format", "csv",
                 "-o", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0] == "file,method,frame,time,score"
    assert 3 <= len(lines) - 1 <= 5


def test_bad_bvh_prints_one_error_line_and_exits_2_without_traceback(tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 1 Xposition\n}\n")
    result = subprocess.run([sys.executable, "-m", "streamkey", "extract", str(bad)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith(f"error: {bad}:")
    assert "MOTION" in result.stderr


def test_verbose_isodata_prints_its_derived_thresholds(capsys):
    assert main(["extract", str(DATA / "07_01.bvh"), "--method", "isodata", "-v", "-q"]) == 0
    err = capsys.readouterr().err
    assert "isodata: N=316" in err and "D_T=" in err


def test_missing_input_and_unknown_method_exit_2(tmp_path, capsys):
    assert main(["extract", str(tmp_path / "nope.bvh")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert main(["extract", str(DATA / "07_01.bvh"), "--method", "magic"]) == 2
    assert "unknown method" in capsys.readouterr().err


def test_demo_runs_on_the_embedded_motion_without_data(capsys):
    assert main(["demo", "--seconds", "8"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("demo motion: 960 frames")
    for method in ("saliency", "speed", "simplify"):
        assert re.search(rf"^t=\s*[\d.]+s\s+{method}\s+keyframe\s+\d+", out, re.M), method
    assert "done: 960 frames" in out


def test_offline_demo_prints_every_method(capsys):
    assert main(["demo", "--offline", "--seconds", "8"]) == 0
    out = capsys.readouterr().out
    for method in ("saliency", "speed", "simplify", "uniform", "decimate"):
        assert f"{method}:" in out


def test_decimate_and_simplify_take_the_space_switch_positions_by_default(tmp_path):
    from streamkey.amc import read_motion
    from streamkey.features import compute_features
    from streamkey.methods import baselines, simplify

    m = read_motion(DATA / "06_15.bvh")
    for space in (None, "channels"):
        out = tmp_path / f"{space}.json"
        args = ["extract", str(DATA / "06_15.bvh"), "--method", "decimate,simplify",
                "--count", "20", "-o", str(out), "-q"] + (["--space", space] if space else [])
        assert main(args) == 0
        methods = json.loads(out.read_text())["files"][0]["methods"]
        want = space or "positions"
        # the CLI's decimate runs on the features extract shares (behind the noise filter)
        feats = compute_features(m)
        for name, fn in (("decimate", lambda mo, k, space, f=feats: baselines.decimate(
                             mo, k, space=space, features=f)),
                         ("simplify", lambda mo, k, space: simplify.extract(mo, count=k,
                                                                           space=space))):
            assert methods[name]["params"]["space"] == want
            assert methods[name]["keyframes"] == fn(m, 20, space=want).frames.tolist()


def test_count_on_an_online_method_that_cannot_honour_it_is_refused_up_front(capsys):
    clip = str(DATA / "07_01.bvh")
    for argv in (["run", "--from", clip, "--fast", "--count", "5"],
                 ["extract", "--online", "--method", "all", "--count", "5", clip, "-q"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: --count: online simplify and optimal cannot aim at a "
                              "key count")
        assert "Traceback" not in err and err.count("\n") == 1


def test_library_extract_equals_the_cli_with_max_gap_and_min_interval(tmp_path):
    """`--max-gap` and `--min-interval` are library options: `batch.extract_files(...)` and
    `extract_files_online(...)` with them give the bytes `streamkey extract` writes."""
    from pathlib import Path

    from streamkey.batch import extract_files, extract_files_online, results_json

    paths = [DATA / "07_01.bvh", DATA / "05_06.bvh"]
    methods = ["saliency", "speed"]
    for online in (False, True):
        out = tmp_path / f"cli{online}.json"
        argv = ["extract", *map(str, paths), "--method", ",".join(methods), "-q", "-o",
                str(out), "--max-gap", "0.8", "--min-interval", "saliency=0.3,speed=0.2"]
        assert main(argv + (["--online"] if online else [])) == 0
        run = extract_files_online if online else extract_files
        results = list(run([Path(p) for p in paths], methods, max_gap=0.8,
                           min_interval={"saliency": 0.3, "speed": 0.2}))
        lib = results_json(results)
        assert lib == out.read_text(), online
        params = [m["params"] for f in json.loads(lib)["files"] for m in f["methods"].values()]
        assert all(p["max_gap"] == 0.8 and p["min_interval"] in (0.3, 0.2) for p in params)
        if not online:  # both did something: keys added in long gaps, close keys dropped
            infos = [k.info for r in results for k in r.results.values()]
            assert any(i["max_gap_added"] for i in infos)
            assert any(i["min_interval_dropped"] for i in infos)


KERNELS = '''
from streamkey.jit import kernel

@kernel
def step(x):
    return 2.0 * x + 1.0

@kernel
def total(a):
    s = 0.0
    for v in a:
        s += step(v)
    return s
'''


def test_a_cold_kernel_cache_prints_progress_per_kernel_and_a_warm_one_nothing(tmp_path):
    (tmp_path / "ff_sample_kernels.py").write_text(KERNELS)
    code = ("import sys, numpy; sys.path.insert(0, sys.argv[1]); "
            "import streamkey.cli.compiling as c; c.HEARTBEAT_S = 0.02; c.report_compilation(); "
            "import ff_sample_kernels as k; print(k.total(numpy.arange(3.0)))")
    env = {**__import__("os").environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    cold = subprocess.run([sys.executable, "-P", "-c", code, str(tmp_path)], env=env,
                          capture_output=True, text=True, timeout=300, check=True)
    assert cold.stdout.strip() == "9.0"
    lines = cold.stderr.splitlines()
    assert lines[0].startswith("compiling kernels for this machine (once")
    done = [ln for ln in lines if re.match(r"compiling kernels \d+/\d+: ", ln)]
    # the callee compiles inside its caller: both named, callee first
    assert [ln.split(":")[1].split()[0] for ln in done] == ["ff_sample_kernels.step",
                                                            "ff_sample_kernels.total"]
    # N/M: M counts every kernel imported so far (here also the package's own)
    assert re.match(r"compiling kernels 2/\d+: ", done[-1])
    assert any(ln.startswith("  still compiling ff_sample_kernels.") for ln in lines)
    warm = subprocess.run([sys.executable, "-P", "-c", code, str(tmp_path)], env=env,
                          capture_output=True, text=True, timeout=300, check=True)
    assert warm.stdout.strip() == "9.0" and "compiling" not in warm.stderr


def test_extract_of_one_long_file_is_never_silent_for_long(tmp_path, capsys, monkeypatch):
    from streamkey.cli import common

    monkeypatch.setattr(common, "HEARTBEAT_S", 0.05)
    # 01_06 (43 s): every method takes ~0.7 s on it warm; 07_01 (2.6 s) took 0.055 s once the
    # process had keyed it before, a hair over the heartbeat, and the test flickered
    assert main(["extract", str(DATA / "01_06.bvh"), "--method", "all",
                 "-o", str(tmp_path / "keys.json")]) == 0
    beats = [ln for ln in capsys.readouterr().err.splitlines()
             if ln.startswith("  ... 01_06.bvh [1/1] (")]
    assert beats, "no progress line while the file was worked on"
    assert main(["extract", str(DATA / "01_06.bvh"), "--method", "all", "-q",
                 "-o", str(tmp_path / "keys.json")]) == 0
    assert "..." not in capsys.readouterr().err


def test_bench_offline_and_online_have_help():
    out = subprocess.run([sys.executable, "-m", "streamkey", "bench", "--help"],
                         capture_output=True, text=True, check=True).stdout
    flat = " ".join(out.split())
    assert "--offline offline methods:" in flat and "--online online keyframers:" in flat


def test_run_from_a_file_of_another_kind_or_a_one_slash_address_says_what_would_work(capsys):
    for source, expected in (
            ("README.md", "run --from README.md: not a BVH (.bvh) or AMC (.amc) file; run "
                          "replays a BVH or AMC file, or listens on a live source: osc://"),
            ("osc:/127.0.0.1:9000", "run --from osc:/127.0.0.1:9000: an address needs two "
                                    "slashes: osc://127.0.0.1:9000"),
            ("take-that-is-not-here", "neither a file nor an address")):
        assert main(["run", "--from", source]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and expected in err and err.count("\n") == 1, err


def test_a_busy_port_is_worded_the_same_for_every_listener(capsys):
    import socket

    from streamkey.cli.main import BUSY_HINT

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp, socket.socket() as tcp:
        udp.bind(("127.0.0.1", 0))
        tcp.bind(("127.0.0.1", 0))
        tcp.listen()
        u, t = udp.getsockname()[1], tcp.getsockname()[1]
        clip = str(DATA / "07_01.bvh")
        for argv, where in (
                (["run", "--from", f"osc://127.0.0.1:{u}", "--skeleton", clip], u),
                (["run", "--from", clip, "--to", f"ws://127.0.0.1:{t}"], t),
                (["run", "--from", clip, "--dashboard", str(t)], t)):
            assert main([*argv, "--method", "simplify"]) == 2
            err = capsys.readouterr().err.strip().splitlines()[-1]
            assert err.endswith(f"cannot listen on 127.0.0.1:{where}: {BUSY_HINT}"), err


def test_ctrl_c_interrupts_a_folder_extract_with_exit_130_and_says_so(tmp_path):
    import signal

    proc = subprocess.Popen([sys.executable, "-m", "streamkey", "extract", str(DATA),
                             "--method", "all", "-o", str(tmp_path / "keys.json")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        while not proc.stderr.readline().startswith("[2/"):  # well into the batch
            assert proc.poll() is None
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130
    assert "interrupted: extract stopped by Ctrl-C before it finished" in err
    assert "Traceback" not in err and not (tmp_path / "keys.json").exists()


def test_demo_dashboard_logs_the_session_outside_the_current_folder(tmp_path):
    import signal

    cwd, sessions = tmp_path / "cwd", tmp_path / "sessions"
    cwd.mkdir()
    env = {**__import__("os").environ, "STREAMKEY_SESSIONS": str(sessions)}
    proc = subprocess.Popen([sys.executable, "-m", "streamkey", "demo", "--dashboard", "0",
                             "--seconds", "2"], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    lines = []
    try:
        while not any("dashboard on http" in ln for ln in lines):
            line = proc.stderr.readline()
            assert line, "".join(lines)
            lines.append(line)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    logs = list(sessions.glob("session-*.jsonl"))
    assert len(logs) == 1 and list(cwd.iterdir()) == []
    assert f"sending to jsonl:{logs[0]}" in "".join(lines)


def test_a_warm_demo_runs_the_four_keyframers_at_once(capfd):
    from streamkey.demo import run_demo

    assert run_demo(seconds=2.0) == 0  # paced at 120 Hz; the kernels are in the cache
    out, err = capfd.readouterr()
    assert "first run on this machine" not in err
    assert "done: 240 frames" in out


@pytest.mark.slow
def test_a_first_demo_shows_simplify_while_the_other_kernels_compile(tmp_path):
    """A cold kernel cache (a new machine): simplify's events come while the others compile
    in a background process, then the four keyframers run from the start."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    proc = subprocess.run([sys.executable, "-m", "streamkey", "demo", "--seconds", "3"],
                          env=env, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr
    out, err = proc.stdout, proc.stderr
    assert "first run on this machine" in err and "background: compiling kernels" in err
    assert "all kernels ready" in err
    methods = re.findall(r"^t=\s*[\d.]+s\s+(\w+)\s+keyframe", out, re.M)
    assert methods[:3] == ["simplify"] * 3  # the preview: simplify alone, live
    assert out.count("done: 360 frames") == 1  # then the demo itself, every keyframer
    assert {"saliency", "speed", "optimal"} <= set(methods[3:])


def test_the_long_memory_stream_of_bench_online_reports_progress_with_an_estimate():
    from streamkey.bench.core import _stream_memory
    from streamkey.replay.demo import demo_motion

    class Sink:
        def push(self, frame) -> None:
            pass

    said: list[str] = []
    _stream_memory(Sink, demo_motion(1.0), 96_001, said.append)
    assert len(said) == 2 and all(re.fullmatch(
        r"bench online: memory stream \d\d,000/96,001 frames, about \d+ s left", s) for s in said)
