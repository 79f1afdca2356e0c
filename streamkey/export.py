"""Keyframes back out as motion files: the keyposes alone, or the motion rebuilt from them.

- `export_keyframes_bvh`: a BVH whose frames are exactly the keyposes, in order, with the
  captured channel values (6 decimals, as `write_bvh` writes them) and the clip's frame time.
  BVH has no per-frame times, so a sidecar `OUT.keys.json` lists each exported frame's
  original frame number and time (what a DCC tool needs to put the keys back at their
  original times; `examples/blender_markers.py` reads it).
- `export_reconstructed_bvh`: the full-length motion rebuilt from the keys only
  (`evaluate.reconstruct`: slerp of 3-rotation joints, linear otherwise), keys exact.

Both files are plain BVH as the project's reader and Blender's importer read them (one
ROOT hierarchy, CHANNELS per joint, `Frames:` / `Frame Time:`, one line per frame).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from .amc import bvh_equivalent
from .bvh import write_bvh
from .errors import UsageError
from .evaluate import reconstruct
from .keyframes import SCHEMA_VERSION, Keyframes
from .motion import Motion, Skeleton

__all__ = ["keyframes_motion", "export_keyframes_bvh", "export_reconstructed_bvh",
           "export_results", "sidecar_path"]


def _frames(motion: Motion, keys: Keyframes | list[int] | np.ndarray) -> np.ndarray:
    frames = np.asarray(keys.frames if isinstance(keys, Keyframes) else keys, dtype=np.int64)
    frames = np.unique(frames)
    if len(frames) == 0:
        raise UsageError("export: no keyframes")
    if frames[0] < 0 or frames[-1] >= motion.n_frames:
        raise UsageError(f"export: keyframes must lie in 0..{motion.n_frames - 1}")
    return frames


def keyframes_motion(motion: Motion, keys: Keyframes | list[int] | np.ndarray) -> Motion:
    """The motion made of the keyposes only (same skeleton and frame time)."""
    frames = _frames(motion, keys)
    return Motion(motion.skeleton, motion.channels[frames], motion.fps, 0,
                  f"{motion.name}_keys" if motion.name else "keys")


def sidecar_path(path: str | os.PathLike[str]) -> Path:
    """`OUT.bvh` -> `OUT.keys.json`: original frame numbers and times of the exported keys."""
    p = Path(path)
    return p.with_name(p.stem + ".keys.json")


def three_rotations(motion: Motion) -> Motion:
    """The same motion with every joint's rotation channels padded to three (the missing
    axes appended at zero angle, which leaves each rotation as it is): BVH importers such as
    Blender's read only joints with three rotation channels, and an AMC bone has 0-3."""
    skel = motion.skeleton
    channels: list[list[str]] = []
    columns: list[np.ndarray] = []
    zero = np.zeros(motion.n_frames)
    for j, chans in enumerate(skel.channels):
        start = skel.channel_start[j]
        have = [c for c in chans if c.endswith("rotation")]
        missing = [c for c in ("Zrotation", "Yrotation", "Xrotation") if c not in have]
        channels.append(list(chans) + missing)
        columns += [motion.channels[:, start + i] for i in range(len(chans))]
        columns += [zero] * len(missing)
    padded = Skeleton(list(skel.names), list(skel.parents), skel.offsets.copy(), channels,
                      dict(skel.end_sites))
    return Motion(padded, np.stack(columns, axis=1), motion.fps, motion.first_frame,
                  motion.name)


def export_keyframes_bvh(motion: Motion, keys: Keyframes | list[int] | np.ndarray,
                         path: str | os.PathLike[str], method: str | None = None) -> Path:
    """Write the keyposes-only BVH and its `.keys.json` sidecar; returns the BVH path."""
    frames = _frames(motion, keys)
    write_bvh(three_rotations(bvh_equivalent(motion)), path, frames)
    meta: dict[str, Any] = {
        "schema": SCHEMA_VERSION, "source": motion.name,
        "method": method or (keys.method if isinstance(keys, Keyframes) else None),
        "fps": motion.fps, "source_frames": motion.n_frames,
        "frames": frames.tolist(), "times": np.round(frames / motion.fps, 6).tolist()}
    sidecar_path(path).write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
    return Path(path)


def export_reconstructed_bvh(motion: Motion, keys: Keyframes | list[int] | np.ndarray,
                             path: str | os.PathLike[str], mode: str = "slerp") -> Path:
    """Write the full-length motion interpolated from the keyframes only."""
    rebuilt = reconstruct(motion, _frames(motion, keys), mode)
    write_bvh(three_rotations(bvh_equivalent(Motion(
        motion.skeleton, rebuilt, motion.fps, motion.first_frame, motion.name))), path)
    return Path(path)


def _target(pattern: str, stem: str, method: str, many: bool) -> Path:
    if many and ("{stem}" not in pattern and "{method}" not in pattern):
        raise UsageError(f"export to {pattern!r}: several files or methods need a pattern "
                         "with {stem} and/or {method}, e.g. out/{stem}_{method}.bvh")
    try:
        return Path(pattern.format(stem=stem, method=method))
    except (KeyError, IndexError, ValueError) as exc:
        raise UsageError(f"export pattern {pattern!r}: only {{stem}} and {{method}} may be "
                         f"used ({exc})") from None


def export_results(results: list[Any], pattern: str, reconstructed: bool = False) -> list[Path]:
    """Export every (file, method) result of `extract`; `pattern` may use {stem}, {method}."""
    pairs = [(r, m, k) for r in results if r.motion is not None for m, k in r.results.items()]
    targets = [_target(pattern, r.path.stem, m, len(pairs) > 1) for r, m, _ in pairs]
    if len(set(targets)) != len(targets):
        raise UsageError(f"export pattern {pattern!r} gives the same file twice; add {{stem}} "
                         "or {method}")
    written = []
    for (r, method, keys), target in zip(pairs, targets, strict=True):
        if len(keys) == 0:
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        if reconstructed:
            written.append(export_reconstructed_bvh(r.motion, keys, target))
        else:
            written.append(export_keyframes_bvh(r.motion, keys, target, method))
    return written
