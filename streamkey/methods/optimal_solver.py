"""The online optimal-keys solver in named parts: the rows the DP holds (`DPRows`), the rate
mode's λ estimate (`RateController`) and the penalised / tolerance DP over a growing stream
with traceback convergence and deadline decisions (`Solver`). Definitions: the module
docstring of `streamkey.methods.optimal`. No I/O, no clocks."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from . import optimal_math as om

__all__ = ["DEFAULT_LAMBDA", "TICKS_PER_SECOND", "PRIOR_SECONDS", "RESOLVE", "RATE_FACTOR",
           "STILL_COST", "DPRows", "MotionFrames", "mark_rows", "RateController", "Solver",
           "motion_weights"]

DEFAULT_LAMBDA = 3.5e-3  # ticks x body heights^2 (a tick: 1/120 s)
TICKS_PER_SECOND = 120.0  # the time unit of costs and lambda: 1/120 s, a frame at 120 Hz
PRIOR_SECONDS = 10.0  # rate mode: weight of the prior lambda, in seconds of motion
RESOLVE = 0.05  # rate mode: re-solve the undecided frames when log lambda moves this much
RATE_FACTOR = 3.2  # lambda / geometric mean cost of key-spaced segments (shared clips, 5 %)
STILL_COST = 1e-8  # body heights^2: mean squared departure from a straight line below which
#                    a key-spaced stretch is still (RMS 1e-4 body heights, about 0.2 mm)
_LOG_FLOOR = 1e-12  # smallest segment cost in the geometric mean


def motion_weights(costs: np.ndarray, span: int, ticks: float) -> np.ndarray:
    """Motion ticks of frames whose key-spaced segments (`span` frames) cost `costs` (frame
    sums): `ticks` for a frame that moves, falling linearly to 0 as the segment's mean
    squared departure from a straight line falls below `STILL_COST` (a still or uniformly
    moving stretch needs no keys, so it earns none)."""
    return ticks * np.minimum(1.0, costs / (span * STILL_COST))


def mark_rows(holds: list[tuple[int, int]], lo: int, hi: int, base: int,
              floor: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Hold marks of stream indices lo .. hi − 1 (rows from `base`): keyable unless strictly
    inside a hold (start, end) (end `_OPEN`: not closed yet), and the row of the hold's
    start for the frames after it up to its end (the long edge; −1: none), or of the last
    decided key `floor` if that is inside the hold (decided before the hold was known)."""
    keyable = np.ones(hi - lo, dtype=np.bool_)
    edge = np.full(hi - lo, -1, dtype=np.int64)
    for s, e in holds:
        i0 = max(s + 1, lo)
        if i0 < min(e, hi):
            keyable[i0 - lo : min(e, hi) - lo] = False
        a = max(s, floor) if floor < e else s
        if i0 <= min(e, hi - 1) and a >= base:
            edge[i0 - lo : min(e, hi - 1) + 1 - lo] = a - base
    return keyable, edge


class MotionFrames:
    """Which frames of the stream are motion (inside a take), as opposed to a calibration
    hold or a still stretch (`streamkey.segments`), as far as that is final."""

    def __init__(self) -> None:
        self.known = 0  # frames (stream indices) before this have their final status
        self.holds: list[tuple[int, int]] = []  # non-motion stretches [start, end]

    def hold(self, start: int, end: int | None) -> None:
        """A calibration hold or still stretch from `start` to `end` (inclusive; None: open,
        lasting at least up to the frames known); replaces the one with the same start."""
        stretch = (start, _OPEN if end is None else end)
        for i, (s, _) in enumerate(self.holds):
            if s == start:
                self.holds[i] = stretch
                return
        self.holds.append(stretch)

    def moving(self, lo: int, hi: int) -> np.ndarray:
        """True for the motion frames among lo .. hi − 1 (all below `known`)."""
        out = np.ones(hi - lo, dtype=bool)
        for s, e in self.holds:
            if s < hi and e >= lo:
                out[max(s, lo) - lo : min(e + 1, hi) - lo] = False
        return out

    def forget_before(self, frame: int) -> None:
        """Drop the stretches that end before `frame` (no longer asked about)."""
        self.holds = [h for h in self.holds if h[1] >= frame]


_OPEN = 2**62  # end of a stretch not closed yet


class RateController:
    """Rate mode's λ: 3.2 × the geometric mean cost of key-spaced segments over the motion
    priced so far, shrunk towards the prior (module docstring of `optimal`). A chunk's frames
    count once their segment status is final (`motion`), chunk after chunk in order, so the
    sums are the same bits online and offline; calibration holds and still stretches add
    nothing."""

    def __init__(self, rate: float, max_len: int, ticks: float) -> None:
        self.rate = rate  # keys per frame
        self.span = int(min(max_len, max(2, round(1.0 / rate))))  # frames per key
        self.column = max_len - self.span  # band column of the key-spaced segment
        self.ticks = ticks  # ticks per frame
        self.log_sum = 0.0  # Σ w log cost(b − span, b), w the motion ticks of frame b
        self.log_n = 0.0  # Σ w: motion ticks seen
        self.motion = MotionFrames()  # which frames are motion
        self.pending: deque[tuple[int, np.ndarray]] = deque()  # chunks not counted yet
        self.ahead = 0.0, 0.0  # the pending chunks' provisional (log_sum, log_n)

    def new_window(self) -> None:
        """A new window of the stream (indices from 0 again): keep the sums."""
        self.motion = MotionFrames()
        self.pending.clear()
        self.ahead = 0.0, 0.0

    def observe(self, costs: np.ndarray, start: int) -> float:
        """Take in the band rows of the newly priced frames start, start + 1, ..; count every
        chunk whose frames' status is final; the DP's λ (per key, frame sums)."""
        self.pending.append((start, costs[:, self.column].copy()))
        return self.absorb()

    def absorb(self) -> float:
        """Count the pending chunks whose frames' status is final, in order; the DP's λ."""
        while self.pending:
            start, c = self.pending[0]
            if start + len(c) > self.motion.known:
                break
            self.pending.popleft()
            self.log_sum, self.log_n = self._count(c, self.motion.moving(start, start + len(c)),
                                                   self.log_sum, self.log_n)
            self.motion.forget_before(start + len(c))
        ahead = 0.0, 0.0
        for start, c in self.pending:  # as far as known: frames not in a hold are motion
            ahead = self._count(c, self.motion.moving(start, start + len(c)), *ahead)
        self.ahead = ahead
        return self.estimate() / self.ticks

    def _count(self, c: np.ndarray, moving: np.ndarray, log_sum: float,
               log_n: float) -> tuple[float, float]:
        """(log_sum, log_n) with the chunk's frames added."""
        finite = np.isfinite(c)
        c, moving = c[finite], moving[finite]
        if len(c):
            logs = np.log(c * self.ticks + _LOG_FLOOR)
            if moving.all() and c.min() >= self.span * STILL_COST:  # the usual chunk
                log_sum += self.ticks * float(np.sum(logs))
                log_n += self.ticks * len(c)
            else:
                w = motion_weights(c, self.span, self.ticks) * moving
                log_sum += float(np.sum(w * logs))
                log_n += float(np.sum(w))
        return log_sum, log_n

    def estimate(self) -> float:
        """λ (ticks x body heights²) from the costs counted so far and, provisionally, those
        of the pending chunks, shrunk towards the prior."""
        prior_weight = PRIOR_SECONDS * TICKS_PER_SECOND
        prior = math.log(DEFAULT_LAMBDA / RATE_FACTOR * (self.span * self.ticks / 20.0) ** 5)
        log_sum, log_n = self.log_sum + self.ahead[0], self.log_n + self.ahead[1]
        weight = prior_weight + log_n
        mean = (prior_weight * prior + log_sum) / weight if weight else prior
        return RATE_FACTOR * math.exp(mean)


class DPRows:
    """The stream rows the DP holds, stream indices `base` .. (arrays grow by doubling; the
    online solver drops rows it no longer reads when it grows them)."""

    def __init__(self, max_len: int, keep_costs: bool) -> None:
        self.max_len = max_len  # longest segment, frames (band width)
        self.keep_costs = keep_costs  # online: each frame's band kept in `costs`
        self.base = 0  # stream index of row 0
        self.x = np.empty((0, 0))  # curve rows
        self.f = np.empty(0)  # F: best penalised cost of a chain ending at the row
        self.bp = np.empty(0, dtype=np.int64)  # back-pointers (row indices)
        self.keys = np.empty(0, dtype=np.int64)  # keys on the chain
        self.costs = np.empty((0, max_len))  # bands (online only)
        self.marks = om.no_marks(0)  # keyable, hold edge (row), its cost (`om.dp_rows`)

    def grow(self, held: int, need: int, width: int, keep: int) -> None:
        """Room for `need` more rows after `held`: drop rows before stream index `keep`
        (online), then enlarge if still full."""
        if held + need <= len(self.f):
            return
        shift = keep - self.base if self.keep_costs else 0
        size = max(64, 2 * (held - shift + need))
        old = (self.x, self.f, self.bp, self.keys, self.costs, *self.marks)
        self.x = np.empty((size, width))
        self.f = np.full(size, np.inf)
        self.bp = np.full(size, -1, dtype=np.int64)
        self.keys = np.zeros(size, dtype=np.int64)
        self.costs = np.empty((size if self.keep_costs else 0, self.max_len))
        self.marks = om.no_marks(size)
        rows = held - shift
        for new, prev in zip((self.x, self.f, self.bp, self.keys, self.costs, *self.marks), old,
                             strict=True):
            if len(new) and rows:
                new[:rows] = prev[shift:held]
        self.bp[:rows] -= shift
        edge = self.marks[1][:rows]
        edge[edge >= 0] -= shift
        self.base += shift


class Solver:
    """The penalised (or tolerance) DP over a growing stream, with traceback convergence.

    Rows in `rows` (`DPRows`: stream indices from `rows.base`). Offline: `add` every row,
    then `finish`. Online: `add` per block, `converge` per chunk, `force` at deadlines.
    """

    def __init__(self, max_len: int, *, lam: float | None = None, rate: float | None = None,
                 tolerance: float | None = None, keep_costs: bool = False,
                 ticks: float = 1.0, chunk: int = om.CHUNK) -> None:
        self.max_len = int(max_len)  # longest segment, frames
        self.chunk = int(chunk)  # frames solved together (`optimal.chunk_frames`)
        self.ticks = float(ticks)  # ticks (1/120 s) per frame: frame sums x ticks = integrals
        self.lam0 = float(lam if lam is not None else DEFAULT_LAMBDA)  # fixed λ, ticks x h²
        self.rate_per_frame = rate  # rate mode: keys per frame (None: fixed λ or tolerance)
        self.tolerance = tolerance  # tolerance mode: mean error bound, body heights²
        self.keep_costs = keep_costs  # online: bands kept for re-solves
        self.reset()

    def reset(self) -> None:
        """Empty stream."""
        self.n = 0  # frames appended
        self.done = 0  # frames with F computed
        self.priced = 0  # online: frames with their costs in `rows.costs`
        self.floor = 0  # last committed key (stream index)
        self.decided = -1  # every frame <= decided is final
        self.stale: tuple[int, int] | None = None  # frames to solve again (stream indices)
        self.rate = None if self.rate_per_frame is None else RateController(
            self.rate_per_frame, self.max_len, self.ticks)  # rate mode's λ estimate
        # the DP's lambda: per key, in the unit of the costs it adds (frame sums)
        self.lam = (self.lam0 if self.rate is None else self.rate.estimate()) / self.ticks
        self.pricer = om.Pricer(self.max_len)  # segment costs, frame after frame
        self.rows = DPRows(self.max_len, self.keep_costs)  # the held rows and DP arrays
        self.holds: list[tuple[int, int]] = []  # no key strictly inside (`hold`)

    @property
    def base(self) -> int:
        """Stream index of the first held row."""
        return self.rows.base

    def add(self, rows: np.ndarray) -> list[int]:
        """Append rows; solve every completed chunk. Returns the stream indices of the chunk
        ends solved (the frames after which convergence may be checked)."""
        r = self.rows
        held = self.n - r.base
        if held + len(rows) > len(r.f):
            # online: rows before the floor and the last window are unused
            keep = max(r.base, min(self.floor, self.done - self.max_len))
            r.grow(held, len(rows), rows.shape[1], keep)
        lo = self.n - r.base
        r.x[lo : lo + len(rows)] = rows
        self.n += len(rows)
        if self.holds:
            self._mark(self.n - len(rows), self.n)
        ends = []
        while self.n - self.done >= self.chunk:
            self._solve(self.done + self.chunk)
            ends.append(self.done - 1)
        return ends

    def _solve(self, end: int) -> None:
        """Solve frames done .. end − 1 (one chunk, or the tail at finish), pricing those not
        priced yet."""
        self.settle()
        r = self.rows
        b0, b1 = self.done - r.base, end - r.base
        if self.keep_costs:
            self.price(end)
            costs = r.costs[b0:b1]
        else:
            costs = self.pricer.price(r.x, r.base, self.done, end)
        start = b0
        if self.done == 0:
            r.f[0], r.bp[0], r.keys[0] = 0.0, -1, 1
            start = 1
        self._dp(costs, start, b1, b0)
        first, self.done = self.done, end
        if self.rate is not None:
            lam = self.rate.observe(costs, first)
            if self.keep_costs and abs(math.log(lam / self.lam)) > RESOLVE:
                self.resolve(lam)

    def price(self, end: int | None = None) -> None:
        """Online: price the frames appended and not priced yet (up to `end`), so a chunk's
        completion finds its frames priced (`Online.idle` prices each frame as it arrives)."""
        end = self.n if end is None else end
        if self.priced < end:
            r = self.rows
            lo, hi = self.priced - r.base, end - r.base
            self.pricer.price(r.x, r.base, self.priced, end, r.costs[lo:hi])
            self.priced = end

    def resolve(self, lam: float) -> None:
        """Solve every undecided frame again with penalty `lam`."""
        self.settle()
        self.lam = lam
        r = self.rows
        self._dp(r.costs, self.floor + 1 - r.base, self.done - r.base)

    def _dp(self, costs: np.ndarray, lo: int, hi: int, c0: int = 0) -> None:
        """The DP over rows lo .. hi − 1 with the current λ, floor and holds; rows up to the
        last deadline decision stay as it left them (no key after the floor up to it)."""
        r = self.rows
        lo = max(lo, self.decided + 1 - r.base)
        if self.holds:
            om.edge_costs(r.x, r.marks[1], r.marks[2], lo, hi, self.max_len)
        om.dp_rows(costs, r.f, r.bp, r.keys, lo, hi, self.lam, self.floor - r.base,
                   self.tolerance, c0=c0, marks=r.marks)

    def hold(self, start: int, end: int | None) -> None:
        """No key strictly inside frames start .. end (stream indices; None: open, up to the
        newest frame and on; replaces the hold with the same start): the segment from
        `start` may then be longer than L. Frames already solved that this changes are
        solved again (penalised form only)."""
        stretch = (start, _OPEN if end is None else end)
        self.holds = [h for h in self.holds if h[0] != start] + [stretch]
        self.settle()
        lo = max(start + 1, self.floor + 1, self.rows.base)
        changed = self._mark(lo, self.n)
        if changed is not None and changed < self.done:
            r = self.rows
            self._dp(r.costs, changed - r.base, self.done - r.base)

    def _mark(self, lo: int, hi: int) -> int | None:
        """Mark stream indices lo .. hi − 1 from the holds; the first whose marks changed."""
        r = self.rows
        if hi <= lo:
            return None
        keyable, edge = mark_rows(self.holds, lo, hi, r.base, self.floor)
        a, b = lo - r.base, hi - r.base
        moved = edge != r.marks[1][a:b]
        diff = np.flatnonzero(moved | (keyable != r.marks[0][a:b]))
        r.marks[0][a:b] = keyable
        r.marks[1][a:b] = edge
        r.marks[2][a:b][moved] = np.nan
        return None if len(diff) == 0 else lo + int(diff[0])

    def converge(self) -> list[int]:
        """Keys that every chain from the last L priced frames shares, newly final."""
        self.settle()
        r = self.rows
        t = self.done - 1
        lo = max(self.floor, t - self.max_len + 1) - r.base
        cur = np.arange(lo, t - r.base + 1)
        cur = cur[np.isfinite(r.f[cur])]
        while len(cur) > 1:
            low = cur[0]
            cur = np.unique(np.where(cur > low, r.bp[cur], cur))
        if len(cur) == 0 or cur[0] + r.base <= self.decided:
            return []
        conv = int(cur[0])
        keys = [k + r.base for k in om.chain(r.bp, conv, self.decided - r.base)]
        self.floor = self.decided = conv + r.base
        return keys

    def force(self, d: int) -> list[int]:
        """Decide every frame <= d from the chain of the newest priced frame; re-price the
        frames after d so every chain passes through the decision."""
        self.settle()
        r = self.rows
        base = r.base
        path = om.chain(r.bp, self.done - 1 - base, self.decided - base)
        keys = [k + base for k in path if k + base <= d]
        if keys:
            self.floor = keys[-1]
        self.decided = d
        lo, hi = self.floor - base, d - base
        if hi > lo:
            r.f[lo + 1 : hi + 1] = np.inf
        # Frames after d whose best chain skips the decision, or passes through such a frame,
        # are solved again (first to last of them). Any other frame keeps its value and its
        # back-pointer: its other options only got worse.
        first, last = om.broken_chains(r.bp, lo, hi, self.done - base)
        if first >= 0:  # solved by `settle`, before anything reads them (spreads the work)
            self.stale = (first + base, last + 1 + base)
        if any(s < self.floor < e for s, e in self.holds):
            # a key decided inside a hold before it was known: its long edge starts there
            self._mark(self.floor + 1, self.n)
            if d + 1 < self.done:
                self.stale = (d + 1, self.done)
        return keys

    def settle(self) -> None:
        """Solve again the frames a deadline decision left stale (`force`), if any."""
        if self.stale is not None:
            lo, hi = self.stale
            self.stale = None
            r = self.rows
            self._dp(r.costs, lo - r.base, hi - r.base)

    def finish(self) -> list[int]:
        """End of stream: price the tail, trace back from the last frame (always a key)."""
        self.settle()
        if self.n == 0:
            return []
        if self.done < self.n:
            self._solve(self.n)
        if self.rate is not None and self.keep_costs:
            lam = self.rate.absorb()
            if lam != self.lam:
                self.resolve(lam)
        r = self.rows
        path = om.chain(r.bp, self.n - 1 - r.base, self.decided - r.base)
        return [k + r.base for k in path]
