"""Intensities and the keypose cut of Miura et al. 2014: the correspondence of minima from
scale to scale (Fig. 3), the candidates' chains and intensities U, and Ward's clustering of U
cut by Mojena's stopping rule one (Mojena 1977), shared by the offline and the online
keyframer (`streamkey.methods.speed`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage

from ..errors import UsageError
from .speed_kernels import (
    band_offsets,
    dropped_threshold,
    mutual_nearest,
    ward_labels,
    ward_levels,
)

__all__ = ["BAND_BUDGET", "match_minima", "nearest_pairs", "intensities", "Chain", "MojenaResult",
           "WARD_1D_FROM", "ward_1d", "mojena_threshold", "two_cluster_threshold", "CUTS",
           "CUT_QUANTILE", "CUT_FRACTION", "quantile_threshold", "check_cut"]

BAND_BUDGET = 4_000_000  # full band DP table entries; above it the windowed DP is used


def match_minima(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Order-preserving matching of sorted `a` and `b` (Miura Fig. 3, DP).

    Every element of the shorter list is matched to a distinct element of the longer one, in
    order, minimising the total |a_i - b_j|. Returns `partner`: for each index of `a`, the index
    of its match in `b`, or -1.
    """
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    if len(a) == 0 or len(b) == 0:
        return np.full(len(a), -1, dtype=np.int64)
    swap = len(b) > len(a)
    long_, short = (b, a) if swap else (a, b)
    idx = _match_indices(long_, short)
    partner = np.full(len(a), -1, dtype=np.int64)
    if swap:
        partner[:] = idx
    else:
        partner[idx] = np.arange(len(short))
    return partner


def _match_indices(long_: np.ndarray, short: np.ndarray) -> np.ndarray:
    """Index into `long_` of each element of `short` in a minimum-cost monotone matching.

    Few unmatched elements (k small): the full band DP, O(len(short) x k) time and memory.
    Many (the candidates against the f_max minima lose about half): a DP restricted to
    partners within `half` ranks of each element's insertion point, O(len(short) x half),
    accepted when its solution covers no frame by more than `half - 1` pairs. Every optimal
    matching whose coverage is at most `half` lies inside that window, and a solution strictly
    below the coverage bound is optimal for the uncapacitated problem too (min-cost flow on the
    line is a linear programme, so an optimum not touching a capacity is a global optimum);
    otherwise `half` grows.
    """
    k = len(long_) - len(short)
    if k == 0:  # equal lengths: the only monotone one-to-one matching
        return np.arange(len(short))
    half = 8
    while (k + 1) * len(short) > BAND_BUDGET and 2 * half + 1 < k + 1:
        idx = _window_dp(long_, short, half)
        if idx is not None and _max_cover(long_[idx], short) <= half - 1:
            return idx
        half *= 4
    matched: np.ndarray = np.arange(len(short)) + _band_dp(long_, short)
    return matched


def _max_cover(x: np.ndarray, y: np.ndarray) -> int:
    """Largest number of pairs (x_j, y_j) whose spans [min, max) share one frame cell."""
    lo, hi = np.minimum(x, y), np.maximum(x, y)
    if len(lo) == 0:
        return 0
    base = int(lo.min())
    n = int(hi.max()) - base + 1
    cover = np.cumsum(np.bincount(lo - base, minlength=n) - np.bincount(hi - base, minlength=n))
    return int(cover.max())


def _window_dp(long_: np.ndarray, short: np.ndarray, half: int) -> np.ndarray | None:
    """Monotone matching DP with short[j]'s partner index in rank_j +- half (None: no path)."""
    p, k = len(short), len(long_) - len(short)
    rank = np.searchsorted(long_, short)
    lo = np.maximum(np.arange(p), rank - half)
    hi = np.minimum(np.arange(p) + k, rank + half)
    if np.any(lo > hi):
        return None
    args: list[np.ndarray] = []
    prev_min = np.zeros(1)
    prev_lo = prev_hi = 0
    for j in range(p):
        i = np.arange(lo[j], hi[j] + 1)
        cost = np.abs(long_[i] - short[j]).astype(np.float64)
        if j:  # best total of rows < j with the previous partner before i
            q = np.minimum(i - 1, prev_hi) - prev_lo
            cost += np.where(q >= 0, prev_min[np.maximum(q, 0)], np.inf)
        prev_min = np.minimum.accumulate(cost)
        better = np.concatenate([[True], cost[1:] < prev_min[:-1]])
        args.append(np.maximum.accumulate(np.where(better, i, 0)))
        prev_lo, prev_hi = int(lo[j]), int(hi[j])
    if not np.isfinite(prev_min[-1]):
        return None
    out = np.empty(p, dtype=np.int64)
    t = len(args[-1]) - 1
    for j in range(p - 1, -1, -1):
        out[j] = args[j][t]
        if j:
            t = min(int(out[j]) - 1, int(hi[j - 1])) - int(lo[j - 1])
    return out


def _band_dp(long_: np.ndarray, short: np.ndarray) -> np.ndarray:
    """Offsets d_j (short[j] pairs with long_[j + d_j]), nondecreasing in [0, k], min total cost.

    C[j, d] = c[j, d] + min(M[j-1, d-1], C[j-1, d]) with M the running minimum over d
    (integer costs, exact); ties keep the smaller offset (earlier partner). Compiled
    (`speed_kernels.band_offsets`), shared with the online chains.
    """
    offsets: np.ndarray = band_offsets(np.ascontiguousarray(long_, dtype=np.int64),
                                       np.ascontiguousarray(short, dtype=np.int64))
    return offsets


def nearest_pairs(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The correspondence of minima from scale to scale: per element of sorted `a`, the index
    of its partner in sorted `b`, or -1. Two minima correspond when each is the other's
    nearest (a tie: the earlier). Order-preserving in one dimension, and local: an extra or a
    missing minimum leaves its neighbours' pairs as they are, where a matching that pairs
    every element of the shorter list (`match_minima`) shifts every pair up to the next
    surplus by one minimum."""
    partner: np.ndarray = mutual_nearest(np.ascontiguousarray(a, dtype=np.int64),
                                         np.ascontiguousarray(b, dtype=np.int64))
    return partner


def intensities(candidates: np.ndarray, per_scale: list[tuple[np.ndarray, np.ndarray]]
                ) -> np.ndarray:
    """Intensity U of each candidate: u summed along its chain of matched minima (Miura 3.2)."""
    chain = Chain(candidates)
    for minima, u in per_scale:
        chain.extend(minima, u)
    return chain.total


class Chain:
    """The candidates' chains of matched minima, scale by scale (`intensities` in steps)."""

    def __init__(self, candidates: np.ndarray) -> None:
        self.total = np.zeros(len(candidates))
        self.chain = np.arange(len(candidates))
        self.prev = np.asarray(candidates)
        self.alive = np.ones(len(candidates), dtype=bool)

    def extend(self, minima: np.ndarray, u: np.ndarray) -> None:
        """Match the next scale's minima to the chain ends (`nearest_pairs`); add their u to
        the live chains."""
        partner = nearest_pairs(self.prev, minima)
        alive = self.alive
        self.chain = np.where(alive, partner[np.where(alive, self.chain, 0)]
                              if len(self.prev) else -1, -1)
        self.alive = self.chain >= 0
        self.total[self.alive] += u[self.chain[self.alive]]
        self.prev = minima


@dataclass(frozen=True)
class MojenaResult:
    """Ward + Mojena outcome: intensity threshold (keep U > threshold), clusters, level cut-off."""

    threshold: float
    n_clusters: int
    level_cutoff: float
    contiguous: bool


WARD_1D_FROM = 64  # values from which the O(n log n) 1-D Ward replaces scipy's O(n^2) one


def ward_1d(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ward's agglomeration of 1-D values in O(n log n): (fusion levels alpha in merge order,
    the sorting permutation, and per merge the sorted position where its right cluster starts).

    In one dimension a Ward merge of two clusters with a third between them never costs less
    than merging that third with one of them (with d = n_a n_b / (n_a + n_b) (mu_a - mu_b)^2:
    min(n_a x^2, n_c y^2) <= n_a n_c / (n_a + n_c) (x + y)^2), so the closest pair is always
    adjacent in sorted order and greedy merging of neighbours gives scipy's hierarchy; alpha
    = 2 d, scipy's squared heights, computed directly instead of by Lance-Williams updates
    (compiled: `speed_kernels.ward_levels`).
    """
    order = np.argsort(u, kind="stable")
    alpha, bounds = ward_levels(np.asarray(u, dtype=np.float64)[order], 2.0)
    return alpha, order, bounds


def mojena_threshold(u: np.ndarray, k: float = 2.75) -> MojenaResult:
    """Ward clustering of intensities, Mojena rule one, dropped cluster -> threshold (Miura 3.2)."""
    u = np.asarray(u, dtype=np.float64)
    if len(u) < 2:
        return MojenaResult(0.0, len(u), float("nan"), True)
    if len(u) < 3:  # one fusion level: no spread to judge it by, one cluster
        return MojenaResult(0.0, 1, float("nan"), True)
    if len(u) >= WARD_1D_FROM:
        alpha, order, bounds = ward_1d(u)
    else:
        z = linkage(u.reshape(-1, 1), method="ward")
        alpha = z[:, 2] ** 2  # Lance-Williams fusion levels of squared distances
    cutoff = float(alpha.mean() + k * alpha.std(ddof=1))
    n_clusters = 1 + int(np.count_nonzero(alpha > cutoff))
    if n_clusters == 1:
        return MojenaResult(0.0, 1, cutoff, True)
    # Ward is monotone: cutting just above the last level kept gives exactly n_clusters.
    if len(u) >= WARD_1D_FROM:
        labels = ward_labels(order, alpha, bounds, n_clusters)
    else:
        labels = fcluster(z, z[len(u) - 1 - n_clusters, 2], criterion="distance") - 1
    threshold, contiguous = dropped_threshold(u, labels.astype(np.int64))
    return MojenaResult(float(threshold), n_clusters, cutoff, bool(contiguous))



def two_cluster_threshold(u: np.ndarray) -> float:
    """Warm-up cut-off: Ward forced to two clusters, the one with the smallest value dropped."""
    if len(u) < 2 or np.all(u == u[0]):
        return 0.0
    z = linkage(u.reshape(-1, 1), method="ward")
    labels = fcluster(z, 2, criterion="maxclust")
    return float(u[labels == labels[np.argmin(u)]].max())


CUTS = ("quantile", "mojena")  # the keypose cuts: the default, then Miura's own rule
CUT_QUANTILE, CUT_FRACTION = 0.95, 0.4  # the quantile cut: U above 0.4 x the 95th percentile


def quantile_threshold(u: np.ndarray) -> float:
    """The quantile cut: keyposes are the candidates whose U is above `CUT_FRACTION` of the
    `CUT_QUANTILE` quantile of the sample's intensities (0 for an empty sample).

    A departure from Miura's Ward + Mojena cut, stable by construction: the threshold moves
    continuously with the sample, so a candidate's verdict changes only when its own U is
    near the threshold, where Ward + Mojena's cluster count jumps between nearly equal
    samples (the module docstring of `streamkey.methods.speed` has the measurements)."""
    u = np.asarray(u, dtype=np.float64)
    return float(CUT_FRACTION * np.quantile(u, CUT_QUANTILE)) if len(u) else 0.0


def check_cut(cut: object) -> str:
    """`cut` if it names a keypose cut (`CUTS`), else a `UsageError`."""
    if cut not in CUTS:
        raise UsageError(f"speed: cut must be one of {', '.join(CUTS)}, got {cut!r}")
    return str(cut)
