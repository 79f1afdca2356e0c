"""Batch extraction over files and folders: the library side of `streamkey extract`."""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .amc import read_motion
from .errors import InputError, StreamkeyError, UsageError
from .features import compute_features
from .keyframes import SCHEMA_VERSION, Keyframes
from .methods import COUNTED_METHODS, offline_method
from .motion import Motion

__all__ = ["MOTION_SUFFIXES", "find_motion_files", "extract_motion", "FileResult",
           "extract_files", "results_json", "results_csv"]

MOTION_SUFFIXES = (".bvh", ".amc")


def find_motion_files(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Expand folders to the motion files inside (sorted); files are kept as given."""
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in MOTION_SUFFIXES)
            if not found:
                raise InputError(f"{p}: no .bvh or .amc files in this folder")
            out.extend(found)
        elif p.exists():
            out.append(p)
        else:
            raise InputError(f"{p}: no such file or folder")
    return out


def extract_motion(motion: Motion, methods: list[str],
                   params: dict[str, dict[str, Any]] | None = None) -> dict[str, Keyframes]:
    """Run the offline `methods` on one motion, sharing its features.

    Counted methods (uniform, decimate, and simplify in count mode) without an explicit
    `count` use the saliency keyframe count, the thesis' equal-count comparison.
    """
    params = params or {}
    features = compute_features(motion)
    results: dict[str, Keyframes] = {}
    order = sorted(methods, key=lambda m: m in COUNTED_METHODS)
    for name in order:
        kwargs = dict(params.get(name, {}))
        if name in ("uniform", "decimate") and kwargs.get("count") is None:
            if "saliency" not in results:
                results["saliency"] = offline_method("saliency")(
                    motion, features=features, **params.get("saliency", {}))
            kwargs["count"] = len(results["saliency"])
        if name in ("uniform", "decimate"):
            results[name] = offline_method(name)(motion, **kwargs)
        else:
            results[name] = offline_method(name)(motion, features=features, **kwargs)
    return {m: results[m] for m in methods}


@dataclass
class FileResult:
    """The keyframes of one file, or the error that stopped it."""

    path: Path
    motion: Motion | None
    results: dict[str, Keyframes]
    error: str | None = None


def extract_files(paths: list[Path], methods: list[str],
                  params: dict[str, dict[str, Any]] | None = None,
                  progress: Callable[[int, int, Path], None] | None = None,
                  roles: dict[str, str] | None = None) -> Iterator[FileResult]:
    """Extract keyframes from every file; a bad file yields its error and the rest go on.
    `roles` is a role mapping for skeletons the built-in tables do not name."""
    for i, path in enumerate(paths):
        if progress:
            progress(i, len(paths), path)
        try:
            motion = read_motion(path)
            motion.skeleton.roles = roles or motion.skeleton.roles
            yield FileResult(path, motion, extract_motion(motion, methods, params))
        except UsageError:
            raise
        except StreamkeyError as exc:
            yield FileResult(path, None, {}, str(exc))


def results_json(results: list[FileResult]) -> str:
    """The documented JSON output of `streamkey extract` (schema in the README)."""
    files = []
    for r in results:
        entry: dict[str, Any] = {"file": str(r.path)}
        if r.error is not None:
            entry["error"] = r.error
        else:
            assert r.motion is not None
            entry.update(frames=r.motion.n_frames, fps=r.motion.fps,
                         first_frame=r.motion.first_frame,
                         methods={m: k.to_dict() for m, k in r.results.items()})
        files.append(entry)
    return json.dumps({"schema": SCHEMA_VERSION, "files": files}, indent=1) + "\n"


def results_csv(results: list[FileResult]) -> str:
    """One row per keyframe: file, method, frame, time, score."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["file", "method", "frame", "time", "score"])
    for r in results:
        if r.motion is None:
            continue
        for name, keys in r.results.items():
            for frame, score in zip(keys.frames, keys.scores, strict=True):
                writer.writerow([r.path, name, int(frame), f"{frame / r.motion.fps:.6f}",
                                 f"{score:.6g}"])
    return buf.getvalue()
