"""Shape of the package: sans-I/O cores, one namespace, consistent exports, README == CI."""

from __future__ import annotations

import ast
import importlib
import importlib.util
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest
from cmu import ROOT

import streamkey

CORE = ["streamkey/signal.py", "streamkey/kinematics.py", "streamkey/features.py",
        "streamkey/online.py", "streamkey/featurestage.py", "streamkey/segments.py",
        "streamkey/motion.py", "streamkey/keyframes.py",
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
    assert "[" not in setup  # the first command installs the core dependencies only
    assert f"{setup} && .venv/bin/streamkey demo" in ci  # CI runs the demo on that alone,
    assert '.venv/bin/pip install -q -e ".[test,dev,cluster,docs]" && .venv/bin/pytest' in ci
    assert ".venv/bin/pytest" in readme


def test_public_names_are_reexported():
    for name in ("read_bvh", "Motion", "Skeleton", "Frame", "KeyframeEvent", "BVHError"):
        assert name in streamkey.__all__
    assert Path(streamkey.__file__).name == "__init__.py"


def _imports(path: Path) -> set[str]:
    """Every streamkey module `path` imports, at any depth of the file (lazy imports too)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    package = parts if parts[-1] == "__init__" else parts[:-1]
    package = [p for p in package if p != "__init__"]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            out.add(module)
            out.update(f"{module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m.startswith("streamkey")}


def _core_files() -> list[Path]:
    outside = ("cli", "bench")
    return [p for p in (ROOT / "streamkey").rglob("*.py")
            if p.relative_to(ROOT / "streamkey").parts[0] not in outside
            and p.name != "__main__.py"]


def test_the_core_never_imports_the_command_line_or_the_benchmarks():
    for path in _core_files():
        bad = {m for m in _imports(path)
               if m.startswith(("streamkey.cli", "streamkey.bench"))}
        assert not bad, f"{path.relative_to(ROOT)} imports {sorted(bad)}"


def test_argument_parsing_lives_in_the_cli_package_only():
    for path in _core_files():
        names = {a.name for node in ast.walk(ast.parse(path.read_text()))
                 if isinstance(node, ast.Import) for a in node.names}
        names |= {node.module for node in ast.walk(ast.parse(path.read_text()))
                  if isinstance(node, ast.ImportFrom) and node.level == 0}
        assert "argparse" not in names, f"{path.relative_to(ROOT)} imports argparse"


def test_batch_and_streaming_import_in_one_direction():
    streaming = _imports(ROOT / "streamkey" / "streaming.py")
    assert not any(m.startswith("streamkey.batch") for m in streaming), streaming
    assert "streamkey.streaming" in _imports(ROOT / "streamkey" / "batch.py")


def test_console_script_and_python_dash_m_reach_the_cli_package():
    from streamkey import cli

    assert Path(cli.__file__).parent.name == "cli" and callable(cli.main)
    text = (ROOT / "pyproject.toml").read_text()
    assert 'streamkey = "streamkey.cli:main"' in text
    assert '"streamkey.cli"' in text and '"streamkey.bench"' in text


def test_the_door_plate_is_quick_to_import_and_names_the_public_api():
    code = ("import sys, streamkey; print(any(m in sys.modules for m in "
            "('numba', 'scipy', 'streamkey.batch', 'streamkey.engine')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
    for name in ("read_motion", "extract_motion", "extract_files", "run_online",
                 "make_keyframers", "Pipeline", "run_live", "Engine", "KeyframeEvent",
                 "StreamkeyError", "Duration"):
        assert name in streamkey.__all__ and getattr(streamkey, name) is not None
    documented = (ROOT / "docs" / "api.md").read_text()
    assert all(f"`{n}" in documented for n in streamkey.__all__ if n != "__version__")
