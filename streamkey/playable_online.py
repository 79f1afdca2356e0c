"""The online side of playable events (`streamkey.playable`): the `MinInterval` and `Playable`
wrappers around any online keyframer, and their wiring (`wrap`, `link_signal`). The rules
are documented in `streamkey.playable`; this module holds what needs the online machinery.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from typing import Any

import numpy as np

from .errors import UsageError
from .keyframes import (
    CancelEvent,
    Event,
    KeyframeEvent,
    ProvisionalEvent,
    SignalEvent,
    rank_strength,
)
from .online import FeatureBlock, OnlineKeyframer, WrappedKeyframer
from .playable import RADIUS_SECONDS, SIGNAL_SMOOTHING_SECONDS, Debouncer, interval_frames
from .roles import MIURA_ROLES

__all__ = ["MinInterval", "Playable", "wrap", "link_signal"]


class MinInterval(WrappedKeyframer):
    """Any online keyframer with `--min-interval`: the debounce rule online (module
    docstring). Latency: the inner lookahead plus the interval, at most."""

    def __init__(self, inner: OnlineKeyframer, seconds: float) -> None:
        self.gap = interval_frames(seconds, inner.fps)  # the shortest interval, frames
        super().__init__(inner, lookahead=inner.lookahead + self.gap,
                         params={**inner.params, "min_interval": seconds})
        self.reset()

    def _forget(self) -> None:
        """The debounce starts over."""
        self.debouncer = Debouncer(self.gap)
        self.t = -1

    @property
    def trace(self) -> Any:
        """The inner keyframer's live trace (saliency), if any."""
        return getattr(self.inner, "trace", None)

    def candidates(self) -> list[tuple[int, float, float]]:
        """The inner candidates and the key held back (provisional hook)."""
        held = self.debouncer.held
        own = [] if held is None else [(held[2].frame, held[2].time, held[2].score)]
        return own + self.inner.candidates()

    def _release(self, items: list[KeyframeEvent], t: int) -> list[KeyframeEvent]:
        return [e if e.decided_at >= t else dataclasses.replace(e, decided_at=t,
                                                                 lookahead=self.lookahead)
                for e in items]

    def _offer(self, events: list[Event], upto: int | None) -> tuple[list[Event], int]:
        """Offer the inner events decided at frames <= upto (all if None)."""
        out: list[Event] = []
        for i, e in enumerate(events):
            if upto is not None and isinstance(e, KeyframeEvent) and e.decided_at > upto:
                return out, i
            if isinstance(e, KeyframeEvent):
                out += self._release(self.debouncer.offer(e.frame, e.score, e), e.decided_at)
            else:
                out.append(e)
        return out, len(events)

    def process(self, block: FeatureBlock) -> list[Event]:
        """The inner keyframer over the block; the debounce frame by frame after it."""
        events: list[Event] = list(self.inner.process(block))
        out: list[Event] = []
        seqs = block.seq.tolist()
        last = len(seqs) - 1
        for i, t in enumerate(seqs):
            got, used = self._offer(events, t)
            out += got
            events = events[used:]
            # Inside a block the inner deferred work already ran; at its end it waits for idle.
            final = t - self.inner.lookahead - (1 if i == last else 0)
            out += self._release(self.debouncer.due(final), t)
        if events:
            out += self._offer(events, None)[0]
        if seqs:
            self.t = seqs[-1]
        return out

    def idle(self) -> list[Event]:
        """The inner deferred work, then what it settles."""
        out = self._offer(list(self.inner.idle()), None)[0]
        if self.t >= 0:
            out += self._release(self.debouncer.due(self.t - self.inner.lookahead), self.t)
        return out

    def finish(self) -> list[Event]:
        """End of stream: the inner rest, then the held key."""
        out = self._offer(list(self.inner.finish()), None)[0]
        return out + self._release(self.debouncer.finish(), self.t)


class Playable(WrappedKeyframer):
    """Any online keyframer with provisional events and/or the keyness signal (module
    docstring). Final events pass unchanged but for `confirms`."""

    def __init__(self, inner: OnlineKeyframer, provisional: bool = True,
                 signal_every: int = 0) -> None:
        if isinstance(signal_every, bool) or not isinstance(signal_every, int) or (
                signal_every < 0):
            raise UsageError(f"signal: decimation must be an integer >= 1, got {signal_every!r}")
        super().__init__(inner, lookahead=inner.lookahead, params=dict(inner.params))
        self.provisional = bool(provisional)
        self.signal_every = int(signal_every)
        self.radius = max(1, int(round(RADIUS_SECONDS * inner.fps)))
        self.scorer = self.innermost  # whose recent scores rank the candidates
        self.siblings: list[Playable] = []  # the signal's other methods (set by link_signal)
        self.sends_signal = signal_every > 0
        self.next_pid = 0
        self._joints = [self.features.roles[name] for name in MIURA_ROLES]
        self.reset()

    def _forget(self) -> None:
        """The provisional bookkeeping starts over (`finish` resolved it); pids keep
        counting."""
        self.open: dict[int, list[Any]] = {}  # pid: [frame, time, strength]
        self.keys: deque[int] = deque(maxlen=8)  # frames of the last final keys
        self.t = -1
        self.keyness: dict[int, float] = {}  # seq: keyness, until the sender has read it
        self.speed = 0.0
        self._prev: np.ndarray | None = None

    @property
    def trace(self) -> Any:
        """The inner keyframer's live trace (saliency), if any."""
        return getattr(self.inner, "trace", None)

    def _strength(self, score: float) -> float:
        recent = list(self.scorer.recent_scores)
        return rank_strength(recent + [score], score)

    def _nearest(self, frame: int) -> int | None:
        best = None
        for pid, p in self.open.items():
            d = abs(p[0] - frame)
            if d <= self.radius and (best is None or d < best[0]):
                best = (d, pid)
        return None if best is None else best[1]

    def _new(self, frame: int, time: float, strength: float, t: int) -> ProvisionalEvent:
        pid, self.next_pid = self.next_pid, self.next_pid + 1
        frame, time, strength = int(frame), float(time), float(strength)
        self.open[pid] = [frame, time, strength]
        return ProvisionalEvent(stream=self.stream, method=self.method, frame=frame, time=time,
                                strength=strength, seen_at=int(t), pid=pid)

    def _track(self, events: list[Event], t: int, final: int, announce: bool = True
               ) -> list[Event]:
        """Confirm with the final keys, announce new candidates, cancel what was passed."""
        if not self.provisional:
            return list(events)
        out: list[Event] = []
        for e in events:
            if not isinstance(e, KeyframeEvent):
                out.append(e)
                continue
            pid = self._nearest(e.frame)
            if pid is None:
                out.append(self._new(e.frame, e.time, e.strength, t))
                pid = self.next_pid - 1
            del self.open[pid]
            self.keys.append(e.frame)
            out.append(dataclasses.replace(e, confirms=pid))
        for frame, time, score in (self.inner.candidates() if announce else []):
            if frame <= final or frame in self.keys:
                continue  # decided, or a key just sent (a candidate list may lag a little)
            pid = self._nearest(frame)
            if pid is None:
                out.append(self._new(frame, time, self._strength(score), t))
            else:
                self.open[pid][0:2] = [int(frame), float(time)]
        for pid in [p for p, v in self.open.items() if v[0] + self.radius <= final]:
            out.append(CancelEvent(stream=self.stream, method=self.method,
                                   frame=self.open.pop(pid)[0], pid=pid, decided_at=t))
        return out

    def _keyness(self, final: int) -> float:
        strengths = [self._strength(s) for f, _, s in self.inner.candidates() if f > final]
        return max(strengths, default=0.0)

    def _signal(self, block: FeatureBlock, i: int, t: int, final: int) -> list[Event]:
        """Log this frame's keyness; the sender (the pipeline's last keyframer, which runs
        after the others have processed the block) reads everyone's, adds the body speed and
        sends (decimated)."""
        self.keyness[t] = self._keyness(final)
        if not self.sends_signal:
            return []
        values = {"body_speed": 0.0}
        for kf in [*self.siblings, self]:
            values[kf.method] = kf.keyness.get(t, 0.0)
            for seq in [s for s in kf.keyness if s <= t]:
                del kf.keyness[seq]
        rows = block.slice(i, i + 1).pelvis_points(self._joints)[0] / self.features.body_height
        if self._prev is not None:
            raw = float(np.linalg.norm(rows - self._prev, axis=1).mean() * self.fps)
            a = 1.0 - math.exp(-1.0 / (SIGNAL_SMOOTHING_SECONDS * self.fps))
            self.speed += a * (raw - self.speed)
        self._prev = rows
        if t % self.signal_every:
            return []
        values["body_speed"] = self.speed
        return [SignalEvent(stream=self.stream, seq=t, time=float(block.time[i]), values=values)]

    def process(self, block: FeatureBlock) -> list[Event]:
        """The inner keyframer frame by frame (its deferred work between frames), tracking
        after each step."""
        out: list[Event] = []
        n = len(block)
        for i in range(n):
            part = block if n == 1 else block.slice(i, i + 1)
            t = self.t = int(block.seq[i])
            final = t - self.lookahead - 1  # before the deferred work of frame t
            out += self._track(list(self.inner.process(part)), t, final, False)
            if self.signal_every:
                out += self._signal(block, i, t, final)
            if i < n - 1:
                out += self._track(list(self.inner.idle()), t, final + 1)
        return out

    def idle(self) -> list[Event]:
        """The inner deferred work of the last frame, tracked; new candidates are announced
        here, once a frame (after the deferred work, which may change them)."""
        events: list[Event] = list(self.inner.idle())
        return self._track(events, self.t, self.t - self.lookahead) if self.t >= 0 else events

    def finish(self) -> list[Event]:
        """End of stream or window: the inner rest; every open provisional resolved."""
        out = self._track(list(self.inner.finish()), self.t, self.t - self.lookahead, False)
        for pid, p in sorted(self.open.items()):
            out.append(CancelEvent(stream=self.stream, method=self.method, frame=p[0], pid=pid,
                                   decided_at=self.t))
        self.open.clear()
        return out


def wrap(kf: OnlineKeyframer, options: dict[str, Any]) -> OnlineKeyframer:
    """`kf` with the playable options of `params["*"]`: min_interval
    ({method or "*": seconds}), provisional (bool), signal (every N frames, 0 = off)."""
    intervals = options.get("min_interval") or {}
    seconds = intervals.get(kf.method, intervals.get("*"))
    if seconds:
        kf = MinInterval(kf, seconds)
    provisional, signal = bool(options.get("provisional")), int(options.get("signal") or 0)
    if provisional or signal:
        kf = Playable(kf, provisional, signal)
    return kf


def link_signal(keyframers: list[OnlineKeyframer]) -> None:
    """One signal per stream: the last keyframer sends it with the others' keyness."""
    mine = [kf for kf in keyframers if isinstance(kf, Playable) and kf.signal_every]
    for kf in mine[:-1]:
        kf.sends_signal = False
    if mine:
        mine[-1].siblings = mine[:-1]
