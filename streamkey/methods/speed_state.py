"""The named parts of the online speed keyframer's state (`speed_online.Online`).

Each part owns one invariant: the spans of the running analysis (`Spans`), the rows of a
block (`PoseRows`), the window's speeds (`WindowSpeeds`), the HP forward passes carried
between analyses (`TrendCarry`), the Ward + Mojena cut-off sample (`CutoffSample`), the
decisions not yet sent (`Decisions`), and one running analysis with its four stages'
results (`Analysis`). Plain attributes: pickled with the keyframer.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ..online import FeatureBlock
from .speed_chains import (
    MojenaResult,
    mojena_threshold,
    quantile_threshold,
    two_cluster_threshold,
)
from .speed_kernels import hp_advance, hp_tail_part
from .speed_scales import HPBank, WorkRows, packed_factors

__all__ = ["Spans", "PoseRows", "WindowSpeeds", "TrendCarry", "CutoffSample",
           "TrendRows", "QuietSpans", "Decisions", "AnalysisInput", "StageSpeeds",
           "StageMinima", "Analysis"]


@dataclass(frozen=True)
class Spans:
    """Frame counts of the running analysis, derived from the parameters."""

    region: int  # newest speeds an analysis re-examines (lookahead, 2 hops, DP context)
    pos_settle: int  # frames the position filter takes to forget a boundary (~1e-6)
    fresh: int  # newest speeds an analysis recomputes (older ones are final)


@dataclass(frozen=True)
class PoseRows:
    """Rows of the speed signal: the 16 joints in the pelvis frame over body height."""

    joints: list[int]  # the roles' joint indices, in `MIURA_ROLES` order
    height: float  # body height (the unit of the rows)

    def of(self, block: FeatureBlock) -> np.ndarray:
        """One 48-vector per frame of `block`."""
        rows: np.ndarray = block.pelvis_points(self.joints).reshape(len(block), -1) / self.height
        return rows


class WindowSpeeds:
    """The window's speeds as of the last analysis, and how many left the window before it."""

    def __init__(self) -> None:
        self.v = np.empty(0)  # speeds of the window's frames (v(n) at frame n)
        self.dropped = 0  # speeds dropped from the window since the reset (global offset)


class TrendCarry:
    """The forward substitution of every scale's HP system (U'y = v), carried from one
    analysis to the next over the final speeds, so that an analysis adds only the fresh
    speeds and back-substitutes over its region (`speed_kernels.hp_advance`, `hp_tail`)."""

    def __init__(self, lams: np.ndarray, region: int) -> None:
        self.lams = lams  # the scales' lambdas, f_i then f_i / 2
        self.size = region + 4  # rows of forward values kept
        self.work = WorkRows()  # reused work rows of `hp_tail` (derived)
        self.reset(0)

    def reset(self, base: int) -> None:
        """Forward passes start afresh at window speed `base` (global numbering)."""
        self.base = base  # the carried systems' first row: this speed
        self.done = 0  # rows carried (forward values of the last ones in `y`)
        self.y = np.zeros((self.size, len(self.lams)))  # forward values, every lambda

    def advance(self, v: np.ndarray, g0: int, fresh: int) -> None:
        """Carry the passes over the speeds of `v` (its first at global `g0`) that are final:
        all but the newest `fresh`."""
        start = g0 - self.base
        if self.done < start:  # the window outran the carried passes (tiny windows)
            self.reset(g0)
            start = 0
        upto = start + len(v) - fresh
        if upto > self.done:
            self.done = hp_advance(v, start, self.done, upto, self.y, *packed_factors(self.lams))

    def trends(self, v: np.ndarray, g0: int, lo: int, bank: HPBank, part: slice | None = None,
               rows: TrendRows | None = None) -> np.ndarray:
        """HP trends of `v[lo:]` for every lambda, side by side (rows: speeds). With `part`,
        only those lambdas' columns are solved (the others are left as they are), into the
        work rows of `rows` (taken on its first use): a part per call gives the same numbers
        as one call for all."""
        start = g0 - self.base
        n_lam = len(self.lams)
        lam0, lam1, _ = (part or slice(0, n_lam)).indices(n_lam)
        if start + len(v) >= 5:
            pre, off, conv = packed_factors(self.lams)
            scratch = rows.rows if rows is not None else None
            if scratch is None:
                scratch = self.work.get(start + len(v) - min(start + lo, self.done), n_lam)
                if rows is not None:
                    rows.rows = scratch
            trends: np.ndarray = hp_tail_part(v, start, lo, self.done, self.y, pre, off, conv,
                                              self.lams, scratch, lam0, lam1)
            return trends
        # a system too short for the corner formulas (start is 0): whole solves
        return np.stack([bank.solve(v, j)[lo:] for j in range(n_lam)], axis=1)


class TrendRows:
    """The work rows of one analysis' trends between its two trend stages (the first part of
    the lambdas solved, the rest to come). Derived: pickled empty, and then the trend stage
    solves every lambda."""

    def __init__(self) -> None:
        self.rows: np.ndarray | None = None

    def __reduce__(self) -> tuple[type, tuple[()]]:
        return (TrendRows, ())


class CutoffSample:
    """The Ward + Mojena cut-off's memory: intensities (as decided) of the candidates decided
    in the last `span` frames, with a warm-up rule while it is small."""

    def __init__(self, span: int, lookahead: int, mojena_k: float, warmup: int,
                 cut: str = "quantile") -> None:
        self.cut = cut  # the keypose cut (`speed_chains.CUTS`)
        self.span = span  # frames of decided candidates kept (`cutoff_history`)
        self.lookahead = lookahead  # frames from a candidate to its decision
        self.mojena_k = mojena_k  # Mojena's k
        self.warmup = warmup  # sample size below which one cluster becomes two
        self.seqs: deque[int] = deque()  # decided candidates' frames, oldest first
        self.values: deque[float] = deque()  # their intensities as decided
        self.resume_after: int | None = None  # last frame before a restart (history kept)

    def emptied(self) -> CutoffSample:
        """A sample with the same parameters and nothing in it."""
        return CutoffSample(self.span, self.lookahead, self.mojena_k, self.warmup, self.cut)

    def resume(self, first_seq: int) -> None:
        """The first frame after a restart: if the source started over, the kept history is
        moved before it (it ages out as it would have)."""
        if self.resume_after is None:
            return
        shift = first_seq - 1 - self.resume_after
        if shift < 0:
            self.seqs = deque(seq + shift for seq in self.seqs)
        self.resume_after = None

    def add(self, seq: int, value: float) -> None:
        """A decided candidate."""
        self.seqs.append(seq)
        self.values.append(value)

    def extend(self, seqs: list[int], values: list[float]) -> None:
        """Decided candidates, in order."""
        self.seqs.extend(seqs)
        self.values.extend(values)

    def recent(self, t: int) -> np.ndarray:
        """Intensities of the candidates decided in the last `span` frames before frame
        t - lookahead (older ones are forgotten)."""
        while self.seqs and self.seqs[0] < t - self.lookahead - self.span:
            self.seqs.popleft()
            self.values.popleft()
        return np.fromiter(self.values, float, len(self.values))

    def threshold(self, sample: np.ndarray, final: bool) -> float:
        """Ward + Mojena threshold over a cut-off sample: the candidates decided in the last
        `span` frames (intensities as decided), the ones being decided and the window's
        pending ones (current intensities). Warm-up (not `final`): a one-cluster verdict on
        fewer than `warmup` values becomes Ward cut into two clusters (the Mojena cut only).
        The quantile cut needs no warm-up rule: the threshold of a few values is already
        fractions of their largest."""
        return self.warmed(sample, self.verdict(sample), final)

    def verdict(self, sample: np.ndarray) -> MojenaResult | float:
        """The cut on `sample`: Ward + Mojena's result, or the quantile cut's threshold."""
        if self.cut == "mojena":
            return mojena_threshold(sample, self.mojena_k)
        return quantile_threshold(sample)

    def warmed(self, sample: np.ndarray, res: MojenaResult | float, final: bool) -> float:
        """`threshold` from the verdict `res` on `sample` (in two steps)."""
        if not isinstance(res, MojenaResult):
            return res
        if res.n_clusters == 1 and not final and len(sample) < self.warmup:
            return two_cluster_threshold(sample)
        return res.threshold


class QuietSpans:
    """Calibration holds and still stretches noted from segment events (`note_segment`):
    candidates inside them stay out of the cut-off sample (session states, not motion)."""

    def __init__(self) -> None:
        self.spans: list[tuple[int, int | None]] = []  # (first, last or None while open)

    def note(self, start: int, end: int | None) -> None:
        """A calibration hold or still stretch from frame `start` (to `end`, None: open)."""
        self.spans = [span for span in self.spans if span[0] != start] + [(start, end)]

    def forget_before(self, seq: int) -> None:
        """Drop the spans that end before frame `seq` (no candidate there is asked about)."""
        self.spans = [span for span in self.spans if span[1] is None or span[1] >= seq]

    def outside(self, seqs: np.ndarray) -> np.ndarray:
        """Per frame of `seqs`: True when it is in no span (a frame of motion)."""
        seqs = np.asarray(seqs)
        out = np.ones(len(seqs), dtype=bool)
        for start, end in self.spans:
            out &= (seqs < start) if end is None else (seqs < start) | (seqs > end)
        return out

    def counts(self, seq: int) -> bool:
        """Is frame `seq` in no span (its intensity counts in the cut-off sample)?"""
        return not any(start <= seq and (end is None or seq <= end)
                       for start, end in self.spans)


class Decisions:
    """Decisions taken and not yet sent, and what the provisional hook may show."""

    def __init__(self) -> None:
        self.due: deque[tuple[int, float, bool]] = deque()  # (frame, U, keep), not sent
        self.upto: int | None = None  # candidates up to this frame have a decision
        self.ahead: list[tuple[int, float, float]] = []  # (frame, time, U): later minima
        # above the last cut-off, for the provisional hook


@dataclass(frozen=True)
class AnalysisInput:
    """Everything an analysis takes at its anchor frame, so that when a stage runs does not
    change its result."""

    anchor: int  # the keyframer's frame count when it started
    zone_end: int  # the last frame it decides
    lo: int  # frames up to this one already have a decision
    base: int  # sequence number of the window's first frame
    g0: int  # global index of the window's first speed
    rows: np.ndarray  # the newest position rows (all of them when `old` is None)
    old: np.ndarray | None  # the window's final speeds, kept (None: all redone)
    sample: np.ndarray  # cut-off sample: intensities decided before it


@dataclass(frozen=True)
class StageSpeeds:
    """Stage 1's result: the window's speeds and the candidates of the region."""

    v: np.ndarray  # speeds of the window
    start: int  # first speed of the region
    lo_trend: int  # first speed whose trend is needed (a minimum needs its left neighbour)
    cand: np.ndarray  # candidates from `lo_trend` on (window speed indices)


@dataclass(frozen=True)
class StageMinima:
    """Stage 2's result: every scale's trend minima in the region, concatenated."""

    minima: np.ndarray  # minima, scale after scale (window speed indices)
    u: np.ndarray  # the speed descent at each
    counts: np.ndarray  # minima per scale


class Analysis:
    """One regular re-analysis in stages (`Online.STAGES`), run in order over the frames
    after its anchor, each stage when its share of the estimated cost is due."""

    def __init__(self, inputs: AnalysisInput, cost: np.ndarray) -> None:
        self.inputs = inputs  # taken at the anchor
        self.cum: list[int] = np.cumsum(cost).tolist()  # cumulative stage costs (µs, integers)
        self.done = 0  # stages run
        self.speeds: StageSpeeds | None = None  # after stage 1
        self.rows = TrendRows()  # the trends between the two trend stages (derived)
        self.split = 0  # the first lambda of the second trend stage
        self.minima: StageMinima | None = None  # after the trend stages
        self.total: np.ndarray | None = None  # after the chains: the candidates' intensities
        self.cut: np.ndarray | None = None  # the cut-off sample of the decisions
        self.verdict: MojenaResult | float | None = None  # the cut on it
