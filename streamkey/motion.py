"""The motion model: Skeleton, Motion and Frame.

A `Skeleton` is a joint tree with BVH-style offsets and per-joint rotation channels. ASF/AMC
skeletons fit the same model through an optional constant pre-rotation per joint (the ASF
`axis`): the local rotation of a joint is ``pre @ R(channels) @ pre.T``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import UsageError

__all__ = [
    "Skeleton",
    "Motion",
    "Frame",
    "ROTATION_CHANNELS",
    "POSITION_CHANNELS",
    "detect_reference_frame",
]

ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")


@dataclass(eq=False)
class Skeleton:
    """A joint hierarchy: names, parent indices (-1 for the root), offsets, channels.

    `channels[j]` lists joint j's channel names in file order; `rotation_order[j]` is the
    order in which its rotations compose (intrinsic, left to right), which is the channel
    order for BVH and the reversed dof order for AMC. `end_sites[j]` is the offset of the
    joint's end site, if it has one. `pre_rotations[j]` (3x3) is the ASF axis, or None.
    `roles` is an optional role mapping (see `streamkey.roles`).
    """

    names: list[str]
    parents: list[int]
    offsets: np.ndarray
    channels: list[list[str]]
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)
    rotation_order: list[list[str]] | None = None
    pre_rotations: list[np.ndarray | None] | None = None
    roles: dict[str, str] | None = None  # role -> joint name (`--roles`), else built-in tables

    def __post_init__(self) -> None:
        self.offsets = np.asarray(self.offsets, dtype=np.float64).reshape(-1, 3)
        n = len(self.names)
        if len(self.parents) != n or len(self.channels) != n or len(self.offsets) != n:
            raise UsageError("names, parents, offsets and channels must have one entry a joint")
        for j, p in enumerate(self.parents):
            if p >= j:
                raise UsageError(f"joint {self.names[j]!r}: parent must come before the child")
        if self.rotation_order is None:
            self.rotation_order = [[c for c in ch if c in ROTATION_CHANNELS]
                                   for ch in self.channels]
        if self.pre_rotations is None:
            self.pre_rotations = [None] * n
        starts = np.cumsum([0] + [len(c) for c in self.channels])
        self.channel_start: list[int] = [int(s) for s in starts[:-1]]
        self.n_channels: int = int(starts[-1])

    @property
    def n_joints(self) -> int:
        """Number of joints (end sites not counted)."""
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the joint called `name` (KeyError if absent)."""
        return self.names.index(name)

    def channel_labels(self) -> list[str]:
        """One `joint.channel` label per column of `Motion.channels`."""
        pairs = zip(self.names, self.channels, strict=True)
        return [f"{n}.{c}" for n, chans in pairs for c in chans]

    def channel_index(self, joint: int, channel: str) -> int | None:
        """Column of `channel` of joint `joint`, or None if the joint has no such channel."""
        chans = self.channels[joint]
        return self.channel_start[joint] + chans.index(channel) if channel in chans else None

    def rotation_columns(self) -> np.ndarray:
        """Columns of every rotation channel (root position excluded)."""
        labels = [c for chans in self.channels for c in chans]
        return np.array([i for i, c in enumerate(labels) if c in ROTATION_CHANNELS], dtype=int)

    def position_columns(self) -> np.ndarray:
        """Columns of every position channel (normally the root's three)."""
        labels = [c for chans in self.channels for c in chans]
        return np.array([i for i, c in enumerate(labels) if c in POSITION_CHANNELS], dtype=int)

    def bvh_compatible(self) -> bool:
        """True if BVH text can say this skeleton: no pre-rotations, channels in compose order."""
        assert self.rotation_order is not None and self.pre_rotations is not None
        return all(p is None for p in self.pre_rotations) and all(
            [c for c in ch if c in ROTATION_CHANNELS] == order
            for ch, order in zip(self.channels, self.rotation_order, strict=True))

    def children(self, joint: int) -> list[int]:
        """Direct children of `joint`."""
        return [j for j, p in enumerate(self.parents) if p == joint]


@dataclass(eq=False)
class Motion:
    """A skeleton with `channels` (n_frames x n_channels, degrees / file units) at `fps`.

    `first_frame` is the first captured frame: 1 when frame 0 is a cgspeed T-pose reference
    frame (2 when a dropout frame follows it), else 0. Methods skip frames before it and
    report indices in the file's numbering.
    """

    skeleton: Skeleton
    channels: np.ndarray
    fps: float
    first_frame: int = 0
    name: str = ""

    def __post_init__(self) -> None:
        self.channels = np.ascontiguousarray(self.channels, dtype=np.float64)
        if self.channels.ndim != 2 or self.channels.shape[1] != self.skeleton.n_channels:
            raise UsageError(
                f"channels must be n_frames x {self.skeleton.n_channels}, got {self.channels.shape}"
            )

    @property
    def n_frames(self) -> int:
        """Number of frames, reference frame included."""
        return int(self.channels.shape[0])

    @property
    def frame_time(self) -> float:
        """Seconds between frames."""
        return 1.0 / self.fps

    def captured(self) -> Motion:
        """The motion without its reference frame (a view when there is none)."""
        if self.first_frame == 0:
            return self
        return Motion(self.skeleton, self.channels[self.first_frame :], self.fps, 0, self.name)

    def frames(self, stream_start_seq: int = 0) -> list[Frame]:
        """Every captured frame as a `Frame`, numbered in the file's own frame numbers."""
        out = []
        for i in range(self.first_frame, self.n_frames):
            out.append(Frame(stream_start_seq + i, i / self.fps, self.channels[i]))
        return out


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame of a stream: the source's frame number, time (s, source clock), channels."""

    seq: int
    time: float
    channels: np.ndarray


def detect_reference_frame(skeleton: Skeleton, channels: np.ndarray) -> int:
    """Index of the first captured frame: past a cgspeed T-pose reference frame (the
    first frame of the CMU BVH cgspeed MotionBuilder release: a T-pose with zero root
    rotation, not part of the capture, so the papers' frame counts exclude it) and past any
    all-zero dropout frames right after it.

    The reference frame has zero root rotation and at most ~10 non-zero joint channels, all
    integers, while the next frame differs; captured frames practically never look like that.
    A frame whose every channel is exactly zero (root at the origin, every joint at rest) is
    a dropout, not a pose: 07_12 has one right after its reference frame; a clip with no
    other frame is a still clip at rest, all captured.
    """
    first = _reference_frame(skeleton, channels)
    posed = np.flatnonzero(np.any(channels[first:] != 0, axis=1))
    # nothing but zero frames: a still clip at rest, every frame captured
    return first + int(posed[0]) if len(posed) else first


def reference_lead(skeleton: Skeleton, first: np.ndarray, second: np.ndarray) -> bool:
    """Is `first`, followed by `second`, a lead frame, a reference T-pose or an all-zero
    dropout (`detect_reference_frame`), rather than a captured one? A sender that streams a
    whole cgspeed BVH starts with one: its one-frame jump into the take is no motion."""
    return detect_reference_frame(skeleton, np.stack([first, second])) > 0


def without_lead(motion: Motion) -> Motion:
    """`motion` with `first_frame` past the lead frames at it, by the rule a stream applies
    frame by frame (`reference_lead` on each first frame and its successor, as
    `filters.FrontEnd` does): the same take with or without its reference frame streamed
    first gets the same keys. `motion` itself when there is none."""
    first, skeleton, channels = motion.first_frame, motion.skeleton, motion.channels
    while motion.n_frames - first >= 2 and reference_lead(skeleton, channels[first],
                                                          channels[first + 1]):
        first += 1
    if first == motion.first_frame:
        return motion
    return Motion(skeleton, channels, motion.fps, first, motion.name)


def _reference_frame(skeleton: Skeleton, channels: np.ndarray) -> int:
    if channels.shape[0] < 2:
        return 0
    rot = skeleton.rotation_columns()
    first = channels[0, rot]
    nonzero = np.flatnonzero(np.abs(first) > 1e-9)
    root_rot = [c for c in range(len(skeleton.channels[0])) if skeleton.channels[0][c]
                in ROTATION_CHANNELS]
    if np.any(np.abs(channels[0, root_rot]) > 1e-9):
        return 0
    if len(nonzero) > 12 or not np.allclose(first[nonzero], np.round(first[nonzero])):
        return 0
    if np.allclose(channels[0, rot], channels[1, rot]):
        return 0
    return 1
