"""Online saliency with the offline default preset "auto" (the registry's online saliency).

Offline `saliency.extract` picks its preset from the body speed (90th percentile) over the
first `AUTO_SECONDS` (1 s) of motion (`saliency.choose_preset`: from the first moving frame
step on, still steps left out). Online, `AutoOnline` runs the "low" and the "high" keyframer
side by side until that second has passed (120 frames at 120 Hz after the motion starts),
then takes the same decision from the same frames and keeps one:

- Before the decision, events come from "low" (its lookahead, 121 frames by default, is the
  longer one and bounds every latency); the events of "high" are held back.
- Decision "low": "low" simply goes on. Decision "high": of the held-back "high" events, those
  after the last one sent and within the lookahead of the decision frame are sent, decided at
  that frame; from then on "high" goes on, its events after the last one sent passed on.
- A stream whose motion lasts less than 1 s is decided at `flush()` from all its frames (as
  offline).

Hence with a lookahead of at least the stream's length (nothing decided before `flush()`) the
events equal offline `extract` with its default exactly, and `params` (after the decision)
equal the offline ones. A preset "low" / "high" given explicitly, or both `sigma` and `k`
(the preset then only names them: "low"), runs that keyframer alone.
A restart forgets the decision (a new stream decides again); `params` keep the last one.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, cast

import numpy as np

from ..errors import UsageError
from ..keyframes import KeyframeEvent
from ..motion import Skeleton
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock, OnlineKeyframer
from ..roles import MIURA_ROLES
from ..segments import SegmentEvent
from ..units import DurationLike
from .saliency import (
    AUTO_SECONDS,
    METHOD,
    PRESETS,
    UPDATE_EVERY,
    Online,
    auto_frames,
    auto_preset,
    moving,
    step_speeds,
)

__all__ = ["AutoOnline"]


class AutoOnline(OnlineKeyframer):
    """Online saliency, preset "auto" by default: decided after the first `AUTO_SECONDS`
    (module docstring); "low" or "high" run a single `saliency.Online`."""

    method = METHOD

    def __init__(self, skeleton: Skeleton, fps: float, *, sigma: DurationLike | None = None,
                 k: int | None = None, contact: bool = True, preset: str = "auto",
                 variance_rule: bool = False, lookahead: DurationLike | None = None,
                 update_every: DurationLike = UPDATE_EVERY, history: DurationLike | None = None,
                 stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES) -> None:
        if preset not in ("auto", *PRESETS):
            raise UsageError(f"saliency: preset must be 'auto', 'low' or 'high', got {preset!r}")
        if preset == "auto" and sigma is not None and k is not None:
            preset = "low"  # sigma and k given: the preset changes nothing but its name
        names = list(PRESETS) if preset == "auto" else [preset]
        self.inners = {name: Online(
            skeleton, fps, sigma=sigma, k=k, contact=contact, preset=name,
            variance_rule=variance_rule, lookahead=lookahead, update_every=update_every,
            history=history, stream=stream, role_mapping=role_mapping,
            max_bridge_frames=max_bridge_frames) for name in names}
        first = self.inners[names[0]]
        look = max(kf.lookahead for kf in self.inners.values())
        params = {**first.params, "preset": preset}
        params.pop("lookahead", None)
        super().__init__(skeleton, fps, lookahead=look, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params=params)
        if preset != "auto":
            self.params = dict(first.params)
        self.requested = preset
        self.horizon = auto_frames(fps)
        self._joints = [self.features.roles[name] for name in MIURA_ROLES]
        self.reset()

    def reset(self) -> None:
        """Forget the stream and the decision (`params` keep the last decision)."""
        for kf in self.inners.values():
            kf.reset()
        self.active: Online | None = (
            None if self.requested == "auto" else self.inners[self.requested])
        self.last_row: np.ndarray | None = None  # Miura-role positions of the newest frame
        self.steps: list[np.ndarray] = []  # the window's moving steps so far (`step_speeds`)
        self.n_steps = 0  # steps seen
        self.first_move = -1  # the first moving step (-1: none yet)
        self.held: list[Any] = []  # "high" events held back until the decision
        self.last = -1  # seq of the last keyframe sent
        self.cut = -1  # after a switch: keys at or before this seq were already covered
        self.dropped: str | None = None  # the preset not chosen, its state freed in `idle()`

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap: the decided preset and its keyframer's running
        statistics are kept (`Online.restart`); before the decision, or without
        `keep_statistics`, everything starts over (`reset`)."""
        if not keep_statistics or self.active is None:
            self.reset()
            return
        self.active.restart(keep_statistics=True)
        self.held, self.last, self.cut = [], -1, -1

    def note_segment(self, event: SegmentEvent) -> None:
        """The pipeline's segment hook, passed to the running keyframer(s)
        (`Online.note_segment`)."""
        for kf in self.inners.values():
            kf.note_segment(event)

    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: the running keyframer's candidates, none at or before a switch's
        cut; before the decision both presets' (either may be the one kept)."""
        if self.active is None:
            return sorted(self.inners["low"].candidates() + self.inners["high"].candidates())
        return [c for c in self.active.candidates() if c[0] > self.cut]

    @property
    def trace(self) -> Any:
        """(seq, saliency) of the classified frames, of the running keyframer ("low" before
        the decision)."""
        return (self.active or self.inners["low"]).trace

    # ------------------------------------------------------------------ stream
    def process(self, block: FeatureBlock) -> list[Any]:
        """Both presets until the decision frame, then the chosen one."""
        self._free()
        if self.active is not None:
            return self._pass(self.active.process(block))
        # read for the decision only: later blocks do not compute these joints for it
        p = block.pelvis_points(self._joints, keep=False) / self.features.body_height
        rows = p if self.last_row is None else np.concatenate([self.last_row[None], p])
        self.last_row = p[-1].copy()
        steps = step_speeds(rows)  # step j ends at block frame j + 1 - (len(rows) - len(block))
        mv = moving(steps, self.fps)
        g0 = self.n_steps  # the stream's index of this block's first step
        self.n_steps += len(steps)
        if self.first_move < 0 and mv.any():
            self.first_move = g0 + int(np.argmax(mv))
        end, decided = len(block), False
        if self.first_move >= 0:
            last = self.first_move + self.horizon - 2 - g0  # the window's last step, here
            self.steps.append(steps[np.flatnonzero(mv[: last + 1])])
            if last < len(steps):
                decided, end = True, last + 2 - (len(rows) - len(block))
        head = block if end >= len(block) else block.slice(0, end)
        out = self._both(self.inners["low"].process(head), self.inners["high"].process(head))
        if decided:
            out += self._decide(int(head.seq[-1]))
            if len(head) < len(block):
                # `_decide` has just set `active` (mypy keeps the narrowing to None from above)
                active = cast(Online, self.active)
                out += self._pass(active.process(block.slice(end, len(block))))
        return out

    def idle(self) -> list[Any]:
        """Deferred work of the running keyframer(s); the preset not chosen is freed."""
        self._free()
        if self.active is not None:
            return self._pass(self.active.idle())
        return self._both(self.inners["low"].idle(), self.inners["high"].idle())

    def finish(self) -> list[Any]:
        """End of stream: decide now if the stream was shorter than the decision window."""
        out: list[Any] = []
        if self.active is None:
            if self.last_row is None:
                return []
            out += self._decide(self.inners["low"].seq0 + self.inners["low"].t)
        assert self.active is not None
        return out + self._pass(self.active.finish())

    # ------------------------------------------------------------------ decision
    def _free(self) -> None:
        if self.dropped is not None:
            self.inners[self.dropped].reset()
            self.dropped = None

    def _both(self, low: list[Any], high: list[Any]) -> list[Any]:
        self.held.extend(high)
        return self._pass(low)

    def _pass(self, events: list[Any]) -> list[Any]:
        out = []
        for e in events:
            if getattr(e, "frame", self.cut + 1) <= self.cut:
                continue
            if isinstance(e, KeyframeEvent):
                self.last = max(self.last, e.frame)
            out.append(e)
        return out

    def _decide(self, seq: int) -> list[Any]:
        """Choose the preset from the recorded frames; switch to "high" if it is chosen."""
        steps = np.concatenate(self.steps) if self.steps else np.zeros((0, 1))
        name, speed = auto_preset(steps, self.fps)
        self.active = self.inners[name]
        self.params = {**self.active.params, "auto_speed": speed, "auto_seconds": AUTO_SECONDS}
        held, self.held, self.steps, self.last_row = self.held, [], [], None
        self.dropped = "high" if name == "low" else "low"  # freed after this frame
        if name == "low":
            return []
        self.cut = self.last
        due = [replace(e, decided_at=seq) if isinstance(e, KeyframeEvent) else e
               for e in held if seq - getattr(e, "frame", seq) <= self.lookahead]
        return self._pass(due)
