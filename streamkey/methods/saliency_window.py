"""The analysis half of the online saliency keyframer: the ring of recent frames, its curves,
curvatures and maps, the running statistics and the basis updates (`saliency_online` states
the method; `Online` adds the decisions on top of this class).
"""

from __future__ import annotations

import copy

import numpy as np

from ..online import OnlineKeyframer
from .saliency_kernels import ring_curves, ring_maps_of
from .saliency_math import (
    Basis,
    MapStats,
    Moments,
    components,
    correlation,
    curvature,
    curve_weights,
    curves_of,
    fit_k,
    local_max_mask,
    map_stats,
    maps_of,
    match_basis,
    moments,
    pca_basis,
    remap_stats,
)
from .saliency_state import (
    SPREAD,
    BasisUpdate,
    CurveBasis,
    OnlineSetup,
    RunningStatistics,
    WindowBuffers,
)

FOLD_EVERY = 64  # frames that left the window folded into the totals at once

__all__ = ["WindowAnalysis", "SPREAD", "FOLD_EVERY"]


class WindowAnalysis(OnlineKeyframer):
    """Rows and statistics of the online saliency keyframer (no decisions): frames enter the
    ring (`ring`), their curve, curvature and map rows are computed incrementally
    (`_catch_up`), the statistics run (`stats`), and the basis (`curves`) is recomputed at
    once (`_update`) or spread over `setup.spread` frames (`spread`)."""

    setup: OnlineSetup  # fixed by the parameters

    def _reset_window(self) -> None:
        """Empty ring, statistics and basis (a new stream starts)."""
        su = self.setup
        self.t = -1  # newest frame of the window
        self.inc_t = -1  # newest frame whose incremental rows are computed (`_catch_up`)
        self.s_ready = 0  # frames before this have final maps
        self.next_update = 0  # frame at which the next basis update is due
        self.ring = WindowBuffers(min(2 * su.window, 512), su.columns)  # the recent frames
        self.stats = RunningStatistics(su.columns)  # running moments and map statistics
        self.curves = CurveBasis(None, su.contact)  # the basis and its curves
        self.spread: BasisUpdate | None = None  # a spread basis update in progress

    @property
    def basis(self) -> Basis | None:
        """The current PCA basis (None before the first)."""
        return self.curves.basis

    @property
    def cap(self) -> int:
        """Rows of the ring."""
        return self.ring.cap

    # ------------------------------------------------------------------ ring
    def _room(self, t: int) -> None:
        """Make row `t` writable: shift the ring (or grow it) after folding old rows out."""
        ring = self.ring
        if t - ring.base < ring.cap:
            return
        lo = max(ring.base, t - self.setup.window + 1)
        self._fold_out(lo)
        keep = t - lo
        ring.move(lo, t, ring.cap if keep <= ring.cap // 2 else 2 * ring.cap)

    def _fold_out(self, upto: int) -> None:
        """Add rows [folded_upto, upto) to the totals of frames that left the window."""
        st, ring = self.stats, self.ring
        if upto <= st.folded_upto:
            return
        a, b = st.folded_upto - ring.base, upto - ring.base
        m = ring.moving[a:b]
        st.folded_moments = st.folded_moments + moments(ring.rotations[a:b][m])
        if self.curves.basis is not None:
            st.folded_maps = st.folded_maps + map_stats(ring.maps[a:b][m], ring.peaks[a:b][m])
        st.folded_upto = upto

    # ------------------------------------------------------------------ incremental rows
    def _catch_up(self, upto: int) -> None:
        """The incremental rows (curve, curvature, maps, statistics) of frames up to `upto`.

        They are computed when something reads them (a classification, a basis update, the
        ring moving), for all frames since the last time at once, in compiled loops that go
        frame by frame (`ring_curves`, `ring_maps_of`): the same bits whatever the split."""
        p = self.inc_t + 1
        if self.curves.basis is None or upto < p or p == 0:  # p == 0: a window restarted
            return  # with the basis kept, before its first analysis (`_update` makes every row)
        self.inc_t = upto
        R = self.setup.radius
        if p <= 2 * R + 1:  # stream start: the edge rules, frame by frame
            for t in range(p, upto + 1):
                self._incremental(t)
            return
        ring, base = self.ring, self.ring.base
        self._curve_rows(p, upto)
        f0, f1 = max(self.s_ready, p - R - 1), upto - R - 1
        if f1 < f0:
            return
        st = self.stats.maps
        st.n += int(np.count_nonzero(ring.moving[f0 - base : f1 - base + 1]))
        ring_maps_of(ring.curvatures, ring.maps, ring.peaks, f0 - base, f1 - base,
                     self.setup.diff_bank, self.curves.bank_cols, st.total, st.top, st.lm_n,
                     st.lm_sum, st.lm_top, ring.moving)
        self.s_ready = f1 + 1
        self.stats.norm = None

    def _incremental(self, t: int) -> None:
        """One new frame between basis updates: its curve row, one curvature, one map row."""
        self._curve_row(t)
        f = t - self.setup.radius - 1
        if f < self.s_ready:
            return
        self._map_row(f)

    def _curve_row(self, t: int) -> None:
        """Frame t's curve row and frame t-1's curvature (frame by frame)."""
        ring, r, su = self.ring, t - self.ring.base, self.setup
        keep, mean, sd, vec = self.curves.proj
        row = ring.curves[r]
        row[: vec.shape[1]] = ((ring.srot[r, keep] - mean) / sd) @ vec
        if su.contact:
            row[-2:] = ring.sfeet[r]
        dd = ring.curves[r - 2 : r + 1]
        d1 = np.subtract(dd[2], dd[0])
        d1 /= su.h2
        num = dd[2] - 2.0 * dd[1]
        num += dd[0]
        num /= su.hh
        den = np.multiply(d1, d1, out=d1)
        den += 1.0
        np.divide(np.abs(num, out=num), np.power(den, 1.5, out=den), out=ring.curvatures[r - 1])
        if t == 2:  # first frame: D' one-sided, D'' copied from frame 1 (as `curvature`)
            d1 = (dd[1] - dd[0]) / su.step
            ring.curvatures[0] = np.abs((dd[2] - 2.0 * dd[1] + dd[0]) / su.hh) / (
                1.0 + d1 * d1) ** 1.5

    def _map_row(self, f: int) -> None:
        """Maps S_i of frame f from the curvatures f-radius..f+radius (start-truncated)."""
        ring, R = self.ring, self.setup.radius
        lo = max(0, f - R)
        cs = ring.curvatures[lo - ring.base : f + R + 1 - ring.base]
        rf = f - ring.base
        if lo > 0:  # G(s_i) - G(2 s_i) is one linear filter: one product for all eight maps
            s = ring.maps[rf]
            np.abs((cs.T @ self.setup.diff_bank).reshape(-1)[self.curves.pick],
                   out=s.reshape(-1))
        else:  # stream start: weights renormalised over the frames that exist
            bank = self.setup.bank2[R - f :]
            g = cs.T @ bank / bank.sum(axis=0)
            g = np.where(self.curves.foot_rows, g[:, 8:], g[:, :8])
            s = np.abs(g[:, :4] - g[:, 4:])
            ring.maps[rf] = s
        st = self.stats.maps
        if ring.moving[rf]:  # only motion enters the statistics
            st.n += 1
            st.total += s
            np.maximum(st.top, s, out=st.top)
        if f >= 2:
            prev, mid = ring.maps[rf - 2], ring.maps[rf - 1]
            flag = (mid > prev) & (mid >= s)
            ring.peaks[rf - 1] = flag
            if ring.moving[rf - 1]:
                st.lm_n += flag
                peak = mid * flag
                st.lm_sum += peak
                np.maximum(st.lm_top, peak, out=st.lm_top)
        self.s_ready = f + 1
        self.stats.norm = None

    def _curve_rows(self, p: int, upto: int) -> None:
        """Curve rows of frames p..upto and curvature rows of frames p-1..upto-1."""
        ring, base = self.ring, self.ring.base
        keep, mean, sd, vec = self.curves.proj
        ring_curves(ring.srot, ring.sfeet, keep, mean, sd, vec, self.setup.contact,
                    ring.curves, ring.curvatures, p - base, upto - base + 1, self.setup.step)

    def _window_maps(self, c: np.ndarray, r0: int, n: int, pick: np.ndarray, out: np.ndarray
                     ) -> None:
        """Maps (n, k, 4) into `out` of n frames from the curvatures `c` (contiguous rows):
        frame i's Gaussian windows are rows r0 + i .. r0 + i + 2 radius (one product)."""
        row = c.strides[0]
        win = np.ndarray((n, c.shape[1], 2 * self.setup.radius + 1), c.dtype, c, r0 * row,
                         (row, c.strides[1], row))  # a sliding window view, without its checks
        np.abs((win @ self.setup.diff_bank).reshape(n, -1)[:, pick], out=out.reshape(n, -1))

    # ------------------------------------------------------------------ basis updates
    def _update(self, final: bool, spread: BasisUpdate | None = None) -> None:
        """New basis from the running moments; recompute the window's curves and maps. With
        `spread`, the basis and most rows come from the spread update (`_spread_step`)."""
        t, su, ring, st = self.t, self.setup, self.ring, self.stats
        # (the ring may already have moved on for frame t + 1: its first row is then the
        # window's first, the one before folded into the totals)
        w0 = max(0, t - su.window + 1, ring.base) if spread is None else spread.lo
        self._fold_out(w0)
        a, e = w0 - ring.base, t - ring.base + 1
        self.spread = None
        if spread is None:
            self._new_basis(st.folded_moments + moments(ring.rotations[a:e][self._motion(a, e)]))
            basis = self.curves.basis
            assert basis is not None
            d = curves_of(basis, ring.srot[a:e], ring.sfeet[a:e], su.contact)
            c = curvature(d, su.step)
            s = maps_of(c, su.sigma, su.contact, su.foot_sigma)
        else:
            d, c, s = self._spread_rows(spread, a, e)
        ring.curves[a:e], ring.curvatures[a:e] = d, c
        # Rows whose Gaussian windows lie inside the window (all of them at stream start) get
        # new maps; older rows keep theirs. At flush the stream's end is a real end.
        hi = t if final else t - su.radius - 1
        lo = w0 if w0 == 0 else w0 + su.radius + 1
        if hi >= lo:
            ring.maps[lo - ring.base : hi - ring.base + 1] = s[lo - w0 : hi - w0 + 1]
        h = hi - ring.base + 1
        if hi >= w0:
            mask = local_max_mask(ring.maps[a:h])
            ring.peaks[a + 1 : h - 1] = mask[1:-1]
            ring.peaks[h - 1] = False
            if w0 == 0:
                ring.peaks[a] = False
        self.s_ready = max(hi + 1, 0)
        m = ring.moving[a:h]  # only motion enters the statistics
        st.maps = st.folded_maps + map_stats(ring.maps[a:h][m], ring.peaks[a:h][m])
        # Below the support, early frames are decided before (almost) any final map exists:
        # until the final maps cover as many frames, normalise with the maps cut at frame t.
        st.warm = None
        if not final and self.lookahead < su.min_lookahead and w0 == 0 and hi < su.radius:
            m = ring.moving[a:e]
            st.warm = map_stats(s[m], local_max_mask(s)[m])
        st.norm = None
        self.inc_t = t
        if spread is None:
            self.next_update = t + 1 + min(t + 1, su.update_every)

    def _spread_rows(self, sp: BasisUpdate, a: int, e: int
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Switch to the spread update's basis; curves, curvatures and maps of the window
        (ring rows a..e-1, frames lo .. u + spread - 1): the spread's rows, completed by the
        frames after u and the maps that reach them."""
        assert sp.basis is not None and sp.d is not None and sp.c is not None
        assert sp.s is not None
        self._set_basis(sp.basis, sp.perm)
        ring, su, n = self.ring, self.setup, len(sp.d)
        R = su.radius
        d_new = curves_of(sp.basis, ring.srot[a + n : e], ring.sfeet[a + n : e], su.contact)
        d = np.concatenate([sp.d, d_new])
        c_new = curvature(d[n - 2 :], su.step)  # frames u - 1 .. t; the first: an edge row
        c = np.concatenate([sp.c[: n - 1], c_new[1:]])
        s = np.concatenate([sp.s, np.zeros((e - a - n,) + sp.s.shape[1:])])
        f0 = sp.maps - sp.lo  # first window row without maps yet
        cnt = len(c) - R - f0  # up to frame t - radius (the windows inside the window)
        if cnt > 0:
            self._window_maps(c, f0 - R, cnt, self.curves.pick, s[f0 : f0 + cnt])
        return d, c, s

    def _motion(self, a: int, e: int) -> np.ndarray:
        """Which ring rows a..e-1 enter the moments: the motion rows, or every row while no
        motion frame has been seen (a stream starting with a calibration hold or stillness
        needs a basis all the same; offline, a clip without a take)."""
        m: np.ndarray = self.ring.moving[a:e]
        if self.stats.folded_moments.n == 0 and not m.any():
            m = np.ones(e - a, dtype=bool)
        return m

    def _new_basis(self, mom: Moments) -> None:
        """PCA of the moments, matched to the previous basis; per-curve state follows it."""
        self._set_basis(*self._pca(mom))

    def _pca(self, mom: Moments) -> tuple[Basis, np.ndarray | None]:
        """The basis of the moments matched to the current one, and `perm` (`match_basis`;
        None for the first basis). Changes no state."""
        su = self.setup
        return self._match(fit_k(pca_basis(mom, su.k, su.variance_rule), su.k, su.contact))

    def _match(self, new: Basis | None) -> tuple[Basis, np.ndarray | None]:
        """`new` matched to the current basis (`match_basis`), and `perm` (None: no basis)."""
        assert new is not None
        old = self.curves.basis
        if old is None:
            return new, None
        feet = 2 if self.setup.contact else 0
        kk = new.vectors.shape[1]
        return match_basis(old, new, len(self.curves.weights) - feet, kk - feet)

    def _set_basis(self, new: Basis, perm: np.ndarray | None) -> None:
        """Switch to the basis `new` (`_pca`): statistics and ring columns follow its curves."""
        st = self.stats
        kk = new.vectors.shape[1]
        if perm is not None:
            st.folded_maps = remap_stats(st.folded_maps, perm)
        elif st.folded_maps.top.shape[0] != kk:
            st.folded_maps = MapStats.empty(kk)
        same = self.ring.has_curves(kk) and (perm is None or np.array_equal(perm, np.arange(kk)))
        if not same:  # the curves moved columns (or their count changed): new ring arrays
            self.ring.alloc_curves(kk, perm)
        self.curves = CurveBasis(new, self.setup.contact, self._pick_of(new))

    def _pick_of(self, basis: Basis | None) -> np.ndarray:
        """Flat index of each curve's four maps in the (k, 8) product of `_window_maps`: foot
        curves take columns 4-7."""
        assert basis is not None
        foot = curve_weights(basis, self.setup.contact)[1]
        kk = len(foot)
        flat: np.ndarray = (np.arange(kk)[:, None] * 8 + np.arange(4) + 4 * foot[:, None]).ravel()
        return flat

    # ------------------------------------------------------------------ spread update
    def _spread_start(self, u: int) -> None:
        """A basis update due at frame u (after its decisions): fold the window's past out
        and keep a copy of the window's rows; the work follows one piece a frame
        (`_spread_step`, in `idle()`), the switch at frame u + spread - 1, so that the
        new basis decides from frame u + spread on (`saliency_online` docstring)."""
        self._catch_up(u)
        ring = self.ring
        w0 = max(0, u - self.setup.window + 1, ring.base)  # (as `_update`'s)
        lo = max(0, u + self.setup.spread - self.setup.window)  # window start at the switch
        self._fold_out(w0)
        a, e = w0 - ring.base, u - ring.base + 1
        self.spread = BasisUpdate(u, w0, lo, self.stats.folded_moments,
                                  ring.rotations[a:e].copy(),
                                  ring.sfeet[lo - ring.base : e].copy(), ring.moving[a:e].copy(),
                                  ring.srot[lo - ring.base : e].copy())
        self.next_update = u + 1 + min(u + 1, self.setup.update_every)

    def _spread_step(self, t: int) -> None:
        """One piece of the spread update (the window's moments, the PCA, its curves, a
        block of maps), or the switch at its last frame."""
        sp, su = self.spread, self.setup
        assert sp is not None
        v = sp.u + su.spread - 1  # the switch, staged for the next frame
        if t >= v:
            self._stage(sp)
            return
        k = t - sp.u
        if k == 1:
            moving = sp.moving if sp.mom.n or sp.moving.any() else np.ones_like(sp.moving)
            sp.mom = sp.mom + moments(sp.xs[moving])
        elif k == 2:
            sp.corr = correlation(sp.mom)
        elif k == 3:
            assert sp.corr is not None
            sp.basis = fit_k(components(sp.corr, su.k, su.variance_rule), su.k, su.contact)
        elif k == 4:
            sp.basis, sp.perm = self._match(sp.basis)
        elif k in (5, 6):  # curves of frames lo .. u, half of them a frame
            self._spread_curves(sp, k == 5)
        elif k == 7:  # their curvatures (the last row, frame u's: at the switch)
            assert sp.d is not None
            sp.c = curvature(sp.d, su.step)
            sp.s = np.zeros((len(sp.d), sp.d.shape[1], 4))
            sp.maps = sp.lo + su.radius + 1 if sp.lo > 0 else 0  # next frame to map
        elif sp.maps == 0:  # stream start: the first radius rows, windows cut at frame 0
            assert sp.c is not None and sp.s is not None
            R = su.radius
            sp.s[:R] = maps_of(sp.c[: 2 * R], su.sigma, su.contact, su.foot_sigma)[:R]
            sp.maps = R
        else:  # maps of frames whose Gaussian windows end before frame u, a block a frame
            assert sp.c is not None and sp.s is not None
            f0, last = sp.maps, sp.u - 1 - su.radius
            f1 = min(last, f0 + -(-(last - f0 + 1) // (v - t)) - 1)
            if f1 >= f0:
                lo = sp.lo
                self._window_maps(sp.c, f0 - su.radius - lo, f1 - f0 + 1,
                                  self._pick_of(sp.basis), sp.s[f0 - lo : f1 - lo + 1])
                sp.maps = f1 + 1

    def _spread_curves(self, sp: BasisUpdate, first: bool) -> None:
        """Curves of frames lo .. u of the spread update: the first or the second half."""
        n = len(sp.ft)
        h = n // 2
        rows = slice(0, h) if first else slice(h, n)
        assert sp.basis is not None
        d = curves_of(sp.basis, sp.sxs[rows], sp.ft[rows], self.setup.contact)
        if first:
            sp.d = np.empty((n, d.shape[1]))
        assert sp.d is not None
        sp.d[rows] = d

    def _stage(self, sp: BasisUpdate) -> None:
        """The switch of a spread update (`_update`), made on a copy of the state at frame
        u + spread - 1 (in `idle()`) and swapped in by the next frame, before its
        decisions: no decision reads it earlier, and the basis changes with that frame."""
        new = copy.copy(self)
        new.ring = self.ring.with_own_curves()
        new.stats = self.stats.copy()
        new._update(final=False, spread=sp)
        sp.staged = new.__dict__
