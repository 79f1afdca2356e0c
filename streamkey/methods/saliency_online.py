"""Online multiscale motion saliency (C. Halit, MSc thesis, Bilkent University, 2010;
Halit & Capin, 2011), the streaming twin of `saliency.extract`.

Online: `Online(skeleton, fps, sigma=..., lookahead=...)`. Each global statistic of the
offline method becomes a running one, chosen so that at `flush()` it equals the global one
exactly (sums, counts and maxima, with the same batch arithmetic as offline), which is what
makes the online result equal the offline one when every decision waits for `flush()`:

- Standardisation and PCA basis -> running moments (count, sum of x, sum of x x^T after
  subtracting the stream's first frame): frames that leave the window are folded into a total,
  the window is added in one batch when the basis is recomputed. Recomputed rarely (warm-up
  end at frame `lookahead`, whenever the frame count doubles, at least every `update_every`
  frames, and at `flush()`), because each basis change moves every curve (the main source of
  disagreement with offline) and costs a batch recompute of the window. New components are
  matched to the previous ones (greedy on |cos|, signs aligned) so that curve j stays curve j
  and keeps its running statistics. Frames that left the window are folded in pieces of
  `FOLD_EVERY` (64) frames. Only the first basis is computed in a push (frame `lookahead`,
  from the frames so far, ~1.5 ms once per window: computed a frame earlier in `idle()`, it
  measured 0.928 / min 0.802 at lookahead 240 instead of 0.931 / 0.811). Every later update,
  once frame 2 radius + 2 has arrived (the stream-start rows' support), is spread: due at
  frame u, it takes the moments of the window at u, and its work (moments, correlation,
  eigen-decomposition, matching, curves, curvatures, blocks of maps, the switch: one piece a
  frame, in `idle()`) runs over the next `SPREAD` (0.2 s: 24 frames at 120 Hz, at least
  `MIN_SPREAD_FRAMES` = 10 for its pieces); the new basis decides from frame u + 24 on (at
  120 Hz), the frames in between are classified with the previous one (at once,
  the stream-start updates cost 1.5-6.5 ms in a deciding push). Measured on the shared clips
  (sigma = 10), mean F1 against offline (lowest clip): 0.801 (0.500) at lookahead 30, 0.852
  (0.615) at 60, 0.895 (0.773) at 121, 0.931 (0.811) at 240; with the stream-start updates
  made at once 0.804, 0.851, 0.897 (0.773), 0.932 (0.822). Other timings of the same work
  move these by +-0.005. The spread was 24 frames at every rate, so a 30 Hz stream switched
  bases 0.8 s after they were due: the same take's online keys at 30 / 60 / 240 Hz against
  the 120 Hz take's (29 shared BVH clips, F1 mean, lowest) 0.844 (0.686) / 0.947 (0.865) /
  0.976 (0.912) with 24 frames, 0.856 (0.686) / 0.950 (0.865) / 0.982 (0.955) with 0.2 s.
- Itti maxima M_i and H, mean of the other local maxima, and the mean-saliency threshold ->
  per (curve, scale) running count, sum, maximum, and local-maximum count / sum / maximum of
  the raw maps of every frame so far. Whole-history statistics, not a short window (they
  agree better). The frames of the window (the lookahead, and at least the last
  `HISTORY_SECONDS` = 10 s) are recomputed with each new basis; older ones keep the values of
  the basis they were computed with. Measured on the shared clips at sigma = 10 and the
  default lookahead: mean F1 against offline 0.877 with the lookahead-sized window only,
  0.894 with 10 s, 0.895 keeping the whole stream.
- Motion (the offline `motion_mask`): the keyframer runs its own `streamkey.segments
  .SegmentDetector` on its frames (the same detector as offline `detect_segments`), and
  each segment event reaches `note_segment` before the frame that decided it. A frame is
  labelled motion or not as it arrives (the open segment's kind) and relabelled when a
  segment is decided; non-motion rows stay out of the moments and map statistics from then
  on (rows already counted leave them at the next basis update, which recomputes the
  window) and are no candidates. At `flush()` every segment is closed, so the final
  statistics are the offline ones.
- Clustering needs no global statistic: runs and 2 sigma cuts are decided frame by frame.
- Below the support (lookahead < radius + 1 + 2 sigma): a frame whose deadline comes
  before its Gaussian windows are complete is classified from maps whose windows are cut at
  the newest frame t, weights renormalised over the part inside, with the curvature of t by
  the clip-end rule (D' one-sided, D'' copied): the offline edge rule, as if the clip ended at
  t. These provisional maps are used once and never enter the running statistics, which keep
  the final maps only. While the final maps cover fewer frames than the last basis update saw
  (stream start, at most `radius` final rows at that update), the Itti statistics come from
  the maps of that update (cut at its frame) instead. A cluster still open at its deadline is
  closed there; the run goes on in a new cluster on the same 2 sigma grid. Measured on the
  shared clips at sigma = 10 (results/agreement_saliency_lookahead.md): mean F1 0.804 at 30
  frames, 0.851 at 60, 0.897 at 121 (the default).
"""

from __future__ import annotations

import copy
from collections import deque
from typing import cast

import numpy as np

from ..errors import UsageError
from ..keyframes import KeyframeEvent
from ..motion import Skeleton
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock
from ..segments import SegmentDetector, SegmentEvent
from ..units import Duration, DurationLike, whole_frames
from .saliency_kernels import Clusterer, classify_block, itti_factors, smooth_rows
from .saliency_math import (
    FOOT_SIGMA,
    cluster_length,
    cluster_size,
    end_curvature,
    frames_at,
    kernel_bank,
    lowpass,
    moments,
    support_radius,
    time_step,
    truncated_maps,
)
from .saliency_presets import HISTORY_SECONDS, METHOD, PRESETS, UPDATE_EVERY, resolve_params
from .saliency_state import OnlineSetup, Preview
from .saliency_window import FOLD_EVERY, SPREAD, WindowAnalysis

TRACE_FRAMES = 2400  # 20 s at 120 Hz of per-frame saliency kept for live views
CANDIDATE_EVERY = 4  # frames between two derivations of the provisional candidates
_NO_STOP = 1 << 62  # `classify_block` without a deadline

__all__ = ["Online", "TRACE_FRAMES", "CANDIDATE_EVERY", "SPREAD", "FOLD_EVERY"]


def _frames(value: DurationLike, fps: float, name: str, whole: bool = False) -> int:
    """A duration parameter of the online keyframer in whole frames at `fps` (>= 1); a plain
    number is frames (an integer if `whole`)."""
    kinds = (Duration, int, np.integer) if whole else (Duration, int, float, np.number)
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise UsageError(f"saliency online: {name} must be a "
                         f"{'whole ' if whole else ''}number of frames or a Duration, "
                         f"got {value!r}")
    frames = whole_frames(value, fps)
    if not frames >= 1:
        raise UsageError(f"saliency online: {name} must be >= 1 frame, got {value}")
    return frames


def _setup(sigma: float, k: int, contact: bool, variance_rule: bool, fps: float,
           lookahead: DurationLike | None, update_every: DurationLike,
           history: DurationLike | None, columns: int) -> tuple[OnlineSetup, int, int]:
    """The fixed part of the online keyframer at `fps`: (setup, lookahead, history), frames."""
    foot_sigma = frames_at(FOOT_SIGMA, fps)
    radius = support_radius(sigma, contact, foot_sigma)
    cmax = cluster_size(sigma)  # the longest cluster, whole frames
    min_lookahead = radius + 1 + cmax  # the support: the default
    look = (min_lookahead if lookahead is None
            else _frames(lookahead, fps, "lookahead", whole=True))
    every = _frames(update_every, fps, "update_every")
    hist = (int(round(HISTORY_SECONDS * float(fps))) if history is None
            else _frames(history, fps, "history"))
    # Frames kept: the decision window, and at least `history` (default 10 s) so that a new
    # basis recomputes the maps and statistics of the recent past consistently.
    window = max(max(look, radius) + radius + 2, hist)
    # main-curve kernels in columns 0-7, foot-curve kernels in columns 8-15
    bank2 = np.hstack([kernel_bank(sigma, radius), kernel_bank(foot_sigma, radius)])
    full = bank2 / bank2.sum(axis=0)
    diff_bank = np.hstack([full[:, 0:4] - full[:, 4:8], full[:, 8:12] - full[:, 12:16]])
    lp_b, lp_a = lowpass(fps)
    setup = OnlineSetup(sigma=sigma, k=k, contact=contact, variance_rule=variance_rule,
                        foot_sigma=foot_sigma, step=time_step(fps), radius=radius, cmax=cmax,
                        clen=cluster_length(sigma), min_lookahead=min_lookahead,
                        update_every=every, window=window, columns=columns, bank2=bank2,
                        diff_bank=diff_bank, lp_b=lp_b, lp_a=lp_a)
    return setup, look, hist


class Online(WindowAnalysis):
    """Online multiscale saliency: `push` frames, get keyframe events within `lookahead`.

    Running statistics replace the global ones (module docstring). Between basis updates a
    new frame costs one low-pass row of its rotations and foot heights
    (`saliency_math.smooth_curves`, the same recursion as offline; the curves are affine in
    them, so a new basis needs no new filtering), one projection, one curvature row and one
    row of maps (compiled loops,
    `saliency_kernels.ring_curves` / `ring_maps_of`), computed in `idle()` after its decisions
    (or first thing at the next frame), so that a deciding frame computes its own row only; a
    basis update's work runs in `idle()` too. A deciding frame classifies and clusters its
    due rows in one compiled loop (`saliency_kernels.classify_block`, the bits of the numpy
    maths). Memory is a ring of `window` frames (`WindowAnalysis`).

    Timing: the maps of frame f need frames up to f + `radius` + 1. Frames are classified
    (candidate or not, with the statistics of that moment) in order and as late as allowed: a
    cluster starting at frame c0 (at most 2 sigma frames) is classified and closed when frame
    c0 + lookahead arrives, and a frame that may start one waits until its own f + lookahead.
    Hence every event has latency_frames <= lookahead, warm-up included, and a lookahead of at
    least the stream's length leaves every decision to `flush()`. The default lookahead is
    radius + 1 + 2 sigma, the method's support: 121 frames at sigma = 10, 37 at sigma = 3 with
    contact. Any lookahead >= 1 is accepted: below the support, frames are decided from
    Gaussian windows cut at the newest frame and clusters closed at their deadline (module
    docstring), so latency_frames <= lookahead still holds; agreement with offline degrades.
    """

    method = METHOD

    def __init__(self, skeleton: Skeleton, fps: float, *, sigma: DurationLike | None = None,
                 k: int | None = None, contact: bool = True, preset: str = "low",
                 variance_rule: bool = False, lookahead: DurationLike | None = None,
                 update_every: DurationLike = UPDATE_EVERY,
                 history: DurationLike | None = None, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES) -> None:
        if preset not in PRESETS:
            raise UsageError("saliency online: preset must be 'low' or 'high' (the 'auto' rule "
                             f"needs the whole motion), got {preset!r}")
        sigma, k = resolve_params(sigma, k, preset, contact, fps)
        su, look, hist = _setup(sigma, k, contact, variance_rule, fps, lookahead,
                                update_every, history, len(skeleton.rotation_columns()))
        self.setup = su
        params = {"sigma": sigma, "sigma_s": sigma / fps, "k": k, "contact": contact,
                  "preset": preset, "variance_rule": variance_rule,
                  "foot_sigma": su.foot_sigma, "cluster_max": su.cmax,
                  "update_every": su.update_every, "history": hist}
        super().__init__(skeleton, fps, lookahead=look, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params=params)
        # session segments (calibration holds, still stretches, takes) as offline; None once
        # a pipeline notes them (`note_segment`)
        self.detector: SegmentDetector | None = SegmentDetector(
            skeleton, fps, stream=stream, role_mapping=role_mapping)
        self.reset()

    # the fixed parameters, in frames at the stream's rate
    sigma = property(lambda self: self.setup.sigma, doc="Base scale, frames.")
    k = property(lambda self: self.setup.k, doc="Curves asked for.")
    contact = property(lambda self: self.setup.contact, doc="Foot curves on.")
    foot_sigma = property(lambda self: self.setup.foot_sigma, doc="Foot scale, frames.")
    radius = property(lambda self: self.setup.radius, doc="Widest Gaussian half-window.")
    cmax = property(lambda self: self.setup.cmax, doc="The longest cluster, frames.")
    min_lookahead = property(lambda self: self.setup.min_lookahead, doc="The support.")
    update_every = property(lambda self: self.setup.update_every, doc="Basis update period.")
    window = property(lambda self: self.setup.window, doc="Frames kept in the ring.")

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the window and running statistics (a new stream starts)."""
        self._reset_window()
        self.seq0 = 0  # seq of the window's frame 0
        self.x0: np.ndarray | None = None  # rotations of the stream's first frame
        self.n_class = 0  # frames before this are classified
        self.clusterer = Clusterer(self.setup.clen)  # the open cluster
        self.preview = Preview()  # provisional candidates' caches
        # (seq, saliency) of each frame as it is classified, for live views: the weighted
        # mean of S_j(f) / mean(S_j) over the curves (> 1 on a candidate of every curve).
        self.trace: deque[tuple[int, float]] = deque(maxlen=TRACE_FRAMES)
        self.resume_at = 0  # after a restart with kept statistics: first frame to analyse
        self.deferred = False  # the newest frame's deferred work (`_deferred`) is pending
        if self.detector is not None:
            self.detector.reset()
        self.label: tuple[bool, int | None] = (True, None)  # frames to come: motion, until seq

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap or a source restart (after `finish()`): the basis,
        the PCA moments and the map statistics of every frame so far carry over, so the new
        window's frames are classified with them (no second warm-up); the reference row
        `x0` too, as the moments are taken about it. Without them: `reset()`."""
        if not keep_statistics or self.curves.basis is None:
            self.reset()
            return
        st, ring = self.stats, self.ring
        a, e = st.folded_upto - ring.base, self.t - ring.base + 1
        mom = st.folded_moments + moments(ring.rotations[a:e])
        kept = st.maps, self.curves, self.x0, self.trace
        self.reset()
        self.stats.folded_maps, self.curves, self.x0, self.trace = kept
        self.stats.folded_moments = mom
        self._new_basis(mom)  # the same PCA matched to the kept basis: weights, ring arrays
        self.stats.maps = self.stats.folded_maps
        # Like a stream start (first analysis at `lookahead`, or once the maps' support is in),
        # but then every decision uses the carried statistics.
        self.resume_at = min(self.setup.radius + 1, self.lookahead)

    # ------------------------------------------------------------------ stream
    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Advance over clean consecutive frames (called by push / push_block)."""
        if len(block) == 0:
            return []
        if self.t < 0:  # a new window (stream start or restart)
            self.seq0 = int(block.seq[0])
            if self.x0 is None:
                self.x0 = block.rotations[0].copy()
        det = self.detector
        points = block.pelvis_points(det.points) if det is not None else None
        xs = block.rotations - self.x0
        feet = block.foot_heights / self.features.body_height
        events: list[KeyframeEvent] = []
        for i in range(len(block)):
            self._settle()  # (a staged basis switch takes the state)
            if det is not None and points is not None and self.detector is det:
                # frame by frame, so that a segment is decided by the same frame whatever
                # the block split, and noted before that frame
                for segment in det.push_points(block.seq[i : i + 1], block.time[i : i + 1],
                                               points[i : i + 1]):
                    self._label(segment)
            events.extend(self._advance(xs[i], feet[i], float(block.time[i])))
        return events

    def note_segment(self, event: SegmentEvent) -> None:
        """The pipeline's hook: a session segment decided by the next frame (`_label`). From
        the first call on, the keyframer's own detector stops (the pipeline runs the same
        one, so the segments are the same)."""
        self.detector = None
        self._label(event)

    def _label(self, event: SegmentEvent) -> None:
        """A session segment (`streamkey.segments`, as offline `detect_segments`): the frames
        of a calibration hold or a still stretch are not motion, so they stay out of the
        running statistics (moments, map statistics) and get no candidate; a take's are.
        Applies to the frames so far in the segment and to the frames to come until its end
        (open: until the next segment)."""
        moving = event.kind == "take"
        self.label = (moving, event.end)
        ring = self.ring
        lo = max(event.start - self.seq0, ring.base)
        hi = self.t if event.end is None else min(event.end - self.seq0, self.t)
        if hi >= lo:
            ring.moving[lo - ring.base : hi - ring.base + 1] = moving

    def _settle(self) -> None:
        """The last frame's deferred work if `idle()` was not called, and a staged basis
        switch (`_stage`) swapped in: the new basis decides from the next frame on."""
        if self.deferred:
            self._deferred()
        if self.spread is not None and self.spread.staged is not None:
            kept = self.detector, self.label  # (segments noted since the staging)
            self.__dict__.update(self.spread.staged)
            self.detector, self.label = kept

    def _advance(self, x: np.ndarray, foot: np.ndarray, time: float) -> list[KeyframeEvent]:
        self._settle()
        self.t += 1
        t = self.t
        if t - self.ring.base >= self.ring.cap:
            self._catch_up(t - 1)  # before the first basis (else `_deferred` made room)
            self._room(t)
        ring = self.ring
        r = t - ring.base
        ring.rotations[r] = x
        ring.feet[r] = foot
        su = self.setup  # the curves' input low-passed as it arrives (as offline)
        smooth_rows(ring.rotations, ring.srot, r, r + 1, 0, su.lp_b, su.lp_a)
        smooth_rows(ring.feet, ring.sfeet, r, r + 1, 0, su.lp_b, su.lp_a)
        ring.times[r] = time
        moving, until = self.label
        ring.moving[r] = moving if until is None or self.seq0 + t <= until else True
        if self._update_due(t):  # the first basis; later ones below 3 frames (else made
            # early by `_deferred`)
            self._catch_up(t - 1)
            self._update(final=False)
        self.deferred = True
        if self.curves.basis is None or t < self.resume_at:  # restarted: the window fills
            return []
        return self._classify_due(t)

    def idle(self) -> list[KeyframeEvent]:
        """The last frame's deferred work (`_deferred`); it decides nothing."""
        if self.deferred:
            self._deferred()
        return []

    def _update_due(self, t: int) -> bool:
        """Whether frame t's decisions need a basis update made at once: the first of a
        window (frame `lookahead`, or `resume_at` after a restart), or one not spread."""
        if self.curves.basis is None:
            return t >= self.lookahead
        if t < self.resume_at or self.spread is not None:
            return False
        return t + 1 >= self.next_update and not self._spreads(t)

    def _deferred(self, early: bool = True) -> None:
        """Work of frame t that no decision of frame t reads, run after them (`idle()`, or
        first thing at the next frame): an update made at once that frame t + 1 needs
        (not the first basis, made in frame `lookahead`'s push), from the frames up to t
        (`early`); else frame t's incremental rows (so that the
        next deciding frame computes only its own), a piece of a spread basis update or
        its start, a piece of the past folded into the totals, room for the next row."""
        self.deferred = False
        t = self.t
        if early and t >= 2 and self.curves.basis is not None and self._update_due(t + 1):
            self._catch_up(t)
            self._update(final=False)
            return
        if self.curves.basis is None or t < self.resume_at:
            return
        self._catch_up(t)
        if t + 1 - self.ring.base >= self.ring.cap:
            self._room(t + 1)
        if self.spread is not None:
            self._spread_step(t)
        elif t + 1 >= self.next_update:  # `_spreads(t)`: else it was made at once
            self._spread_start(t)
        elif (min(t - self.setup.window + 1, self.s_ready - 1) - self.stats.folded_upto
              >= FOLD_EVERY):
            self._fold_out(self.stats.folded_upto + FOLD_EVERY)  # the past in small pieces

    def _spreads(self, t: int) -> bool:
        """Whether a basis update due at frame t is spread over `setup.spread` frames rather than
        made at once: every one but the first of a window (`lookahead`, or `resume_at`),
        once frame t holds the support of the stream-start rows' maps (frame 2 radius + 2)."""
        R = self.setup.radius
        return self.setup.window > self.setup.spread + 2 * R + 2 and t >= 2 * R + 2

    def _peek(self, upto: int) -> None:
        """Curve rows up to `upto` for the provisional candidates only, without catching up
        (`_catch_up` writes the same rows again), so decisions and scores never depend on
        who read when."""
        p = self.inc_t + 1
        if self.curves.basis is None or upto < p or p == 0:  # p == 0: a restarted window
            return
        if p <= 2 * self.setup.radius + 1:  # stream start: `_catch_up` goes frame by frame
            for t in range(p, upto + 1):
                self._curve_row(t)
        else:
            self._curve_rows(p, upto)

    # ------------------------------------------------------------------ decisions
    def _classify_due(self, t: int) -> list[KeyframeEvent]:
        """Classify the frames whose deadline has come: a cluster starting at c0 (or a frame
        that may start one) is classified, and closed, when frame c0 + lookahead arrives.

        Below the support, frames past t - radius - 1 are classified from maps cut at frame t
        (`truncated_maps`), and a cluster still open at its deadline is closed there."""
        rows = self.clusterer.rows
        if t < (rows[0] if rows else self.n_class) + self.lookahead:
            return []  # nothing is due: the incremental rows can wait
        self._catch_up(t)
        events: list[KeyframeEvent] = []
        g, ready = self.n_class, t - self.setup.radius - 1
        edge: tuple[int, np.ndarray] | None = None
        if g <= min(t, ready) and t >= (rows[0] if rows else g) + self.lookahead:
            # Frames with stored maps, as one block: the statistics do not change meanwhile.
            events.extend(self._classify(g, min(t, ready), due=t))
            g = self.n_class
        while g <= t:
            rows = self.clusterer.rows
            if t < (rows[0] if rows else g) + self.lookahead:
                break
            s = None
            if g > ready:  # only below the support
                edge = edge or self._edge_curvatures(t)
                s = truncated_maps(edge[1], self.setup.bank2, np.array([g - edge[0]]),
                                   self.curves.footmask)
            events.extend(self._classify(g, g, s))
            g += 1
        rows = self.clusterer.rows
        if rows and t >= rows[0] + self.lookahead:
            events.extend(self._emit([self.clusterer.close()]))
        return events

    def _edge_curvatures(self, t: int) -> tuple[int, np.ndarray]:
        """(first frame, curvatures up to frame t) as if the clip ended at t (eq. 3.4 ends)."""
        lo = max(0, t - 2 * self.setup.radius)
        ring = self.ring
        cs = ring.curvatures[lo - ring.base : t - ring.base + 1].copy()
        r = t - ring.base
        cs[-1] = (end_curvature(ring.curves[r - 2 : r + 1], self.setup.step) if t >= 2
                  else 0.0)
        return lo, cs

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: final basis from every frame, then decide every pending frame."""
        for event in self.detector.finish() if self.detector is not None else []:
            self._label(event)
        if self.deferred:
            self._deferred(early=False)  # the final update comes next
        if self.t < 2:
            return []
        ring = self.ring
        if self.stats.folded_upto == 0 and not ring.moving[: self.t - ring.base + 1].any():
            ring.moving[:] = True  # no take at all: every frame counts (as offline)
        self._catch_up(self.t)
        self._update(final=True)
        events = self._classify(self.n_class, self.t)
        if self.clusterer.rows:
            events.extend(self._emit([self.clusterer.close()]))
        return events

    def _classify(self, g0: int, g1: int, s: np.ndarray | None = None,
                  due: int | None = None) -> list[KeyframeEvent]:
        """Candidates of frames g0..g1 with the current statistics, fed to the clusterer;
        `s` their maps when not the stored ones. With `due` (the newest frame), stop before
        the first frame not yet due (the open cluster's start, or the frame itself, plus the
        lookahead after `due`)."""
        if s is None:
            s = self.ring.maps[g0 - self.ring.base : g1 - self.ring.base + 1]
        stop = _NO_STOP if due is None else due - self.lookahead
        n, level, closed = self._feed(self.clusterer, s, g0, stop)
        self.trace.extend(zip(range(self.seq0 + g0, self.seq0 + g0 + n), level[:n].tolist(),
                              strict=True))
        self.n_class = g0 + n
        return self._emit(closed)

    def _feed(self, cl: Clusterer, s: np.ndarray, g0: int, stop: int
              ) -> tuple[int, np.ndarray, list[tuple[int, float]]]:
        """Rows g0.. of maps `s` classified with the current statistics and fed to `cl` in
        one compiled loop (`classify_block`), up to the first row whose cluster would start
        after `stop`; `cl` takes the open cluster's new state (new lists: a copy's lists
        stay the original's); rows that are not motion are no candidates. Returns (rows
        taken, their trace levels, clusters closed)."""
        m = self.setup.cmax + 1  # the open cluster, as `classify_block`'s buffers
        rows, wrow, foot = np.zeros(m, dtype=np.int64), np.zeros(m), np.zeros(m, dtype=bool)
        k = len(cl.rows)
        if k:
            rows[:k], wrow[:k], foot[:k] = cl.rows, cl.wrow, cl.foot
        cv = self.curves
        n, level, keys, scores, nk, k, cl.score, cl.last, cl.run = classify_block(
            s, *self._normal(), cv.weights, cv.footmask, cv.wsum, g0, stop, self.setup.clen,
            rows, wrow, foot, k, cl.score, cl.last, cl.run,
            self.ring.moving[g0 - self.ring.base : g0 - self.ring.base + len(s)])
        cl.rows, cl.wrow, cl.foot = rows[:k].tolist(), wrow[:k].tolist(), foot[:k].tolist()
        return n, level, list(zip(keys[:nk].tolist(), scores[:nk].tolist(), strict=True))

    def _emit(self, closed: list[tuple[int, float]]) -> list[KeyframeEvent]:
        times, base = self.ring.times, self.ring.base
        return [self.event(frame=self.seq0 + row, time=float(times[row - base]), score=score,
                           decided_at=self.seq0 + self.t) for row, score in closed]

    def _normal(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(a, thr, thr with its zeros as 1): the map normalisation of the current
        statistics (the warm-up's while they hold fewer frames), cached until they change."""
        stats = self.stats
        if stats.norm is None:
            warm = stats.warm
            st = warm if warm is not None and stats.maps.n < warm.n else stats.maps
            args = (st.total, st.n, st.lm_n, st.lm_sum, st.lm_top)
            hmax, h3 = stats.cubes
            a, thr, safe, ok = (itti_factors(st.top, hmax, h3, *args) if len(hmax) == len(st.top)
                                else (None, None, None, False))
            if not ok:  # a new row maximum (rare): its cube as `normalisation` takes it
                h = st.top.max(axis=1, keepdims=True)
                stats.cubes = hmax, h3 = h.reshape(-1), (h**3).reshape(-1)
                a, thr, safe, ok = itti_factors(st.top, hmax, h3, *args)
            stats.norm = cast(tuple[np.ndarray, np.ndarray, np.ndarray], (a, thr, safe))
        return stats.norm

    # ------------------------------------------------------------------ provisional
    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: the keys that the open cluster and the frames not yet classified
        point to, with the statistics of this moment (nothing decided): frames with final
        maps, then frames with early maps (`_early_maps`). Re-derived every
        `CANDIDATE_EVERY` frames (a clustering over ~100 frames)."""
        if self.curves.basis is None or self.inc_t < 0:  # no analysis in this window yet
            return []
        self._peek(self.t)
        early = self._early_maps(max(self.n_class, self.s_ready))  # one new row a frame
        pv = self.preview
        if pv.slot == self.t // CANDIDATE_EVERY and pv.slot_basis is self.curves.basis:
            rows = self.clusterer.rows  # clusters closed since are no longer candidates
            lo = self.seq0 + (rows[0] if rows else self.n_class)
            return [c for c in pv.cached if c[0] >= lo]
        pv.slot, pv.slot_basis = self.t // CANDIDATE_EVERY, self.curves.basis
        pv.cached = self._candidates(early)
        return pv.cached

    def _candidates(self, early: np.ndarray) -> list[tuple[int, float, float]]:
        sim = copy.copy(self.clusterer)  # `_feed` gives it new lists: the clusterer's stay
        closed: list[tuple[int, float]] = []
        lo, hi, base = self.n_class, self.s_ready, self.ring.base
        maps = [self.ring.maps[lo - base : max(lo, hi) - base], early]
        if len(maps[0]) + len(maps[1]):
            closed = self._feed(sim, np.concatenate(maps), lo, _NO_STOP)[2]
        if sim.rows:
            closed.append(sim.close())
        times = self.ring.times
        return [(self.seq0 + row, float(times[row - base]), score) for row, score in closed]

    def _early_maps(self, start: int) -> np.ndarray:
        """Maps of the rows start.. that have no final maps yet, each computed once, 2 sigma
        frames after its frame, from windows cut there (the clip-end rule); for provisional
        candidates only, never for decisions or statistics."""
        pv = self.preview
        if pv.early_basis is not self.curves.basis:  # a new basis moves every curve
            pv.early = {}
        cache = pv.early
        g = self.t - self.setup.cmax
        if g >= start and g not in cache and self.t >= 2:
            lo, cs = self._edge_curvatures(self.t)
            cache[g] = truncated_maps(cs, self.setup.bank2, np.array([g - lo]),
                                      self.curves.footmask)[0]
        for row in [r for r in cache if r < start]:
            del cache[row]
        pv.early_basis = self.curves.basis
        out: list[np.ndarray] = []
        while start + len(out) in cache:
            out.append(cache[start + len(out)])
        return np.array(out).reshape(len(out), len(self.curves.weights), 4)
