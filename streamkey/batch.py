"""Batch extraction over files and folders: the library side of `streamkey extract`."""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import os
import stat
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .amc import read_motion
from .errors import InputError, StreamkeyError
from .features import compute_features
from .keyframes import SCHEMA_VERSION, Keyframes, Segment
from .methods import COUNTED_METHODS, offline_method
from .methods.params import to_method_units
from .motion import Motion
from .playable import debounce
from .streaming import MinIntervalLike, common_params, noise_cutoff, run_online_with_segments
from .units import DurationLike

__all__ = ["MOTION_SUFFIXES", "find_motion_files", "extract_motion", "FileResult",
           "extract_files", "results_json", "results_csv", "file_error", "per_file",
           "load_motion", "naming", "extract_one", "merge_results", "extract_files_online"]

MOTION_SUFFIXES = (".bvh", ".amc")


def find_motion_files(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Expand folders to the motion files inside (sorted); files are kept as given.

    A path that is not a folder is kept even if it cannot be read: its reader reports why,
    as that file's own error, and the other files still run.
    """
    out: list[Path] = []
    for raw in paths:
        p = Path(raw)
        try:
            if not stat.S_ISDIR(os.stat(p).st_mode):
                out.append(p)
                continue
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in MOTION_SUFFIXES)
        except OSError as exc:
            if os.path.lexists(p) or exc.errno != errno.ENOENT:
                out.append(p)
                continue
            raise InputError(f"{p}: no such file or folder") from None
        if not found:
            raise InputError(f"{p}: no .bvh or .amc files in this folder")
        out.extend(found)
    return out


def file_error(path: Path, exc: BaseException) -> str:
    """One error line for one file of a batch, naming the file once.

    Anything but a `StreamkeyError` is a bug that this file triggered: it is reported as an
    internal error (the fuzz tests count these and require none) so the batch goes on.
    """
    text = str(exc)
    if not isinstance(exc, StreamkeyError):
        return (f"{path}: internal error ({type(exc).__name__}: {text}); please report this"
                " file")
    return text if text.startswith(f"{path}:") else f"{path}: {text}"


@contextlib.contextmanager
def naming(path: str | os.PathLike[str]) -> Iterator[None]:
    """Re-raise a `StreamkeyError` of the body as an `InputError` that names `path`."""
    try:
        yield
    except StreamkeyError as exc:
        raise InputError(file_error(Path(path), exc)) from None


def per_file(paths: list[Path], work: Callable[[Path], FileResult],
             progress: Callable[[int, int, Path], None] | None = None) -> Iterator[FileResult]:
    """`work(path)` for every file; a file that fails yields its named error, the rest go on."""
    for i, path in enumerate(paths):
        if progress:
            progress(i, len(paths), path)
        yield _guarded(work, path)


def _guarded(work: Callable[[Path], FileResult], path: Path) -> FileResult:
    try:
        return work(path)
    except (KeyboardInterrupt, MemoryError):
        raise
    except Exception as exc:  # noqa: BLE001 - one file must not lose the batch
        return FileResult(path, None, {}, file_error(path, exc))


def extract_motion(motion: Motion, methods: list[str],
                   params: dict[str, dict[str, Any]] | None = None, *,
                   max_gap: float | None = None,
                   min_interval: MinIntervalLike = None) -> dict[str, Keyframes]:
    """Run the offline `methods` on one motion, sharing its features.

    Counted methods (uniform, decimate, and simplify in count mode) without an explicit
    `count` use the saliency keyframe count, the thesis' equal-count comparison. `max_gap`
    (seconds) then inserts a key in every longer stretch without one, and `min_interval`
    (seconds, or {method or "*": seconds}) keeps the stronger of keys closer than that, as the
    online keyframers do (both may also come in `params["*"]`, as `streamkey extract` passes
    them).
    """
    params = {name: to_method_units(name, kwargs, motion.fps) if name != "*" else kwargs
              for name, kwargs in common_params(params, max_gap, min_interval).items()}
    features = compute_features(motion, noise_cutoff_hz=noise_cutoff(params))
    results: dict[str, Keyframes] = {}
    order = sorted(methods, key=lambda m: m in COUNTED_METHODS)
    for name in order:
        kwargs = dict(params.get(name, {}))
        captured = motion.n_frames - motion.first_frame
        if name in ("uniform", "decimate") and captured < 1:
            raise InputError(f"{name} keeps the first and last frame, so it needs at least 1"
                             f" captured frame; the clip has none")
        if name in ("uniform", "decimate") and kwargs.get("count") is None:
            if "saliency" not in results:
                results["saliency"] = offline_method("saliency")(
                    motion, features=features, **params.get("saliency", {}))
            # At least first and last: a still clip has no salient pose but still two ends;
            # a clip of one captured frame (after its reference frame) has that one key, as
            # the other methods and the online keyframers give it.
            kwargs["count"] = min(max(len(results["saliency"]), 2), captured)
        if name == "uniform":
            results[name] = offline_method(name)(motion, **kwargs)
        else:
            results[name] = offline_method(name)(motion, features=features, **kwargs)
    return _playable({m: results[m] for m in methods}, motion, params.get("*", {}))


def _playable(results: dict[str, Keyframes], motion: Motion,
              common: dict[str, Any]) -> dict[str, Keyframes]:
    """`max_gap`, then the `min_interval` debounce, of `params["*"]` over offline keys."""
    if common.get("max_gap") is not None:
        from .methods.optimal import max_gap

        results = {m: max_gap(motion, k, common["max_gap"]) for m, k in results.items()}
    intervals = common.get("min_interval") or {}
    for name, keys in results.items():
        seconds = intervals.get(name, intervals.get("*"))
        if seconds:
            results[name] = debounce(keys, seconds, motion.fps)
    return results


@dataclass
class FileResult:
    """The keyframes of one file, or the error that stopped it."""

    path: Path
    motion: Motion | None
    results: dict[str, Keyframes]
    error: str | None = None
    segments: list[Segment] | None = None  # found with the keys (None: by `results_json`)


def extract_files(paths: list[Path], methods: list[str],
                  params: dict[str, dict[str, Any]] | None = None,
                  progress: Callable[[int, int, Path], None] | None = None,
                  roles: dict[str, str] | None = None, *, max_gap: float | None = None,
                  min_interval: MinIntervalLike = None) -> Iterator[FileResult]:
    """Extract keyframes from every file; a bad file yields its error and the rest go on.
    `roles` is a role mapping for skeletons the built-in tables do not name; `max_gap` and
    `min_interval` as in `extract_motion`."""
    params = common_params(params, max_gap, min_interval)

    def work(path: Path) -> FileResult:
        motion = load_motion(path, roles=roles)
        return _offline_result(path, motion, methods, params)

    return per_file(paths, work, progress)


def extract_files_online(paths: list[Path], methods: list[str],
                         params: dict[str, dict[str, Any]] | None = None,
                         lookahead: DurationLike | None = None,
                         progress: Callable[[int, int, Path], None] | None = None,
                         roles: dict[str, str] | None = None, *, max_gap: float | None = None,
                         min_interval: MinIntervalLike = None) -> Iterator[FileResult]:
    """`streaming.run_online` over files (`extract --online`); a bad file yields its error and
    the rest go on. `roles`, `max_gap` and `min_interval` as in `extract_files`."""
    params = common_params(params, max_gap, min_interval)

    def work(path: Path) -> FileResult:
        motion = load_motion(path, roles=roles)
        return _online_result(path, motion, methods, params, lookahead)

    return per_file(paths, work, progress)


def extract_one(path: Path, methods: list[str], params: dict[str, dict[str, Any]] | None = None,
                roles: dict[str, str] | None = None, online: bool = False,
                lookahead: DurationLike | None = None) -> FileResult:
    """One file of a batch, engine-neutral (a local loop, a Ray task or a Dask future run
    exactly this): its keyframes, or its named error. `online` runs the online keyframers
    as if streamed (`extract --online`)."""
    def work(p: Path) -> FileResult:
        motion = load_motion(p, roles=roles)
        if online:
            return _online_result(p, motion, methods, params, lookahead)
        return _offline_result(p, motion, methods, params)

    return _guarded(work, Path(path))


def _offline_result(path: Path, motion: Motion, methods: list[str],
                    params: dict[str, dict[str, Any]] | None) -> FileResult:
    """One file through the offline methods, and its segments behind the same noise filter
    (`noise_cutoff`), as the online pipeline finds them."""
    from .segments import detect_segments

    segments = detect_segments(motion, noise_cutoff_hz=noise_cutoff(params))
    return FileResult(path, motion, extract_motion(motion, methods, params), segments=segments)


def _online_result(path: Path, motion: Motion, methods: list[str],
                   params: dict[str, dict[str, Any]] | None,
                   lookahead: DurationLike | None) -> FileResult:
    """One file through the online pipeline: its keys and the segments it sent."""
    keys, segments = run_online_with_segments(motion, methods, params, lookahead)
    return FileResult(path, motion, keys, segments=segments)


def merge_results(paths: list[Path], done: Iterable[tuple[int, FileResult]]) -> list[FileResult]:
    """The merge step of a distributed batch: (input index, result) pairs in completion order
    back to input order, each file exactly once."""
    out: list[FileResult | None] = [None] * len(paths)
    for i, result in done:
        out[i] = result
    missing = [str(paths[i]) for i, r in enumerate(out) if r is None]
    if missing:
        raise StreamkeyError(f"batch lost {len(missing)} file(s): {', '.join(missing[:5])}")
    return [r for r in out if r is not None]


def load_motion(path: str | os.PathLike[str], min_frames: int = 1,
                roles: dict[str, str] | None = None) -> Motion:
    """`read_motion`, refusing a file with fewer than `min_frames` captured frames; `roles`
    (a `--roles` mapping) replaces the built-in role tables for its skeleton."""
    motion = read_motion(path)
    motion.skeleton.roles = roles or motion.skeleton.roles
    captured = motion.n_frames - motion.first_frame
    if captured < min_frames:
        raise InputError(f"{path}: expected at least {min_frames} captured frame"
                         f"{'s' if min_frames > 1 else ''}, got {captured}"
                         + (" (a skeleton-only file)" if motion.n_frames == 0 else ""))
    return motion


def results_json(results: list[FileResult]) -> str:
    """The documented JSON output of `streamkey extract` (schema in the README), with each
    file's session segments (calibration holds, still stretches, takes): those the online
    pipeline sent (`extract --online`), else found offline."""
    from .segments import detect_segments

    files = []
    for r in results:
        entry: dict[str, Any] = {"file": str(r.path)}
        if r.error is not None:
            entry["error"] = r.error
        else:
            assert r.motion is not None
            entry.update(frames=r.motion.n_frames, fps=r.motion.fps,
                         first_frame=r.motion.first_frame,
                         methods={m: k.to_dict() for m, k in r.results.items()},
                         segments=[s.to_dict() for s in (
                             detect_segments(r.motion) if r.segments is None else r.segments)])
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
