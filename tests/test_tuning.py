"""Tuning in the open: every method parameter on the command line, grouped per
method; per-method lookahead; `--count` online refused; identical defaults offline and online;
gap bridging from the command line."""

from __future__ import annotations

import inspect
import json
import subprocess
import sys

import numpy as np
import pytest
from cmu import DATA, clips
from hypothesis import given, settings
from hypothesis import strategies as st
from live_helpers import MS, read_jsonl

from streamkey.amc import read_motion
from streamkey.batch import extract_motion
from streamkey.cli import _method_params, build_parser, main
from streamkey.errors import UsageError
from streamkey.keyframes import KeyframeEvent
from streamkey.methods import (
    OFFLINE_METHODS,
    ONLINE_METHODS,
    offline_method,
    online_class,
    saliency,
)
from streamkey.online import Pipeline
from streamkey.streaming import make_keyframers, run_online

CMD = [sys.executable, "-m", "streamkey"]
CLIP = str(DATA / "07_01.bvh")

# (flag, value on the command line, value in params) of every method parameter
OPTION = {
    "sigma": ("--sigma", "4", 4.0), "k": ("--k", "8", 8), "contact": ("--no-contact", None, False),
    "preset": ("--preset", "high", "high"), "variance_rule": ("--variance-rule", None, True),
    "update_every": ("--update-every", "600", 600), "history": ("--history", "900", 900),
    "f_c": ("--f-c", "6", 6.0), "f_max": ("--f-max", "5", 5.0), "f_min": ("--f-min", "0.5", 0.5),
    "r": ("--scale-ratio", "0.9", 0.9), "mojena_k": ("--mojena-k", "2", 2.0),
    "cut": ("--cut", "mojena", "mojena"),
    "hop": ("--hop", "6", 6), "cutoff_history": ("--cutoff-history", "3000", 3000),
    "warmup_candidates": ("--warmup-candidates", "10", 10),
    "segment_statistics": ("--segment-statistics", None, True),
    "ratio": ("--ratio", "0.1", 0.1), "space": ("--space", "channels", "channels"),
    "merge": ("--merge", "4", 4), "max_span": ("--max-span", "900", 900),
    "count": ("--count", "12", 12), "rate": ("--rate", "4", 4.0), "lam": ("--lam", "0.01", 0.01),
    "max_segment": ("--max-segment", "1.5", 1.5),
    "root_translation": ("--root-translation", None, True),
    "hold_keys": ("--hold-keys", None, True),
    "cluster_seconds": ("--cluster-seconds", "0.3", 0.3), "max_merges": ("--max-merges", "3", 3),
    "outlier_fence": ("--outlier-fence", "5", 5.0), "smooth": ("--smooth", "2", 2.0),
    "key_cost": ("--key-cost", "0.5", 0.5), "tol": ("--curvefit-tol", "0.01", 0.01),
    "max_passes": ("--max-passes", "20", 20), "lookahead": ("--lookahead", "90", 90),
}
TOLERANCE = {"simplify": ("--simplify-tolerance", "0.05", 0.05),
             "optimal": ("--optimal-tolerance", "0.002", 0.002)}
# Not command-line parameters: shared inputs, identity, wiring, a per-joint array, a callback
# (`-v` sets isodata's verbose + log), the gap bridging (`--max-bridge`, tested below) and the
# noise front end every method shares (`--noise-cutoff`, tested in test_noise_filter.py).
NOT_OPTIONS = {"motion", "features", "skeleton", "fps", "stream", "role_mapping", "weights",
               "log", "verbose", "max_bridge_frames", "noise_cutoff_hz", "segments"}


def _parameters(fn) -> list[str]:
    return [n for n, p in inspect.signature(fn).parameters.items()
            if n not in NOT_OPTIONS and p.kind is not inspect.Parameter.VAR_KEYWORD]


def _option(method: str, name: str) -> tuple[str, str | None, object]:
    return TOLERANCE[method] if name == "tolerance" else OPTION[name]


def _subparser(command: str):
    return next(a for a in build_parser()._actions if a.dest == "command").choices[command]


def _groups(command: str) -> dict[str, set[str]]:
    return {g.title: {s for a in g._group_actions for s in a.option_strings}
            for g in _subparser(command)._action_groups}


@pytest.mark.parametrize("command", ["run", "extract"])
def test_every_method_parameter_has_an_option_in_its_method_group(command):
    online = command == "run"
    groups = _groups(command)
    helptext = _subparser(command).format_help()
    names = ONLINE_METHODS if online else OFFLINE_METHODS
    for method in names:
        fns = [online_class(method)] if method in ONLINE_METHODS else []
        fns += [] if online else [offline_method(method)]
        for fn in fns:
            live = not online and fn is not offline_method(method)
            for name in _parameters(fn):
                flag, text, value = _option(method, name)
                # its method's group (decimate's --space: simplify's), or the shared one
                home = "simplify" if method == "decimate" else method
                titles = [t for t in groups if t.startswith(home + " ") or t == "every method"]
                assert any(flag in groups[t] for t in titles), (command, method, name, flag)
                assert flag in helptext
                argv = [command, *(["--from", CLIP] if online else [CLIP])]
                argv += ["--method", method, flag] + ([text] if text is not None else [])
                args = build_parser().parse_args(argv + (["--online"] if live else []))
                params = _method_params(args, online=online or live)
                assert params[method][name] == value, (command, method, name)
    assert "--max-bridge" in groups["every method"]
    assert "--noise-cutoff" in groups["every method"]


def test_tolerance_keeps_its_old_spelling_where_it_is_unambiguous(capsys):
    def params(*argv: str) -> dict:
        return _method_params(build_parser().parse_args(["extract", CLIP, *argv]))

    assert params("--method", "simplify", "--tolerance", "0.05")["simplify"]["tolerance"] == 0.05
    assert params("--method", "optimal", "--tolerance", "0.002")["optimal"]["tolerance"] == 0.002
    both = params("--method", "simplify,optimal", "--tolerance", "simplify=0.05,optimal=0.002")
    assert (both["simplify"]["tolerance"], both["optimal"]["tolerance"]) == (0.05, 0.002)
    assert main(["extract", CLIP, "--method", "simplify,optimal", "--tolerance", "0.05"]) == 2
    assert capsys.readouterr().err.startswith("error: --tolerance is ambiguous with both "
                                              "simplify (body heights) and optimal")


def test_lookahead_per_method_and_for_all(tmp_path):
    out = tmp_path / "keys.json"

    def lookaheads(*argv: str) -> dict[str, int]:
        assert main(["extract", "--online", CLIP, "-q", "-o", str(out), *argv]) == 0
        methods = json.loads(out.read_text())["files"][0]["methods"]
        return {m: v["params"]["lookahead"] for m, v in methods.items()}

    assert lookaheads("--method", "all", "--lookahead", "saliency=60,speed=90") == {
        "saliency": 60, "speed": 90, "simplify": 60, "optimal": 120}
    assert lookaheads("--method", "saliency,speed", "--lookahead", "100") == {
        "saliency": 100, "speed": 100}


@pytest.mark.parametrize("argv, message", [
    (["--lookahead", "salience=60"], "error: --lookahead: 'salience' is not a method"),
    (["--lookahead", "speed=6x"], "error: --lookahead: '6x' is not a whole number"),
    (["--method", "speed", "--lookahead", "saliency=60"],
     "error: --lookahead: saliency is not among the chosen methods (speed)"),
    (["--max-bridge", "lots"], "error: --max-bridge: 'lots' is not FRAMES"),
    (["--method", "saliency", "--count", "10"],
     "error: --count: none of the chosen methods (saliency) takes it"),
    (["--method", "speed", "--sigma", "3"],
     "error: --sigma is a saliency option, and saliency is not among the chosen methods"),
])
def test_bad_tuning_options_are_one_clear_line(argv, message, capsys):
    assert main(["run", "--from", CLIP, "--fast", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(message) and err.count("\n") == 1, err


def test_run_count_is_refused_by_the_real_cli():
    run = subprocess.run([*CMD, "run", "--from", CLIP, "--fast", "--count", "10"],
                         capture_output=True, text=True, timeout=60 * MS)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr == ("error: --count: online simplify and optimal cannot aim at a key "
                          "count (it needs the whole take); give a tolerance (simplify) or "
                          "--rate (optimal) instead; counts are offline (extract without "
                          "--online)\n")


@pytest.mark.parametrize("option", [["--lookahead", "50"], ["--max-bridge", "30"],
                                    ["--history", "600"], ["--update-every", "600"]])
def test_online_only_options_offline_ask_for_online(option, capsys):
    assert main(["extract", CLIP, *option]) == 2
    assert capsys.readouterr().err == f"error: {option[0]}: online only; add --online\n"


def test_extract_online_simplify_count_is_refused_by_the_real_cli():
    run = subprocess.run([*CMD, "extract", "--online", "--method", "simplify", "--count", "10",
                          CLIP], capture_output=True, text=True, timeout=60 * MS)
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr == ("error: --count: online simplify cannot aim at a key count (it needs "
                          "the whole take); give a tolerance (simplify) or --rate (optimal) "
                          "instead; counts are offline (extract without --online)\n")


AUTO_KEEPS_LOW = pytest.mark.xfail(strict=True, reason="measured: behind the default 5 Hz "
                                   "noise filter saliency's auto preset keeps low on 05_06 "
                                   "(offline and online; high without the filter)")


@pytest.mark.parametrize("name", [pytest.param("05_06.bvh", marks=AUTO_KEEPS_LOW), "07_05.bvh",
                                  "09_01.bvh"])
def test_offline_and_online_resolve_the_same_default_params_for_every_method(name):
    m = read_motion(DATA / name)
    offline = extract_motion(m, list(ONLINE_METHODS))
    online = run_online(m, list(ONLINE_METHODS))
    for method in ONLINE_METHODS:
        off, on = offline[method].params, online[method].params
        shared = set(_parameters(offline_method(method))) & set(_parameters(online_class(method)))
        assert shared & set(off) & set(on), method
        # a parameter a mode leaves unused (optimal's count in rate mode) is absent on both
        assert {k: off.get(k) for k in shared} == {k: on.get(k) for k in shared}, (name, method)
        common = (set(off) & set(on)) - {"lookahead", "online"}
        assert {k: off[k] for k in common} == {k: on[k] for k in common}, (name, method)
    # 05_06 (fast dance, 7 s) and 09_01 (a run, 1.2 s): "high"; 07_05 (slow walk): "low"
    want = "low" if name == "07_05.bvh" else "high"
    assert offline["saliency"].params["preset"] == online["saliency"].params["preset"] == want


@pytest.mark.parametrize("name", ["05_06.bvh", "09_01.bvh", "07_05.bvh"])
def test_online_saliency_default_equals_offline_default_at_unbounded_lookahead(name):
    m = read_motion(DATA / name)
    off = saliency.extract(m)
    on = run_online(m, ["saliency"], lookahead=m.n_frames + 1)["saliency"]
    assert on.frames.tolist() == off.frames.tolist()
    assert np.allclose(on.scores, off.scores, rtol=1e-9)


@pytest.mark.slow
def test_default_saliency_online_equals_offline_and_picks_its_preset_on_every_shared_clip():
    for name in clips():  # measured: exact on all 35 (and the same preset at the default
        m = read_motion(DATA / name)  # lookahead too, checked once by hand)
        off = saliency.extract(m)
        on = run_online(m, ["saliency"], lookahead=m.n_frames + 1)["saliency"]
        assert on.frames.tolist() == off.frames.tolist(), name
        assert np.allclose(on.scores, off.scores, rtol=1e-9), name
        assert off.params["preset"] == on.params["preset"], name


@AUTO_KEEPS_LOW
def test_online_saliency_auto_switches_to_high_after_two_seconds_within_its_lookahead():
    m = read_motion(DATA / "05_06.bvh")  # 7.4 s, "high" from the first 2 s on
    kf = online_class("saliency")(m.skeleton, m.fps)
    assert kf.params["preset"] == "auto" and kf.lookahead == 121
    events = Pipeline([kf]).push_block(m.frames())
    keys = [e for e in events if isinstance(e, KeyframeEvent)]
    assert kf.params["preset"] == "high" and kf.params["sigma"] == 3.0
    frames = [e.frame for e in keys]
    assert frames == sorted(set(frames))
    assert all(0 <= e.latency_frames <= kf.lookahead for e in keys)
    # after the switch at frame 240 the keys come at the high preset's own lookahead (37)
    late = [e for e in keys if e.decided_at > 240]
    assert late and all(e.latency_frames <= 37 for e in late)
    # measured: 109 keys online at the default lookahead against 121 offline (41 before,
    # when online saliency always ran the low preset)
    assert len(keys) + len(kf.flush()) >= 0.85 * len(saliency.extract(m))


def test_max_bridge_seconds_or_frames_reach_every_keyframer_and_the_pipeline():
    m = read_motion(DATA / "07_01.bvh")
    for common, frames in (({"max_bridge_seconds": 0.5}, 60), ({"max_bridge_frames": 40}, 40),
                           ({}, 12)):
        kfs = make_keyframers(m, list(ONLINE_METHODS), {"*": common})
        assert {kf.guard.max_bridge_frames for kf in kfs} == {frames}
        assert Pipeline(kfs).guard.max_bridge_frames == frames


def test_max_bridge_from_the_command_line_bridges_a_hole_instead_of_restarting(tmp_path):
    lines = subprocess.run([*CMD, "replay", CLIP, "--to", "-", "--rate", "3000"],
                           capture_output=True, text=True, timeout=60 * MS).stdout.splitlines()
    holed = "\n".join(lines[:101] + lines[131:]) + "\n"  # 30 frames never arrive
    gaps = {}
    for i, extra in enumerate(([], ["--max-bridge", "0.3s"])):
        log = tmp_path / f"events{i}.jsonl"
        run = subprocess.run([*CMD, "run", "--from", "-", "--method", "speed", "--to",
                              f"jsonl:{log}", *extra], input=holed, capture_output=True,
                             text=True, timeout=120 * MS)
        assert run.returncode == 0, run.stderr
        gaps[tuple(extra)] = [(e["missing"], e["bridged"]) for e in read_jsonl(log)
                              if e["type"] == "gap"]
    assert gaps[()] == [(30, False)]
    assert gaps[("--max-bridge", "0.3s")] == [(30, True)]  # 36 frames at 120 Hz


TOKENS = st.sampled_from(["saliency", "speed", "simplify", "optimal", "uniform", "=", ",", "60",
                          "0", "-3", "1e3", "0.1s", "s", "nan", "x", " ", "", "9" * 30, "é"])


@settings(max_examples=150, deadline=None)
@given(flag=st.sampled_from(["--lookahead", "--count", "--tolerance", "--max-bridge",
                             "--history", "--hop"]),
       text=st.lists(TOKENS, max_size=8).map("".join), online=st.booleans())
def test_tuning_option_values_fuzzed_give_params_or_one_usage_error(flag, text, online):
    argv = ["extract", CLIP, "--method", "all", f"{flag}={text}", *(["--online"] if online else [])]
    args = build_parser().parse_args(argv)
    try:
        params = _method_params(args, online=online)
    except UsageError as exc:
        assert str(exc).startswith(flag) and "\n" not in str(exc)
        return
    assert online or flag in ("--count", "--tolerance")
    assert all(isinstance(v, dict) for v in params.values())
