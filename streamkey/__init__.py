"""streamkey: find the keyframes of human motion while it is being captured."""

from __future__ import annotations

from .threads import single_thread_defaults

single_thread_defaults()  # before numpy loads its BLAS (see threads.py)

# ruff: noqa: E402 - the thread defaults above must come before numpy is imported
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
from .motion import Frame, Motion, Skeleton

__version__ = "0.1.0"

__all__ = [
    "AMCError", "BVHError", "Frame", "GapEvent", "InputError", "KeyframeEvent", "Keyframes",
    "Motion", "RoleError", "Skeleton", "StatusEvent", "StreamkeyError", "UsageError",
    "parse_bvh", "read_bvh", "write_bvh", "__version__",
    "CancelEvent", "ProvisionalEvent", "SignalEvent",
]
