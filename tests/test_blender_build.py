"""The Blender extension package: built by Blender's own extension builder, validated by
Blender's validator, installed into Blender (bpy) by its extension installer, and run."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest
from blender_helpers import clip_path, require_bpy
from cmu import ROOT
from live_helpers import free_port

require_bpy()

ADDON_FILES = {"__init__.py", "rig.py", "keys.py", "measure.py", "live.py",
               "blender_manifest.toml"}
INSTALL_AND_RUN = """
import sys, bpy
zip_path, clip = sys.argv[1], sys.argv[2]
assert bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                enable_on_install=True) == {"FINISHED"}
assert "bl_ext.user_default.streamkey_blender" in bpy.context.preferences.addons
import streamkey
assert "/extensions/" in streamkey.__file__, streamkey.__file__  # the bundled wheel
bpy.ops.import_anim.bvh(filepath=clip)
assert bpy.ops.streamkey.mark_keyposes(method="optimal", count=8) == {"FINISHED"}
print("markers", sorted(m.frame for m in bpy.context.scene.timeline_markers))
prefs = bpy.context.preferences.addons["bl_ext.user_default.streamkey_blender"].preferences
assert prefs.address == "zmq+tcp://127.0.0.1:5556" and prefs.method == "optimal"
prefs.address = "zmq+tcp://127.0.0.1:" + sys.argv[3]  # nothing listens there
try:
    bpy.ops.streamkey.listen()
except RuntimeError as exc:
    print("listen", exc)
"""


def _build(out: Path, *args: str) -> list[Path]:
    run = subprocess.run([sys.executable, "-P", str(ROOT / "blender" / "build.py"), "--out",
                          str(out), *args], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "Success parsing TOML" in run.stdout  # Blender's validator on the zip
    return [Path(line) for line in run.stdout.splitlines() if line.startswith("/")]


def _check_layout(zip_path: Path) -> dict[str, object]:
    with zipfile.ZipFile(zip_path) as z:
        names = set(z.namelist())
        manifest = tomllib.loads(z.read("blender_manifest.toml").decode())
    assert ADDON_FILES <= names
    for key in ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
                "blender_version_min", "license"):
        assert key in manifest, key
    assert manifest["id"] == "streamkey_blender" and manifest["type"] == "add-on"
    assert len(str(manifest["tagline"])) <= 64 and manifest["blender_version_min"] >= "4.2.0"
    wheels = manifest["wheels"]
    assert isinstance(wheels, list) and wheels
    assert {w.removeprefix("./") for w in wheels} == {n for n in names if n.endswith(".whl")}
    assert any(Path(w).name.startswith("streamkey-") for w in wheels)
    return manifest


def test_extension_builds_installs_into_blender_and_runs(tmp_path: Path) -> None:
    """streamkey's wheel bundled (no dependencies: they are importable here): the zip that
    Blender's builder makes installs through Blender's installer and marks keyposes."""
    zips = _build(tmp_path / "dist", "--no-deps")
    assert [z.name for z in zips] == ["streamkey_blender-0.1.0.zip"]
    _check_layout(zips[0])
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(tmp_path / "blender-user")}
    port = free_port(socket.SOCK_STREAM)
    run = subprocess.run([sys.executable, "-P", "-c", INSTALL_AND_RUN, str(zips[0]),
                          str(clip_path("07_01")), str(port)], capture_output=True, text=True,
                         env=env, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    markers = [line for line in run.stdout.splitlines() if line.startswith("markers")]
    assert markers and len(eval(markers[0].split(" ", 1)[1])) == 8
    # the preferences' address is the operator's default
    assert f"listen Error: nothing listening at zmq+tcp://127.0.0.1:{port}" in run.stdout


@pytest.mark.slow
def test_extension_bundles_the_dependency_wheels_for_linux(tmp_path: Path) -> None:
    """The installable package: every dependency's wheel for Blender's Python 3.11 on Linux
    (pip downloads them; numpy is Blender's own and is left out)."""
    zips = _build(tmp_path / "dist", "--platforms", "linux-x64")
    manifest = _check_layout(zips[0])
    names = " ".join(str(w) for w in manifest["wheels"])  # type: ignore[union-attr]
    for dep in ("scipy-", "numba-", "llvmlite-", "pyzmq-", "python_osc-", "websockets-"):
        assert dep in names, dep
    assert "numpy-" not in names and manifest["platforms"] == ["linux-x64"]
