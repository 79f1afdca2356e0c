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
Recorded CMU holds move more (their stillest 1/6 s stretches depart ≥ 1.6·10⁻⁴ body
heights RMS) and count as motion, so λ on the shared clips is today's except where a
recording holds exactly still (06_02). At stream start λ is the prior; the data takes over
as the stream goes on, which keeps λ steady on short takes (a moving λ spends keys
unevenly).
Online, whenever the estimate moves by more than 5 % (`RESOLVE`) every undecided frame is
solved again with it; since λ still moves, converged chains are not final in rate mode and
keys are decided at the deadline. Offline, λ is the estimate after the whole take (one
penalised pass); with an unbounded lookahead `flush()` solves everything with that same λ,
so the two agree exactly. The key count follows the rate only as far as the estimate is
right (0.3–1.7 × on the shared clips, most within ±15 %); the same take at 60 or 30 Hz,
after a calibration hold or followed by stillness gets 0.83–1.09 × the clean take's keys
on every shared clip, offline and online.

Deadlines are checked once a chunk, deciding every frame whose deadline falls before the
next chunk is complete (so the effective lookahead is `lookahead` − (chunk − 1) frames to
`lookahead`: 0.875 to 1 s by default, at 120 Hz as at 30 Hz).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import UsageError
from ..features import DEFAULT_NOISE_CUTOFF_HZ, Features, compute_features
from ..keyframes import KeyframeEvent, Keyframes
from ..motion import Motion, Skeleton
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock, OnlineKeyframer
from ..units import Duration, DurationLike, whole_frames
from . import optimal_math as om

__all__ = ["extract", "curve", "Solver", "Online", "MaxGap", "max_gap", "METHOD",
           "DEFAULT_LOOKAHEAD", "DEFAULT_MAX_SEGMENT", "DEFAULT_RATE", "DEFAULT_LAMBDA"]

METHOD = "optimal"
DEFAULT_LOOKAHEAD = Duration.seconds(1.0)  # 120 frames at 120 Hz
DEFAULT_MAX_SEGMENT = 2.0  # seconds
DEFAULT_RATE = 6.0  # keys per second of motion: 5 % of frames at 120 Hz
DEFAULT_LAMBDA = 3.5e-3  # ticks x body heights^2 (a tick: 1/120 s)
TICKS_PER_SECOND = 120.0  # the time unit of costs and lambda: 1/120 s, a frame at 120 Hz
PRIOR_SECONDS = 10.0  # rate mode: weight of the prior lambda, in seconds of motion
RESOLVE = 0.05  # rate mode: re-solve the undecided frames when log lambda moves this much
RATE_FACTOR = 3.2  # lambda / geometric mean cost of key-spaced segments (shared clips, 5 %)
STILL_COST = 1e-8  # body heights^2: mean squared departure from a straight line below which
#                    a key-spaced stretch is still (RMS 1e-4 body heights, about 0.2 mm)
_LOG_FLOOR = 1e-12  # smallest segment cost in the geometric mean
_GRID = 16  # lambdas per pass of the count search
_EXACT_BUDGET = 4e7  # frames x K x L below which count mode runs the exact K-key DP


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


class Solver:
    """The penalised (or tolerance) DP over a growing stream, with traceback convergence.

    Plain attributes; arrays hold stream indices base .. n − 1. Offline: `add` every row,
    then `finish`. Online: `add` per block, `converge` per chunk, `force` at deadlines.
    """

    def __init__(self, max_len: int, *, lam: float | None = None, rate: float | None = None,
                 tolerance: float | None = None, keep_costs: bool = False,
                 ticks: float = 1.0, chunk: int = om.CHUNK) -> None:
        self.max_len = int(max_len)
        self.chunk = int(chunk)  # frames solved together (`chunk_frames`)
        self.ticks = float(ticks)  # ticks (1/120 s) per frame: frame sums x ticks = integrals
        self.lam0 = float(lam if lam is not None else DEFAULT_LAMBDA)  # ticks x heights^2
        self.rate = rate  # keys per frame, or None
        self.span = int(min(max_len, max(2, round(1.0 / rate)))) if rate else 0
        self.tolerance = tolerance
        self.keep_costs = keep_costs
        self.reset()

    def reset(self) -> None:
        """Empty stream."""
        self.base = 0
        self.n = 0
        self.done = 0  # frames with F computed
        self.priced = 0  # online: frames with their costs in `costs`
        self.floor = 0  # last committed key (stream index)
        self.decided = -1  # every frame <= decided is final
        self.stale: tuple[int, int] | None = None  # frames to solve again (stream indices)
        self.log_sum = 0.0  # rate controller: Σ w log cost(b − s, b) and Σ w (motion ticks)
        self.log_n = 0.0
        # the DP's lambda: per key, in the unit of the costs it adds (frame sums)
        self.lam = (self.lam0 if self.rate is None else self.rate_estimate()) / self.ticks
        self.pricer = om.Pricer(self.max_len)
        self.x = np.empty((0, 0))
        self.f = np.empty(0)
        self.bp = np.empty(0, dtype=np.int64)
        self.keys = np.empty(0, dtype=np.int64)
        self.costs = np.empty((0, self.max_len))

    def _grow(self, need: int, width: int) -> None:
        """Room for `need` more rows: drop rows no longer used, then enlarge if still full."""
        held = self.n - self.base
        if held + need <= len(self.f):
            return
        if self.keep_costs:  # online: rows before the floor and the last window are unused
            keep = max(self.base, min(self.floor, self.done - self.max_len))
            shift = keep - self.base
        else:
            shift = 0
        size = max(64, 2 * (held - shift + need))
        old = (self.x, self.f, self.bp, self.keys, self.costs)
        self.x = np.empty((size, width))
        self.f = np.full(size, np.inf)
        self.bp = np.full(size, -1, dtype=np.int64)
        self.keys = np.zeros(size, dtype=np.int64)
        self.costs = np.empty((size if self.keep_costs else 0, self.max_len))
        rows = held - shift
        for new, prev in zip((self.x, self.f, self.bp, self.keys, self.costs), old,
                             strict=True):
            if len(new) and rows:
                new[:rows] = prev[shift:held]
        self.bp[:rows] -= shift
        self.base += shift

    def add(self, rows: np.ndarray) -> list[int]:
        """Append rows; solve every completed chunk. Returns the stream indices of the chunk
        ends solved (the frames after which convergence may be checked)."""
        if self.n - self.base + len(rows) > len(self.f):
            self._grow(len(rows), rows.shape[1])
        lo = self.n - self.base
        self.x[lo : lo + len(rows)] = rows
        self.n += len(rows)
        ends = []
        while self.n - self.done >= self.chunk:
            self._solve(self.done + self.chunk)
            ends.append(self.done - 1)
        return ends

    def _solve(self, end: int) -> None:
        """Solve frames done .. end − 1 (one chunk, or the tail at finish), pricing those not
        priced yet."""
        self.settle()
        b0, b1 = self.done - self.base, end - self.base
        if self.keep_costs:
            self.price(end)
            costs = self.costs[b0:b1]
        else:
            costs = self.pricer.price(self.x, self.base, self.done, end)
        start = b0
        if self.done == 0:
            self.f[0], self.bp[0], self.keys[0] = 0.0, -1, 1
            start = 1
        om.dp_rows(costs, self.f, self.bp, self.keys, start, b1, self.lam,
                   self.floor - self.base, self.tolerance, c0=b0)
        self.done = end
        if self.rate is not None:
            lam = self.rate_lambda(costs)
            if self.keep_costs and abs(math.log(lam / self.lam)) > RESOLVE:
                self.resolve(lam)

    def price(self, end: int | None = None) -> None:
        """Online: price the frames appended and not priced yet (up to `end`), so a chunk's
        completion finds its frames priced (`Online.idle` prices each frame as it arrives)."""
        end = self.n if end is None else end
        if self.priced < end:
            lo, hi = self.priced - self.base, end - self.base
            self.pricer.price(self.x, self.base, self.priced, end, self.costs[lo:hi])
            self.priced = end

    def rate_lambda(self, costs: np.ndarray) -> float:
        """Rate controller (module docstring): the DP's λ from every frame priced so far,
        each weighted by the motion ticks it stands for (`motion_weights`)."""
        assert self.rate is not None
        c = costs[:, self.max_len - self.span]
        c = c[np.isfinite(c)]
        if len(c):
            logs = np.log(c * self.ticks + _LOG_FLOOR)
            if c.min() >= self.span * STILL_COST:  # all moving (the usual chunk): full weight
                self.log_sum += self.ticks * float(np.sum(logs))
                self.log_n += self.ticks * len(c)
            else:
                w = motion_weights(c, self.span, self.ticks)
                self.log_sum += float(np.sum(w * logs))
                self.log_n += float(np.sum(w))
        return self.rate_estimate() / self.ticks

    def rate_estimate(self) -> float:
        """λ of the rate mode (ticks x body heights²) from the costs priced so far, shrunk
        towards the prior."""
        assert self.rate is not None
        prior_weight = PRIOR_SECONDS * TICKS_PER_SECOND
        prior = math.log(DEFAULT_LAMBDA / RATE_FACTOR * (self.span * self.ticks / 20.0) ** 5)
        weight = prior_weight + self.log_n
        mean = (prior_weight * prior + self.log_sum) / weight if weight else prior
        return RATE_FACTOR * math.exp(mean)

    def resolve(self, lam: float) -> None:
        """Solve every undecided frame again with penalty `lam`."""
        self.settle()
        self.lam = lam
        lo = self.floor - self.base
        om.dp_rows(self.costs, self.f, self.bp, self.keys, lo + 1, self.done - self.base, lam,
                   lo, self.tolerance)

    def converge(self) -> list[int]:
        """Keys that every chain from the last L priced frames shares, newly final."""
        self.settle()
        t = self.done - 1
        lo = max(self.floor, t - self.max_len + 1) - self.base
        cur = np.arange(lo, t - self.base + 1)
        cur = cur[np.isfinite(self.f[cur])]
        while len(cur) > 1:
            low = cur[0]
            cur = np.unique(np.where(cur > low, self.bp[cur], cur))
        if len(cur) == 0 or cur[0] + self.base <= self.decided:
            return []
        conv = int(cur[0])
        keys = [k + self.base for k in om.chain(self.bp, conv, self.decided - self.base)]
        self.floor = self.decided = conv + self.base
        return keys

    def force(self, d: int) -> list[int]:
        """Decide every frame <= d from the chain of the newest priced frame; re-price the
        frames after d so every chain passes through the decision."""
        self.settle()
        base = self.base
        path = om.chain(self.bp, self.done - 1 - base, self.decided - base)
        keys = [k + base for k in path if k + base <= d]
        if keys:
            self.floor = keys[-1]
        self.decided = d
        lo, hi = self.floor - base, d - base
        if hi > lo:
            self.f[lo + 1 : hi + 1] = np.inf
        # Frames after d whose best chain skips the decision, or passes through such a frame,
        # are solved again (first to last of them). Any other frame keeps its value and its
        # back-pointer: its other options only got worse.
        first, last = om.broken_chains(self.bp, lo, hi, self.done - base)
        if first >= 0:  # solved by `settle`, before anything reads them (spreads the work)
            self.stale = (first + base, last + 1 + base)
        return keys

    def settle(self) -> None:
        """Solve again the frames a deadline decision left stale (`force`), if any."""
        if self.stale is not None:
            lo, hi = self.stale
            self.stale = None
            om.dp_rows(self.costs, self.f, self.bp, self.keys, lo - self.base, hi - self.base,
                       self.lam, self.floor - self.base, self.tolerance)

    def finish(self) -> list[int]:
        """End of stream: price the tail, trace back from the last frame (always a key)."""
        self.settle()
        if self.n == 0:
            return []
        if self.done < self.n:
            self._solve(self.n)
        if self.rate is not None and self.keep_costs:
            lam = self.rate_estimate() / self.ticks
            if lam != self.lam:
                self.resolve(lam)
        path = om.chain(self.bp, self.n - 1 - self.base, self.decided - self.base)
        return [k + self.base for k in path]


def motion_weights(costs: np.ndarray, span: int, ticks: float) -> np.ndarray:
    """Motion ticks of frames whose key-spaced segments (`span` frames) cost `costs` (frame
    sums): `ticks` for a frame that moves, falling linearly to 0 as the segment's mean
    squared departure from a straight line falls below `STILL_COST` (a still or uniformly
    moving stretch needs no keys, so it earns none)."""
    return ticks * np.minimum(1.0, costs / (span * STILL_COST))


def _segment_errors(f: np.ndarray, keys: np.ndarray, lam: float) -> np.ndarray:
    """Costs of the segments between consecutive keys from the DP's F (F(b) = F(a) +
    cost(a, b) + λ along a chain; λ = 0 in tolerance mode)."""
    errors: np.ndarray = np.maximum(np.diff(f[keys]) - lam, 0.0)
    return errors


def _solve_all(x: np.ndarray, max_len: int, ticks: float,
               **mode: Any) -> tuple[np.ndarray, np.ndarray]:
    """Offline λ / tolerance: the online solver over every row, nothing forced; the keys and
    the costs of the segments between them (frame sums)."""
    solver = Solver(max_len, ticks=ticks, **mode)
    solver.add(x)
    keys = np.array(solver.finish(), dtype=np.int64)
    lam = 0.0 if solver.tolerance is not None else solver.lam
    return keys, _segment_errors(solver.f, keys - solver.base, lam)


def _rate_keys(x: np.ndarray, max_len: int, rate: float, ticks: float,
               chunk: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Offline rate: λ from every frame's cost (as the online controller ends up with), then
    one penalised pass (keys, segment costs as frame sums, λ in ticks x body heights²).
    Same costs and chunks as `Solver`, so bit-identical to it."""
    solver = Solver(max_len, rate=rate, ticks=ticks, chunk=chunk)
    band = np.empty((len(x), max_len))
    for b0 in range(0, len(x), chunk):
        b1 = min(len(x), b0 + chunk)
        band[b0:b1] = solver.pricer.price(x, 0, b0, b1)
        lam = solver.rate_lambda(band[b0:b1])
    keys, f = _penalised(band, lam)
    return keys, _segment_errors(f, keys, lam), solver.rate_estimate()


def _penalised(band: np.ndarray, lam: float) -> tuple[np.ndarray, np.ndarray]:
    n = len(band)
    f = np.full(n, np.inf)
    bp = np.full(n, -1, dtype=np.int64)
    keys = np.zeros(n, dtype=np.int64)
    f[0], keys[0] = 0.0, 1
    om.dp_rows(band, f, bp, keys, 1, n, lam)
    return np.array(om.chain(bp, n - 1), dtype=np.int64), f


def _exact_count(band: np.ndarray, count: int) -> np.ndarray:
    """The K-key optimum: G_j(b) = min_a G_{j−1}(a) + cost(a, b), j segments ending at b."""
    n, max_len = band.shape
    a = np.arange(n)[:, None] - max_len + np.arange(max_len)[None, :]
    a_ok = np.maximum(a, 0)
    g = np.full(n, np.inf)
    g[0] = 0.0
    back = np.empty((count - 1, n), dtype=np.int64)
    for j in range(count - 1):
        vals = g[a_ok] + band
        vals[a < 0] = np.inf
        arg = np.argmin(vals, axis=1)
        back[j] = a_ok[np.arange(n), arg]
        g = vals[np.arange(n), arg]
        g[0] = np.inf
    keys = [n - 1]
    for j in range(count - 2, -1, -1):
        keys.append(int(back[j, keys[-1]]))
    return np.array(keys[::-1], dtype=np.int64)


def _adjust(x: np.ndarray, rows: np.ndarray, count: int) -> np.ndarray:
    """Remove (least cost increase) or insert (largest decrease) keys until `count`; only
    the segments next to each change are priced again."""
    keys = [int(k) for k in rows]

    def removal(i: int) -> float:  # cost increase of removing keys[i]
        p, k, q = keys[i - 1], keys[i], keys[i + 1]
        return float(om.pair_costs(x, [p, p, k], [q, k, q]) @ [1.0, -1.0, -1.0])

    def split(a: int, b: int) -> tuple[float, int]:  # best inserted key in (a, b), its gain
        if b - a < 2:
            return -np.inf, a
        ks = np.arange(a + 1, b)
        gain = (om.pair_costs(x, [a], [b])[0] - om.pair_costs(x, np.full(len(ks), a), ks)
                - om.pair_costs(x, ks, np.full(len(ks), b)))
        i = int(np.argmax(gain))
        return float(gain[i]), int(ks[i])

    if len(keys) > count:
        up = [np.inf] + [removal(i) for i in range(1, len(keys) - 1)] + [np.inf]
        while len(keys) > count:
            i = int(np.argmin(up))
            del keys[i], up[i]
            for j in (i - 1, i):
                if 0 < j < len(keys) - 1:
                    up[j] = removal(j)
    if len(keys) < count:
        best = [split(a, b) for a, b in zip(keys[:-1], keys[1:], strict=True)]
        while len(keys) < count:
            i = int(np.argmax([g for g, _ in best]))
            k = best[i][1]
            keys.insert(i + 1, k)
            best[i : i + 1] = [split(keys[i], k), split(k, keys[i + 2])]
    return np.array(keys, dtype=np.int64)


def _count_keys(x: np.ndarray, count: int, max_len: int) -> tuple[np.ndarray, dict[str, Any]]:
    n = len(x)
    max_len = max(max_len, -(-(n - 1) // (count - 1)))  # K keys must be able to cover n
    band = om.band_costs(x, max_len)
    if n * count * max_len <= _EXACT_BUDGET:
        return _exact_count(band, count), {"solver": "exact", "max_segment_frames": max_len}
    band32 = band.astype(np.float32)
    del band
    lo, hi = math.log(1e-9), math.log(1e3)  # log lambda bracket: lo gives >= count keys
    best: dict[int, float] = {}
    for _ in range(4):
        grid = np.linspace(lo, hi, _GRID)
        counts = _penalised_counts(band32, np.exp(grid))
        for g, c in zip(grid, counts, strict=True):
            best.setdefault(int(c), float(g))
        if count in best:
            break
        above = np.flatnonzero(counts > count)
        below = np.flatnonzero(counts < count)
        lo = grid[above[-1]] if len(above) else lo - 4.0
        hi = grid[below[0]] if len(below) else hi + 4.0
    near = min(best, key=lambda k: (abs(k - count), k < count))
    keys = _adjust(x, _penalised(band32, math.exp(best[near]))[0], count)
    return keys, {"solver": "lambda" if near == count else "lambda+greedy",
                  "lambda_count": near, "max_segment_frames": max_len}


def _penalised_counts(band: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """Key counts of the penalised optimum for several λ at once (one pass over the band)."""
    n, max_len = band.shape
    width = len(lams)
    f = np.full((n, width), np.inf)
    keys = np.zeros((n, width), dtype=np.int64)
    f[0], keys[0] = 0.0, 1
    cols = np.arange(width)
    for b in range(1, n):
        lo = max(0, b - max_len)
        vals = f[lo:b] + band[b, max_len - (b - lo):, None]
        i = np.argmin(vals, axis=0)
        f[b] = vals[i, cols] + lams
        keys[b] = keys[lo + i, cols] + 1
    counts: np.ndarray = keys[n - 1]
    return counts


def extract(motion: Motion, *, count: int | None = None, rate: float | None = None,
            tolerance: float | None = None, lam: float | None = None,
            max_segment: DurationLike = DEFAULT_MAX_SEGMENT, weights: np.ndarray | None = None,
            root_translation: bool = False, features: Features | None = None,
            noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> Keyframes:
    """Optimal keys of `motion` (module docstring); default mode: `rate=DEFAULT_RATE`.
    `max_segment`: a `Duration`, or a plain number of seconds."""
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
                              "weights": None if weights is None else list(weights)}
    info: dict[str, Any] = {}
    if n == 1:
        rows, err = np.zeros(1, dtype=np.int64), np.zeros(0)
    elif "count" in mode:
        if mode["count"] > n:
            raise UsageError(f"count must be in [2, {n}] (captured frames), got {count}")
        rows, info = _count_keys(x, mode["count"], max_len)
        err = om.pair_costs(x, rows[:-1], rows[1:])
    elif "rate" in mode:
        rows, err, info["lambda"] = _rate_keys(x, max_len, mode["rate"] / motion.fps, ticks,
                                               chunk_frames(motion.fps))
    else:
        rows, err = _solve_all(x, max_len, ticks, **mode)
    info["error"] = float(err.sum() / n)  # mean per-frame error, body heights^2 (lerp proxy)
    scores = key_scores(x, rows, ticks)
    return Keyframes(METHOD, rows + motion.first_frame, scores, params, motion.n_frames, info)


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
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES) -> None:
        if count is not None:
            raise UsageError("optimal online: a key count needs the whole take; give a rate "
                             "(keys per second) or a tolerance")
        mode = _mode(None, rate, tolerance, lam)
        frames = _lookahead_frames(lookahead, fps)
        self.max_len = _frames(max_segment, fps, "max_segment")
        self.ticks = TICKS_PER_SECOND / float(fps)
        super().__init__(skeleton, fps, lookahead=frames, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params={**mode, "max_segment": _span_param(max_segment),
                                 "root_translation": root_translation,
                                 "weights": None if weights is None else list(weights)})
        self.mode = mode
        self.weights = None if weights is None else np.asarray(weights, dtype=np.float64)
        self.root_translation = root_translation
        self.scale = om.point_scale(skeleton.n_joints, self.features.body_height, self.weights,
                                    root_translation)
        self.reset()

    def reset(self) -> None:
        """Forget the stream; keep parameters."""
        kw = {"rate": self.mode["rate"] / self.fps} if "rate" in self.mode else dict(self.mode)
        self.solver = Solver(self.max_len, keep_costs=True, ticks=self.ticks,
                             chunk=chunk_frames(self.fps), **kw)
        self.solver.pricer.prepare(3 * len(self.scale))
        self.seq: list[int] = []
        self.time: list[float] = []
        self.t0 = 0  # stream index of seq[0]
        self.prev_key: int | None = None  # stream index of the last key sent

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap or a source restart: the rate controller's cost
        statistics (hence λ) are kept, so the key rate holds from the new window's first
        frames. Without them: `reset()`."""
        log = self.solver.log_sum, self.solver.log_n
        self.reset()
        if keep_statistics and self.solver.rate is not None:
            self.solver.log_sum, self.solver.log_n = log
            self.solver.lam = self.solver.rate_estimate() / self.solver.ticks

    def _events(self, keys: list[int], decided_at: int) -> list[KeyframeEvent]:
        out = []
        s = self.solver
        for k in keys:
            prev, self.prev_key = self.prev_key, k
            score = 0.0 if prev is None else key_scores(s.x, np.array([prev, k]) - s.base,
                                                        s.ticks)[1]
            out.append(self.event(self.seq[k - self.t0], self.time[k - self.t0], score,
                                  decided_at))
        return out

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Append the block's frames; decide what converged or reached its deadline."""
        rows = om.body_rows(block.positions, self.scale, self.root_translation)
        s = self.solver
        events: list[KeyframeEvent] = []
        for i in range(len(block)):
            self.seq.append(int(block.seq[i]))
            self.time.append(float(block.time[i]))
            if s.stale is not None:  # the frame after a chunk's: its decision's re-solve
                s.settle()
            for end in s.add(rows[i : i + 1]):
                keys = [] if s.rate is not None else s.converge()
                d = end + s.chunk - 1 - self.lookahead
                if d > s.decided:
                    keys += s.force(d)
                events += self._events(keys, int(block.seq[i]))
            drop = min(s.decided, s.base) - self.t0
            if drop > 256:
                del self.seq[:drop], self.time[:drop]
                self.t0 += drop
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
        if self.solver.n == 0:
            return []
        return self._events(self.solver.finish(), self.seq[-1])

    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: the keys after the decided part on the best chain of the newest
        priced frame (what a deadline would take now), that frame itself left out."""
        s = self.solver
        if s.stale is not None or s.done == 0:
            return []
        path = om.chain(s.bp, s.done - 1 - s.base, s.decided - s.base)
        rows = [k + s.base - self.t0 for k in path[:-1]]
        return [(self.seq[r], self.time[r], 0.0) for r in rows if 0 <= r < len(self.seq)]


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


class MaxGap(OnlineKeyframer):
    """Any online keyframer with `--max-gap`: once the inner keyframer has decided a stretch
    longer than the gap without a key (frames older than its lookahead are final), a key is
    inserted at the best frame by the optimal segment cost. Inserted keys have latency up to
    inner lookahead + gap, which is this keyframer's lookahead; inner keys pass unchanged."""

    method = "?"

    def __init__(self, inner: OnlineKeyframer, seconds: DurationLike) -> None:
        self.inner = inner
        self.method = inner.method  # type: ignore[misc]
        self.gap = _frames(seconds, inner.fps, "max_gap")
        super().__init__(inner.skeleton, inner.fps, lookahead=inner.lookahead + self.gap,
                         stream=inner.stream,
                         params={**inner.params, "max_gap": _span_param(seconds)})
        self.guard = inner.guard
        self.features = inner.features
        self.scale = om.point_scale(inner.skeleton.n_joints, inner.features.body_height)
        self.reset()

    def reset(self) -> None:
        """Forget the stream (the inner keyframer too)."""
        self.inner.reset()
        self._forget()

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window: the inner keyframer restarts (keeping its statistics unless told
        otherwise); the stretch since the last key starts over."""
        self.inner.restart(keep_statistics)
        self._forget()

    def _forget(self) -> None:
        self.rows: list[np.ndarray] = []  # curve rows from the last key on
        self.seq: list[int] = []
        self.time: list[float] = []
        self.t0 = 0  # stream index of rows[0]
        self.t = -1
        self._idle_final = 0  # the final frame `idle` fills gaps up to
        self.last = 0  # stream index of the last key (the first frame is an anchor)

    def _fill(self, end: int) -> list[KeyframeEvent]:
        """Keys while the stretch from the last key to `end` (a key, or a bound on the next
        one) is longer than the gap."""
        out = []
        while end - self.last > self.gap:
            a = self.last - self.t0
            k = om.best_split(np.array(self.rows), a, a + self.gap + 1, a + self.gap)
            out.append(KeyframeEvent(stream=self.stream, method=self.method, frame=self.seq[k],
                                     time=self.time[k], score=0.0, decided_at=self.seq[-1],
                                     lookahead=self.lookahead, params=self.params_digest,
                                     strength=0.0))  # inserted: not a key the method found
            self.last = k + self.t0
        return out

    def _advance(self, events: list[KeyframeEvent], final: int) -> list[KeyframeEvent]:
        """Inner events in order with the gaps before them filled, then the gaps of the
        decided part (frames <= final carry no other key)."""
        out: list[KeyframeEvent] = []
        for e in events:
            k = self.t0 + e.frame - self.seq[0]
            out += self._fill(k)
            out.append(e)
            self.last = max(self.last, k)
        out += self._fill(final)
        drop = self.last - self.t0
        if drop > 0:
            del self.rows[:drop], self.seq[:drop], self.time[:drop]
            self.t0 += drop
        return out

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Frame by frame: the inner keyframer, then gap filling over the part it has
        finalised (older than its lookahead). The inner deferred work of the block's last
        frame is left to `idle`, so a re-analysis (speed) stays off the due path; until then
        frame t - lookahead may still get an inner key, so filling stops one frame short."""
        rows = om.body_rows(block.positions, self.scale)
        out: list[KeyframeEvent] = []
        last = len(block) - 1
        for i in range(len(block)):
            self.rows.append(rows[i])
            self.seq.append(int(block.seq[i]))
            self.time.append(float(block.time[i]))
            self.t += 1
            events = self.inner.process(block.slice(i, i + 1))
            if i < last:
                events += self.inner.idle()
            out += self._advance(events, self.t - self.inner.lookahead + (i < last))
        self._idle_final = self.t - self.inner.lookahead + 1
        return out

    def idle(self) -> list[KeyframeEvent]:
        """The inner keyframer's deferred work of the last frame, then the gaps it settles."""
        if self.t < 0:
            return self.inner.idle()
        return self._advance(self.inner.idle(), self._idle_final)

    def candidates(self) -> list[tuple[int, float, float]]:
        """The inner keyframer's candidates (provisional hook)."""
        return self.inner.candidates()

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: the inner keyframer's rest, then the gaps up to the last frame."""
        if self.t < 0:
            return self.inner.finish()
        return self._advance(self.inner.finish(), self.t)
