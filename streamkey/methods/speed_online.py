"""Online speed-minima keyposes (Miura et al. 2014, "Adaptive keypose extraction from motion
capture data"), with a bounded lookahead: a key at frame f is sent by frame f + lookahead.
`streamkey.methods.speed` re-exports `Online`; the offline method is `speed.extract`.

`Online`: every `hop` frames an analysis of the window (the last `history +
lookahead + hop` frames) starts; it runs in four stages over the next `delay` frames (two
thirds of the hop; no burst) and decides the candidates whose deadline (frame +
lookahead) falls after it is done and before the next one is; a decision is sent when its
deadline frame arrives (latency_frames == lookahead), and `flush()` redoes whatever was not
sent yet. Windowed replacements of the offline global steps:

- HP filters over the whole clip -> HP filters over the stream so far, solved where they
  count. The 10 Hz position filter is redone on the newest `hop + settle` speeds (those a
  frame since the last update can still change, to ~1e-6); older speeds are final. The
  forward substitution of every scale's HP system (U'y = v, the factor of `hp_factor`) only
  looks back, so it is carried from one analysis to the next over the final speeds (those
  leaving the window included); an analysis adds the fresh speeds and the factor's bottom
  corner and back-substitutes over the newest `lookahead + 2 hop` frames plus 2 s (the region),
  all 144 lambdas side by side in one compiled kernel (`speed_kernels.hp_tail`, ~40 µs).
  Minima outside the region are ignored. Earlier, each scale was solved on the region
  plus 20 lambda^(1/4) frames of the window (the 0.1 Hz half-scale saw 20 s): the trends now
  see the whole stream, like the offline ones; on the shared clips looped to 30,000 frames
  the same keys, intensities within 5.4e-5 relative, and the same agreement table.
- Candidate correspondence over the whole clip -> the same mutual nearest minima over the
  region (compiled, `speed_kernels.chain_totals`: `nearest_pairs`, same ties, same sums).
- The keypose cut over all candidates (the quantile cut, or Ward + Mojena with
  `cut="mojena"`) -> one cut-off per update, re-derived from a bounded sample:
  the candidates decided in the last `cutoff_history` frames (intensities as decided), those
  decided now and the window's pending ones. Applying it to the candidates due (U > cut-off)
  replaces re-clustering per candidate, whose cluster count flips as candidates arrive.
- Warm-up (the Mojena cut only): while the sample holds fewer than `warmup_candidates`
  (Mojena's rule cannot split fewer than ~10 levels at k = 2.75), a single-cluster verdict is
  replaced by Ward cut into two clusters; after that, the rule is Mojena's. The quantile cut
  of a few values is already a fraction of their largest. Its estimator is the stream's own
  95th percentile from the first candidate on, with no prior: a prior measured on the corpus
  (the median over the 35 shared clips of the offline 95th percentile, 17.26 body heights/s
  summed over scales) shrunk to the stream's value in log space with the weight of W
  candidates fixes the takes that start calm (05_18 online/offline keys 2.44x -> 1.56x at
  W = 20, 1.0x at W = 60) and breaks the calm ones (49_18, whose 95th percentile is 0.81:
  0.23x at W = 20, F1 0.375; at W = 8, 0.54x): a calm start and a calm take look the same
  until the motion comes, and no goal cell was gained at any W.
- `flush()` analyses the whole window (full-window HP filters) and decides everything pending.
  With a lookahead of at least the stream's length nothing is sent before, the window is the
  whole stream and the sample all its candidates: the offline result, bit for bit.


The state is kept in named parts (`speed_state`): the window of position rows
(`ring.RingWindow`), the window's speeds, the carried HP passes, the cut-off sample, the
decisions not yet sent and the running analysis with its stages' results. A stream's lead
frame (a reference T-pose) never reaches it: the front end drops it (`filters.FrontEnd`).
"""

from __future__ import annotations

from typing import SupportsIndex, cast

import numpy as np

from ..errors import UsageError
from ..keyframes import KeyframeEvent
from ..motion import Skeleton
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock, OnlineKeyframer
from ..roles import MIURA_ROLES
from ..segments import SegmentEvent
from ..signal import hp_lambda
from ..units import Duration, DurationLike, whole_frames
from .ring import RingWindow
from .speed_chains import check_cut, intensities
from .speed_kernels import chain_totals, tail_minima
from .speed_scales import (
    METHOD,
    REST_SPEED,
    HPBank,
    candidates_of,
    check_params,
    packed_factors,
    scale_frequencies,
    scale_lambdas,
    scale_minima,
    settle_frames,
    speed_signal,
    speed_tail,
)
from .speed_state import (
    Analysis,
    AnalysisInput,
    CutoffSample,
    Decisions,
    PoseRows,
    QuietSpans,
    Spans,
    StageMinima,
    StageSpeeds,
    TrendCarry,
    WindowSpeeds,
)

__all__ = ["Online", "LOOKAHEAD", "MAX_HOP", "HISTORY", "CUTOFF_HISTORY", "REGION_MARGIN"]

REGION_MARGIN = Duration.seconds(2.0)  # DP context left of the decision zone in an update
LOOKAHEAD = Duration.seconds(1.0)  # online defaults; at 120 Hz: 120, 24, 2400 and 7200 frames
MAX_HOP = Duration.seconds(0.2)
HISTORY = Duration.seconds(20.0)
CUTOFF_HISTORY = Duration.seconds(60.0)


class Online(OnlineKeyframer):
    """Online speed-minima keyposes: `push` frames, get keypose events within `lookahead`.

    Durations (`lookahead`, `hop`, `history`, `cutoff_history`) are `Duration`s or integer
    frame counts; the defaults are in seconds (1 s, a fifth of the lookahead but at most
    0.2 s, 20 s and 60 s: 120, 24, 2400 and 7200 frames at 120 Hz), so a stream at another
    rate sees the same motion. `lookahead` (the attribute) is the latency bound in frames.
    Every `hop` frames an analysis of the window
    (`history` + `lookahead` + `hop` frames) starts; its work is spread over the next `delay`
    frames (two thirds of the hop, fewer if the lookahead is short: four stages on four
    frames instead of a burst) and it decides the candidates whose deadline (frame +
    `lookahead`) comes before the next analysis is done. Each decision is sent when its
    deadline frame arrives, so latency_frames == lookahead for every event except those of
    `flush()`, which analyses the whole window and decides the rest (decisions not yet sent
    included). A decision sees at least lookahead - hop - delay frames after its candidate;
    its deadline is after the frame that finishes its analysis, so the analysis never holds
    up an event. `cutoff_history` frames of candidate intensities feed the Ward + Mojena
    cut-off; below `warmup_candidates` a one-cluster verdict becomes two.
    The module docstring lists what replaces each global step of the offline method.
    """

    method = METHOD
    # The stages of an analysis, in order (`Analysis.done` counts those run).
    STAGES = ("speeds", "trends", "trends", "chains", "cut-off", "decisions")

    def __init__(self, skeleton: Skeleton, fps: float, *, f_c: float = 10.0, f_max: float = 8.0,
                 f_min: float = 0.2, r: float = 0.95, mojena_k: float = 2.75,
                 lookahead: DurationLike = LOOKAHEAD, hop: DurationLike | None = None,
                 history: DurationLike = HISTORY, cutoff_history: DurationLike = CUTOFF_HISTORY,
                 warmup_candidates: int = 20, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES,
                 segment_statistics: bool = False, cut: str = "quantile") -> None:
        check_params(f_c, f_max, f_min, r, mojena_k)
        cut = check_cut(cut)
        lookahead = _frames("lookahead", lookahead, fps, 3)
        if hop is None:  # a fifth of the lookahead, at most 0.2 s (24 frames at 120 Hz)
            hop = max(1, min(whole_frames(MAX_HOP, fps), lookahead // 5))
        hop = _frames("hop", hop, fps, 1)
        _check_count("lookahead", lookahead, hop + 2)
        history = _frames("history", history, fps, 0)
        cutoff_history = _frames("cutoff_history", cutoff_history, fps, 0)
        _check_count("warmup_candidates", warmup_candidates, 0)
        params = {"f_c": f_c, "f_max": f_max, "f_min": f_min, "r": r, "mojena_k": mojena_k,
                  "hop": hop, "history": history, "cutoff_history": cutoff_history,
                  "warmup_candidates": int(warmup_candidates), "cut": cut}
        if segment_statistics:  # in the digest only when on, so today's digests stay
            params["segment_statistics"] = True
        super().__init__(skeleton, fps, lookahead=lookahead, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params=params)
        self.f_c = f_c  # position filter cut-off (Hz)
        self.hop = int(hop)  # frames between analyses
        self.history = int(history)  # frames of window before the lookahead
        self.cutoff_history = int(cutoff_history)  # frames of decided intensities in the cut
        # segments out of the cut-off sample (off: the detector reads calm motion as still)
        self.segment_statistics = segment_statistics
        # Frames an analysis is spread over; its zone ends lookahead - hop - delay frames back.
        # Two thirds of the hop: the mean online/offline F1 on the shared clips is 0.867 with
        # no spread, 0.856 / 0.854 / 0.853 / 0.849 spread over 8 / 12 / 16 / 23 frames.
        self.delay = max(0, min(2 * self.hop // 3, self.lookahead - self.hop - 2))
        self._pose = PoseRows([self.features.roles[name] for name in MIURA_ROLES],
                              self.features.body_height)  # rows of a block
        lams = scale_lambdas(scale_frequencies(f_max, f_min, r), 1.0 / self.fps)
        # Region re-analysed by a regular update: the lookahead plus room for the DP context.
        region = self.lookahead + 2 * self.hop + whole_frames(REGION_MARGIN, self.fps)
        pos_settle = int(settle_frames(np.array([hp_lambda(f_c, 1.0 / self.fps)]))[0])
        # Speeds redone by a regular update: those a frame of the last hop can still change.
        self._spans = Spans(region=region, pos_settle=pos_settle,
                            fresh=min(region, self.hop + pos_settle + 1))  # frame counts
        self._ring = RingWindow(self.history + self.lookahead + self.hop + 2,
                                3 * len(MIURA_ROLES))  # position rows of the window
        self._bank = HPBank(lams)  # whole HP solves (short systems, `flush`)
        packed_factors(lams)  # built now (shared, derived), not on a streaming frame
        self._carry = TrendCarry(lams, region)  # HP forward passes
        self._cutoff = CutoffSample(self.cutoff_history, self.lookahead, mojena_k,
                                    int(warmup_candidates), cut)  # the cut's memory
        self.reset()

    @property
    def cut(self) -> str:
        """The keypose cut (`speed_chains.CUTS`): "quantile" (the default) or "mojena"."""
        return self._cutoff.cut

    @property
    def mojena_k(self) -> float:
        """Mojena's k (the cut-off is mean + k std of the fusion levels)."""
        return self._cutoff.mojena_k

    @property
    def warmup_candidates(self) -> int:
        """Cut-off sample size below which a one-cluster verdict becomes two."""
        return self._cutoff.warmup

    def reset(self) -> None:
        """Forget the window and the cut-off history; keep parameters."""
        self._ring.clear()
        self._carry.reset(0)
        self._cutoff = self._cutoff.emptied()
        self._count = 0  # frames analysed since the reset
        self._analysis_due = False  # the block's last frame starts an analysis in `idle`
        self._last_seq = 0  # the newest frame
        self._decisions = Decisions()  # taken, not sent
        self._speeds = WindowSpeeds()  # of the window
        self._job: Analysis | None = None  # the running analysis
        self._quiet = QuietSpans()  # calibration holds and still stretches

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap or a source restart (after `finish()`): the cut-off
        history (candidate intensities of the last `cutoff_history` frames) is kept, so the
        Ward + Mojena cut-off needs no second warm-up. Without it: `reset()`."""
        kept, last = self._cutoff, self._last_seq
        self.reset()
        if keep_statistics:
            kept.resume_after = last
            self._cutoff = kept

    def note_segment(self, event: SegmentEvent) -> None:
        """A session segment event (before the frame that decided it is pushed): candidates
        in calibration holds and still stretches stay out of the cut-off sample, as
        `extract(..., segments=...)` leaves them out offline; they still get keys by it. Only
        with `segment_statistics=True`: on the shared clips it moved no variant's keys closer
        to the clean take's, and the detector reads calm motion as still."""
        if self.segment_statistics and event.kind in ("calibration", "still"):
            self._quiet.note(event.start, event.end)

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Append frames, doing each frame's share of the running analysis; every `hop`
        frames start the next one. The block's last frame leaves its share to `idle`."""
        rows = self._pose.of(block)
        seqs, times = np.asarray(block.seq), np.asarray(block.time)
        if len(rows):
            self._cutoff.resume(int(seqs[0]))
        events: list[KeyframeEvent] = []
        i = 0
        n, hop = len(seqs), self.hop
        while i < n:
            take = min(n - i, hop - self._count % hop)
            self._ring.extend(int(seqs[i]), rows[i : i + take], times[i : i + take])
            self._count += take
            i += take
            self._last_seq = int(seqs[i - 1])
            self._advance(self._count if i < n else self._count - 1)
            if self._decisions.due:
                events.extend(self._emit())
            if self._count % hop == 0:
                if i < n:
                    self._schedule()
                    events.extend(self._emit())
                else:  # the block's last frame: start the analysis in `idle`
                    self._analysis_due = True
        return events

    def idle(self) -> list[KeyframeEvent]:
        """The last frame's deferred work: its share of the analysis, or the analysis start
        (same frame, same decisions)."""
        self._advance(self._count)
        if self._analysis_due:
            self._analysis_due = False
            self._schedule()
        return self._emit() if self._decisions.due else []

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: analyse the whole window and decide every candidate not yet sent.

        Decisions scheduled but not sent (their frame + lookahead never arrived) are redone
        with the whole window, like everything else still pending; so is a running analysis.
        """
        events = self.idle()  # normally already run by the driver
        self._job = None
        if not len(self._ring):
            return events
        decisions = self._decisions
        decisions.due.clear()
        t = self._last_seq
        if decisions.upto is not None:  # what was sent: candidates <= t - lookahead
            decisions.upto = min(decisions.upto, t - self.lookahead)
        base = self._ring.first_seq
        v = self._speed()
        cand = candidates_of(v)
        u = intensities(cand, scale_minima(v, self._bank))
        seqs = cand + base
        new = seqs > (base - 1 if decisions.upto is None else decisions.upto)
        decisions.upto = t
        if not np.any(new):
            return events
        counted = new & self._quiet.outside(seqs)
        threshold = self._cutoff.threshold(
            np.concatenate([self._cutoff.recent(t), u[counted]]), final=True)
        self._cutoff.extend(seqs[counted].tolist(), u[counted].tolist())  # for a restart
        return events + [self.event(frame=int(c), time=self._ring.time(int(c)),
                                    score=float(x), decided_at=t)
                         for c, x in zip(seqs[new], u[new], strict=True) if x > threshold]

    def _emit(self) -> list[KeyframeEvent]:
        """Send the scheduled decisions whose frame + lookahead has arrived (their deadline)."""
        events = []
        due = self._decisions.due
        while due and due[0][0] + self.lookahead <= self._last_seq:
            c, u, keep = due.popleft()
            if self._quiet.counts(c):
                self._cutoff.add(c, u)
            if keep:
                events.append(self.event(frame=c, time=self._ring.time(c), score=u,
                                         decided_at=c + self.lookahead))
        return events

    def _schedule(self) -> None:
        """Start the analysis deciding the candidates whose deadline comes after it is done
        (`delay` frames from now) and before the next one is."""
        if self._job is not None:  # only when delay >= hop: never with the checked parameters
            self._advance(self._job.inputs.anchor + self.delay)
        t, upto, ring, spans = self._last_seq, self._decisions.upto, self._ring, self._spans
        zone_end = t + self.hop + self.delay - self.lookahead
        if zone_end < ring.first_seq or (upto is not None and zone_end <= upto):
            return  # nothing is due yet
        # The speeds older than the newest `fresh` are final (to ~1e-6): kept, not redone.
        rows = ring.rows()
        n = len(rows)
        seg = spans.fresh + spans.pos_settle
        old: np.ndarray | None = self._speeds.v[ring.dropped_since :][: n - 1 - spans.fresh]
        if n <= seg or old is None or len(old) < n - 1 - spans.fresh:
            snap, old = rows.copy(), None
        else:
            snap = rows[n - seg :].copy()
        self._speeds.dropped += ring.dropped_since
        ring.dropped_since = 0
        # Decided (sent or not) in the last `cutoff_history` frames: intensities as decided.
        self._quiet.forget_before(ring.first_seq)
        sample = np.concatenate([self._cutoff.recent(t), [u for c, u, _ in self._decisions.due
                                                          if self._quiet.counts(c)]])
        # Stage costs, ~µs (measured at the defaults: speed signal, HP trends, chains,
        # Ward + Mojena and decisions).
        trend = 20 + min(spans.region, n) // 8
        cost = np.array([50 if old is not None else 50 + len(snap) // 4, trend, trend, 40,
                         60 + len(sample) // 8, 20])
        inputs = AnalysisInput(anchor=self._count, zone_end=zone_end,
                               lo=ring.first_seq - 1 if upto is None else upto,
                               base=ring.first_seq, g0=self._speeds.dropped, rows=snap, old=old,
                               sample=sample)
        self._job = Analysis(inputs, cost)
        self._advance(self._count)

    def _advance(self, count: int) -> None:
        """Run the running analysis' stages due by frame `count`: a stage starts on the
        frame after the anchor where its share of the estimated cost begins (the first on
        the next frame), and whatever is left runs on the `delay`-th."""
        job = self._job
        if job is None or (count <= job.inputs.anchor and self.delay > 0):
            return
        k, total = count - job.inputs.anchor, job.cum[-1]
        while self._job is job and (k >= self.delay or (job.cum[job.done - 1] if job.done else 0)
                                    * self.delay <= total * (k - 1)):
            self._run_stage(job)

    def _run_stage(self, job: Analysis) -> None:
        """Run the next stage of the analysis `job` (`STAGES`)."""
        stage = job.done
        job.done += 1
        if stage == 0:
            self._stage_speeds(job)
        elif stage == 1:
            self._stage_trends(job, first=True)
        elif stage == 2:
            self._stage_trends(job, first=False)
        elif stage == 3:
            self._stage_chains(job)
        elif stage == 4:
            self._stage_cutoff(job)
        else:
            self._stage_decisions(job)

    def _stage_speeds(self, job: Analysis) -> None:
        """Stage 1: the speed signal, its candidates, the HP forward passes carried over the
        speeds that became final."""
        inputs, fresh = job.inputs, self._spans.fresh
        if inputs.old is None:
            v = speed_signal(inputs.rows, 1.0 / self.fps, self.f_c)
        else:
            v = np.concatenate([inputs.old, speed_tail(inputs.rows, 1.0 / self.fps, self.f_c,
                                                       fresh)])
        self._speeds.v = v
        start = max(0, len(v) - self._spans.region)
        lo_trend = max(start - 1, 0)  # a minimum needs its left neighbour
        job.speeds = StageSpeeds(v=v, start=start, lo_trend=lo_trend,
                                 cand=candidates_of(v[lo_trend:]) + lo_trend)
        self._carry.advance(v, inputs.g0, fresh)

    def _stage_trends(self, job: Analysis, first: bool) -> None:
        """Stages 2 and 3: HP trends of the region, the first part of the scales' lambdas,
        then the rest (all of them if the first part was lost to a pickle) and the minima.
        The parts cost about the same: a lambda costs ~3x while its factor's columns have
        not converged (its first 20 lambda^(1/4) rows of the stream)."""
        sp = job.speeds
        assert sp is not None
        lams, g0 = self._carry.lams, job.inputs.g0
        if first:
            k = np.diff(packed_factors(lams)[1])
            w = 1.0 + 2.0 * np.minimum(1.0, k / (g0 + len(sp.v)))
            job.split = int(np.clip(np.searchsorted(np.cumsum(w), w.sum() / 2), 1,
                                    len(lams) - 1))
            self._carry.trends(sp.v, g0, sp.lo_trend, self._bank, slice(0, job.split),
                               job.rows)
            return
        part = slice(job.split, None) if job.rows.rows is not None else None
        trends = self._carry.trends(sp.v, g0, sp.lo_trend, self._bank, part, job.rows)
        job.rows.rows = None
        minima, u, counts = tail_minima(trends, len(lams) // 2, sp.lo_trend, sp.start,
                                        REST_SPEED)
        job.minima = StageMinima(minima=minima, u=u, counts=counts)

    def _stage_chains(self, job: Analysis) -> None:
        """Stage 3: the chains of matched minima, the candidates' intensities."""
        sp, mn = job.speeds, job.minima
        assert sp is not None and mn is not None
        job.total = chain_totals(sp.cand, mn.minima, mn.u, mn.counts)

    def _stage_cutoff(self, job: Analysis) -> None:
        """Stage 5: the cut over the cut-off sample (Ward + Mojena's, or the quantile's)."""
        sp, u, inputs = job.speeds, job.total, job.inputs
        assert sp is not None and u is not None
        seqs = sp.cand + inputs.base
        new = (seqs > inputs.lo) & (seqs <= inputs.zone_end)
        if np.any(new):
            counted = self._quiet.outside(seqs)
            job.cut = np.concatenate([inputs.sample, u[new & counted],
                                      u[(seqs > inputs.zone_end) & counted]])
            job.verdict = self._cutoff.verdict(job.cut)

    def _stage_decisions(self, job: Analysis) -> None:
        """Stage 6: the warm-up rule, the decisions of the zone."""
        sp, u, inputs, decisions = job.speeds, job.total, job.inputs, self._decisions
        assert sp is not None and u is not None
        decisions.upto = inputs.zone_end
        self._job = None
        if job.cut is None or job.verdict is None:
            return
        seqs = sp.cand + inputs.base
        new = (seqs > inputs.lo) & (seqs <= inputs.zone_end)
        threshold = self._cutoff.warmed(job.cut, job.verdict, False)
        decisions.due.extend(zip(seqs[new].tolist(), u[new].tolist(),
                                 (u[new] > threshold).tolist(), strict=True))
        ahead = (seqs > inputs.zone_end) & (u > threshold)
        decisions.ahead = [(c, self._ring.time(c), x) for c, x in  # provisional hook
                           zip(seqs[ahead].tolist(), u[ahead].tolist(), strict=True)]

    def _speed(self) -> np.ndarray:
        """Speed over the whole window (at flush)."""
        self._speeds.v = speed_signal(self._ring.rows(), 1.0 / self.fps, self.f_c)
        self._ring.dropped_since = 0
        return self._speeds.v

    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: keys decided but not yet sent, and the window's later minima
        whose intensity clears the cut-off at the last analysis."""
        t = self._last_seq - self.lookahead
        return ([(c, self._ring.time(c), u) for c, u, keep in self._decisions.due if keep]
                + [p for p in self._decisions.ahead if p[0] > t])


def _check_count(name: str, value: object, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise UsageError(f"speed online: {name} must be an integer >= {low}, got {value!r}")


def _frames(name: str, value: object, fps: float, low: int) -> int:
    """A duration parameter in whole frames at `fps`: a `Duration`, or an integer count of
    frames (the meaning plain numbers always had); at least `low` frames."""
    if isinstance(value, Duration):
        frames = whole_frames(value, fps)
        if frames < low:
            raise UsageError(f"speed online: {name} must be at least {low} frames, got {value} "
                             f"({frames} frames at {fps:g} fps)")
        return frames
    _check_count(name, value, low)
    return int(cast(SupportsIndex, value))

