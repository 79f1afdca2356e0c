"""Shape of the package: sans-I/O cores, one namespace, consistent exports, README == CI."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import pkgutil
import re
from pathlib import Path

import pytest
from cmu import ROOT

import streamkey

CORE = ["streamkey/signal.py", "streamkey/kinematics.py", "streamkey/features.py",
        "streamkey/online.py", "streamkey/motion.py", "streamkey/keyframes.py",
        "streamkey/playable.py", "streamkey/playable_online.py",
        "streamkey/snapshot.py",
        *[str(p.relative_to(ROOT)) for p in (ROOT / "streamkey" / "methods").glob("*.py")]]
FORBIDDEN = {"asyncio", "socket", "time", "zmq", "pythonosc", "websockets", "selectors",
             "threading", "subprocess", "os", "pathlib", "io"}


@pytest.mark.parametrize("path", CORE)
def test_algorithm_modules_do_no_io(path):
    tree = ast.parse((ROOT / path).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name.split(".")[0] for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0:
            names = [(node.module or "").split(".")[0]]
        elif isinstance(node, ast.Call) and getattr(node.func, "id", None) == "open":
            names = ["open()"]
        else:
            continue
        bad = FORBIDDEN.intersection(names) | ({"open()"} & set(names))
        assert not bad, f"{path}:{node.lineno} imports {bad}"


def all_modules():
    names = ["streamkey"]
    for info in pkgutil.walk_packages(streamkey.__path__, "streamkey."):
        if not info.name.endswith("__main__"):
            names.append(info.name)
    return sorted(names)


@pytest.mark.parametrize("name", all_modules())
def test_every_module_has_a_consistent_all(name):
    module = importlib.import_module(name)
    exported = getattr(module, "__all__", None)
    assert exported is not None, f"{name} has no __all__"
    missing = [n for n in exported if not hasattr(module, n)]
    assert not missing, f"{name}.__all__ names missing attributes: {missing}"
    assert module.__doc__, f"{name} has no docstring"


def test_adapters_and_replay_are_subpackages_not_top_level():
    assert importlib.import_module("streamkey.adapters.osc")
    assert importlib.import_module("streamkey.replay.demo")
    assert importlib.util.find_spec("adapters") is None
    assert importlib.util.find_spec("replay") is None


def test_readme_starts_with_the_two_commands_and_ci_runs_the_same_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    block = re.search(r"```bash\n(.*?)```", readme, re.S)
    assert block and readme.index("```bash") < 40
    first, second = block.group(1).strip().splitlines()[:2]
    assert first.endswith("streamkey demo") and "bash .ci/run" in second
    setup = first.rsplit("&&", 1)[0].strip()
    assert f"{setup} && .venv/bin/pytest" in ci
    assert ".venv/bin/pytest" in readme


def test_public_names_are_reexported():
    for name in ("read_bvh", "Motion", "Skeleton", "Frame", "KeyframeEvent", "BVHError"):
        assert name in streamkey.__all__
    assert Path(streamkey.__file__).name == "__init__.py"
