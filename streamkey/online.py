"""The online (streaming) side shared by every keyframer: stream hygiene, the
`OnlineKeyframer` base class and the `Pipeline` that runs several keyframers on one stream
while computing features once (the per-stream feature stage: `streamkey.featurestage`,
whose `FeatureStage` and `FeatureBlock` are importable from here too).

Sans-I/O: nothing here reads clocks, files or sockets. Frames come in through `push`,
events go out as return values.

Flow of one frame::

    Frame -> StreamGuard.accept -> [clean frames] -> FeatureStage.compute
          -> FrontEnd (unwrap, noise low-pass: frame f comes out when f + delay is in)
          -> FeatureBlock -> SegmentDetector.process(block) -> [SegmentEvent ...]
                             (each noted by every keyframer, `note_segment`, before the
                             keyframers are given the frame that decided it)
          -> FeatureBlock -> keyframer.process(block) -> [KeyframeEvent ...]
          -> FeatureStage.arrived (decided_at: the frame whose arrival decided it)

The segment detector (`Pipeline(segments=True)`, the default; `streamkey.segments`) sends
the session's calibration holds, still stretches and takes as they are found.

The noise filter (`filters.FrontEnd`, on by default at `filters.DEFAULT_NOISE_CUTOFF_HZ`,
5 Hz; `noise_cutoff_hz=None` or 0 turns it off) is the same offline
(`features.compute_features`) and online, so the keyframers see the same numbers; it holds
each frame `delay` frames (its half-width, from the cut-off and the rate).
Keyframers decide on filtered frames as before; each event is then restated once, here: a
decision made on filtered frame d was made when frame d + delay arrived (or at the last
frame in, when the window ends), and its `lookahead` (the latency bound) is the keyframer's
`lookahead` plus `delay`. At the end of a window (flush, a long gap, a source restart) the
front end gives the frames it holds, the window's last frame standing in for those after
it, as offline at the end of a clip; then the keyframers finish.

Stream hygiene (`StreamGuard`): a frame whose `seq` is not greater than the last accepted one
is dropped (counted as duplicate or out-of-order) unless it lies more than
`max_reorder_frames` back, which means the source started over (a restart and a
`StatusEvent`); a frame with the wrong channel count or a NaN/Inf value is dropped (counted
as invalid); a frame whose `seq` skips ahead by at most
`max_bridge_frames` missing frames is preceded by linearly interpolated frames (a bridged
`GapEvent`); a longer gap ends the current window: the keyframers flush what they hold and
restart, and a `GapEvent` with `bridged=False` is emitted. Nothing in this path raises.

A restart (long gap, source restart) starts new windows but keeps every method's running
statistics (`OnlineKeyframer.restart(keep_statistics=True)`) and the rotation unwrap state,
so nothing warms up again; `reset_on_gap=True` (`run --reset-on-gap`) forgets them too.
A pipeline's skeleton never changes (a different one announced on the wire is refused by
the source), so statistics are never carried across skeletons.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from types import EllipsisType
from typing import Any

import numpy as np

from .errors import RoleError, UsageError
from .featurestage import FeatureBlock, FeatureStage
from .filters import DEFAULT_NOISE_CUTOFF_HZ
from .keyframes import (
    STRENGTH_WINDOW,
    Event,
    GapEvent,
    KeyframeEvent,
    SegmentEvent,
    StatusEvent,
    params_digest,
    rank_strength,
)
from .motion import Frame, Skeleton
from .segments import SegmentDetector

__all__ = ["StreamGuard", "GuardCounters", "FeatureStage", "FeatureBlock", "OnlineKeyframer",
           "WrappedKeyframer", "Pipeline", "DEFAULT_MAX_BRIDGE_FRAMES",
           "DEFAULT_MAX_REORDER_FRAMES"]

DEFAULT_MAX_BRIDGE_FRAMES = 12  # 0.1 s at 120 Hz: short enough that a straight line is honest
DEFAULT_MAX_REORDER_FRAMES = 120  # a seq further back than this means the source restarted


@dataclass
class GuardCounters:
    """What the guard did to the stream so far."""

    accepted: int = 0
    duplicates: int = 0
    out_of_order: int = 0
    invalid: int = 0
    gaps: int = 0
    bridged_frames: int = 0
    restarts: int = 0
    lost: int = 0  # frames that never arrived: the seq holes of every gap, bridged or not

    def as_dict(self) -> dict[str, int]:
        """Counters as a plain dict (for summaries and status events)."""
        return dict(self.__dict__)


@dataclass
class StreamGuard:
    """Stream hygiene at the keyframer boundary: never raises, counts everything it drops."""

    n_channels: int
    stream: str = "default"
    method: str = "*"
    max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES
    max_reorder_frames: int = DEFAULT_MAX_REORDER_FRAMES
    counters: GuardCounters = field(default_factory=GuardCounters)
    last: Frame | None = None

    def accept(self, frame: Frame) -> tuple[list[Frame], list[Event], bool]:
        """Check one frame. Returns (frames to process, gap/status events, restart-before-them)."""
        try:
            channels = np.asarray(frame.channels, dtype=np.float64)
            seq, time = int(frame.seq), float(frame.time)
        except (TypeError, ValueError):
            self.counters.invalid += 1
            return [], [], False
        if channels.shape != (self.n_channels,) or not np.all(np.isfinite(channels)):
            self.counters.invalid += 1
            return [], [], False
        clean = Frame(seq, time, channels)
        last = self.last
        if last is not None and clean.seq < last.seq - self.max_reorder_frames:
            # The source started over (a replay restarted, a publisher came back).
            self.counters.accepted += 1
            self.counters.restarts += 1
            self.last = clean
            return [clean], [StatusEvent(stream=self.stream, method=self.method,
                                         status="restart",
                                         detail={"last_seq": last.seq, "seq": clean.seq})], True
        if last is not None and clean.seq <= last.seq:
            if clean.seq == last.seq:
                self.counters.duplicates += 1
            else:
                self.counters.out_of_order += 1
            return [], [], False
        self.counters.accepted += 1
        self.last = clean
        if last is None or clean.seq == last.seq + 1:
            return [clean], [], False
        missing = clean.seq - last.seq - 1
        self.counters.gaps += 1
        self.counters.lost += missing
        bridged = missing <= self.max_bridge_frames
        gap = GapEvent(stream=self.stream, method=self.method, first=last.seq + 1,
                       last=clean.seq - 1, bridged=bridged)
        if not bridged:
            self.counters.restarts += 1
            return [clean], [gap], True
        self.counters.bridged_frames += missing
        w = (np.arange(1, missing + 1) / (missing + 1))[:, None]
        values = last.channels + w * (clean.channels - last.channels)
        times = last.time + w[:, 0] * (clean.time - last.time)
        filled = [Frame(last.seq + 1 + i, float(times[i]), values[i]) for i in range(missing)]
        return filled + [clean], [gap], False

    def reset(self) -> None:
        """Forget the last frame (a new stream starts); counters are kept."""
        self.last = None


class OnlineKeyframer:
    """Base of every online keyframer: hygiene and features here, the method in subclasses.

    Subclasses set `method`, call `super().__init__`, and implement `process(block)` (advance
    over clean consecutive frames; must give the same events whatever the block split, with
    `decided_at` the seq of the frame whose arrival decided each key), `finish()` (decide
    everything pending at end of stream) and `reset()` (forget the window, keep parameters).
    """

    method: str = "?"  # the method's name (a wrapper's: the method it wraps)
    reset_on_gap = False  # True: a long gap forgets the running statistics too

    def __init__(self, skeleton: Skeleton, fps: float, *, lookahead: int, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES,
                 params: dict[str, Any] | None = None,
                 noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> None:
        if lookahead < 1:
            raise UsageError(f"lookahead must be at least 1 frame, got {lookahead}")
        self.skeleton = skeleton
        self.fps = float(fps)
        self.lookahead = int(lookahead)
        self.stream = stream
        self.params = dict(params or {})
        self.params["lookahead"] = self.lookahead
        self.params_digest = params_digest({"method": self.method, **self.params})
        self.guard = StreamGuard(skeleton.n_channels, stream, self.method, max_bridge_frames)
        self.features = FeatureStage(skeleton, fps, role_mapping, noise_cutoff_hz)
        # Scores of the last keys sent, for their strength (kept over gaps, not over a flush).
        self.recent_scores: deque[float] = deque(maxlen=STRENGTH_WINDOW)

    def push(self, frame: Frame) -> list[Event]:
        """Feed one frame; returns the events it decided (each final)."""
        return self.push_block([frame])

    def push_block(self, frames: Iterable[Frame]) -> list[Event]:
        """Feed many frames; same events as pushing them one by one."""
        return _drive(self.guard, self.features, [self], frames,
                      reset_on_gap=self.reset_on_gap)

    def flush(self) -> list[Event]:
        """End of stream: decide everything still pending, then restart the window."""
        events = _end_window(self.features, [self])
        self.reset()
        self.guard.reset()
        self.features.reset()
        forget_scores(self)
        return events

    def event(self, frame: int, time: float, score: float, decided_at: int) -> KeyframeEvent:
        """Build a `KeyframeEvent` carrying this keyframer's identity and parameters; its
        strength ranks the score among the keys sent before (`keyframes.rank_strengths`)."""
        self.recent_scores.append(float(score))
        return KeyframeEvent(stream=self.stream, method=self.method, frame=int(frame),
                             time=float(time), score=float(score), decided_at=int(decided_at),
                             lookahead=self.lookahead, params=self.params_digest,
                             strength=rank_strength(self.recent_scores, float(score)))

    def process(self, block: FeatureBlock) -> Sequence[Event]:
        """Advance over clean consecutive frames (subclass hook). A method gives its
        `KeyframeEvent`s; a wrapper may give other events too (provisional, signal)."""
        raise NotImplementedError

    def note_segment(self, event: SegmentEvent) -> None:
        """A session segment was decided (a calibration hold, a still stretch or a take, open
        or closed; `streamkey.segments`). The pipeline calls this for every segment event
        before giving the keyframer the frame that decided it (`event.decided_at`, in the
        numbering of the frames the keyframer is given), and before `finish()` for the
        segment an end of window closes; a method may keep those frames out of its running
        statistics. Default: nothing (subclass hook; a `WrappedKeyframer` passes it on)."""

    def candidates(self) -> list[tuple[int, float, float]]:
        """Keys this keyframer expects among its undecided frames now, as (seq, time, score)
        (subclass hook, read for provisional events; must not change state)."""
        return []

    def idle(self) -> Sequence[Event]:
        """Deferred work of the last frame (subclass hook): called right after `process`,
        once the events that were already due have been handed on, so a slow re-analysis
        does not hold up finished decisions. Same frame, so `decided_at` is unchanged."""
        return []

    def finish(self) -> Sequence[Event]:
        """Decide everything pending at end of stream or before a restart (subclass hook)."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the window and running state; keep parameters (subclass hook)."""
        raise NotImplementedError

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap or a source restart, called after `finish()`:
        forget the window; with `keep_statistics` keep the running statistics (a method's
        PCA moments, cut-off history, rate controller), so it does not warm up again.
        Without, or for a method that keeps none, this is `reset()`. (subclass hook)"""
        self.reset()

    def snapshot(self) -> bytes:
        """Versioned snapshot of the whole state, without derived caches (`snapshot.py`)."""
        from .snapshot import snapshot

        return snapshot(self)

    @classmethod
    def restore(cls, data: bytes, params: str | None = None) -> OnlineKeyframer:
        """A new keyframer from `snapshot()` bytes; `params`: the digest it must carry."""
        from .snapshot import restore

        return restore(data, cls, params)  # type: ignore[no-any-return]


class WrappedKeyframer(OnlineKeyframer):
    """Base of a keyframer that wraps another to apply a rule to its output
    (`optimal.MaxGap`, `playable_online.MinInterval`, `playable_online.Playable`).

    A wrapper is the inner keyframer seen through the rule: it shares its skeleton, rate,
    stream, guard, feature stage and score history (no second role resolution, one feature
    computation), carries its method name, and passes segments, candidates, resets and
    restarts on to it. It has its own `lookahead` (the inner one plus what the rule holds
    back) and `params` (the inner ones plus the rule's); its digest is the inner one unless
    the rule changes the keys (`params_digest`). Subclasses implement `process`, `idle` and
    `finish` over `self.inner`, and `_forget()` (the rule's own window state).
    """

    def __init__(self, inner: OnlineKeyframer, *, lookahead: int, params: dict[str, Any],
                 params_digest: str | None = None) -> None:
        self.inner = inner  # the wrapped keyframer (itself possibly a wrapper)
        self.method = inner.method
        self.skeleton, self.fps, self.stream = inner.skeleton, inner.fps, inner.stream
        self.lookahead = int(lookahead)
        self.params = params
        self.params_digest = inner.params_digest if params_digest is None else params_digest
        self.guard, self.features = inner.guard, inner.features
        self.recent_scores = inner.recent_scores

    @property
    def innermost(self) -> OnlineKeyframer:
        """The method keyframer under every wrapper."""
        kf = self.inner
        while isinstance(kf, WrappedKeyframer):
            kf = kf.inner
        return kf

    def note_segment(self, event: SegmentEvent) -> None:
        """Passed to the wrapped keyframer."""
        self.inner.note_segment(event)

    def candidates(self) -> list[tuple[int, float, float]]:
        """The wrapped keyframer's candidates (provisional hook)."""
        return self.inner.candidates()

    def reset(self) -> None:
        """Forget the stream (the wrapped keyframer too)."""
        self.inner.reset()
        self._forget()

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window: the wrapped keyframer restarts (keeping its statistics unless told
        otherwise); the rule's window state starts over."""
        self.inner.restart(keep_statistics)
        self._forget()

    def _forget(self) -> None:
        """Forget the rule's window state (subclass hook)."""
        raise NotImplementedError


def forget_scores(kf: OnlineKeyframer) -> None:
    """A new stream: the strength ranks start afresh (wrapped keyframers too). A restart
    inside a stream (a long gap) keeps them."""
    kf.recent_scores.clear()
    if isinstance(kf, WrappedKeyframer):
        forget_scores(kf.inner)


def _drive(guard: StreamGuard, stage: FeatureStage, keyframers: Sequence[OnlineKeyframer],
           frames: Iterable[Frame], defer_idle: bool = False,
           reset_on_gap: bool = False, detector: SegmentDetector | None = None) -> list[Event]:
    events: list[Event] = []
    pending: list[Frame] = []

    def run_pending() -> None:
        if pending:
            events.extend(_feed(stage, keyframers, stage.compute(pending), defer_idle,
                                detector))
            pending.clear()

    for frame in frames:
        clean, gaps, restart = guard.accept(frame)
        if gaps:
            run_pending()
        if restart:  # a long gap or a source restart: new windows, statistics kept
            events.extend(_end_window(stage, keyframers, defer_idle, detector))
            for kf in keyframers:
                kf.restart(keep_statistics=not reset_on_gap)
            if reset_on_gap:  # else the rotations unwrap on across the hole, as the
                stage.reset()  # statistics kept in their frame of reference need
            else:
                stage.restart()
        events.extend(gaps)
        pending.extend(clean)
    run_pending()
    return events


def _process(keyframers: Sequence[OnlineKeyframer], block: FeatureBlock,
             detector: SegmentDetector | None) -> list[Event]:
    """The segment detector, then every keyframer, on a block. Each segment event is noted
    by every keyframer before it is given the frame that decided it (the block is cut
    there), and goes out just before that frame's keyframe events."""
    events: list[Event] = []
    lo = 0
    for segment in detector.process(block) if detector is not None else ():
        cut = segment.decided_at - int(block.seq[0])
        if cut > lo:
            part = block.slice(lo, cut)
            for kf in keyframers:
                events.extend(kf.process(part))
            lo = cut
        for kf in keyframers:
            kf.note_segment(segment)
        events.append(segment)
    part = block if lo == 0 else block.slice(lo, len(block))
    for kf in keyframers:
        events.extend(kf.process(part))
    return events


def _feed(stage: FeatureStage, keyframers: Sequence[OnlineKeyframer], block: FeatureBlock,
          defer_idle: bool = False, detector: SegmentDetector | None = None) -> list[Event]:
    """Every keyframer's events on a block, at the frames whose arrival decided them."""
    if not len(block):
        return []
    events = _process(keyframers, block, detector)
    if not defer_idle:
        for kf in keyframers:
            events.extend(kf.idle())
    return stage.arrived(events)


def _end_window(stage: FeatureStage, keyframers: Sequence[OnlineKeyframer],
                defer_idle: bool = False, detector: SegmentDetector | None = None
                ) -> list[Event]:
    """The frames the front end still holds, then everything pending decided: the end of
    a window (a long gap, a restart, the end of the stream). The open segment closes
    first (noted by the keyframers before they finish)."""
    events = _feed(stage, keyframers, stage.drain(), defer_idle, detector)
    done: list[Event] = []
    for segment in detector.finish() if detector is not None else ():
        for kf in keyframers:
            kf.note_segment(segment)
        done.append(segment)
    for kf in keyframers:
        done.extend(kf.finish())
    out = events + stage.arrived(done)
    # Every event here is decided at the last arrival (the held frames have no later one to
    # wait for), where segment events go out before the keyframes decided with them.
    return ([e for e in out if isinstance(e, SegmentEvent)]
            + [e for e in out if not isinstance(e, SegmentEvent)])


class Pipeline:
    """Several keyframers on one stream: one guard, one feature stage, features computed once,
    and one session-segment detector beside them (`streamkey.segments`).

    `segments=True` (the default) runs a `SegmentDetector` on the same clean, filtered frames
    as the keyframers: its `SegmentEvent`s (calibration holds, still stretches, takes, open
    and closed) go out in the event stream in order, each noted by every keyframer
    (`OnlineKeyframer.note_segment`) before the keyframers are given the frame that decided
    it. A skeleton without the joints the detector reads (`segments.SEGMENT_ROLES`) runs
    without it. `segments=False`: no detector, no segment events.
    """

    segments: SegmentDetector | None = None  # the stream's detector (None: off; and in
    # snapshots of pipelines from before it, which then run without it)

    def __init__(self, keyframers: Sequence[OnlineKeyframer], stream: str = "default",
                 max_bridge_frames: int | None = None,
                 reset_on_gap: bool = False,
                 noise_cutoff_hz: float | None | EllipsisType = ...,
                 segments: bool = True) -> None:
        if not keyframers:
            raise UsageError("a pipeline needs at least one keyframer")
        first = keyframers[0]
        self.keyframers = list(keyframers)
        self.reset_on_gap = reset_on_gap  # a long gap keeps running statistics unless set
        if max_bridge_frames is None:  # the keyframers' own setting (`--max-bridge`)
            max_bridge_frames = first.guard.max_bridge_frames
        self.guard = StreamGuard(first.skeleton.n_channels, stream, "*", max_bridge_frames)
        self.features = first.features
        # `...`: the keyframers' own setting; else the pipeline's wins
        if noise_cutoff_hz is not ... and noise_cutoff_hz != self.features.noise_cutoff_hz:
            self.features.configure(noise_cutoff_hz)
        self.segments = _detector(self.features, stream) if segments else None
        self._idle_due = False

    @property
    def delay(self) -> int:
        """Frames the noise filter holds each frame (in every event's latency)."""
        return self.features.delay

    def push(self, frame: Frame) -> list[Event]:
        """Feed one frame to every keyframer; returns the events due now. Deferred work (a
        re-analysis) waits for `idle()`, so due decisions leave first; if `idle()` is not
        called, its events come with the next call."""
        events = self.idle()
        before = self.features.given
        events.extend(_drive(self.guard, self.features, self.keyframers, [frame], True,
                             self.reset_on_gap, self.segments))
        self._idle_due = self.features.given != before
        return events

    def idle(self) -> list[Event]:
        """The deferred work of the last pushed frame (same `decided_at`); [] if none."""
        if not self._idle_due:
            return []
        self._idle_due = False
        events: list[Event] = []
        for kf in self.keyframers:
            events.extend(kf.idle())
        return self.features.arrived(events)

    def push_block(self, frames: Iterable[Frame]) -> list[Event]:
        """Feed many frames; same events as pushing them one by one."""
        return self.idle() + _drive(self.guard, self.features, self.keyframers, frames,
                                    reset_on_gap=self.reset_on_gap, detector=self.segments)

    def snapshot(self) -> bytes:
        """Versioned snapshot of every keyframer, the guard and the features (`snapshot.py`)."""
        from .snapshot import snapshot

        return snapshot(self)

    @classmethod
    def restore(cls, data: bytes, params: str | None = None) -> Pipeline:
        """A new pipeline from `snapshot()` bytes; `params`: the digest it must carry."""
        from .snapshot import restore

        return restore(data, cls, params)  # type: ignore[no-any-return]

    def flush(self) -> list[Event]:
        """End of stream for every keyframer."""
        events: list[Event] = self.idle()
        events.extend(_end_window(self.features, self.keyframers, detector=self.segments))
        self._idle_due = False
        self.reset()
        return events

    def reset(self) -> None:
        """Forget the stream (after `flush`, or a fault): every keyframer's window and
        statistics, the guard's last frame, the front end, the open segment."""
        self._idle_due = False
        for kf in self.keyframers:
            kf.reset()
            forget_scores(kf)
        self.guard.reset()
        self.features.reset()
        if self.segments is not None:
            self.segments.reset()


def _detector(stage: FeatureStage, stream: str) -> SegmentDetector | None:
    """The pipeline's segment detector (None: the skeleton lacks the joints it reads)."""
    try:
        return SegmentDetector(stage.skeleton, stage.fps, stream=stream,
                               role_mapping=stage.role_mapping)
    except RoleError:
        return None
