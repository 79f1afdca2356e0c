"""The method parameters declared once (`streamkey.methods.params`): they match the methods'
signatures, the command line is built from them, and durations in seconds reach the methods
as the frame counts they take."""

from __future__ import annotations

import inspect
import json

import pytest
from cmu import DATA

from streamkey.amc import read_motion
from streamkey.batch import extract_motion
from streamkey.cli import build_parser, main
from streamkey.methods import OFFLINE_METHODS, ONLINE_METHODS, offline_method, online_class
from streamkey.methods.params import METHOD_PARAMS, SHARED_PARAMS, params_of, to_method_units
from streamkey.streaming import run_online
from streamkey.units import Duration

CLIP = str(DATA / "07_01.bvh")  # 120 fps


def _signature(fn) -> dict[str, inspect.Parameter]:
    return dict(inspect.signature(fn).parameters)


@pytest.mark.parametrize("method", list(METHOD_PARAMS))
def test_every_declared_parameter_is_taken_by_its_method_with_the_declared_default(method):
    offline = _signature(offline_method(method))
    online = _signature(online_class(method)) if method in ONLINE_METHODS else {}
    for param in METHOD_PARAMS[method]:
        if param.online_only:
            assert param.name in online and param.name not in offline, (method, param.name)
        else:
            assert param.name in offline, (method, param.name)
        for sig in (offline, online):
            given = sig.get(param.name)
            if given is None or param.default is None or given.default in (None, given.empty):
                continue
            assert given.default == param.default, (method, param.name, given.default)
    for name in ("saliency", "speed", "simplify", "optimal"):
        for param, takers in SHARED_PARAMS:
            assert (param.name in _signature(online_class(name))) == (name in takers)


def test_every_declared_parameter_has_its_option_on_extract():
    options = {s for a in build_parser()._subparsers._group_actions[0].choices["extract"]
               ._actions for s in a.option_strings}
    for method in OFFLINE_METHODS:
        for param in params_of(method):
            assert param.option in options, (method, param.option)


def test_durations_become_the_frames_the_methods_take():
    kwargs = {"sigma": Duration.seconds(0.025), "update_every": Duration.seconds(5),
              "history": Duration.frames(90), "k": 7}
    assert to_method_units("saliency", kwargs, 120.0) == {
        "sigma": 3.0, "update_every": 600, "history": 90, "k": 7}
    assert to_method_units("speed", {"hop": Duration.seconds(0.05)}, 60.0) == {"hop": 3}


def test_seconds_in_the_library_equal_the_frame_counts_at_the_clip_rate():
    m = read_motion(CLIP)
    assert m.fps == 120
    a = extract_motion(m, ["saliency"], {"saliency": {"sigma": Duration.seconds(0.025)}})
    b = extract_motion(m, ["saliency"], {"saliency": {"sigma": 3.0}})
    assert a["saliency"].frames.tolist() == b["saliency"].frames.tolist()
    assert a["saliency"].params == b["saliency"].params
    a = run_online(m, ["speed"], {"speed": {"hop": Duration.seconds(0.05)}},
                   lookahead=Duration.seconds(0.75))
    b = run_online(m, ["speed"], {"speed": {"hop": 6}}, lookahead=90)
    assert a["speed"].frames.tolist() == b["speed"].frames.tolist()
    assert a["speed"].params == b["speed"].params


@pytest.mark.parametrize("seconds, frames", [
    (["--lookahead", "0.5s"], ["--lookahead", "60"]),
    (["--update-every", "5s", "--sigma", "0.025s"], ["--update-every", "600", "--sigma", "3"]),
    (["--history", "speed=20s", "--hop", "50ms"], ["--history", "speed=2400", "--hop", "6"]),
])
def test_seconds_on_the_command_line_equal_the_frame_counts(tmp_path, seconds, frames):
    out = []
    for i, option in enumerate((seconds, frames)):
        path = tmp_path / f"{i}.json"
        assert main(["extract", "--online", CLIP, "--method", "saliency,speed", "-q", "-o",
                     str(path), *option]) == 0
        out.append(json.loads(path.read_text()))
    assert out[0] == out[1]


def test_a_bad_duration_is_one_usage_error(capsys):
    assert main(["extract", "--online", CLIP, "--method", "speed", "--lookahead", "speed=1h"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --lookahead: '1h' is not a whole number of frames or "
                          "seconds") and err.count("\n") == 1
