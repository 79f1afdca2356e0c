"""Curve simplification keyframes — Lowe's recursive split (1987) as used by Lim & Thalmann
(2001) and Önder et al. 2008, "Keyframe reduction techniques for motion capture data" (§3.2);
compared with saliency in Halit & Capin's thesis (2010, ch. 4).

The motion is a curve X (one row per captured frame) in R^d:

- ``space="positions"`` (default): every joint (ROOT and JOINT, not End Sites) minus the
  root, world orientation (the points of the evaluation's E, thesis eq. 4.1), flattened and
  divided by body height x sqrt(joints): a row distance is the RMS joint distance in body
  heights, whatever the skeleton's unit and joint count. Default tolerance 0.03 (5.3 cm on a
  1.75 m body; a few percent of the frames of the shared clips are keys).
- ``space="channels"``: every channel, rotations unwrapped (degrees), root translation in file
  units (the thesis' "Euler representation"). Not the default: a near-gimbal joint whose Euler
  angles jump 140-180 degrees in a frame (the thumbs of 02_03, 131_03) takes the keys.

Definitions this module settles:

- Distance of frame i to the chord of segment [a, b] is time-parametrised: the Euclidean
  distance between X_i and the linear interpolation X_a + (i - a)/(b - a) (X_b - X_a). This is
  exactly what linear reconstruction puts at frame i, and it bounds the perpendicular distance
  to the line from above, so the tolerance guarantee holds in both senses: **every frame is
  within the tolerance of the chord between its enclosing keyframes**.
- Stopping rules (exactly one): ``tolerance`` (Lim & Thalmann's error margin: split while the
  largest distance exceeds it), ``ratio`` (Önder §3.2 step 3: split while largest distance /
  chord length |X_b - X_a| exceeds it; Önder's text says "higher ... stop", which inverts the
  rule of its own Fig. 2, we follow the figure), ``count`` (thesis ch. 4: split the worst
  segment first, heap, exactly K keyframes).
- Split frame (tolerance and ratio rules): of the frames within `NEAR_TIE` (30 %) of the
  largest distance, the one on the coarsest dyadic grid in time (then the larger distance,
  the earliest). The grid of level L is every multiple of 2^L ticks of `GRID_TICK` (1/120 s)
  after the stream's first frame, each grid time on the frame nearest to it: at 120 Hz a
  frame's level is the trailing zero bits of its number, and a stream at 30, 60, 90, 100 or
  240 Hz puts the grid at the same times. Where the motion sweeps an arc (a turn, a
  pirouette) the distance has a broad maximum whose peak follows the segment's ends, so a
  window that ends elsewhere (online) would split elsewhere, and every later split with it;
  the grid frame does not depend on the ends. Shared clips, online vs offline F1 (±4 frames,
  lookahead 0.5 s): median 0.70 / worst 0.29 with the farthest frame, 1.00 / 0.92 with the
  grid frame, for 5.6 % more keys (the guarantee is unchanged). A grid of frame numbers
  instead of times gave the same keys at 30-240 Hz powers of two but not at 90 / 100 Hz
  (four shared clips, F1 against the clean take 0.44 / 0.54 there, 1.00 / 0.99 in time).
  Measured and not adopted: the grid anchored at each take's start (session segments):
  the detected start lies in the motion into the take (a calibration hold's blend), so the
  grid does not meet the clean take's (calibration-before E ratio 1.97 -> 2.10 on 07_01),
  and online the start arrives late (agreement worst 0.92 -> 0.86, 49_18); narrower bands
  (0.15-0.25) cut that E ratio to 0.96-1.14 but broke agreement (worst F1 0.31-0.77, 49_18;
  sessions after 10 s down to 0.94 at 0.2). The count rule splits at the farthest frame
  (ties: the earliest).
- What the variants' E ratios above 1.10 are (29 shared BVH clips, noise front end on): one
  key each, lost at the tolerance: a split whose distance is within 1-10 % of it (0.3 deg
  noise: 02_01's 0.0301, 05_11's 0.0304 fall below it; E 1.19, 1.24), the 30 Hz take
  without the clean take's last 3 frames (03_01: the last chord then meets the tolerance;
  1.23), or a calibration hold moving the grid (07_01, keys every 16 frames on the clean
  take's grid: 16 keys, not 20, on the shifted one; 1.97). Measured and not adopted: the
  grid capped at 8 ticks (calibration worst 1.97 -> 2.52, stillness after 1.00 -> 1.26) and
  levels counted from each segment's start (online vs offline F1 worst 0.92 -> 0.19).
- Scores: the distance at which a frame became a key (endpoints: 0, as online, where the first
  frame is a key before anything is known).
- Iterative (stack / heap), never recursive; the result of the tolerance rules does not depend
  on the order in which segments are processed. One compiled loop (`streamkey.jit`) computes
  every row's distance to the chord directly (100k frames in ~0.3 s CPU, the curve's
  positions given), so the guarantee holds up to floating-point rounding (tests allow 1e-9
  relative).

Online (`Online`: a key at frame f is sent by frame f + lookahead). The offline method has
no running statistic; its one global quantity is the recursion over the whole clip, whose
splits depend on segment ends far in the future. Online it becomes a recursion over a
window, and frame d = t - lookahead is decided when frame t arrives (c is the last committed
keyframe, t the newest frame):

- Windowed recursion: every `hop` frames (default 1/15 s: 8 at 120 Hz), P = the keys of
  the recursion on [a, t], anchored at the oldest committed keyframe a at most `history`
  frames (default 4 x lookahead: 2 s) before the deadline: a longer past reproduces more of
  the offline split hierarchy. With 2 x lookahead, when the anchor moves on to a newer key
  the coarse split that put a key at frame d (the recursion from the older anchor) is gone,
  the shorter window [a, t] meets the rule without it, and d is passed by for a witness
  beyond it (06_02 at 60 Hz: offline keys at 0.53, 0.80 and 1.07 s became one key at
  1.55 s). Shared clips with the noise front end on, clean motion's E from a variant's
  online keys over E from the clean take's online keys, worst clip: at 60 Hz 1.371 (2 x
  lookahead) / 1.108 (3 x) / 1.087 (4 x); under 0.3 deg noise 1.291 / 1.238 / 1.238; online
  vs offline F1 worst 0.917 / 0.923 / 0.923, sessions after 10 s 0.958 / 0.958 / 0.961;
  per-push cost unchanged within the measurement's noise.
- Decision: d is committed if d is in P, the segment [c, d] meets the rule (checked directly),
  and d is not P's version of c (a P key within `merge` frames after c, default 1/15 s, while c
  itself is not in P, is taken to be c: without this rule near-duplicate keys appear).
- Witness (the guarantee): otherwise a frame w > d with [c, w] meeting the rule is kept: the
  first key of P after d that meets it, else the first key k1 after c of the recursion on
  [c, t] (`first_key`; [c, k1] is a final segment of that recursion). If none lies beyond d,
  w = d (or k1 = d) is committed now. Every committed segment meets the rule, so **every frame
  is within the tolerance of the chord between its enclosing keyframes**, and every event has
  latency_frames <= lookahead.
- Window bound: the open segment never exceeds `max_span` frames (default 8 x lookahead;
  longer, w is committed early), the buffer holds frames from the anchor on: memory is
  O((history + max_span) x d), whatever the stream length.
- flush(): the recursion on [c, t] decides the rest (after the witness, if that recursion
  would put a key at or before the last deadline). With a lookahead of at least the stream's
  length nothing is decided before flush(), so this is exactly `extract`.
"""

from __future__ import annotations

import heapq
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import UsageError
from ..features import DEFAULT_NOISE_CUTOFF_HZ, Features, compute_features
from ..keyframes import KeyframeEvent, Keyframes
from ..kinematics import root_relative_joints
from ..motion import Motion, Skeleton, without_lead
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock, OnlineKeyframer
from ..signal import unwrap_degrees
from ..units import Duration, DurationLike, whole_frames
from .simplify_kernels import _farthest_rows, _first, _split_all, _splits, chord_sq

__all__ = ["extract", "curve", "farthest", "split_keys", "split_order", "max_chord_error",
           "first_key", "Online", "METHOD", "DEFAULT_TOLERANCE", "DEFAULT_LOOKAHEAD", "DEFAULT_HOP",
           "DEFAULT_MERGE", "SPACES",
           "DEFAULT_SPACE", "position_rows", "chord_sq"]

METHOD = "simplify"
SPACES = ("channels", "positions")
# Default absolute tolerances per space: degrees (file units for the root) / body heights.
DEFAULT_TOLERANCE = {"channels": 40.0, "positions": 0.03}
DEFAULT_SPACE = "positions"
DEFAULT_LOOKAHEAD = Duration.seconds(0.5)  # online defaults: 60 and 8 frames at 120 Hz
DEFAULT_HOP = Duration.seconds(8 / 120)
DEFAULT_MERGE = Duration.seconds(8 / 120)
NEAR_TIE = 0.3  # split distances within 30 % of the largest are near-ties (module docstring)
GRID_TICK = 1 / 120  # seconds: the finest step of the split grid (one frame at 120 Hz)


def curve(motion: Motion, space: str = DEFAULT_SPACE,
          features: Features | None = None) -> np.ndarray:
    """The motion as a curve in R^d, one row per captured frame (see the module docstring)."""
    first = motion.first_frame
    if space == "channels":  # the filtered channels when features were computed
        x = (motion if features is None else features.motion).channels[first:].copy()
        rot = motion.skeleton.rotation_columns()
        x[:, rot] = unwrap_degrees(x[:, rot]) if features is None else features.rotations[first:]
        return x
    if space == "positions":
        feats = features if features is not None else compute_features(motion)
        return position_rows(feats.fk.positions[first:], motion.skeleton.n_joints,
                             feats.body_height)
    raise UsageError(f"space must be one of {SPACES}, got {space!r}")


def position_rows(positions: np.ndarray, n_joints: int, height: float) -> np.ndarray:
    """Rows of the positions curve from world FK points (n, points, 3): root-relative joints,
    flattened, divided by body height x sqrt(joints) (a row distance is an RMS joint distance
    in body heights). Shared by `curve` and the online keyframer (identical arithmetic)."""
    rel = root_relative_joints(positions, n_joints)
    flat: np.ndarray = rel.reshape(len(rel), -1) / (height * np.sqrt(n_joints))
    return flat


_NO_ANCHOR = np.zeros(1, dtype=np.int64)  # the grid from row 0


def _grid(anchors: object, rate: float) -> tuple[np.ndarray, float]:
    """Kernel arguments of a grid: its anchors (sorted rows; none: row 0) and its rate."""
    a = np.unique(np.asarray(anchors, dtype=np.int64).reshape(-1))
    if not np.isfinite(rate) or rate <= 0:
        raise UsageError(f"simplify: the grid's rate must be a number > 0, got {rate!r}")
    return (a if len(a) else _NO_ANCHOR), float(rate)


def _rule_args(x: np.ndarray, tolerance: float | None, ratio: float | None
               ) -> tuple[np.ndarray, float, bool]:
    x = np.ascontiguousarray(x, dtype=np.float64)
    if tolerance is not None:
        return x, float(tolerance), False
    assert ratio is not None
    return x, float(ratio), True


def farthest(seg: np.ndarray) -> tuple[int, float]:
    """Farthest interior row of `seg` from its time-parametrised chord: (local index, distance).

    `seg` holds rows a..b of the curve; returns (0, 0.0) when there is no interior row. One
    compiled loop; ties go to the earliest row.
    """
    m = len(seg) - 1
    if m < 2:
        return 0, 0.0
    i, sq = _farthest_rows(np.ascontiguousarray(seg, dtype=np.float64), 0, m, _NO_ANCHOR, 1.0,
                           0.0, np.empty(m + 1))
    return int(i), float(np.sqrt(sq))


def split_keys(x: np.ndarray, lo: int, hi: int, *, tolerance: float | None = None,
               ratio: float | None = None, skip_to: int | None = None,
               anchors: Sequence[int] | np.ndarray = (), rate: float = 1.0,
               near: float | None = None) -> dict[int, float]:
    """Keys strictly inside [lo, hi] chosen by recursive splitting: {row: split distance}.

    Iterative (explicit stack, one compiled loop). Shared by `extract` and the online
    keyframer. With `skip_to`, segments ending at or before that row are not split (their
    keys are left out; every other key is unchanged, as each segment's recursion is
    independent of the others). `anchors` (rows where takes start; none: row 0) and `rate`
    (frames per 1/120 s) place the split grid (module docstring); `near`: the near-tie band.
    """
    x, limit, use_ratio = _rule_args(x, tolerance, ratio)
    room = max(hi - lo, 1)
    rows, dists = np.empty(room, dtype=np.int64), np.empty(room)
    n = _split_all(x, lo, hi, limit, use_ratio, -1 if skip_to is None else int(skip_to),
                   *_grid(anchors, rate), NEAR_TIE if near is None else float(near), rows,
                   dists)
    return dict(zip(rows[:n].tolist(), dists[:n].tolist(), strict=True))


def first_key(x: np.ndarray, lo: int, hi: int, *, tolerance: float | None = None,
              ratio: float | None = None, anchors: Sequence[int] | np.ndarray = (),
              rate: float = 1.0, near: float | None = None) -> tuple[int, float]:
    """First key after `lo` of `split_keys(x, lo, hi)` (or `hi`), and its split distance.

    Only left halves are visited: the first key lies in [lo, m] of the first split m.
    """
    x, limit, use_ratio = _rule_args(x, tolerance, ratio)
    k, dist = _first(x, lo, hi, limit, use_ratio, *_grid(anchors, rate),
                     NEAR_TIE if near is None else float(near))
    return int(k), float(dist)


def split_order(x: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """First `count` keys of worst-segment-first splitting (heap): (rows in order, distances).

    Rows 0 and n-1 come first (distance 0); every later row is the farthest frame of the
    segment with the largest distance at that moment (ties: earliest segment).
    """
    n = len(x)
    order = [0, n - 1] if n > 1 else [0]
    dists = [0.0] * len(order)
    heap: list[tuple[float, int, int, int]] = []

    def push(a: int, b: int) -> None:
        if b - a >= 2:
            i, dist = farthest(x[a : b + 1])
            heapq.heappush(heap, (-dist, a, b, a + i))

    push(0, n - 1)
    while len(order) < count and heap:
        neg, a, b, k = heapq.heappop(heap)
        order.append(k)
        dists.append(-neg)
        push(a, k)
        push(k, b)
    return np.array(order[:count], dtype=np.int64), np.array(dists[:count])


def max_chord_error(x: np.ndarray, keys: np.ndarray, rows: int = 4096) -> np.ndarray:
    """Largest time-parametrised chord distance inside each segment between sorted `keys`.

    `keys` must hold row 0 and the last row; returns one value a segment (vectorised, `rows`
    frames at a time so the temporaries stay cache-sized).
    """
    keys = np.asarray(keys, dtype=np.int64)
    if len(keys) < 2:
        return np.zeros(0)
    out = np.zeros(len(keys) - 1)
    for lo in range(0, len(x), rows):
        frames = np.arange(lo, min(len(x), lo + rows))
        seg = np.clip(np.searchsorted(keys, frames, side="right") - 1, 0, len(keys) - 2)
        a, b = keys[seg], keys[seg + 1]
        t = ((frames - a) / (b - a))[:, None]
        resid = x[frames] - x[a] - t * (x[b] - x[a])
        dist = np.sqrt(np.einsum("ij,ij->i", resid, resid))
        first = np.flatnonzero(np.diff(seg, prepend=-1))  # seg is sorted: runs of one segment
        runs = seg[first]
        out[runs] = np.maximum(out[runs], np.maximum.reduceat(dist, first))
    return out


def _rule(tolerance: float | None, ratio: float | None, count: int | None,
          space: str) -> tuple[float | None, float | None, int | None]:
    given = [v is not None for v in (tolerance, ratio, count)]
    if sum(given) > 1:
        raise UsageError("give exactly one of tolerance, ratio, count")
    if not any(given):
        tolerance = DEFAULT_TOLERANCE[space]
    if tolerance is not None and not (np.isfinite(tolerance) and tolerance >= 0):
        raise UsageError(f"tolerance must be a finite number >= 0, got {tolerance!r}")
    if ratio is not None and not (np.isfinite(ratio) and ratio >= 0):
        raise UsageError(f"ratio must be a finite number >= 0, got {ratio!r}")
    if count is not None and (isinstance(count, bool) or int(count) != count or count < 1):
        raise UsageError(f"count must be a positive integer, got {count!r}")
    return tolerance, ratio, (int(count) if count is not None else None)


def extract(motion: Motion, *, tolerance: float | None = None, ratio: float | None = None,
            count: int | None = None, space: str = DEFAULT_SPACE,
            features: Features | None = None,
            noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> Keyframes:
    """Curve-simplification keyframes of `motion` (one stopping rule; default: tolerance).

    Frames before `motion.first_frame` are skipped; indices are in the file's numbering.
    """
    motion = without_lead(motion)  # a stream drops them too (`filters.FrontEnd`)
    if space not in SPACES:
        raise UsageError(f"space must be one of {SPACES}, got {space!r}")
    tolerance, ratio, count = _rule(tolerance, ratio, count, space)
    features = features or compute_features(motion, noise_cutoff_hz=noise_cutoff_hz)
    x = curve(motion, space, features)
    n = len(x)
    if n == 0:
        raise UsageError("the motion has no captured frames")
    params: dict[str, Any] = {"space": space, "tolerance": tolerance, "ratio": ratio,
                              "count": count}
    if count is not None:
        if not min(2, n) <= count <= n:
            raise UsageError(f"count must be in [2, {n}] (captured frames), got {count}")
        rows, dists = split_order(x, count)
        sort = np.argsort(rows)
        rows, scores = rows[sort], dists[sort]
    else:
        keys = split_keys(x, 0, n - 1, tolerance=tolerance, ratio=ratio,
                          rate=motion.fps * GRID_TICK)
        keys.setdefault(0, 0.0)
        keys.setdefault(n - 1, 0.0)
        rows = np.array(sorted(keys), dtype=np.int64)
        scores = np.array([keys[int(r)] for r in rows])
    scores[[0, -1]] = 0.0  # the endpoints are keys without a split (as online, where the
    # first frame is a key before anything is known)
    err = max_chord_error(x, rows)
    info = {"max_error": float(err.max()) if len(err) else 0.0, "dimensions": int(x.shape[1])}
    return Keyframes(METHOD, rows + motion.first_frame, scores, params, motion.n_frames, info)


def _frames(name: str, value: object, fps: float, low: int) -> int:
    """A duration parameter in whole frames at `fps`: a `Duration`, or an integer count of
    frames (the meaning plain numbers always had); at least `low` frames."""
    if isinstance(value, Duration):
        frames = whole_frames(value, fps)
    elif isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise UsageError(f"simplify online: {name} must be an integer number of frames or a "
                         f"Duration, got {value!r}")
    else:
        frames = int(value)
    if frames < low:
        raise UsageError(f"simplify online: {name} must be an integer >= {low}, got {value!r}"
                         + (f" ({frames} frames at {fps:g} fps)" if isinstance(value, Duration)
                            else ""))
    return frames


class Online(OnlineKeyframer):
    """Online curve simplification: keyframes within `lookahead` frames, tolerance guaranteed.

    Tolerance or ratio rule (a count needs the whole clip). See the module docstring for the
    windowed recursion, the decision and witness rules and the window bound. Durations
    (`lookahead`, `history`, `hop`, `merge`, `max_span`) are `Duration`s or integer frame
    counts; the defaults are in seconds (0.5 s, 4 x lookahead, 1/15 s, 1/15 s, 8 x lookahead:
    60, 240, 8, 8 and 480 frames at 120 Hz), so a stream at another rate sees the same motion.
    """

    method = METHOD

    def __init__(self, skeleton: Skeleton, fps: float, *, tolerance: float | None = None,
                 ratio: float | None = None, space: str = DEFAULT_SPACE,
                 lookahead: DurationLike = DEFAULT_LOOKAHEAD, history: DurationLike | None = None,
                 hop: DurationLike = DEFAULT_HOP, merge: DurationLike = DEFAULT_MERGE,
                 max_span: DurationLike | None = None, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES) -> None:
        if space not in SPACES:
            raise UsageError(f"space must be one of {SPACES}, got {space!r}")
        tolerance, ratio, _ = _rule(tolerance, ratio, None, space)
        lookahead = _frames("lookahead", lookahead, fps, 1)
        history = 4 * lookahead if history is None else _frames("history", history, fps, 0)
        span = (8 * lookahead if max_span is None
                else _frames("max_span", max_span, fps, lookahead + 1))
        hop, merge = _frames("hop", hop, fps, 1), _frames("merge", merge, fps, 0)
        super().__init__(skeleton, fps, lookahead=lookahead, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params={"space": space, "tolerance": tolerance, "ratio": ratio,
                                 "history": int(history), "hop": int(hop),
                                 "merge": int(merge), "max_span": int(span)})
        self.space, self.tolerance, self.ratio = space, tolerance, ratio
        self.history, self.hop, self.merge, self.max_span = (int(history), int(hop),
                                                             int(merge), int(span))
        self._rot = skeleton.rotation_columns()
        self.rate = fps * GRID_TICK
        self.reset()

    def reset(self) -> None:
        """Forget the window; keep parameters."""
        self._buf = np.empty((0, 0))
        self._seq = np.empty(0, dtype=np.int64)
        self._time = np.empty(0)
        self._base = 0  # stream index of buffer row 0
        self._t = -1  # stream index of the newest frame
        self._c = 0  # stream index of the last committed keyframe
        self._w: tuple[int, float] | None = None  # witness: (stream index, score)
        self._keys: deque[int] = deque()  # committed keyframes from the anchor on
        self._p: dict[int, float] = {}  # keys of the windowed recursion (stream index: dist)
        self._p_time = -(10**9)

    @property
    def held(self) -> int:
        """Frames held in the window now (bounded by history + max_span + lookahead)."""
        return self._t + 1 - self._base

    # -- buffer --------------------------------------------------------------------------
    def _rows(self, block: FeatureBlock) -> np.ndarray:
        if self.space == "channels":
            x = block.channels.copy()
            x[:, self._rot] = block.rotations
            return x
        return position_rows(block.positions, self.features.skeleton.n_joints,
                             self.features.body_height)

    def _append(self, row: np.ndarray, seq: int, time: float) -> None:
        """Append one row; rows before the anchor are dropped (buffer grows only if full)."""
        n = self._t + 1 - self._base
        if n == len(self._buf):
            keep = self._keys[0] - self._base
            size = max(64, 2 * (n - keep))
            buf = np.empty((size, len(row)))
            buf[: n - keep] = self._buf[keep:n]
            self._seq = np.concatenate([self._seq[keep:n], np.zeros(size - n + keep, np.int64)])
            self._time = np.concatenate([self._time[keep:n], np.zeros(size - n + keep)])
            self._buf, self._base, n = buf, self._keys[0], n - keep
        self._buf[n], self._seq[n], self._time[n] = row, seq, time
        self._t += 1

    def _x(self) -> np.ndarray:
        return self._buf[: self._t + 1 - self._base]

    def _anchor_rows(self) -> np.ndarray:
        """The split grid's anchor, the stream's first frame, as a row of the buffer."""
        return np.array([-self._base], dtype=np.int64)

    # -- rules ---------------------------------------------------------------------------
    def _meets(self, lo: int, hi: int) -> bool:
        """Does the segment [lo, hi] (stream indices) meet the stopping rule?"""
        x, limit, use_ratio = _rule_args(self._x(), self.tolerance, self.ratio)
        return bool(_splits(x, lo - self._base, hi - self._base, limit, use_ratio, _NO_ANCHOR,
                            1.0, 0.0, np.empty(hi - lo + 1))[0] < 0)

    def _commit(self, k: int, score: float) -> KeyframeEvent:
        self._c, self._w = k, None
        self._keys.append(k)
        r = k - self._base
        decided = int(self._seq[self._t - self._base])
        return self.event(frame=int(self._seq[r]), time=float(self._time[r]), score=score,
                          decided_at=decided)

    def _window_keys(self, t: int) -> None:
        """P: keys of the recursion on [anchor, t] (every `hop` frames)."""
        while len(self._keys) > 1 and self._keys[0] < t - self.lookahead - self.history:
            self._keys.popleft()
        a = self._keys[0]
        keys = split_keys(self._x(), a - self._base, t - self._base, tolerance=self.tolerance,
                          ratio=self.ratio, skip_to=self._c - self._base,  # only c on is used
                          anchors=self._anchor_rows(), rate=self.rate)
        self._p = {k + self._base: dist for k, dist in keys.items()}
        self._p_time = t

    def _witness(self, c: int, d: int, t: int) -> tuple[int, float]:
        """A frame w > d with [c, w] meeting the rule (P's first such key, else k1)."""
        for k in sorted(k for k in self._p if d < k <= t)[:2]:
            if self._meets(c, k):
                return k, self._p[k]
        k1, score = first_key(self._x(), c - self._base, t - self._base,
                              tolerance=self.tolerance, ratio=self.ratio,
                              anchors=self._anchor_rows(), rate=self.rate)
        return k1 + self._base, score

    def _step(self) -> list[KeyframeEvent]:
        """Decide frame d = t - lookahead (module docstring)."""
        t, c = self._t, self._c
        d = t - self.lookahead
        events = []
        if d > c:
            if t - self._p_time >= self.hop:
                self._window_keys(t)
            same_as_c = d - c <= self.merge and c not in self._p
            if d in self._p and not same_as_c and self._meets(c, d):
                events.append(self._commit(d, self._p[d]))
            elif self._w is None or self._w[0] <= d:
                w = self._witness(c, d, t)
                if w[0] > d:
                    self._w = w
                elif self._w is not None:  # the kept witness is d: its deadline
                    events.append(self._commit(*self._w))
                elif w[0] == d:  # k1 == d: [c, d] is a final segment of the recursion
                    events.append(self._commit(*w))
        if self._w is not None and t - self._c >= self.max_span:
            events.append(self._commit(*self._w))
        return events

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Append frames one by one; each decides the frame `lookahead` frames back."""
        rows = self._rows(block)
        if len(self._buf) == 0:
            self._buf = np.empty((64, rows.shape[1]))
            self._seq = np.zeros(64, dtype=np.int64)
            self._time = np.zeros(64)
        events: list[KeyframeEvent] = []
        for i in range(len(block)):
            self._append(rows[i], int(block.seq[i]), float(block.time[i]))
            if self._t == 0:
                events.append(self._commit(0, 0.0))  # the first frame is always a keyframe
            else:
                events.extend(self._step())
        return events

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: the recursion on the open segment decides the rest."""
        events: list[KeyframeEvent] = []
        t, d = self._t, self._t - self.lookahead
        if t <= self._c:
            return events
        if self._c < d and self._w is not None:
            k1, _ = first_key(self._x(), self._c - self._base, t - self._base,
                              tolerance=self.tolerance, ratio=self.ratio,
                              anchors=self._anchor_rows(), rate=self.rate)
            if k1 + self._base <= d:  # would be late: the witness first
                events.append(self._commit(*self._w))
        lo, hi = self._c - self._base, t - self._base
        keys = split_keys(self._x(), lo, hi, tolerance=self.tolerance, ratio=self.ratio,
                          anchors=self._anchor_rows(), rate=self.rate)
        keys[hi] = 0.0
        events += [self._commit(self._base + r, keys[r]) for r in sorted(keys)]
        return events

    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: the undecided keys in view, the window recursion's keys after
        the decision frame and the witness."""
        d = max(self._t - self.lookahead, self._c)
        keys = {k: v for k, v in self._p.items() if d < k <= self._t}
        if self._w is not None and self._w[0] > d:
            keys[self._w[0]] = self._w[1]
        return [(int(self._seq[k - self._base]), float(self._time[k - self._base]), float(v))
                for k, v in sorted(keys.items()) if k >= self._base]
