"""Capture sessions built from single takes: several takes of one subject back to back.

A live session lasts minutes to hours, while the shared CMU clips are trimmed takes of 1-43 s.
To measure what happens once a stream is past its first seconds (warm-up, running statistics),
a session strings the takes of one subject together in their own (trial) order, as the actor
performed them, all of them once, then repeats the list in further rounds until the session
lasts at least `min_seconds` (default 60 s); a take that would carry it past `max_seconds`
(default 600 s) is left out.

Transitions: the actor ends a take and starts the next from wherever they stand, so

- the last pose of a take is held for `hold_s` (default 0.5 s), then blended over `blend_s`
  (default 0.5 s) into the next take's first pose: quaternion slerp per joint for the
  rotations, linear for the root position (`streamkey.variants` interpolation);
- the next take's root is moved on the ground plane (the X and Z position channels; CMU files
  are Y-up) so that it starts where the previous take ended: no jump of the root, while its
  height and every rotation (heading included) are the take's own.

Each take's cgspeed reference frame (frame 0 T-pose) is left out, and rotations are unwrapped
per take. `Session.takes` says where each take lies in the session's frames.

`build_session` works on motions already read; `subject_takes` and `read_sessions` find and
read the takes of a folder of clips (BVH only: a subject's BVH takes share one skeleton).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import UsageError
from .evaluate import _unwrapped
from .motion import Motion
from .variants import _interpolate

__all__ = ["Take", "Session", "build_session", "subject_takes", "read_sessions",
           "MIN_SECONDS", "MAX_SECONDS", "HOLD_S", "BLEND_S"]

MIN_SECONDS = 60.0
MAX_SECONDS = 600.0
HOLD_S = 0.5
BLEND_S = 0.5
_CLIP_NAME = re.compile(r"^(\d+)_(\d+)$")


@dataclass(frozen=True)
class Take:
    """One take inside a session: its clip name, round, and frames [start, end)."""

    name: str
    round: int
    start: int
    end: int


@dataclass(frozen=True)
class Session:
    """A session: its motion (120 Hz for CMU, reference frame none) and where each take lies."""

    name: str
    motion: Motion
    takes: tuple[Take, ...]

    @property
    def seconds(self) -> float:
        """Length of the session in seconds."""
        return self.motion.n_frames / self.motion.fps

    def frame_at(self, seconds: float) -> int:
        """The first frame at or after `seconds` from the session's start."""
        return int(np.ceil(seconds * self.motion.fps - 1e-9))


def _layout_matches(a: Motion, b: Motion) -> bool:
    sa, sb = a.skeleton, b.skeleton
    return sa.names == sb.names and sa.channels == sb.channels and sa.parents == sb.parents


def _transition(last: np.ndarray, first: np.ndarray, motion: Motion, hold: int,
                blend: int) -> np.ndarray:
    """`hold` copies of `last`, then `blend` frames slerped from `last` into `first`."""
    pair = np.stack([last, first])
    ramp = _interpolate(pair, motion, np.arange(1, blend + 1) / (blend + 1))
    return np.concatenate([np.repeat(last[None], hold, axis=0), ramp])


def _order(takes: Sequence[Motion], min_seconds: float, max_seconds: float,
           gap: float) -> list[tuple[int, int]]:
    """(take index, round) in session order: the whole list once, then further rounds until
    `min_seconds` (`gap`: seconds of each transition)."""
    fps = takes[0].fps
    order: list[tuple[int, int]] = []
    total, rnd = 0.0, 0
    while total < min_seconds:
        added = False
        for i, take in enumerate(takes):
            length = (take.n_frames - take.first_frame) / fps + (gap if order else 0.0)
            if total + length > max_seconds:
                continue
            order.append((i, rnd))
            total += length
            added = True
            if total >= min_seconds and rnd > 0:
                break
        if not added:
            break
        rnd += 1
    return order


def build_session(name: str, takes: Sequence[Motion], *, min_seconds: float = MIN_SECONDS,
                  max_seconds: float = MAX_SECONDS, hold_s: float = HOLD_S,
                  blend_s: float = BLEND_S) -> Session:
    """The takes back to back in the given order, in rounds until `min_seconds` (module
    docstring: transitions, root placement)."""
    if not takes:
        raise UsageError(f"session {name}: no takes")
    fps = takes[0].fps
    for take in takes[1:]:
        if take.fps != fps or not _layout_matches(takes[0], take):
            raise UsageError(f"session {name}: take {take.name!r} does not match "
                             f"{takes[0].name!r} (frame rate and skeleton channels must agree)")
    if hold_s < 0 or blend_s < 0 or min_seconds > max_seconds:
        raise UsageError(f"session {name}: need hold_s, blend_s >= 0 and "
                         f"min_seconds <= max_seconds")
    hold, blend = int(round(hold_s * fps)), int(round(blend_s * fps))
    ground = [c for c in takes[0].skeleton.position_columns()
              if takes[0].skeleton.channel_labels()[c].split(".")[-1] in ("Xposition",
                                                                          "Zposition")]
    ground_cols = np.array(ground, dtype=int)
    clean = [_unwrapped(t) for t in takes]
    parts: list[np.ndarray] = []
    spans: list[Take] = []
    n = 0
    for i, rnd in _order(takes, min_seconds, max_seconds, (hold + blend) / fps):
        x = clean[i].copy()
        if parts:
            last = parts[-1][-1]
            x[:, ground_cols] += last[ground_cols] - x[0, ground_cols]
            bridge = _transition(last, x[0], takes[i], hold, blend)
            parts.append(bridge)
            n += len(bridge)
        parts.append(x)
        spans.append(Take(takes[i].name, rnd, n, n + len(x)))
        n += len(x)
    motion = Motion(takes[0].skeleton, np.concatenate(parts), fps, 0, name)
    return Session(name, motion, tuple(spans))


def subject_takes(paths: Sequence[Path]) -> dict[str, list[Path]]:
    """BVH clips named `SS_TT` grouped by subject, in trial order; subjects with one take and
    files of other names are left out."""
    groups: dict[str, list[tuple[int, Path]]] = {}
    for path in paths:
        match = _CLIP_NAME.match(path.stem)
        if path.suffix.lower() == ".bvh" and match:
            groups.setdefault(match.group(1), []).append((int(match.group(2)), path))
    return {subject: [p for _, p in sorted(items)]
            for subject, items in sorted(groups.items()) if len(items) > 1}


def read_sessions(data: Path, subjects: Sequence[str] | None = None, *,
                  min_seconds: float = MIN_SECONDS, max_seconds: float = MAX_SECONDS
                  ) -> list[Session]:
    """One session per subject of the clips in folder `data` (or the given `subjects`,
    e.g. "01"), named `session SS`."""
    from .amc import read_motion

    if not data.is_dir():
        raise UsageError(f"sessions: no folder {data} (the CMU clips)")
    groups = subject_takes(sorted(data.iterdir()))
    wanted = list(groups) if subjects is None else list(subjects)
    missing = [s for s in wanted if s not in groups]
    if missing:
        raise UsageError(f"sessions: no subject {', '.join(missing)} with two or more BVH "
                         f"takes in {data}; have {', '.join(groups) or 'none'}")
    out = []
    for subject in wanted:
        motions = []
        for path in groups[subject]:
            motion = read_motion(path)
            motion.name = motion.name or path.stem
            motions.append(motion)
        out.append(build_session(f"session {subject}", motions, min_seconds=min_seconds,
                                 max_seconds=max_seconds))
    return out
