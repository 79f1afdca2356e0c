"""Session segments: calibration holds, still stretches and takes, offline and online alike.

A capture session is not all motion: the performer holds a calibration pose before the take
and stands still between and after takes. Those frames are session states, not movement, and
a method that learns running statistics (a PCA, a speed cut-off, a key rate) should not
learn from them. This module cuts a stream into typed segments; `motion_mask` gives the
frames inside takes.

Definitions (every duration in seconds, every speed in body heights per second, so the
segments are the same in seconds at any capture rate):

- Body speed at frame f: the root mean square over the 16 body joints of Miura et al.,
  "Adaptive Keypose Extraction from Motion Capture Data", 2014 (`roles.MIURA_ROLES`, in
  the pelvis-fixed frame, divided by the body height) of their displacement between frames
  f - h and f + h, divided by the time between them, with `h = half_window` (0.2 s): a
  centred difference over 0.4 s. The window is what makes the
  speed robust to sensor noise: 0.3 degrees of Gaussian noise on every rotation channel of a
  perfectly still body reads at most 0.043 body heights/s on every shared CMU clip at 120
  and 30 Hz (0.089 with h = 0.1 s, 0.058 with 0.15 s), while the 16 gait clips (walks,
  runs, dribbles) never drop below 0.145.
  At the ends of a window of the stream the displacement is taken to the first / last frame
  (a shorter span); a stream of one frame has speed 0.
- Still frames: a Schmitt trigger on the body speed: a frame becomes still when the speed is
  below `still_speed` (0.07 body heights/s) and stays still until it exceeds `motion_speed`
  (0.10): the short hysteresis that keeps noise from splitting a hold. A NaN speed (invalid
  input) counts as motion.
- Still stretch: a run of still frames lasting at least `min_still` (0.5 s).
- Calibration hold: a still stretch lasting at least `min_calibration` (1 s) whose first
  `min_calibration` frames are all in the same calibration pose (`calibration_pose`): arms
  straight (elbow bent at most 20 degrees), at the same elevation within 15 degrees, and
  either near horizontal (T-pose, -20..+25 degrees from the plane perpendicular to the
  spine), or at a fixed angle down (A-pose, -65..-20 degrees), both pointing sideways
  (within 45 degrees of the shoulder line), or straight down along the body (N-pose, the
  Xsens calibration pose, below -65 degrees); both legs straight (knee bent at most 20
  degrees) and pointing down (thigh and shin within 35 degrees of the spine's direction). A
  relaxed stance does not pass: its elbows bend 25-40 degrees on the CMU clips. The
  directions are body-relative (the spine is the mid-hip to neck line), so no world axis
  is assumed.
- Take: every frame not in a still stretch or a calibration hold.

The speed of frame f is known when frame f + h arrives. Online latency (`SegmentEvent`):
a still stretch starting at frame s is confirmed (an open event) when frame
s + min_still - 1 + h arrives, a calibration hold when frame s + max(min_still,
min_calibration) - 1 + h arrives; the end e of a still stretch or a calibration hold is
decided when frame e + 1 + h arrives, i.e. as soon as the body speed rises past
`motion_speed`; a take's end is decided with the next still stretch's confirmation, its
start with the end of the stretch before it (or, at the start of a stream, as soon as the
first frame is known not to begin a still stretch). Closed events are final; an open event
may be followed by another open event with the same start (still, then calibration).
Pushing every frame then `flush()` gives exactly the segments of `detect_segments`.

A hold is found from about h after the body stops to about h before it moves again (the
window straddles the motion): on the shared clips a calibration hold ends 0.03-0.17 s before
the body starts moving, and stillness after a take starts 0.14-0.18 s after it stops.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import UsageError
from .filters import DEFAULT_NOISE_CUTOFF_HZ
from .jit import kernel, warm_up, warmer
from .keyframes import Segment, SegmentEvent, SegmentKind
from .motion import Frame, Motion, Skeleton
from .roles import MIURA_ROLES
from .units import Duration, DurationLike, whole_frames

__all__ = ["Segment", "SegmentEvent", "SegmentDetector", "SegmentLimits", "SegmentKind",
           "detect_segments", "motion_mask", "calibration_pose", "SEGMENT_ROLES", "STILL_SPEED",
           "MOTION_SPEED", "HALF_WINDOW", "MIN_STILL", "MIN_CALIBRATION"]

STILL_SPEED = 0.07  # body heights/s: below it a frame becomes still
MOTION_SPEED = 0.10  # body heights/s: above it a still frame moves again
HALF_WINDOW = Duration.seconds(0.2)  # the body speed is a centred difference over 2x this
MIN_STILL = Duration.seconds(0.5)
MIN_CALIBRATION = Duration.seconds(1.0)

# The 16 speed joints, then the hips (for the legs of the calibration pose).
SEGMENT_ROLES = MIURA_ROLES + ("left_hip", "right_hip")
_R = {r: i for i, r in enumerate(SEGMENT_ROLES)}
_N_SPEED = len(MIURA_ROLES)

ARM_BEND_MAX = 20.0  # degrees: straight arms
KNEE_BEND_MAX = 20.0  # degrees: straight legs
LEG_TILT_MAX = 35.0  # degrees between thigh / shin and the downward spine direction
ARM_ASYMMETRY_MAX = 15.0  # degrees between the two arms' elevations
ARM_SIDEWAYS_MAX = 45.0  # degrees between an arm (T, A) and the shoulder line
T_ELEVATION = (-20.0, 25.0)
A_ELEVATION = (-65.0, -20.0)


@kernel
def _speed_kernel(q: np.ndarray, ahead: np.ndarray, behind: np.ndarray, scale: np.ndarray,
                  n_joints: int, out: np.ndarray) -> None:  # pragma: no cover - compiled
    for i in range(len(out)):
        a, b = ahead[i], behind[i]
        ss = 0.0
        for j in range(n_joints):
            for c in range(3):
                d = q[a, j, c] - q[b, j, c]
                ss += d * d
        out[i] = math.sqrt(ss / n_joints) * scale[i]


@kernel
def _speed_one(q: np.ndarray, a: int, b: int, scale: float,
               n_joints: int) -> float:  # pragma: no cover - compiled
    ss = 0.0
    for j in range(n_joints):
        for c in range(3):
            d = q[a, j, c] - q[b, j, c]
            ss += d * d
    return math.sqrt(ss / n_joints) * scale


@warmer
def warm_segments() -> None:
    """Compile (or load from the cache) the body-speed kernel."""
    q = np.zeros((2, _N_SPEED, 3))
    _speed_kernel(q, np.array([1], dtype=np.int64), np.array([0], dtype=np.int64),
                  np.ones(1), _N_SPEED, np.empty(1))
    _speed_one(q, 1, 0, 1.0, _N_SPEED)
    _pose_kernel(np.zeros((1, len(SEGMENT_ROLES), 3)), _POSE_ROWS, _POSE_LIMITS,
                 np.zeros(1, dtype=np.int64))


_POSES = (None, "T", "A", "N")
_POSE_LIMITS = np.array([ARM_BEND_MAX, KNEE_BEND_MAX, LEG_TILT_MAX, ARM_ASYMMETRY_MAX,
                         ARM_SIDEWAYS_MAX, T_ELEVATION[0], T_ELEVATION[1], A_ELEVATION[0]])
# point rows of the pose: neck, hips, then per side shoulder, elbow, wrist, hip, knee, ankle
_POSE_ROWS = np.array([_R["neck"], _R["left_hip"], _R["right_hip"]]
                      + [_R[f"{side}_{j}"] for side in ("left", "right")
                         for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")],
                      dtype=np.int64)


@kernel
def _angle_deg(ax: float, ay: float, az: float, bx: float, by: float,
               bz: float) -> float:  # pragma: no cover - compiled
    na = math.sqrt(ax * ax + ay * ay + az * az)
    nb = math.sqrt(bx * bx + by * by + bz * bz)
    if not na * nb > 0.0:  # a zero or NaN vector: no angle, fails every limit
        return 180.0
    c = (ax * bx + ay * by + az * bz) / (na * nb)
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


@kernel
def _pose_kernel(p: np.ndarray, rows: np.ndarray, lim: np.ndarray,
                 out: np.ndarray) -> None:  # pragma: no cover - compiled
    for i in range(len(out)):
        out[i] = 0
        q = p[i]
        neck, lh, rh = q[rows[0]], q[rows[1]], q[rows[2]]
        ux = neck[0] - 0.5 * (lh[0] + rh[0])
        uy = neck[1] - 0.5 * (lh[1] + rh[1])
        uz = neck[2] - 0.5 * (lh[2] + rh[2])
        nu = math.sqrt(ux * ux + uy * uy + uz * uz)
        if not nu > 0.0:
            continue
        ux, uy, uz = ux / nu, uy / nu, uz / nu
        ls, rs = q[rows[3]], q[rows[9]]
        sx, sy, sz = ls[0] - rs[0], ls[1] - rs[1], ls[2] - rs[2]
        d = sx * ux + sy * uy + sz * uz
        sx, sy, sz = sx - d * ux, sy - d * uy, sz - d * uz
        ok = True
        sideways = True
        elev = np.empty(2)
        for k in range(2):
            b = 3 + 6 * k
            sign = 1.0 if k == 0 else -1.0
            s, e, w = q[rows[b]], q[rows[b + 1]], q[rows[b + 2]]
            h, kn, a = q[rows[b + 3]], q[rows[b + 4]], q[rows[b + 5]]
            if _angle_deg(e[0] - s[0], e[1] - s[1], e[2] - s[2],
                          w[0] - e[0], w[1] - e[1], w[2] - e[2]) > lim[0]:
                ok = False
            ax, ay, az = w[0] - s[0], w[1] - s[1], w[2] - s[2]
            na = math.sqrt(ax * ax + ay * ay + az * az)
            if not na > 0.0:
                ok = False
                break
            ax, ay, az = ax / na, ay / na, az / na
            d = ax * ux + ay * uy + az * uz
            elev[k] = math.degrees(math.asin(min(1.0, max(-1.0, d))))
            fx, fy, fz = ax - d * ux, ay - d * uy, az - d * uz
            if not _angle_deg(fx, fy, fz, sign * sx, sign * sy, sign * sz) <= lim[4]:
                sideways = False
            if _angle_deg(kn[0] - h[0], kn[1] - h[1], kn[2] - h[2],
                          a[0] - kn[0], a[1] - kn[1], a[2] - kn[2]) > lim[1]:
                ok = False
            if _angle_deg(kn[0] - h[0], kn[1] - h[1], kn[2] - h[2], -ux, -uy, -uz) > lim[2]:
                ok = False
            if _angle_deg(a[0] - kn[0], a[1] - kn[1], a[2] - kn[2], -ux, -uy, -uz) > lim[2]:
                ok = False
        if not ok or not abs(elev[0] - elev[1]) <= lim[3]:
            continue
        mean = 0.5 * (elev[0] + elev[1])
        if sideways and lim[5] <= mean <= lim[6]:
            out[i] = 1
        elif sideways and lim[7] <= mean < lim[5]:
            out[i] = 2
        elif mean < lim[7]:
            out[i] = 3


def calibration_pose(points: np.ndarray) -> list[str | None]:
    """The calibration pose ("T", "A", "N") of each frame of `points` (n, `SEGMENT_ROLES`, 3),
    or None: see the module docstring for the angles. NaN points have none."""
    p = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, len(SEGMENT_ROLES), 3)
    codes = np.zeros(len(p), dtype=np.int64)
    _pose_kernel(p, _POSE_ROWS, _POSE_LIMITS, codes)
    return [_POSES[c] for c in codes]


@dataclass(frozen=True, slots=True)
class SegmentLimits:
    """A detector's thresholds, its durations in whole frames at the stream's rate."""

    still_speed: float  # body heights/s: below it a frame becomes still
    motion_speed: float  # body heights/s: above it a still frame moves again
    half: int  # frames: half the body-speed window
    min_still: int  # frames: the shortest still stretch
    min_calibration: int  # frames: the shortest calibration hold


class _PointWindow:
    """The recent frames' points, seqs and times (rows from stream index `first`), and how far
    the stream has come in and been decided."""

    def __init__(self) -> None:
        self.q = np.empty((0, len(SEGMENT_ROLES), 3))  # points, rows from `first`
        self.first = 0  # stream index of `q[0]`
        self.seqs: list[int] = []  # seq of each row
        self.times: list[float] = []  # time of each row
        self.count = 0  # frames in so far
        self.next = 0  # stream index of the next frame to decide

    def append(self, seqs: list[int], times: list[float], pts: np.ndarray,
               min_rows: int) -> None:
        """Add consecutive frames (the buffer grows by doubling, at least to `min_rows`)."""
        n, m = self.count - self.first, len(pts)
        if n + m > len(self.q):  # grow the buffer (rows before `first` are gone)
            grown = np.empty((max(2 * len(self.q), n + m, min_rows), len(SEGMENT_ROLES), 3))
            grown[:n] = self.q[:n]
            self.q = grown
        self.q[n:n + m] = pts
        self.seqs += seqs
        self.times += times
        self.count += m

    def forget_before(self, keep_from: int) -> None:
        """Drop the rows before stream index `keep_from`, now and then (when at least half
        the buffer can go), so compaction costs O(1) a frame."""
        drop = keep_from - self.first
        if drop > 0 and 2 * drop >= len(self.q):
            n = self.count - self.first
            self.q[:n - drop] = self.q[drop:n]
            del self.seqs[:drop]
            del self.times[:drop]
            self.first = keep_from


@dataclass
class _StillRun:
    """The current run of still frames (the last one, while the body moves)."""

    still: bool = False  # the last decided frame is still
    start: int = 0  # seq of the run's first frame
    start_time: float = 0.0  # its time
    length: int = 0  # frames in the run
    pose_length: int = 0  # the run's first frames, all in calibration pose `pose`
    pose: str | None = None  # that pose ("T", "A", "N"), None before one is seen
    confirmed: bool = False  # at least `min_still` frames: a still stretch
    kind: SegmentKind = "still"  # "calibration" once the pose has held `min_calibration`
    before: tuple[int, float] = (0, 0.0)  # seq and time of the frame before: a take's last


class SegmentDetector:
    """Online (sans-I/O) session segments of one stream: feed frames, get `SegmentEvent`s.

    Three ways in, all giving the same events: `process(block)` with a pipeline's
    `online.FeatureBlock` (the front end: reads the pelvis-frame points of `SEGMENT_ROLES`,
    which the speed keyframer's FK pass already composes); `push_points(seq, time, points)`
    with those points directly (file units, consecutive frames); `push(frame)` /
    `push_block(frames)` with raw frames (its own `online.FeatureStage`; frames must be
    consecutive, as after the pipeline's stream guard). `flush()` ends the stream; `finish()`
    and `reset()` are the pipeline's end-of-window hooks. Durations: a `Duration`, or a plain
    number of frames.
    """

    def __init__(self, skeleton: Skeleton, fps: float, *, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 still_speed: float = STILL_SPEED, motion_speed: float = MOTION_SPEED,
                 half_window: DurationLike = HALF_WINDOW, min_still: DurationLike = MIN_STILL,
                 min_calibration: DurationLike = MIN_CALIBRATION,
                 noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> None:
        from .kinematics import body_height
        from .roles import resolve_roles

        if not (math.isfinite(fps) and fps > 0):
            raise UsageError(f"fps must be a positive number, got {fps}")
        if not (0 < still_speed <= motion_speed and math.isfinite(motion_speed)):
            raise UsageError("expected 0 < still_speed <= motion_speed (body heights/s), got "
                             f"{still_speed} and {motion_speed}")
        self.skeleton = skeleton  # the stream's skeleton (its own feature stage's)
        self.fps = float(fps)  # the stream's rate
        self.stream = stream  # the stream id its events carry
        self.limits = SegmentLimits(float(still_speed), float(motion_speed),
                                    whole_frames(half_window, fps, 1),
                                    whole_frames(min_still, fps, 1),
                                    whole_frames(min_calibration, fps, 1))
        self.roles = resolve_roles(skeleton, role_mapping, SEGMENT_ROLES)  # role -> joint
        self.points = [self.roles[r] for r in SEGMENT_ROLES]  # FK points read, in role order
        height = body_height(skeleton)
        self._speed_scale = self.fps / height if height > 0 else 0.0  # to body heights/s
        self._role_mapping = role_mapping  # of the own feature stage (`push`)
        self._noise_cutoff_hz = noise_cutoff_hz  # of the own feature stage (`push`)
        self._stage: Any = None  # the own feature stage, made on the first `push`
        warm_up(warm_segments)
        self.reset()

    @property
    def half(self) -> int:
        """Frames: half the body-speed window."""
        return self.limits.half

    @property
    def min_still(self) -> int:
        """Frames: the shortest still stretch."""
        return self.limits.min_still

    @property
    def min_calibration(self) -> int:
        """Frames: the shortest calibration hold."""
        return self.limits.min_calibration

    @property
    def still_speed(self) -> float:
        """Body heights/s: below it a frame becomes still."""
        return self.limits.still_speed

    @property
    def motion_speed(self) -> float:
        """Body heights/s: above it a still frame moves again."""
        return self.limits.motion_speed

    # --- state -----------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the stream (a new window starts); parameters are kept."""
        self._window = _PointWindow()  # recent frames, the stream's progress
        self._run = _StillRun()  # the current still run
        self._take: tuple[int, float] | None = None  # seq and time of the open take's start
        self._last = (0, 0.0)  # seq and time of the last decided frame

    # --- ways in ---------------------------------------------------------------------------

    def process(self, block: Any) -> list[SegmentEvent]:
        """Advance over an `online.FeatureBlock` (consecutive clean frames)."""
        if len(block) == 0:
            return []
        points = block.pelvis_points(self.points)
        return self.push_points(block.seq, block.time, points)

    def push(self, frame: Frame) -> list[SegmentEvent]:
        """Feed one raw frame (channels in file units)."""
        return self.push_block([frame])

    def push_block(self, frames: Iterable[Frame]) -> list[SegmentEvent]:
        """Feed consecutive raw frames; the same events as pushing them one by one."""
        frames = list(frames)
        for f in frames:
            shape = np.shape(f.channels)
            if shape != (self.skeleton.n_channels,):
                raise UsageError(f"frame {f.seq}: expected {self.skeleton.n_channels} channels,"
                                 f" got shape {shape}")
        return self.process(self._feature_stage().compute(frames))

    def flush(self) -> list[SegmentEvent]:
        """End of stream: decide the frames still pending, close the open segment, reset."""
        events: list[SegmentEvent] = []
        if self._stage is not None:
            events += self.process(self._stage.drain())
            self._stage.reset()
        events += self.finish()
        self.reset()
        return events

    def _feature_stage(self) -> Any:
        if self._stage is None:
            from .featurestage import FeatureStage

            self._stage = FeatureStage(self.skeleton, self.fps, self._role_mapping,
                                       self._noise_cutoff_hz)
        return self._stage

    def push_points(self, seq: Sequence[int] | np.ndarray, time: Sequence[float] | np.ndarray,
                    points: np.ndarray) -> list[SegmentEvent]:
        """Feed consecutive frames as their pelvis-frame points (n, len(SEGMENT_ROLES), 3),
        file units; returns the events they decided."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, len(SEGMENT_ROLES), 3)
        seqs = [int(s) for s in np.asarray(seq).reshape(-1)]
        times = [float(t) for t in np.asarray(time, dtype=np.float64).reshape(-1)]
        if not (len(seqs) == len(times) == len(pts)):
            raise UsageError(f"expected as many seqs, times and point rows, got {len(seqs)}, "
                             f"{len(times)} and {len(pts)}")
        if not len(pts):
            return []
        w = self._window
        w.append(seqs, times, pts, 4 * self.limits.half + 8)
        return self._decide(w.count - 1 - self.limits.half, final=False)

    def finish(self) -> list[SegmentEvent]:
        """Decide every pending frame (the window's last frame standing in for the frames
        after it), close the open segment, and start a new window (a pipeline's end of
        window: after a long gap, a restart, the end of the stream)."""
        if self._window.count == 0:
            return []
        events = self._decide(self._window.count - 1, final=True)
        seq, time = self._last
        run = self._run
        if run.still and run.confirmed:
            events.append(self._closed(run.kind, run.start, run.start_time, seq, time, seq,
                                       run.pose))
        elif self._take is not None:
            events.append(self._closed("take", *self._take, seq, time, seq))
        elif run.still:  # an unconfirmed run from the window's first frame: a take
            events.append(self._closed("take", run.start, run.start_time, seq, time, seq))
        self.reset()
        return events

    # --- decisions -------------------------------------------------------------------------

    def _decide(self, upto: int, final: bool) -> list[SegmentEvent]:
        """Decide frames `next`..`upto` (stream indices) now that their speed is known."""
        w, half = self._window, self.limits.half
        lo, hi = w.next, upto
        if hi < lo:
            return []
        last = w.count - 1
        base = w.first
        if lo == hi:  # one frame (a live stream): no index arrays
            a, b = min(lo + half, last), max(lo - half, 0)
            scale = self._speed_scale / (a - b) if a > b else 0.0
            speeds = [_speed_one(w.q, a - base, b - base, scale, _N_SPEED)]
        else:
            idx = np.arange(lo, hi + 1, dtype=np.int64)
            ahead = np.minimum(idx + half, last)
            behind = np.maximum(idx - half, 0)
            span = (ahead - behind).astype(np.float64)
            scales = np.where(span > 0, self._speed_scale / np.maximum(span, 1.0), 0.0)
            out = np.empty(len(idx))
            _speed_kernel(w.q, ahead - base, behind - base, scales, _N_SPEED, out)
            speeds = out.tolist()
        events: list[SegmentEvent] = []
        for k, i in enumerate(range(lo, hi + 1)):  # frame i is known when i + half is in
            self._frame(i - base, float(speeds[k]), w.seqs[min(i + half, last) - base],
                        events)
        w.next = hi + 1
        if not final:  # keep the rows the next frames' windows and poses read
            w.forget_before(max(0, w.next - half))
        return events

    def _frame(self, row: int, speed: float, decided_at: int,
               events: list[SegmentEvent]) -> None:
        """One frame through the state machine (its speed known)."""
        w, run, lim = self._window, self._run, self.limits
        seq, time = w.seqs[row], w.times[row]
        still = speed <= lim.motion_speed if run.still else speed < lim.still_speed
        if still:
            if not run.still:
                self._run = run = _StillRun(start=seq, start_time=time, before=self._last)
            run.length += 1
            if run.pose_length == run.length - 1 and run.pose_length < lim.min_calibration:
                pose = calibration_pose(w.q[row])[0]
                if pose is not None and run.pose in (None, pose):
                    run.pose_length += 1
                    run.pose = pose
            if not run.confirmed and run.length >= lim.min_still:
                run.confirmed = True
                if self._take is not None:
                    events.append(self._closed("take", *self._take, *run.before, decided_at))
                    self._take = None
                events.append(self._opened("still", run.start, run.start_time, decided_at))
            if run.confirmed and run.kind == "still" and run.pose_length >= lim.min_calibration:
                run.kind = "calibration"
                events.append(self._opened("calibration", run.start, run.start_time,
                                           decided_at, run.pose))
        else:
            if run.still and run.confirmed:
                events.append(self._closed(run.kind, run.start, run.start_time, *self._last,
                                           decided_at, run.pose))
                self._take = (seq, time)
                events.append(self._opened("take", seq, time, decided_at))
            elif self._take is None:  # the window's first frames: a take from there
                self._take = (run.start, run.start_time) if run.still else (seq, time)
                events.append(self._opened("take", *self._take, decided_at))
        run.still = still
        self._last = (seq, time)

    def _opened(self, kind: SegmentKind, start: int, start_time: float, decided_at: int,
                pose: str | None = None) -> SegmentEvent:
        return SegmentEvent(stream=self.stream, kind=kind, start=start, end=None,
                            start_time=start_time, end_time=None, decided_at=decided_at,
                            pose=pose)

    def _closed(self, kind: SegmentKind, start: int, start_time: float, end: int,
                end_time: float, decided_at: int, pose: str | None = None) -> SegmentEvent:
        return SegmentEvent(stream=self.stream, kind=kind, start=start, end=end,
                            start_time=start_time, end_time=end_time, decided_at=decided_at,
                            pose=pose if kind == "calibration" else None)


def segments_of(events: Iterable[SegmentEvent]) -> list[Segment]:
    """The closed segments among `events`, in order."""
    return [e.segment() for e in events if e.end is not None]


def detect_segments(motion: Motion, *, role_mapping: dict[str, str] | None = None,
                    noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ, **params: Any
                    ) -> list[Segment]:
    """The session segments of a whole motion (its captured frames, file numbering, times
    frame / fps): the same segments as `SegmentDetector` fed every frame then flushed, with
    the same sensor-noise front end (`noise_cutoff_hz`, as `features.compute_features`).
    `params`: `SegmentDetector`'s thresholds and durations."""
    from .features import compute_features

    det = SegmentDetector(motion.skeleton, motion.fps, role_mapping=role_mapping, **params)
    if motion.n_frames <= motion.first_frame:
        return []
    feats = compute_features(motion, role_mapping, noise_cutoff_hz)
    points = feats.pelvis_points(det.points)[motion.first_frame:]
    seq = np.arange(motion.first_frame, motion.n_frames)
    events = det.push_points(seq, seq / motion.fps, points)
    events += det.flush()
    return segments_of(events)


def motion_mask(segments: Sequence[Segment], n_frames: int, first_frame: int = 0) -> np.ndarray:
    """Boolean per frame (0..n_frames-1): True inside takes; calibration holds, still
    stretches and frames before `first_frame` are False (for a method's running statistics)."""
    mask = np.zeros(n_frames, dtype=bool)
    for s in segments:
        if s.kind == "take":
            mask[max(s.start, first_frame): min(s.end, n_frames - 1) + 1] = True
    return mask
