"""Pure maths of multiscale motion saliency (C. Halit, "A multi scale motion saliency method
for keyframe extraction from motion capture sequences", MSc thesis, 2010, chapter 3).

Shared by the offline `extract` and the online `Online` of `streamkey.methods.saliency`, whose
module docstring states the definitions settled here. No state, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.linalg import eigh
from scipy.ndimage import correlate1d
from scipy.signal import butter

from ..jit import warmer
from ..units import Duration, DurationLike, frames_of
from .saliency_kernels import (
    Clusterer,
    classify_block,
    classify_terms,
    cuts,
    itti_factors,
    pick_keyframe,
    ring_curves,
    ring_maps_of,
    smooth_rows,
)

__all__ = ["REFERENCE_FPS", "FOOT_SIGMA", "SCALES", "VARIANCE_SHARE", "Basis", "Moments",
           "MapStats", "Clusterer", "time_step", "frames_at",
           "moments", "pca_basis",
           "correlation", "components", "curvature", "end_curvature", "kernel", "widths",
           "kernel_bank", "gaussian_means", "scale_maps", "truncated_maps", "local_max_mask",
           "map_stats", "normalisation", "combine", "curves_of", "maps_of", "curve_weights",
           "fit_k", "cluster_keyframes", "pick_keyframe", "match_basis", "remap", "remap_stats",
           "cluster_size", "cluster_length", "cuts", "support_radius", "itti_factors",
           "classify_terms",
           "classify_block",
           "ring_curves", "ring_maps_of", "CURVE_CUTOFF_HZ", "CURVE_ORDER", "lowpass",
           "smooth_curves", "smooth_with", "smooth_rows"]

# Derivatives are taken per frame of 120 Hz (the CMU rate, on which the defaults were tuned), so
# that a take at any rate has the curvatures of the same motion and 120 Hz those per frame.
REFERENCE_FPS = 120.0
FOOT_SIGMA = Duration.seconds(3.0 / REFERENCE_FPS)  # Halit sec. 3.3: 3 frames of 120 Hz
SCALES = (1.0, 1.5, 2.0, 2.5)  # Halit eq. 3.7
VARIANCE_SHARE = 0.9
# Low-pass of the curves before their curvature, a cut-off in Hz (the same at any rate): the
# curvature of the raw curves is mostly content above the Nyquist frequency of a 30 Hz take.
CURVE_CUTOFF_HZ = 3.5
CURVE_ORDER = 6
_MIN_VAR = 1e-10
# RMS degrees of motion below visibility: its variance is added to every column's before
# standardising (`saliency` module docstring, Input).
NOISE_FLOOR_DEG = 0.5
_TIE = 1e-9


def time_step(fps: float) -> float:
    """One frame of a stream at `fps` in the time unit of the derivatives (1/120 s)."""
    return REFERENCE_FPS / float(fps)


def frames_at(duration: DurationLike, fps: float) -> float:
    """`duration` in frames at `fps`, round-off below 1e-9 frames removed (so that a default
    in seconds is exactly its whole frame count at 120 Hz)."""
    return round(frames_of(duration, fps), 9)


def cluster_length(sigma: float) -> float:
    """Cluster length, 2 sigma frames (Halit sec. 3.1.4), not rounded: runs are cut where the
    frame number from the first frame crosses a multiple of it (`cuts`), a grid in seconds,
    so that clusters are the same slots of the motion at any rate (a whole number of frames
    at 120 Hz with the presets)."""
    return max(1.0, 2.0 * sigma)


def cluster_size(sigma: float) -> int:
    """Largest cluster in frames: `cluster_length` rounded up."""
    return max(1, math.ceil(cluster_length(sigma) - 1e-9))



def support_radius(sigma: float, contact: bool, foot: float) -> int:
    """Widest half-window of the Gaussian means (eq. 3.5), floor(2 * 2 * 2.5 sigma) frames,
    of `sigma` and, with contact, of the foot curves' `foot` (both in frames)."""
    r = _radius(sigma)
    return max(r, _radius(foot)) if contact else r


def _radius(sigma: float) -> int:
    return max(len(kernel(s)) // 2 for s in widths(sigma))


# --------------------------------------------------------------------------- PCA

@dataclass
class Moments:
    """Sums over frames of x and x x^T (x shifted by a reference row): exact to accumulate."""

    n: int
    sx: np.ndarray
    sxx: np.ndarray

    def __add__(self, other: Moments) -> Moments:
        return Moments(self.n + other.n, self.sx + other.sx, self.sxx + other.sxx)


def moments(xs: np.ndarray) -> Moments:
    """Moments of shifted rows `xs` (n, m) in one batch (same arithmetic offline and online)."""
    xs = np.ascontiguousarray(xs, dtype=np.float64)
    return Moments(len(xs), xs.sum(axis=0), xs.T @ xs)


@dataclass
class Basis:
    """Standardisation and principal axes: z = ((x - mean) / sd)[keep] @ vectors."""

    mean: np.ndarray
    sd: np.ndarray
    keep: np.ndarray
    vectors: np.ndarray
    values: np.ndarray
    explained: float

    def project(self, xs: np.ndarray) -> np.ndarray:
        """Curves D of shifted rows `xs` (n, m) -> (n, k)."""
        z = (xs[..., self.keep] - self.mean[self.keep]) / self.sd[self.keep]
        curves: np.ndarray = z @ self.vectors
        return curves


def pca_basis(mo: Moments, k: int, variance_rule: bool) -> Basis:
    """Halit sec. 3.1.1: PCA of the standardised columns from their covariance (correlation) matrix.

    Returns at most as many components as non-constant columns (possibly zero).
    """
    return components(correlation(mo), k, variance_rule)


def correlation(mo: Moments) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """First half of `pca_basis`: (mean, sd, kept columns, their correlation matrix); sd
    includes the noise floor (`NOISE_FLOOR_DEG`), so a column of sensor noise weighs little."""
    n = max(mo.n, 1)
    mean = mo.sx / n
    cov = mo.sxx / n - np.outer(mean, mean)
    var = np.maximum(np.diag(cov).copy(), 0.0)
    keep = np.flatnonzero(var > _MIN_VAR)
    sd = np.sqrt(np.where(var > _MIN_VAR, var + NOISE_FLOOR_DEG**2, 1.0))
    return mean, sd, keep, cov[np.ix_(keep, keep)] / np.outer(sd[keep], sd[keep])


def components(stats: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], k: int,
               variance_rule: bool) -> Basis:
    """Second half of `pca_basis`: the components of `correlation`'s matrix."""
    mean, sd, keep, corr = stats
    if len(keep) == 0:
        return Basis(mean, sd, keep, np.zeros((0, 0)), np.zeros(0), 1.0)
    values, vectors = eigh(corr, check_finite=False)
    values, vectors = np.maximum(values[::-1], 0.0), vectors[:, ::-1]
    total = float(values.sum())
    if variance_rule and total > 0:
        share = np.cumsum(values) / total
        k = max(k, int(np.searchsorted(share, VARIANCE_SHARE - 1e-12)) + 1)
    k = min(k, len(keep))
    vectors = vectors[:, :k]
    top = np.argmax(np.abs(vectors), axis=0)
    vectors = vectors * np.where(vectors[top, np.arange(k)] < 0, -1.0, 1.0)
    explained = float(values[:k].sum() / total) if total > 0 else 1.0
    return Basis(mean, sd, keep, vectors, values[:k].copy(), explained)


# --------------------------------------------------------------------------- saliency maps

def curvature(d: np.ndarray, step: float = 1.0) -> np.ndarray:
    """Halit eq. 3.4 with D': |D''| / (1 + D'^2)^(3/2), per column of (n, k),
    derivatives per time unit, `step` the frame time in it (`time_step`)."""
    n = len(d)
    if n < 3:
        return np.zeros_like(d)
    d1 = np.empty_like(d)
    d1[1:-1] = (d[2:] - d[:-2]) / (2.0 * step)
    d1[0] = (d[1] - d[0]) / step
    d1[-1] = (d[-1] - d[-2]) / step
    d2 = np.empty_like(d)
    d2[1:-1] = (d[2:] - 2.0 * d[1:-1] + d[:-2]) / (step * step)
    d2[0] = d2[1]
    d2[-1] = d2[-2]
    kappa: np.ndarray = np.abs(d2) / (1.0 + d1 * d1) ** 1.5
    return kappa


def lowpass(fps: float, cutoff_hz: float | None = CURVE_CUTOFF_HZ, order: int = CURVE_ORDER
            ) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) of the curves' causal Butterworth low-pass at `cutoff_hz` for a stream at `fps`
    (S. Butterworth, "On the theory of filter amplifiers", 1930; bilinear transform); the
    identity (1, 0, ...) when off or at or above the Nyquist frequency."""
    if cutoff_hz is None or not 0.0 < cutoff_hz < 0.5 * float(fps):
        one = np.zeros(order + 1)
        one[0] = 1.0
        return one, one.copy()
    b, a = _butter(order, float(cutoff_hz), float(fps))
    return b.copy(), a.copy()


@lru_cache(maxsize=32)
def _butter(order: int, cutoff_hz: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """scipy's design, remembered: every new stream's keyframers ask for the same filter."""
    b, a = butter(order, cutoff_hz, fs=fps)
    return np.asarray(b, dtype=np.float64), np.asarray(a, dtype=np.float64)


def smooth_curves(d: np.ndarray, fps: float, cutoff_hz: float | None = CURVE_CUTOFF_HZ
                  ) -> np.ndarray:
    """The curves `d` (n, k) low-passed in time (`lowpass`, from the first row, which starts
    at rest), so that their curvature describes the motion, not the sampling: the same
    motion at 30, 60 or 120 Hz gets the same curvature extrema."""
    return smooth_with(d, *lowpass(fps, cutoff_hz))


def smooth_with(d: np.ndarray, b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """`smooth_curves` with the filter (b, a) given."""
    x = np.ascontiguousarray(d, dtype=np.float64)
    y = np.empty_like(x)
    smooth_rows(x, y, 0, len(x), 0, b, a)
    return y


def kernel(s: float) -> np.ndarray:
    """Gaussian weights exp(-d^2 / 2 s^2) for |d| <= floor(2 s) (Halit eq. 3.5), unnormalised."""
    r = int(np.floor(2 * s))
    d = np.arange(-r, r + 1, dtype=np.float64)
    return np.exp(-d * d / (2.0 * s * s))


def widths(sigma: float) -> list[float]:
    """The eight Gaussian widths: s_i for the four scales, then 2 s_i (eq. 3.6)."""
    s = [sigma * f for f in SCALES]
    return s + [2 * x for x in s]


def gaussian_means(c: np.ndarray, sigma: float) -> np.ndarray:
    """G(f, w) for the eight widths of `sigma`, (n, k, 8); weights renormalised at the ends."""
    out = np.empty(c.shape + (8,))
    ones = np.ones(len(c))
    for i, s in enumerate(widths(sigma)):
        w = kernel(s)
        num = correlate1d(c, w, axis=0, mode="constant", cval=0.0)
        den = correlate1d(ones, w, mode="constant", cval=0.0)
        out[..., i] = num / den[:, None]
    return out


def scale_maps(g: np.ndarray) -> np.ndarray:
    """S_i = |G(f, s_i) - G(f, 2 s_i)| (Halit eq. 3.6): (..., 8) -> (..., 4)."""
    maps: np.ndarray = np.abs(g[..., :4] - g[..., 4:])
    return maps


def end_curvature(d3: np.ndarray, step: float = 1.0) -> np.ndarray:
    """Curvature of the last of three rows `d3` (3, k) when it ends the clip (eq. 3.4): D'
    one-sided, D'' copied from its neighbour, as `curvature` does at a clip's end."""
    d1 = (d3[2] - d3[1]) / step
    kappa: np.ndarray = (np.abs((d3[2] - 2.0 * d3[1] + d3[0]) / (step * step))
                         / (1.0 + d1 * d1) ** 1.5)
    return kappa


def truncated_maps(cs: np.ndarray, bank: np.ndarray, offsets: np.ndarray, foot: np.ndarray
                   ) -> np.ndarray:
    """Raw maps S_i (m, k, 4) of m frames from the curvatures `cs` (n, k) of the frames that
    exist: frame j sits at row `offsets[j]` of `cs`, and its Gaussian windows (eq. 3.5) are cut
    at both ends of `cs` with the weights renormalised over the part inside (clip-end rule).

    `bank` is `kernel_bank` of the main sigma (columns 0-7) and of the foot sigma (8-15) with
    radius R, (2 R + 1, 16); `foot` (k,) flags the curves using the foot columns.
    """
    n, radius = len(cs), (len(bank) - 1) // 2
    out = np.empty((len(offsets), cs.shape[1], 4))
    for j, o in enumerate(offsets):
        lo, hi = max(0, o - radius), min(n, o + radius + 1)
        w = bank[radius - (o - lo) : radius + (hi - o)]
        g = cs[lo:hi].T @ w / w.sum(axis=0)
        g = np.where(foot[:, None], g[:, 8:], g[:, :8])
        out[j] = np.abs(g[:, :4] - g[:, 4:])
    return out


@dataclass
class MapStats:
    """Running statistics of the raw maps S_i per (curve, scale): count, sum, max, local maxima."""

    n: int
    total: np.ndarray
    top: np.ndarray
    lm_n: np.ndarray
    lm_sum: np.ndarray
    lm_top: np.ndarray

    @classmethod
    def empty(cls, k: int) -> MapStats:
        """No frames yet."""
        z = np.zeros((k, 4))
        return cls(0, z.copy(), z.copy(), np.zeros((k, 4), dtype=np.int64), z.copy(), z.copy())

    def __add__(self, o: MapStats) -> MapStats:
        return MapStats(self.n + o.n, self.total + o.total, np.maximum(self.top, o.top),
                        self.lm_n + o.lm_n, self.lm_sum + o.lm_sum,
                        np.maximum(self.lm_top, o.lm_top))


def local_max_mask(s: np.ndarray) -> np.ndarray:
    """Interior local maxima along axis 0 (v[f-1] < v[f] >= v[f+1]), as a boolean mask."""
    mask = np.zeros(s.shape, dtype=bool)
    if len(s) >= 3:
        mask[1:-1] = (s[1:-1] > s[:-2]) & (s[1:-1] >= s[2:])
    return mask


def map_stats(s: np.ndarray, lm: np.ndarray | None = None) -> MapStats:
    """Statistics of raw maps `s` (n, k, 4); `lm` the local-maximum mask (default: computed)."""
    if lm is None:
        lm = local_max_mask(s)
    k = s.shape[1]
    if len(s) == 0:
        return MapStats.empty(k)
    lm_vals = np.where(lm, s, 0.0)
    return MapStats(len(s), s.sum(axis=0), s.max(axis=0), lm.sum(axis=0),
                    lm_vals.sum(axis=0), lm_vals.max(axis=0))


def normalisation(st: MapStats) -> tuple[np.ndarray, np.ndarray]:
    """Itti factors a (k, 4) with S = sum_i a_i S_i, and the per-curve threshold mean(S) (k,)."""
    top = st.top
    pos = top > 0
    safe = np.where(pos, top, 1.0)
    # one local maximum equal to the global one is left out (none left -> m = 0)
    has_top = st.lm_top == top
    m = (st.lm_sum - has_top * top) / np.maximum(st.lm_n - has_top, 1)
    r = 1.0 - m / safe
    a = top.max(axis=1, keepdims=True) ** 3 / safe * (r * r) * pos
    return a, combine(st.total / max(st.n, 1), a)


def combine(s: np.ndarray, a: np.ndarray) -> np.ndarray:
    """S = sum_i a_i S_i over the last axis, in a fixed order (identical bits for any batch)."""
    total: np.ndarray = (((s[..., 0] * a[:, 0] + s[..., 1] * a[:, 1]) + s[..., 2] * a[:, 2])
                         + s[..., 3] * a[:, 3])
    return total


# --------------------------------------------------------------------------- clusters

def cluster_keyframes(cand: np.ndarray, weights: np.ndarray, foot: np.ndarray, cmax: float,
                      rel: np.ndarray) -> dict[str, np.ndarray]:
    """Halit sec. 3.1.4 / sec. 3.3 clustering of a candidate matrix (n, k), vectorised.

    `foot` flags the foot curves, `rel` (n, k) is S_j(f) / mean(S_j). Returns per cluster its
    start, end, keyframe (0-based rows), foot flag and score.
    """
    rows = np.flatnonzero(cand.any(axis=1))
    if len(rows) == 0:
        e = np.zeros(0, dtype=np.int64)
        return {"start": e, "end": e, "key": e, "foot": e.astype(bool), "score": e * 0.0}
    new_run = np.ones(len(rows), dtype=bool)
    new_run[1:] = np.diff(rows) != 1
    i = rows.astype(np.float64)  # the grid starts at the first frame (`cuts`)
    new_cl = new_run | (np.floor(i / cmax) > np.floor((i - 1.0) / cmax))
    cl = np.cumsum(new_cl) - 1
    c = cand[rows]
    w_row = c.astype(np.float64) @ weights
    wsum = np.bincount(cl, w_row)
    mean = np.bincount(cl, w_row * rows) / wsum
    is_foot = c[:, foot].any(axis=1)
    cl_foot = np.bincount(cl, is_foot).astype(bool)
    eligible = is_foot | ~cl_foot[cl]
    dist = np.where(eligible, np.abs(rows - mean[cl]), np.inf)
    best = np.minimum.reduceat(dist, np.flatnonzero(new_cl))
    pick = np.flatnonzero(dist <= best[cl] + _TIE)
    _, first = np.unique(cl[pick], return_index=True)
    score = np.bincount(cl, (np.where(c, rel[rows], 0.0) @ weights)) / weights.sum()
    starts = np.flatnonzero(new_cl)
    ends = np.append(starts[1:], len(rows)) - 1
    return {"start": rows[starts], "end": rows[ends], "key": rows[pick[first]],
            "foot": cl_foot, "score": score}


def curve_weights(basis: Basis, contact: bool) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalue weights of the curves and the foot-curve flags (feet last, sec. 3.3).

    Weights are floored at a tiny positive value: a rank-deficient motion (a synthetic one,
    a performer standing still) has zero or round-off negative eigenvalues, and a cluster
    made only of such curves' candidates would otherwise have no weighted mean.
    """
    k = len(basis.values)
    top = float(np.max(np.abs(basis.values))) if k else 0.0
    weights = np.maximum(basis.values, max(1e-12 * top, np.finfo(np.float64).tiny))
    foot = np.zeros(k, dtype=bool)
    if contact:
        foot[-2:] = True
    return weights, foot


def fit_k(basis: Basis, k: int, contact: bool) -> Basis:
    """With contact, keep at least 3 components' worth of curves (pad with zero curves)."""
    need = 3 if contact else 1
    have = basis.vectors.shape[1]
    if have >= need:
        return basis
    pad = need - have
    vec = np.hstack([basis.vectors, np.zeros((basis.vectors.shape[0], pad))])
    return Basis(basis.mean, basis.sd, basis.keep, vec, np.append(basis.values, np.zeros(pad)),
                 basis.explained)


def curves_of(basis: Basis, xs: np.ndarray, feet: np.ndarray, contact: bool) -> np.ndarray:
    """The k curves: PCA projections, the last two replaced by the foot heights (sec. 3.3)."""
    d = basis.project(xs)
    if contact:
        d = np.concatenate([d[:, :-2], feet], axis=1)
    return d


def maps_of(c: np.ndarray, sigma: float, contact: bool, foot: float) -> np.ndarray:
    """Raw scale maps S_i (n, k, 4) of curvatures `c`; the foot curves use sigma = `foot`
    (sec. 3.3; both in frames)."""
    out = np.empty(c.shape + (4,))
    if not contact:
        out[...] = _maps_t(c, sigma)
    else:
        out[:, :-2] = _maps_t(c[:, :-2], sigma)
        out[:, -2:] = _maps_t(c[:, -2:], foot)
    return out


def _maps_t(c: np.ndarray, sigma: float) -> np.ndarray:
    """`scale_maps(gaussian_means(c, sigma))` as a (n, k, 4) view, computed curve by curve
    along contiguous rows (the same sums and divisions, so the same bits)."""
    ct = np.ascontiguousarray(c.T)
    g = np.empty((8,) + ct.shape)
    ones = np.ones(len(c))
    for i, s in enumerate(widths(sigma)):
        w = kernel(s)
        num = correlate1d(ct, w, axis=1, mode="constant", cval=0.0)
        np.divide(num, correlate1d(ones, w, mode="constant", cval=0.0), out=g[i])
    return np.abs(g[:4] - g[4:]).transpose(2, 1, 0)



def kernel_bank(sigma: float, radius: int) -> np.ndarray:
    """The eight Gaussian kernels of `sigma`, zero-padded to (2 radius + 1, 8), unnormalised."""
    bank = np.zeros((2 * radius + 1, 8))
    for i, s in enumerate(widths(sigma)):
        w = kernel(s)
        r = len(w) // 2
        bank[radius - r : radius + r + 1, i] = w
    return bank


def match_basis(old: Basis, new: Basis, n_pca_old: int, n_pca_new: int
                ) -> tuple[Basis, np.ndarray]:
    """Reorder and re-sign the new components to follow the old ones (greedy on |cos|).

    Returns the reordered basis and `perm`: for each new curve, the old curve it continues
    (-1 for none). Only the first `n_pca_*` components are matched; with contact the foot
    curves (the last two) always continue themselves.
    """
    k_new = new.vectors.shape[1]
    perm = np.full(k_new, -1, dtype=np.int64)
    vo = np.zeros((len(new.mean), n_pca_old))
    vo[old.keep] = old.vectors[:, :n_pca_old]
    vn = np.zeros((len(new.mean), n_pca_new))
    vn[new.keep] = new.vectors[:, :n_pca_new]
    cos = np.abs(vo.T @ vn)[: min(n_pca_old, n_pca_new)]
    order = np.full(n_pca_new, -1, dtype=np.int64)
    taken = np.zeros(n_pca_new, dtype=bool)
    for flat in np.argsort(-cos, axis=None, kind="stable"):
        i, j = divmod(int(flat), n_pca_new)
        if order[i] < 0 and not taken[j]:
            order[i], taken[j], perm[i] = j, True, i
    free = iter(np.flatnonzero(~taken))
    order = np.array([o if o >= 0 else next(free) for o in order], dtype=np.int64)
    idx = np.concatenate([order, np.arange(n_pca_new, k_new)]).astype(np.int64)
    vec = new.vectors[:, idx]
    sign = np.ones(k_new)
    ok = perm[:n_pca_new] >= 0
    dots = np.einsum("ij,ij->j", vo[:, perm[:n_pca_new][ok]], vn[:, order[ok]])
    sign[np.flatnonzero(ok)] = np.where(dots < 0, -1.0, 1.0)
    if k_new > n_pca_new:
        perm[n_pca_new:] = np.arange(k_new - n_pca_new) + old.vectors.shape[1] - (
            k_new - n_pca_new)
    return Basis(new.mean, new.sd, new.keep, vec * sign, new.values[idx], new.explained), perm


def remap(arr: np.ndarray, perm: np.ndarray) -> np.ndarray:
    """Columns (axis 1) of `arr` laid out for the new curves; new curves start at zero."""
    out = np.zeros((arr.shape[0], len(perm)) + arr.shape[2:], dtype=arr.dtype)
    ok = perm >= 0
    out[:, ok] = arr[:, perm[ok]]
    return out


def remap_stats(st: MapStats, perm: np.ndarray) -> MapStats:
    def col(a: np.ndarray) -> np.ndarray:
        moved: np.ndarray = remap(a[None], perm)[0]
        return moved

    return MapStats(st.n, col(st.total), col(st.top), col(st.lm_n), col(st.lm_sum),
                    col(st.lm_top))


@warmer
def _warm() -> None:
    """A first basis and its maps on a tiny sample: LAPACK's eigensolver and the Gaussian
    correlations load their code on first use (2-4 ms), in a live stream's first basis push."""
    xs = np.random.default_rng(0).normal(size=(16, 4))
    basis = pca_basis(moments(xs), 2, True)
    maps_of(np.abs(basis.project(xs)), 2.0, False, 1.0)
