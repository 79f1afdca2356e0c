"""The per-stream feature stage: the sensor-noise front end, then forward kinematics and
derived signals, computed once per frame and shared by every keyframer of a pipeline.

Sans-I/O: nothing here reads clocks, files or sockets. `FeatureStage.compute(frames)` takes
clean consecutive frames (after `online.StreamGuard`) and gives a `FeatureBlock`; the
front end (`filters.FrontEnd`: unwrap, noise low-pass) holds each frame `delay` frames, so a
block holds the frames now complete, `delay` behind the last frame in. `FeatureStage.arrived`
restates events decided on filtered frames at the frames whose arrival decided them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from .errors import UsageError
from .filters import DEFAULT_NOISE_CUTOFF_HZ, FrontEnd, Rows, warm_filters
from .jit import warm_up
from .keyframes import CancelEvent, Event, KeyframeEvent, ProvisionalEvent, SegmentEvent
from .kinematics import (
    FKResult,
    body_height,
    fk_points,
    forward_kinematics,
    pelvis_frame,
    warm_kinematics,
)
from .motion import Frame, Skeleton
from .roles import resolve_roles
from .signal import warm_unwrap

__all__ = ["FeatureBlock", "FeatureStage"]


class FeatureBlock:
    """Features of consecutive clean frames, computed once and shared by every keyframer.

    `rotations` are the unwrapped rotation channels (columns `rotation_columns`),
    `positions` world FK points, `pelvis_positions` the same in the pelvis frame,
    `pelvis_points(points)` some of them, `foot_heights` the world Y of the left and right
    ankle. The FK-based ones are computed on first access, composing only the joints some
    keyframer on this stream reads (`FeatureStage.fk_points`): a keyframer that needs no
    positions never pays for FK, one that needs a few joints pays for their chains only.
    """

    def __init__(self, seq: np.ndarray, time: np.ndarray, channels: np.ndarray,
                 rotations: np.ndarray, skeleton: Skeleton, roles: dict[str, int],
                 stage: FeatureStage | None = None) -> None:
        self.seq, self.time, self.channels, self.rotations = seq, time, channels, rotations
        self.skeleton, self.roles, self.stage = skeleton, roles, stage
        self._fk: FKResult | None = None  # maybe partial: `valid` points only
        self._pelvis: np.ndarray | None = None

    def __len__(self) -> int:
        return int(len(self.seq))

    def _kinematics(self, points: frozenset[int] | None = None, keep: bool = True) -> FKResult:
        """FK holding at least `points` (None: every point). With `keep`, the stream's later
        blocks compute these points too, in their one FK pass."""
        fk, stage = self._fk, self.stage
        if fk is not None and (fk.valid is None or (points is not None
                                                    and fk.valid.issuperset(points))):
            return fk
        need = points
        if stage is not None and need is not None:
            if stage.fk_points is None:
                need = None
            elif not stage.fk_points.issuperset(need):
                need = stage.fk_points | need
                if keep:
                    stage.fk_points = need
            else:
                need = stage.fk_points
        elif stage is not None and keep:
            stage.fk_points = None
        if need is not None and fk is not None:
            need = need | fk.valid  # type: ignore[operator]
        if need is None or len(need) >= self.skeleton.n_joints:
            fk = forward_kinematics(self.skeleton, self.channels)
        else:
            fk = fk_points(self.skeleton, self.channels, need)
        self._fk = fk
        return fk

    @property
    def positions(self) -> np.ndarray:
        """World FK points (n, points, 3)."""
        return self._kinematics().positions

    @property
    def pelvis_positions(self) -> np.ndarray:
        """FK points in the pelvis-fixed frame (n, points, 3)."""
        if self._pelvis is None:
            self._pelvis = pelvis_frame(self._kinematics(), self.roles["pelvis"])
        return self._pelvis

    def pelvis_points(self, points: Sequence[int], keep: bool = True) -> np.ndarray:
        """Some FK points in the pelvis-fixed frame (n, len(points), 3): the bits of
        `pelvis_positions[:, points]`, composing only the joints needed. `keep=False`: a
        one-off read, later blocks do not compute these points for it."""
        idx, need = self._request(points)
        if self._pelvis is not None:
            return self._pelvis[:, idx]
        return pelvis_frame(self._kinematics(need, keep), self.roles["pelvis"], idx)

    def _request(self, points: Sequence[int]) -> tuple[np.ndarray, frozenset[int]]:
        """`points` as an index array, and the FK points their pelvis frame reads (cached
        on the stage: a keyframer asks for the same points every frame)."""
        key = tuple(points)
        cache = self.stage._requests if self.stage is not None else {}
        got = cache.get(key)
        if got is None:
            idx = np.array(key, dtype=np.int64).reshape(-1)
            got = cache[key] = (idx, frozenset(int(p) for p in idx) | {self.roles["pelvis"]})
        return got

    @property
    def foot_heights(self) -> np.ndarray:
        """World Y of the left and right ankle (n, 2)."""
        feet = [self.roles["left_ankle"], self.roles["right_ankle"]]
        return self._kinematics(frozenset(feet)).positions[:, feet, 1]

    def materialise(self) -> FeatureBlock:
        """Compute every lazy feature now (benchmarks)."""
        self.pelvis_positions  # noqa: B018 - computes FK and the pelvis frame
        return self

    def slice(self, lo: int, hi: int) -> FeatureBlock:
        """Rows lo..hi-1 (views; FK results are shared when already computed)."""
        out = FeatureBlock(self.seq[lo:hi], self.time[lo:hi], self.channels[lo:hi],
                           self.rotations[lo:hi], self.skeleton, self.roles, self.stage)
        if self._fk is not None:
            fk = self._fk
            out._fk = FKResult(fk.positions[lo:hi], fk.root_rotation[lo:hi], fk.names, fk.valid)
        if self._pelvis is not None:
            out._pelvis = self._pelvis[lo:hi]
        return out


class FeatureStage:
    """Per-stream feature computation: the front end, then FK and derived signals, once per
    frame.

    The front end (`filters.FrontEnd`, `front`) unwraps the rotation channels (its unwrap
    state is carried between blocks and across long gaps) and low-passes them and the root
    position at `noise_cutoff_hz` (the library default, `DEFAULT_NOISE_CUTOFF_HZ`; None or
    0: off), which holds each frame `delay` frames: a block's features are those of the
    frames now complete, `delay` frames behind the last frame in. `drain()` gives the rest
    at the end of a window. FK composes the points some keyframer on this stream reads
    (`fk_points`; None: every point) in one pass a block.
    """

    def __init__(self, skeleton: Skeleton, fps: float,
                 role_mapping: dict[str, str] | None = None,
                 noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> None:
        self.skeleton = skeleton
        self.fps = float(fps)
        self.role_mapping = role_mapping  # given roles (None: the skeleton's own)
        self.roles = resolve_roles(skeleton, role_mapping)
        self.body_height = body_height(skeleton)
        self.rotation_columns = skeleton.rotation_columns().astype(np.int64)
        self.front = FrontEnd(skeleton, fps, noise_cutoff_hz)
        self.given = 0  # frames whose features were given (keyframers ran on them)
        self.fk_points: frozenset[int] | None = frozenset()
        self._requests: dict[tuple[int, ...], tuple[np.ndarray, frozenset[int]]] = {}
        warm_up(warm_kinematics, warm_unwrap, warm_filters)  # no frame waits to compile

    @property
    def delay(self) -> int:
        """Frames the front end holds each frame (the filter's half-width)."""
        return self.front.delay

    @property
    def noise_cutoff_hz(self) -> float | None:
        """The front end's low-pass cut-off (None: off)."""
        return self.front.noise_cutoff_hz

    def configure(self, noise_cutoff_hz: float | None) -> None:
        """Set the noise filter's cut-off (None or 0: off) before the stream starts."""
        if self.front.last_seq is not None:
            raise UsageError("the noise filter is set before the first frame")
        self.front = FrontEnd(self.skeleton, self.fps, noise_cutoff_hz)

    def compute(self, frames: Sequence[Frame]) -> FeatureBlock:
        """Features of the frames complete after these consecutive clean frames arrive
        (the same frames when the filter is off; FK on demand)."""
        n = len(frames)
        if n == 1:
            f = frames[0]
            channels = np.array(f.channels, dtype=np.float64).reshape(1, -1)
            seq, time = np.array([f.seq], dtype=np.int64), np.array([f.time], dtype=np.float64)
        else:
            channels = np.array([f.channels for f in frames], dtype=np.float64).reshape(
                n, self.skeleton.n_channels)
            seq = np.array([f.seq for f in frames], dtype=np.int64)
            time = np.array([f.time for f in frames], dtype=np.float64)
        return self._block(self.front.push(seq, time, channels))

    def drain(self) -> FeatureBlock:
        """End of a window (a long gap, a restart, the end of the stream): features of the
        frames still held, the window's last frame standing in for the frames after it."""
        return self._block(self.front.drain())

    def _block(self, rows: Rows) -> FeatureBlock:
        self.given += len(rows)
        return FeatureBlock(rows.seq, rows.time, rows.channels, rows.rotations, self.skeleton,
                            self.roles, self)

    def arrived(self, events: list[Event]) -> list[Event]:
        """Events decided on filtered frames, restated at the frames whose arrival decided
        them (`FrontEnd.arrival`), their lookahead including the filter's delay."""
        if self.front.delay == 0 or not events:
            return events
        at, h = self.front.arrival, self.front.delay
        out: list[Event] = []
        for e in events:
            if isinstance(e, KeyframeEvent):
                e = replace(e, decided_at=at(e.decided_at), lookahead=e.lookahead + h)
            elif isinstance(e, ProvisionalEvent):
                e = replace(e, seen_at=at(e.seen_at))
            elif isinstance(e, (CancelEvent, SegmentEvent)):
                e = replace(e, decided_at=at(e.decided_at))
            out.append(e)
        return out

    def restart(self) -> None:
        """A new window after a long gap (once drained): the unwrap state is kept."""
        self.front.restart()

    def reset(self) -> None:
        """Start a new stream: forget the unwrap state too."""
        self.front.reset()

    def __getstate__(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items() if k != "_requests"}  # a derived cache

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._requests = {}
