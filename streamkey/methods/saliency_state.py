"""Named parts of the online saliency keyframer's state (`saliency_online.Online`).

- `OnlineSetup`: what the parameters fix for the whole stream (scales, support, kernels).
- `WindowBuffers`: the ring of the newest frames, one named array per per-frame quantity.
- `RunningStatistics`: the running versions of the offline method's global statistics.
- `CurveBasis`: the current PCA basis and what each curve derives from it.
- `BasisUpdate`: a basis update spread over several frames, in progress.
- `Preview`: the provisional candidates' caches.

No behaviour beyond bookkeeping: the maths is in `saliency_math` and `saliency_kernels`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..units import Duration, whole_frames
from .saliency_math import REFERENCE_FPS, Basis, MapStats, Moments, curve_weights, remap

__all__ = ["OnlineSetup", "WindowBuffers", "RunningStatistics", "CurveBasis", "BasisUpdate",
           "Preview", "SPREAD", "MIN_SPREAD_FRAMES", "spread_frames"]

SPREAD = Duration.seconds(0.2)  # a periodic basis update's work, spread before it applies
MIN_SPREAD_FRAMES = 10  # its pieces: moments, correlation, eigenvectors, matching, curves in
# two halves, curvatures, at least one block of maps, the switch


def spread_frames(fps: float) -> int:
    """`SPREAD` in frames at `fps` (24 at 120 Hz), at least `MIN_SPREAD_FRAMES`."""
    return whole_frames(SPREAD, fps, MIN_SPREAD_FRAMES)


@dataclass(frozen=True)
class OnlineSetup:
    """Fixed for the stream: scales in frames at its rate, support, window, kernel banks."""

    sigma: float  # base scale, frames
    k: int  # curves asked for
    contact: bool  # two foot-height curves replace the last two components
    variance_rule: bool  # k raised to reach 90 % of the variance
    foot_sigma: float  # the foot curves' scale, frames
    step: float  # frame time in 1/120 s (`saliency_math.time_step`)
    radius: int  # widest Gaussian half-window, frames
    cmax: int  # the longest cluster, whole frames
    clen: float  # cluster length where runs are cut (`saliency_kernels.cuts`)
    min_lookahead: int  # the support radius + 1 + cmax: the default lookahead
    update_every: int  # frames between basis updates, at most
    window: int  # frames kept for recomputation (decision window and history)
    columns: int  # rotation channels per frame
    bank2: np.ndarray  # unnormalised kernels: main curves in columns 0-7, foot curves 8-15
    diff_bank: np.ndarray  # normalised kernel differences G(s_i) - G(2 s_i), main then foot
    lp_b: np.ndarray  # the low-pass of the curves' inputs (`saliency_math.lowpass`): numerator
    lp_a: np.ndarray  # and denominator

    @property
    def spread(self) -> int:
        """Frames a periodic basis update is spread over (`spread_frames`)."""
        return spread_frames(REFERENCE_FPS / self.step)

    @property
    def h2(self) -> float:
        """Twice the frame time (the central difference's denominator)."""
        return 2.0 * self.step

    @property
    def hh(self) -> float:
        """The frame time squared (the second difference's denominator)."""
        return self.step * self.step


class WindowBuffers:
    """The ring of the newest frames: row r holds frame `base` + r. The per-curve arrays have
    no columns until the first basis (`alloc_curves`)."""

    PER_CURVE = ("curves", "curvatures", "maps", "peaks")

    def __init__(self, cap: int, columns: int) -> None:
        self.cap = cap  # rows
        self.base = 0  # frame of row 0
        self.rotations = np.zeros((cap, columns))  # rotation channels minus the first frame's
        self.feet = np.zeros((cap, 2))  # foot heights / body height
        self.srot = np.zeros((cap, columns))  # `rotations` low-passed (the curves' input)
        self.sfeet = np.zeros((cap, 2))  # `feet` low-passed
        self.times = np.zeros(cap)  # frame times, s
        self.moving = np.ones(cap, dtype=bool)  # in a take (not a calibration hold or still)
        self.curves = np.zeros((cap, 0))  # curve values D (PCA projections, foot heights)
        self.curvatures = np.zeros((cap, 0))  # curvature C of each curve
        self.maps = np.zeros((cap, 0, 4))  # scale maps S_i of each curve
        self.peaks = np.zeros((cap, 0, 4), dtype=bool)  # local-maximum flags of the maps

    def has_curves(self, kk: int) -> bool:
        """Whether the per-curve arrays exist with `kk` columns."""
        return self.curves.shape[1] == kk

    def alloc_curves(self, kk: int, perm: np.ndarray | None) -> None:
        """(Re)allocate the per-curve arrays for `kk` curves, remapping kept columns."""
        had = self.maps.shape[1] > 0
        old_maps, old_peaks = self.maps, self.peaks
        self.curves = np.zeros((self.cap, kk))
        self.curvatures = np.zeros((self.cap, kk))
        if perm is not None and had:
            self.maps = remap(old_maps, perm)
            self.peaks = remap(old_peaks, perm)
        else:
            self.maps = np.zeros((self.cap, kk, 4))
            self.peaks = np.zeros((self.cap, kk, 4), dtype=bool)

    def move(self, lo: int, t: int, cap: int) -> None:
        """Rows of frames lo..t-1 to the front of arrays of `cap` rows: frame lo is row 0, the
        rows after them zero. At the same capacity the rows move within the arrays: fresh
        arrays cost page faults on first touch (~1 ms a shift at 120 Hz, in one push)."""
        keep = t - lo
        a, b = lo - self.base, t - self.base
        for name in ("rotations", "feet", "srot", "sfeet", "times", "moving", *self.PER_CURVE):
            arr = getattr(self, name)
            if cap == self.cap:
                arr[:keep] = arr[a:b]  # numpy copies overlapping ranges as if through a buffer
                arr[keep:] = 0
            else:
                new = np.zeros((cap,) + arr.shape[1:], dtype=arr.dtype)
                new[:keep] = arr[a:b]
                setattr(self, name, new)
        self.base, self.cap = lo, cap

    def with_own_curves(self) -> WindowBuffers:
        """A copy whose per-curve arrays are copies (the frame arrays are shared)."""
        new = WindowBuffers.__new__(WindowBuffers)
        new.__dict__.update(self.__dict__)
        for name in self.PER_CURVE:
            setattr(new, name, getattr(self, name).copy())
        return new


class RunningStatistics:
    """Running versions of the offline global statistics: PCA moments and Itti map
    statistics, split into the frames that left the window (folded) and the rest."""

    def __init__(self, columns: int) -> None:
        self.folded_moments = Moments(0, np.zeros(columns), np.zeros((columns, columns)))
        self.folded_upto = 0  # frames before this are folded into the totals
        self.folded_maps = MapStats.empty(0)  # map statistics of the folded frames
        self.maps = MapStats.empty(0)  # map statistics of every frame with final maps
        self.warm: MapStats | None = None  # below the support: the stream start's cut maps
        self.norm: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # cached factors
        self.cubes: tuple[np.ndarray, np.ndarray] = (np.zeros(0), np.zeros(0))  # row max, ^3

    def copy(self) -> RunningStatistics:
        """A shallow copy (every field is replaced, never changed in place, by a basis
        update)."""
        new = RunningStatistics.__new__(RunningStatistics)
        new.__dict__.update(self.__dict__)
        return new


class CurveBasis:
    """The current PCA basis and what the curves derive from it (weights, foot flags, the
    map columns of each curve, the projection)."""

    def __init__(self, basis: Basis | None, contact: bool, pick: np.ndarray | None = None
                 ) -> None:
        self.basis = basis  # the PCA basis (None before the first)
        if basis is None or pick is None:
            self.weights = np.zeros(0)  # eigenvalue weight of each curve
            self.wsum = 1e-300  # max(sum of the weights, tiny)
            self.footmask = np.zeros(0, dtype=bool)  # foot curves
            self.foot_rows = np.zeros((0, 1), dtype=bool)  # `footmask` as a column
            self.pick = np.zeros(0, dtype=np.int64)  # flat map index of each curve's maps
            self.bank_cols = np.zeros(0, dtype=np.int64)  # first kernel column of each curve
            self.proj: tuple[np.ndarray, ...] = ()  # kept columns, mean, sd, PCA vectors
            return
        feet = 2 if contact else 0
        kk = basis.vectors.shape[1]
        self.weights, self.footmask = curve_weights(basis, contact)
        self.wsum = max(float(self.weights.sum()), 1e-300)
        self.foot_rows = self.footmask[:, None]
        self.pick = pick
        cols = pick.reshape(kk, 4) - 8 * np.arange(kk)[:, None]  # the kernel bank's columns
        self.bank_cols = np.ascontiguousarray(cols[:, 0])
        self.proj = (basis.keep, basis.mean[basis.keep], basis.sd[basis.keep],
                     np.ascontiguousarray(basis.vectors[:, : kk - feet]))


@dataclass
class BasisUpdate:
    """A basis update in progress, spread over frames: due at frame u, the moments of its
    window w0..u (rows copied); the window at the switch (frame u + spread - 1) starts at
    frame lo, and the basis decides from frame u + spread on (`OnlineSetup.spread`)."""

    u: int  # the frame it is due at
    w0: int  # first frame of its moments' window
    lo: int  # first frame of the window at the switch
    mom: Moments  # moments so far
    xs: np.ndarray  # rotation rows w0..u
    ft: np.ndarray  # low-passed foot rows lo..u
    moving: np.ndarray  # which rows w0..u are motion (in a take)
    sxs: np.ndarray  # low-passed rotation rows lo..u (the curves' input)
    corr: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None  # correlation
    basis: Basis | None = None  # the new basis, matched
    perm: np.ndarray | None = None  # old curve each new curve continues
    d: np.ndarray | None = None  # curves of frames lo..u
    c: np.ndarray | None = None  # their curvatures
    s: np.ndarray | None = None  # their maps (filled block by block)
    maps: int = 0  # next frame to map
    staged: dict[str, Any] | None = None  # the keyframer's state after the switch


@dataclass
class Preview:
    """Caches of the provisional candidates (never read by a decision)."""

    slot: int | None = None  # `candidates` slot of the cached list
    slot_basis: Basis | None = None  # the basis it was derived with
    cached: list[tuple[int, float, float]] = field(default_factory=list)  # (seq, time, score)
    early_basis: Basis | None = None  # the basis of the early maps
    early: dict[int, np.ndarray] = field(default_factory=dict)  # early maps by frame
