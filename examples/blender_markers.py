"""Import streamkey keyframes into Blender as timeline markers.

Run inside Blender after importing the clip's BVH (File > Import > Motion Capture (.bvh)):

    blender --python examples/blender_markers.py -- keys.json [--method saliency]
            [--file 07_01] [--start 1] [--scale-fps] [--markers timeline|pose|both]

`keys.json` is the output of `streamkey extract` (or the `OUT.keys.json` sidecar of
`--export-bvh`). Blender's BVH importer puts BVH frame i at scene frame `start + i`
(its "Start Frame" option, default 1), reference frame included, so a keyframe numbered in
the file's own numbering lands on marker frame `start + frame`; with the importer's "Scale
FPS" option use `--scale-fps` to rescale by scene fps / file fps.

The markers are placed by the streamkey Blender extension (`blender/streamkey_blender`, its
`keys.set_markers`, or `keys.set_pose_markers` for the active armature's action with
`--markers pose`): one per keyframe, named `<method> <strength>`, the method's earlier
markers replaced. Installed, the extension's "Mark Keyposes" operator finds the keys inside
Blender without a JSON file; this script is for keys found elsewhere.

The module imports without Blender (bpy is imported only in `main`), so `markers_from_json`
(`(<method> <frame>, scene frame)` pairs) can be tested and the file syntax-checked anywhere.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path
from typing import Any

__all__ = ["markers_from_json", "main"]


def markers_from_json(data: dict[str, Any], method: str | None = None, file: str | None = None,
                      start: int = 1, fps_scale: float = 1.0) -> list[tuple[str, int]]:
    """(name, scene frame) of every keyframe in an extract JSON or a `.keys.json` sidecar."""
    if "files" not in data and "frames" in data:  # the --export-bvh sidecar
        name = data.get("method") or "key"
        return [(f"{name} {f}", start + round(f * fps_scale)) for f in data["frames"]]
    out: list[tuple[str, int]] = []
    for entry in data.get("files", []):
        if "methods" not in entry:
            continue  # a file that failed to load
        if file is not None and Path(entry["file"]).stem != file:
            continue
        for name, result in entry["methods"].items():
            if method is None or name == method:
                out += [(f"{name} {f}", start + round(f * fps_scale))
                        for f in result["keyframes"]]
    return out


def _file_fps(data: dict[str, Any]) -> float | None:
    if "fps" in data:
        return float(data["fps"])
    fps = [e["fps"] for e in data.get("files", []) if "fps" in e]
    return float(fps[0]) if fps else None


def _extension_keys() -> Any:
    """The extension's `keys` module: installed in Blender, else from this checkout."""
    for name in ("bl_ext.user_default.streamkey_blender.keys", "streamkey_blender.keys"):
        try:
            return importlib.import_module(name)
        except ImportError:
            continue
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "blender"))
    return importlib.import_module("streamkey_blender.keys")


def _strengths(data: dict[str, Any], method: str | None,
               file: str | None) -> dict[str, list[float]]:
    """Each method's key strengths in key order (0.5 where the JSON has none)."""
    if "files" not in data and "frames" in data:
        return {data.get("method") or "key": [0.5] * len(data["frames"])}
    out: dict[str, list[float]] = {}
    for entry in data.get("files", []):
        if "methods" not in entry or (file is not None and Path(entry["file"]).stem != file):
            continue
        for name, result in entry["methods"].items():
            if method is None or name == method:
                out.setdefault(name, []).extend(
                    result.get("strength") or [0.5] * len(result["keyframes"]))
    return out


def main(argv: list[str] | None = None) -> int:
    """Add the markers to the current Blender scene, through the extension."""
    import bpy  # only inside Blender

    from streamkey.keyframes import Keyframes

    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    parser = argparse.ArgumentParser(prog="blender_markers")
    parser.add_argument("keys")
    parser.add_argument("--method")
    parser.add_argument("--file", help="clip name (file stem) when the JSON holds several")
    parser.add_argument("--start", type=int, default=1, help="the importer's Start Frame")
    parser.add_argument("--scale-fps", action="store_true",
                        help="the BVH was imported with Scale FPS")
    parser.add_argument("--markers", choices=("timeline", "pose", "both"), default="timeline",
                        help="the scene's timeline markers, the active object's action's pose"
                             " markers, or both")
    args = parser.parse_args(argv)
    data = json.loads(Path(args.keys).read_text(encoding="utf-8"))
    scene = bpy.context.scene
    scale = 1.0
    if args.scale_fps and _file_fps(data):
        scale = scene.render.fps / scene.render.fps_base / _file_fps(data)
    markers = markers_from_json(data, args.method, args.file, args.start, scale)
    keys = _extension_keys()
    strengths = _strengths(data, args.method, args.file)
    for name, strength in strengths.items():
        frames = [f - args.start for n, f in markers if n.split(" ")[0] == name]
        found = Keyframes(name, frames, [0.0] * len(frames), {}, 0, strength=strength)
        if args.markers in ("timeline", "both"):
            keys.set_markers(scene, found, args.start)
        if args.markers in ("pose", "both"):
            keys.set_pose_markers(bpy.context.active_object.animation_data.action, found,
                                  args.start)
    print(f"blender_markers: added {len(markers)} markers")
    return 0


if __name__ == "__main__":
    main()
