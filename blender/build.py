"""Build the streamkey Blender extension: the add-on, streamkey's wheel and its dependencies'.

    .venv/bin/python -P blender/build.py [--out dist/] [--platforms linux-x64,...] [--no-deps]

Stages blender/streamkey_blender/ with a `wheels/` folder (streamkey built from this checkout;
scipy, numba, llvmlite, pyzmq, python-osc, websockets downloaded by pip for Blender's Python
3.11 on each platform; numpy left out: Blender ships its own 1.26, and the wheels are
resolved against it), lists them in `blender_manifest.toml`, then runs Blender's own
extension builder and validator (`blender_ext.py`, the code behind
`blender --command extension build`, found inside the installed `bpy` wheel). With several
platforms the builder writes one zip per platform (`--split-platforms`). `--no-deps` bundles
streamkey's wheel only (a quick layout check; that zip installs only where the dependencies
are already importable).
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
ADDON = HERE / "streamkey_blender"
PLATFORMS = {  # Blender platform -> pip --platform tags (Blender 4.2: Python 3.11)
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "macos-arm64": ["macosx_11_0_arm64", "macosx_12_0_arm64", "macosx_14_0_arm64"],
    "macos-x64": ["macosx_10_9_x86_64", "macosx_10_15_x86_64", "macosx_11_0_x86_64"],
    "windows-x64": ["win_amd64"],
}
DEPENDENCIES = ["scipy", "numba", "pyzmq", "python-osc", "websockets"]
BLENDER_NUMPY = "numpy==1.26.4"  # Blender 4.2's bundled numpy: dependencies must fit it


def blender_ext() -> Path:
    """Blender's extension command-line tool inside the installed bpy module."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or spec.origin is None:
        raise SystemExit("error: bpy is not installed (pip install 'bpy==4.2.*')")
    found = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        raise SystemExit(f"error: blender_ext.py not found under {Path(spec.origin).parent}")
    return found[-1]


def _pip(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "pip", "-q", *args], check=True)


def stage(dest: Path, platforms: list[str], deps: bool) -> list[str]:
    """Copy the add-on to `dest`, fill `dest/wheels`, write the manifest; the wheel names."""
    shutil.copytree(ADDON, dest, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    wheels = dest / "wheels"
    wheels.mkdir()
    try:  # the environment's setuptools first: no build environment to download
        _pip("wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(ROOT))
    except subprocess.CalledProcessError:
        _pip("wheel", "--no-deps", "-w", str(wheels), str(ROOT))
    if deps:
        for platform in platforms:
            tags = [a for tag in PLATFORMS[platform] for a in ("--platform", tag)]
            _pip("download", "--only-binary=:all:", "--python-version", "3.11",
                 "--implementation", "cp", "--abi", "cp311", "--abi", "abi3", "--abi", "none",
                 *tags, "-d", str(wheels), BLENDER_NUMPY, *DEPENDENCIES)
        for numpy in wheels.glob("numpy-*.whl"):
            numpy.unlink()
    names = sorted(w.name for w in wheels.glob("*.whl"))
    manifest = (ADDON / "blender_manifest.toml").read_text(encoding="utf-8")
    extra = "wheels = [\n" + "".join(f'  "./wheels/{n}",\n' for n in names) + "]\n"
    if deps:
        extra += "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]\n"
    head, sep, tail = manifest.partition("\n[permissions]")
    (dest / "blender_manifest.toml").write_text(head + "\n" + extra + sep + tail,
                                                encoding="utf-8")
    return names


def build(out: Path, platforms: list[str], deps: bool = True) -> list[Path]:
    """Build (and validate) the extension zip(s) into `out`; their paths."""
    tool = blender_ext()
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        source = Path(tmp) / "streamkey_blender"
        stage(source, platforms, deps)
        before = set(out.glob("*.zip"))
        split = ["--split-platforms"] if deps and len(platforms) > 1 else []
        subprocess.run([sys.executable, str(tool), "build", "--source-dir", str(source),
                        "--output-dir", str(out), *split], check=True)
    zips = sorted(set(out.glob("*.zip")) - before) or sorted(out.glob("streamkey_blender*.zip"))
    for z in zips:
        subprocess.run([sys.executable, str(tool), "validate", str(z)], check=True)
    return zips


def main(argv: list[str] | None = None) -> int:
    """Command line."""
    parser = argparse.ArgumentParser(prog="blender/build.py")
    parser.add_argument("--out", type=Path, default=HERE / "dist")
    parser.add_argument("--platforms", default=",".join(PLATFORMS))
    parser.add_argument("--no-deps", action="store_true", help="bundle streamkey's wheel only")
    args = parser.parse_args(argv)
    platforms = [p for p in args.platforms.split(",") if p]
    bad = [p for p in platforms if p not in PLATFORMS]
    if bad:
        parser.error(f"unknown platform(s) {', '.join(bad)}; choose from {', '.join(PLATFORMS)}")
    for z in build(args.out, platforms, deps=not args.no_deps):
        print(z)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
