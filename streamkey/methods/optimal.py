"""Optimal keys: the keys that minimise the error of linearly interpolating the
body between them, by dynamic programming — offline `extract` and online `Online`.

Definitions this module settles:

- Curve: per captured frame, the skeleton's joints (ROOT and JOINT, not End Sites) minus the
  root joint, in world orientation — the points of the evaluation's E — divided by body
  height and √joints (`optimal_math.body_rows`; optional per-joint weights, optional root
  translation). |difference|² of two rows is then a mean squared joint distance in body
  heights², the unit of the evaluation's E / h².
- Segment cost(a, b): the integral over the time strictly inside (a, b) of the squared
  distance to the linear interpolation between a and b — Σ over the frames inside, from
  prefix sums (`optimal_math.Pricer`), times the frame time — in ticks × body heights², a
  tick being 1/120 s (`TICKS_PER_SECOND`; a frame at 120 Hz, so costs and λ there are
  today's frame sums). Being integrals over time, the costs of a take are the same at any
  capture rate, so are the keys. At most `max_segment` (default 2 s) between keys. The
  first and the last captured frames are always keys.
- Penalised form (the common core): minimise Σ cost + λ · keys. Ties go to the earliest
  predecessor, so the result is deterministic. (The DP adds frame sums and λ / ticks per
  frame: the same minimiser, and bit for bit today's at 120 Hz.)
- `count=K`: exactly K keys minimising Σ cost. Exact K-key DP when frames × K × L is small
  (≤ 4·10⁷); else a search over λ of the penalised form, and if no λ lands on K, the nearest
  λ solution with keys removed (least cost increase) or inserted (largest cost decrease) one
  at a time; `info["solver"]` and `info["lambda_count"]` say which. If K keys cannot cover
  the clip with segments ≤ L, L is stretched to fit.
- `rate=R` keys per second of motion: the penalised form with λ from a running controller
  (below), the same computation online and offline. `lam=λ` fixes λ (units: ticks × body
  heights²).
- `tolerance=T`: the fewest keys such that every stretch (a, b] between consecutive keys has a
  mean error ≤ T over its frames (body heights², the evaluation's E / h² of the linear
  interpolation of the curve; so the whole take's mean meets T too), ties to the least cost.
  A mean over frames is a mean over time: the same at any rate.

Online (`Online`): each frame's segments are priced as it arrives, in `idle` once the push's
events have left (`optimal_math.Pricer`, frame after frame in a fixed order, so offline
pricing a chunk or the whole take gets the same bits); the DP runs in chunks
(`chunk_frames`: 16 frames at 120 Hz, 2/15 s) aligned at stream index 0, as offline does,
so the chunk-completing push pays only for its own frame's pricing, the DP, the decisions
and the events. F(b) keeps back-pointers.
A key is final once every back-pointer chain from the frames that could still precede a
future key (the last L frames) passes through it (Viterbi traceback convergence). When the
oldest undecided frame is `lookahead` frames old, the chain of the newest priced frame
decides it and everything before it; later chains are re-priced to pass through that
decision (only the frames whose chains it broke, on the next frame: `Solver.settle`).
Events carry latency_frames ≤ lookahead (`lookahead` a `Duration`, default 1 s, or a plain
number of frames; in frames at the stream's rate at least a chunk). With
an unbounded lookahead nothing is forced and `flush()` traces back from the last frame: the
offline result exactly.

Rate mode (R keys a second, s = fps / R frames a key): on the shared clips the λ that gives
5 % of frames is 3.2× the geometric mean cost of s-frame segments (within a factor of 1.5 on
most clips), where λ itself spans three orders of magnitude. So λ = 3.2 · exp(mean log
cost(b − s, b)), the mean over the motion seconds priced so far plus `PRIOR_SECONDS` (10 s)
of motion at the prior (`DEFAULT_LAMBDA` = 3.5·10⁻³ at 5 %, the shared clips' median,
scaled as (s in ticks)⁵ for other rates). Motion seconds: each frame b weighs its frame
time, times min(1, mean squared departure of its key-spaced segment from a straight line /
`STILL_COST`) (`motion_weights`): a stretch that stays within 1e-4 body heights (RMS) of a
straight line over 1/R s — a calibration hold, stillness after the take, a held pose —
needs no keys and adds nothing to the mean, so it neither earns keys nor drags λ down and
spends keys in the take (a zero cost weighed in fully would pull λ towards the log floor).
Recorded holds move more (the stillest 1/6 s stretches of the CMU clips depart ≥ 1.6·10⁻⁴
body heights RMS), so the session segments decide too: frames of a calibration hold or a
still stretch (`streamkey.segments`: the body's speed below 0.07 body heights a second for
0.5 s) weigh nothing (`optimal_solver.MotionFrames`). Online a keyframer-owned
`SegmentDetector` reads the same feature blocks; a frame's status is final
`settle_frames` later (0.5 s + 0.2 s), and the controller counts a chunk of frames once
all of them are final, chunk after chunk, so its sums are offline's bit for bit; until
then the chunk counts provisionally, as motion unless inside a hold already found. In a
`Pipeline` the keyframer takes the pipeline's segment events instead (`note_segment`; its
own detector then stops): the same segments by the same chunk ends, so the same keys.
(49_18, balancing on one leg, holds still for 6 of its 9 s: λ 1.44·10⁻³ instead of
4.6·10⁻⁴.) No key falls strictly inside a calibration hold (`hold_keys=True` allows them): a chain
enters a hold at its first frame or jumps over all of it, and a hold longer than
`max_segment` is one segment (`optimal_solver.Solver.hold`); online, every solved frame a
newly found or closed hold changes is solved again. Only calibration holds are keyless
(`KEYLESS`): still stretches are not perfectly still, and with them keyless too E rose where
they are long (49_18: 11 keys, E 25x; 05_02, 05_18: 2.2x). At stream start λ is the
prior; the data takes over as the stream goes on, which keeps λ steady on short takes (a
moving λ spends keys unevenly).
Online, whenever the estimate moves by more than 5 % (`RESOLVE`) every undecided frame is
solved again with it (frames a deadline decided without a key stay keyless: a re-solve that
reopened them let a later chain pass through one, whose key was then never sent); since λ
still moves, converged chains are not final in rate mode and
keys are decided at the deadline. Offline, λ is the estimate after the whole take (one
penalised pass); with an unbounded lookahead `flush()` solves everything with that same λ,
so the two agree exactly. The key count follows the rate only as far as the estimate is
right (0.3–1.7 × on the shared clips, most within ±15 %); the same take at 60 or 30 Hz,
after a calibration hold or followed by stillness gets 0.91–1.07 × the clean take's keys
on every shared clip, offline and online.

Deadlines are checked once a chunk, deciding every frame whose deadline falls before the
next chunk is complete (so the effective lookahead is `lookahead` − (chunk − 1) frames to
`lookahead`: 0.875 to 1 s by default, at 120 Hz as at 30 Hz).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import UsageError
from ..features import DEFAULT_NOISE_CUTOFF_HZ, Features, compute_features
from ..keyframes import Event, KeyframeEvent, Keyframes, params_digest
from ..motion import Motion, Skeleton, without_lead
from ..online import (
    DEFAULT_MAX_BRIDGE_FRAMES,
    FeatureBlock,
    OnlineKeyframer,
    WrappedKeyframer,
)
from ..segments import SegmentDetector, SegmentEvent
from ..units import Duration, DurationLike, whole_frames
from . import optimal_math as om
from .optimal_offline import count_keys, rate_keys, solve_all
from .optimal_solver import (
    DEFAULT_LAMBDA,
    PRIOR_SECONDS,
    RATE_FACTOR,
    RESOLVE,
    STILL_COST,
    TICKS_PER_SECOND,
    Solver,
    motion_weights,
)
from .ring import RingWindow

__all__ = ["extract", "curve", "Solver", "Online", "MaxGap", "max_gap", "METHOD",
           "DEFAULT_LOOKAHEAD", "DEFAULT_MAX_SEGMENT", "DEFAULT_RATE", "DEFAULT_LAMBDA",
           "TICKS_PER_SECOND", "PRIOR_SECONDS", "RESOLVE", "RATE_FACTOR", "STILL_COST",
           "motion_weights", "chunk_frames", "key_scores", "holds"]

METHOD = "optimal"
DEFAULT_LOOKAHEAD = Duration.seconds(1.0)  # 120 frames at 120 Hz
DEFAULT_MAX_SEGMENT = 2.0  # seconds
DEFAULT_RATE = 6.0  # keys per second of motion: 5 % of frames at 120 Hz
# Segments that get no key inside (rate mode, unless hold_keys): calibration holds only. Still
# stretches are not perfectly still (49_18 balances on one leg for 5 s), and a chain that
# jumps over them costs E: with them keyless, 49_18's E rose 25x and lost to uniform keys.
KEYLESS = ("calibration",)


def curve(motion: Motion, features: Features | None = None, weights: np.ndarray | None = None,
          root_translation: bool = False) -> np.ndarray:
    """Curve rows (captured frames x D) of `motion` (module docstring)."""
    feats = features if features is not None else compute_features(motion)
    scale = om.point_scale(motion.skeleton.n_joints, feats.body_height, weights,
                           root_translation)
    return om.body_rows(feats.fk.positions[motion.first_frame :], scale, root_translation)


def _frames(span: DurationLike, fps: float, name: str) -> int:
    """Frames of a span given as a `Duration`, or as a plain number of seconds (what
    `max_segment` and `max_gap` have always taken); at least 2."""
    value = span.value if isinstance(span, Duration) else span
    if isinstance(value, bool) or not (isinstance(value, int | float) and math.isfinite(value)
                                       and value > 0):
        raise UsageError(f"{name} must be a positive duration (seconds), got {span!r}")
    seconds = span if isinstance(span, Duration) else Duration.seconds(float(value))
    return max(2, whole_frames(seconds, fps))


def _span_param(span: DurationLike) -> float | str:
    """A span as recorded in the parameters: seconds as a number (as before units were
    explicit), a frame count as text."""
    if isinstance(span, Duration):
        return span.value if span.unit == "s" else str(span)
    return float(span)


def chunk_frames(fps: float) -> int:
    """Frames solved together at `fps`: `optimal_math.CHUNK` (16) at 120 Hz and above, the
    same time (2/15 s) at lower rates, so deadlines fall as finely in time at any rate."""
    return max(1, min(om.CHUNK, int(round(om.CHUNK * fps / TICKS_PER_SECOND))))


def _lookahead_frames(lookahead: DurationLike, fps: float) -> int:
    """The lookahead in frames of the stream (a plain number is a frame count), at least a
    chunk (`chunk_frames`)."""
    if isinstance(lookahead, Duration):
        ok = math.isfinite(lookahead.value)
    else:
        ok = isinstance(lookahead, int | np.integer) and not isinstance(lookahead, bool)
    frames = whole_frames(lookahead, fps) if ok else -1
    chunk = chunk_frames(fps)
    if frames < chunk:
        raise UsageError(f"optimal online: lookahead must be a whole number of frames or a "
                         f"Duration of at least {chunk} frames ({chunk / fps:.3g} s at "
                         f"{fps:g} Hz), got {lookahead!r}")
    return frames


def _hold_param(hold_keys: bool) -> dict[str, bool]:
    """`hold_keys` in the parameters only when set (the default leaves them as they were)."""
    return {"hold_keys": True} if hold_keys else {}


def _mode(count: int | None, rate: float | None, tolerance: float | None,
          lam: float | None) -> dict[str, Any]:
    given = {k: v for k, v in (("count", count), ("rate", rate), ("tolerance", tolerance),
                               ("lam", lam)) if v is not None}
    if len(given) > 1:
        raise UsageError("optimal: give at most one of count, rate, tolerance, lam")
    if not given:
        return {"rate": DEFAULT_RATE}
    (name, value), = given.items()
    if name == "count":
        if isinstance(value, bool) or int(value) != value or value < 2:
            raise UsageError(f"count must be an integer >= 2, got {value!r}")
        return {"count": int(value)}
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise UsageError(f"{name} must be a positive number, got {value!r}")
    return {name: float(value)}



def extract(motion: Motion, *, count: int | None = None, rate: float | None = None,
            tolerance: float | None = None, lam: float | None = None,
            max_segment: DurationLike = DEFAULT_MAX_SEGMENT, weights: np.ndarray | None = None,
            root_translation: bool = False, features: Features | None = None,
            noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ,
            hold_keys: bool = False) -> Keyframes:
    """Optimal keys of `motion` (module docstring); default mode: `rate=DEFAULT_RATE`.
    `max_segment`: a `Duration`, or a plain number of seconds. `hold_keys`: rate mode may
    put keys inside calibration holds and still stretches."""
    motion = without_lead(motion)  # a stream drops them too (`filters.FrontEnd`)
    mode = _mode(count, rate, tolerance, lam)
    max_len = _frames(max_segment, motion.fps, "max_segment")
    ticks = TICKS_PER_SECOND / motion.fps
    features = features or compute_features(motion, noise_cutoff_hz=noise_cutoff_hz)
    x = curve(motion, features, weights, root_translation)
    n = len(x)
    if n == 0:
        raise UsageError("the motion has no captured frames")
    params: dict[str, Any] = {**mode, "max_segment": _span_param(max_segment),
                              "root_translation": root_translation,
                              "weights": None if weights is None else list(weights),
                              **_hold_param(hold_keys)}
    info: dict[str, Any] = {}
    if n == 1:
        rows, err = np.zeros(1, dtype=np.int64), np.zeros(0)
    elif "count" in mode:
        if mode["count"] > n:
            raise UsageError(f"count must be in [2, {n}] (captured frames), got {count}")
        rows, info = count_keys(x, mode["count"], max_len)
        err = om.pair_costs(x, rows[:-1], rows[1:])
    elif "rate" in mode:
        found = holds(motion, features)
        rows, err, info["lambda"] = rate_keys(x, max_len, mode["rate"] / motion.fps, ticks,
                                              chunk_frames(motion.fps), found, hold_keys,
                                              holds(motion, features, KEYLESS))
    else:
        rows, err = solve_all(x, max_len, ticks, **mode)
    info["error"] = float(err.sum() / n)  # mean per-frame error, body heights^2 (lerp proxy)
    scores = key_scores(x, rows, ticks)
    return Keyframes(METHOD, rows + motion.first_frame, scores, params, motion.n_frames, info)


def holds(motion: Motion, features: Features,
          kinds: tuple[str, ...] = ("calibration", "still")) -> list[tuple[int, int]]:
    """The segments of `kinds` (calibration holds, still stretches: `streamkey.segments`) of
    `motion` as (first, last) rows of the curve: what the online keyframer's own
    `SegmentDetector` finds."""
    det = SegmentDetector(motion.skeleton, motion.fps)
    points = features.pelvis_points(det.points)[motion.first_frame :]
    seq = np.arange(motion.first_frame, motion.n_frames)
    events = det.push_points(seq, seq / motion.fps, points) + det.flush()
    return [(e.start - motion.first_frame, e.end - motion.first_frame) for e in events
            if e.end is not None and e.kind in kinds]


def key_scores(x: np.ndarray, rows: np.ndarray, ticks: float = 1.0) -> np.ndarray:
    """A key's score: the cost of the segment it ends (the first key: 0), in ticks x body
    heights² (`ticks` per frame), each segment summed alone (`optimal_math.chain_costs`), so
    offline and online (which knows it once the key is decided) agree bit for bit."""
    scores: np.ndarray = om.chain_costs(np.ascontiguousarray(x, dtype=np.float64),
                                        np.asarray(rows, dtype=np.int64)) * ticks
    return scores


class Online(OnlineKeyframer):
    """Online optimal keys: the penalised DP with traceback convergence and a lookahead
    deadline (module docstring); rate (default), fixed λ or tolerance mode."""

    method = METHOD

    def __init__(self, skeleton: Skeleton, fps: float, *, rate: float | None = None,
                 tolerance: float | None = None, lam: float | None = None,
                 max_segment: DurationLike = DEFAULT_MAX_SEGMENT,
                 weights: np.ndarray | None = None, root_translation: bool = False,
                 lookahead: DurationLike = DEFAULT_LOOKAHEAD,
                 count: int | None = None, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES,
                 hold_keys: bool = False) -> None:
        if count is not None:
            raise UsageError("optimal online: a key count needs the whole take; give a rate "
                             "(keys per second) or a tolerance")
        mode = _mode(None, rate, tolerance, lam)
        frames = _lookahead_frames(lookahead, fps)
        self.max_len = _frames(max_segment, fps, "max_segment")  # longest segment, frames
        self.ticks = TICKS_PER_SECOND / float(fps)  # ticks (1/120 s) per frame
        super().__init__(skeleton, fps, lookahead=frames, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params={**mode, "max_segment": _span_param(max_segment),
                                 "root_translation": root_translation,
                                 "weights": None if weights is None else list(weights),
                                 **_hold_param(hold_keys)})
        self.hold_keys = hold_keys  # rate mode: keys inside holds and still stretches allowed
        self.mode = mode  # {"rate" | "lam" | "tolerance": value}
        self.weights = None if weights is None else np.asarray(  # per joint, or None
            weights, dtype=np.float64)
        self.root_translation = root_translation  # the root's position is a curve point
        self.scale = om.point_scale(skeleton.n_joints, self.features.body_height, self.weights,
                                    root_translation)
        # rate mode: the session segments, whose holds stay out of λ (`RateController`);
        # None once a pipeline notes them (`note_segment`: its detector is the same one)
        det = SegmentDetector(skeleton, fps, stream=stream, role_mapping=role_mapping)
        self.segments: SegmentDetector | None = det
        # frames after which a frame's segment status is final: a still stretch is confirmed
        # `min_still` after it starts, its speed known `half` frames after each frame
        self.settle_frames = det.min_still - 1 + det.half
        self.reset()

    def reset(self) -> None:
        """Forget the stream; keep parameters."""
        kw = {"rate": self.mode["rate"] / self.fps} if "rate" in self.mode else dict(self.mode)
        self.solver = Solver(  # the DP over the stream
            self.max_len, keep_costs=True, ticks=self.ticks, chunk=chunk_frames(self.fps), **kw)
        self.solver.pricer.prepare(3 * len(self.scale))
        if self.segments is not None:
            self.segments.reset()
        self.held_points: list[np.ndarray] = []  # pelvis-frame points not yet detected
        # times of the newest frames, enough for every undecided one: a deadline leaves at
        # most lookahead + 1 frames undecided (`force` at each chunk end)
        self.frames = RingWindow(self.lookahead + 2 * self.solver.chunk + 2, 0)
        self.seq0 = 0  # sequence number of stream index 0 (a window's frames are consecutive)
        self.prev_key: int | None = None  # stream index of the last key sent

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap or a source restart: the rate controller's cost
        statistics (hence λ) are kept, so the key rate holds from the new window's first
        frames. Without them: `reset()`."""
        rate = self.solver.rate
        self.reset()
        if keep_statistics and rate is not None:
            rate.new_window()
            self.solver.rate = rate
            self.solver.lam = rate.estimate() / self.solver.ticks

    def _events(self, keys: list[int], decided_at: int) -> list[KeyframeEvent]:
        out = []
        s = self.solver
        for k in keys:
            prev, self.prev_key = self.prev_key, k
            score = 0.0 if prev is None else key_scores(
                s.rows.x, np.array([prev, k]) - s.base, s.ticks)[1]
            seq = self.seq0 + k
            out.append(self.event(frame=seq, time=self.frames.time(seq), score=score,
                                  decided_at=decided_at))
        return out

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Append the block's frames; decide what converged or reached its deadline."""
        rows = om.body_rows(block.positions, self.scale, self.root_translation)
        s = self.solver
        events: list[KeyframeEvent] = []
        if s.n == 0 and len(block):
            self.seq0 = int(block.seq[0])
        det = self.segments if s.rate is not None else None
        points = block.pelvis_points(det.points) if det is not None else None
        no_values = np.empty((1, 0))
        for i in range(len(block)):
            self.frames.extend(int(block.seq[i]), no_values, block.time[i : i + 1])
            if points is not None:
                self.held_points.append(points[i])
            if s.rate is not None and (s.n + 1) % s.chunk == 0:  # statuses, once a chunk
                self._detect(s.n)
            if s.stale is not None:  # the frame after a chunk's: its decision's re-solve
                s.settle()
            for end in s.add(rows[i : i + 1]):
                keys = [] if s.rate is not None else s.converge()
                d = end + s.chunk - 1 - self.lookahead
                if d > s.decided:
                    keys += s.force(d)
                events += self._events(keys, int(block.seq[i]))
        return events

    def idle(self) -> list[KeyframeEvent]:
        """Deferred work of the last frame, after its events left: the re-solve its deadline
        decision left (`Solver.settle`) and the pricing of its segments (`Solver.price`);
        else the next frame, or the chunk's last, does them first."""
        self.solver.settle()
        self.solver.price()
        return []

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: the chain from the last frame decides the rest."""
        s = self.solver
        if s.rate is not None:
            self._detect(s.n - 1)
            if self.segments is not None:
                self._note(self.segments.finish())
            s.rate.motion.known = s.n
        if s.n == 0:
            return []
        return self._events(s.finish(), self.seq0 + s.n - 1)

    def _detect(self, last: int) -> None:
        """Statuses up to stream index `last`, at stream indices fixed by the chunks (so a
        frame's status is known at the same frame whatever the block split): the held frames
        to the own segment detector (when no pipeline notes segments), then the frames
        `settle_frames` back have their final status (segments decided by frames up to
        `last` are in, whoever detected them)."""
        s = self.solver
        assert s.rate is not None
        if self.held_points and self.segments is not None:
            seqs = np.arange(last + 1 - len(self.held_points), last + 1) + self.seq0
            times = [self.frames.time(int(q)) for q in seqs]
            self._note(self.segments.push_points(seqs, times, np.array(self.held_points)))
        self.held_points.clear()
        s.rate.motion.known = max(s.rate.motion.known, last + 1 - self.settle_frames)

    def note_segment(self, event: SegmentEvent) -> None:
        """The pipeline's hook: a session segment decided by the next frame. From the first
        call on, the keyframer's own detector stops (the pipeline's is the same detector on
        the same frames, and a segment reaches the solver by the same chunk end either way,
        so the keys are the same)."""
        self.segments = None
        self.held_points.clear()
        if self.solver.rate is not None:
            self._note([event])

    def _note(self, events: list[SegmentEvent]) -> None:
        """Calibration holds and still stretches to the rate controller and, unless
        `hold_keys`, calibration holds to the DP (no key strictly inside)."""
        assert self.solver.rate is not None
        for e in events:
            if e.kind != "take":
                end = None if e.end is None else e.end - self.seq0
                self.solver.rate.motion.hold(e.start - self.seq0, end)
                if not self.hold_keys and e.kind in KEYLESS:
                    self.solver.hold(e.start - self.seq0, end)

    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: the keys after the decided part on the best chain of the newest
        priced frame (what a deadline would take now), that frame itself left out."""
        s = self.solver
        if s.stale is not None or s.done == 0:
            return []
        path = om.chain(s.rows.bp, s.done - 1 - s.base, s.decided - s.base)
        first = self.frames.first_seq
        seqs = [self.seq0 + k + s.base for k in path[:-1]]
        return [(q, self.frames.time(q), 0.0) for q in seqs if first <= q < first + len(
            self.frames)]


# ----------------------------------------------------------------------------- --max-gap


def max_gap(motion: Motion, keys: Keyframes, seconds: DurationLike,
            features: Features | None = None) -> Keyframes:
    """`keys` with a key inserted in every stretch longer than `seconds` (a `Duration`, or a
    plain number of seconds) without one, at the best frame by the optimal segment cost
    (`optimal_math.fill_gaps`)."""
    gap = _frames(seconds, motion.fps, "max_gap")
    x = curve(motion, features)
    rows = np.asarray(keys.frames, dtype=np.int64) - motion.first_frame
    ends = np.unique(np.concatenate([[0], rows, [len(x) - 1]]))
    filled = om.fill_gaps(x, ends, gap)
    added = np.setdiff1d(filled, rows)
    frames = np.union1d(rows, added)
    score = dict(zip(rows.tolist(), keys.scores.tolist(), strict=True))
    scores = np.array([score.get(int(r), 0.0) for r in frames])
    strength = dict(zip(rows.tolist(), np.asarray(keys.strength).tolist(), strict=True))
    info = {**keys.info, "max_gap_added": (added + motion.first_frame).tolist()}
    return Keyframes(keys.method, frames + motion.first_frame, scores,
                     {**keys.params, "max_gap": _span_param(seconds)}, keys.n_frames, info,
                     strength=np.array([strength.get(int(r), 0.0) for r in frames]))


class MaxGap(WrappedKeyframer):
    """Any online keyframer with `--max-gap`: once the inner keyframer has decided a stretch
    longer than the gap without a key (frames older than its lookahead are final), a key is
    inserted at the best frame by the optimal segment cost. Inserted keys have latency up to
    inner lookahead + gap, which is this keyframer's lookahead; inner events pass unchanged."""

    def __init__(self, inner: OnlineKeyframer, seconds: DurationLike) -> None:
        self.gap = _frames(seconds, inner.fps, "max_gap")  # longest stretch, frames
        lookahead = inner.lookahead + self.gap
        params = {**inner.params, "max_gap": _span_param(seconds), "lookahead": lookahead}
        super().__init__(inner, lookahead=lookahead, params=params,
                         params_digest=params_digest({"method": inner.method, **params}))
        self.scale = om.point_scale(  # curve point factors
            inner.skeleton.n_joints, inner.features.body_height)
        self.reset()

    def _forget(self) -> None:
        """The stretch since the last key starts over."""
        self.rows: list[np.ndarray] = []  # curve rows from the last key on
        self.seq: list[int] = []  # their sequence numbers
        self.time: list[float] = []  # their times, seconds
        self.t0 = 0  # stream index of rows[0]
        self.t = -1  # stream index of the newest frame
        self._idle_final = 0  # the final frame `idle` fills gaps up to
        self.last = 0  # stream index of the last key (the first frame is an anchor)

    def _fill(self, end: int) -> list[Event]:
        """Keys while the stretch from the last key to `end` (a key, or a bound on the next
        one) is longer than the gap."""
        out: list[Event] = []
        while end - self.last > self.gap:
            a = self.last - self.t0
            k = om.best_split(np.array(self.rows), a, a + self.gap + 1, a + self.gap)
            out.append(KeyframeEvent(  # inserted: not a key the method found, strength 0
                stream=self.stream, method=self.method, frame=self.seq[k], time=self.time[k],
                score=0.0, decided_at=self.seq[-1], lookahead=self.lookahead,
                params=self.params_digest, strength=0.0))
            self.last = k + self.t0
        return out

    def _advance(self, events: Sequence[Event], final: int) -> list[Event]:
        """Inner events in order with the gaps before their keys filled, then the gaps of
        the decided part (frames <= final carry no other key)."""
        out: list[Event] = []
        for e in events:
            if isinstance(e, KeyframeEvent):
                k = self.t0 + e.frame - self.seq[0]
                out += self._fill(k)
                self.last = max(self.last, k)
            out.append(e)
        out += self._fill(final)
        drop = self.last - self.t0
        if drop > 0:
            del self.rows[:drop], self.seq[:drop], self.time[:drop]
            self.t0 += drop
        return out

    def process(self, block: FeatureBlock) -> list[Event]:
        """Frame by frame: the inner keyframer, then gap filling over the part it has
        finalised (older than its lookahead). The inner deferred work of the block's last
        frame is left to `idle`, so a re-analysis (speed) stays off the due path; until then
        frame t - lookahead may still get an inner key, so filling stops one frame short."""
        rows = om.body_rows(block.positions, self.scale)
        out: list[Event] = []
        last = len(block) - 1
        for i in range(len(block)):
            self.rows.append(rows[i])
            self.seq.append(int(block.seq[i]))
            self.time.append(float(block.time[i]))
            self.t += 1
            events = list(self.inner.process(block.slice(i, i + 1)))
            if i < last:
                events += self.inner.idle()
            out += self._advance(events, self.t - self.inner.lookahead + (i < last))
        self._idle_final = self.t - self.inner.lookahead + 1
        return out

    def idle(self) -> list[Event]:
        """The inner keyframer's deferred work of the last frame, then the gaps it settles."""
        if self.t < 0:
            return list(self.inner.idle())
        return self._advance(self.inner.idle(), self._idle_final)

    def finish(self) -> list[Event]:
        """End of stream: the inner keyframer's rest, then the gaps up to the last frame."""
        if self.t < 0:
            return list(self.inner.finish())
        return self._advance(self.inner.finish(), self.t)
