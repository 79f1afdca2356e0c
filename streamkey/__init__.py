"""streamkey: find the keyframes (keyposes) of human motion while it is being captured.

The public API, by what you do with it (docs/api.md):

- read motion: `read_motion` (BVH or ASF/AMC), `read_bvh`, `parse_bvh`, `write_bvh`; the data
  model `Motion`, `Skeleton`, `Frame`; durations that keep their meaning at any rate:
  `Duration`, `parse_duration`.
- extract keyframes of recorded motion: `extract_motion` (one motion, offline methods),
  `run_online` (the online keyframers as if streamed), `extract_files` /
  `extract_files_online` over files and folders (`find_motion_files`, `FileResult`,
  `results_json`); the result is a `Keyframes`.
- the online pipeline: `make_keyframers` builds one `OnlineKeyframer` per method name, a
  `Pipeline` pushes frames through them and returns events; the registry `OFFLINE_METHODS`,
  `ONLINE_METHODS`, `offline_method`, `online_class`, `parse_methods`.
- the engine: `run_live` (a source to sinks until the source ends), `build_engine`,
  `Engine`, `RunSummary`.
- events: `KeyframeEvent`, `ProvisionalEvent`, `CancelEvent`, `SignalEvent`, `GapEvent`,
  `StatusEvent`.
- errors: `StreamkeyError` and its kinds `InputError` (`BVHError`, `AMCError`, `RoleError`)
  and `UsageError`.

The heavier parts (extraction, the pipeline, the engine) load on first use, so `import
streamkey` stays quick.
"""

from __future__ import annotations

from .threads import single_thread_defaults

single_thread_defaults()  # before numpy loads its BLAS (see threads.py)

# ruff: noqa: E402 - the thread defaults above must come before numpy is imported
import importlib
from typing import TYPE_CHECKING, Any

from .amc import read_motion
from .bvh import parse_bvh, read_bvh, write_bvh
from .errors import AMCError, BVHError, InputError, RoleError, StreamkeyError, UsageError
from .keyframes import (
    CancelEvent,
    GapEvent,
    KeyframeEvent,
    Keyframes,
    ProvisionalEvent,
    SignalEvent,
    StatusEvent,
)
from .methods import (
    OFFLINE_METHODS,
    ONLINE_METHODS,
    offline_method,
    online_class,
    parse_methods,
)
from .motion import Frame, Motion, Skeleton
from .units import Duration, parse_duration

if TYPE_CHECKING:
    from .batch import (
        FileResult,
        extract_files,
        extract_files_online,
        extract_motion,
        find_motion_files,
        results_json,
    )
    from .engine import Engine, RunSummary
    from .live import build_engine, run_live
    from .online import OnlineKeyframer, Pipeline
    from .streaming import make_keyframers, run_online

__version__ = "0.1.0"

# name -> the module that defines it, imported on first use
_LAZY = {
    "extract_motion": "batch", "extract_files": "batch", "extract_files_online": "batch",
    "find_motion_files": "batch", "FileResult": "batch", "results_json": "batch",
    "run_online": "streaming", "make_keyframers": "streaming",
    "Pipeline": "online", "OnlineKeyframer": "online",
    "Engine": "engine", "RunSummary": "engine", "run_live": "live", "build_engine": "live",
}

__all__ = [
    # reading motion
    "read_motion", "read_bvh", "parse_bvh", "write_bvh", "Motion", "Skeleton", "Frame",
    "Duration", "parse_duration",
    # extracting
    "extract_motion", "run_online", "extract_files", "extract_files_online",
    "find_motion_files", "FileResult", "results_json", "Keyframes",
    # the pipeline and the keyframers
    "make_keyframers", "Pipeline", "OnlineKeyframer", "OFFLINE_METHODS", "ONLINE_METHODS",
    "offline_method", "online_class", "parse_methods",
    # the engine
    "run_live", "build_engine", "Engine", "RunSummary",
    # events
    "KeyframeEvent", "ProvisionalEvent", "CancelEvent", "SignalEvent", "GapEvent",
    "StatusEvent",
    # errors
    "StreamkeyError", "InputError", "BVHError", "AMCError", "RoleError", "UsageError",
    "__version__",
]


def __getattr__(name: str) -> Any:
    """The lazily loaded names of `__all__` (extraction, pipeline, engine)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'streamkey' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
