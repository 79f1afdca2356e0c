"""Adaptive speed-minima keyposes — Miura et al. 2014, "Adaptive keypose extraction from
motion capture data" (§3), offline and online.

Offline: `extract(motion)`. Definitions this module settles (the paper leaves them open):

- Speed (Miura eq. 3): the 16 joints of `MIURA_ROLES` in the pelvis frame, divided by body
  height, stacked into one 48-vector p(n) per captured frame and HP-filtered at f_c (eq. 2);
  v(n) = |p_F(n+1) - p_F(n)| / dt, the Euclidean norm over all 48 coordinates (eq. 3). v has
  one value fewer than the motion has captured frames and v(n) is reported at frame n (the
  first frame of the forward difference). A first frame that is a reference T-pose (or an
  all-zero dropout) by `motion.detect_reference_frame` is not captured motion and is left
  out, by `extract` and by a stream (`Online` holds a stream's first frame until its second
  arrives): its one-frame jump would be the largest speed of all and leave one cluster above
  Mojena's cut (07_05 streamed with its reference frame: 1 key instead of 6).
- Rest: candidates (local minima of v) and the minima of every scale's trend lie at speeds of
  at least `REST_SPEED` (0.02 body heights/s); below it an exact hold has only rounding noise
  and HP ringing, whose minima counted as candidates and moved Mojena's cut-off.
- Correspondence (Miura Fig. 3): between two sorted lists of minima, the order-preserving
  one-to-one matching that pairs every element of the shorter list and minimises the total
  absolute time difference (`match_minima`). Chains start at the candidates, are matched to
  the f_max minima, then scale to scale; a candidate whose chain breaks gets u = 0 at every
  coarser scale.
- Mojena's stopping rule one (Mojena 1977) on the Ward fusion levels alpha (squared scipy
  heights, the Lance-Williams levels): cut-off mean(alpha) + k * std(alpha, ddof=1); the number
  of clusters is one more than the number of levels above it (fewer than 3 candidates: one
  cluster). The dropped cluster (the one with a zero intensity, else the lowest mean) becomes
  an intensity threshold: keyposes are the candidates with U above the dropped cluster's
  largest intensity (0 for a single cluster). On every shared clip Ward's clusters are
  intervals of intensity, so this is the paper's rule (`info["contiguous_clusters"]` checks).
  From `WARD_1D_FROM` values on, Ward runs as greedy merging of sorted neighbours
  (`ward_1d`, O(n log n); in 1-D the closest pair is always adjacent) instead of scipy's
  O(n^2) linkage: same levels to rounding, the same keys on every shared clip and at 100,000
  frames (3.2 -> 2.0 s CPU there); online, ~550 values per update: 3.7 -> 1.2 ms.

Online (`Online`): every `hop` frames an analysis of the window (the last `history +
lookahead + hop` frames) starts; it runs in four steps over the next `delay` frames (two
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
- Candidate correspondence over the whole clip -> the same DP over the region (compiled,
  `speed_kernels.chain_totals`: the band DP of `match_minima`, same ties, same sums).
- Ward + Mojena over all candidates -> one cut-off per update, re-derived from a bounded sample:
  the candidates decided in the last `cutoff_history` frames (intensities as decided), those
  decided now and the window's pending ones. Applying it to the candidates due (U > cut-off)
  replaces re-clustering per candidate, whose cluster count flips as candidates arrive.
- Warm-up: while the sample holds fewer than `warmup_candidates` (Mojena's rule cannot split
  fewer than ~10 levels at k = 2.75), a single-cluster verdict is replaced by Ward cut into
  two clusters; after that, the rule is Mojena's.
- `flush()` analyses the whole window (full-window HP filters) and decides everything pending.
  With a lookahead of at least the stream's length nothing is sent before, the window is the
  whole stream and the sample all its candidates: the offline result, bit for bit.

HP factors (`signal.hp_factor`, offline and online alike): LAPACK's banded Cholesky factor in
its first 20 lambda^(1/4) columns, then its converged column (within LAPACK's own ~1e-11
rounding noise there), then the bottom corner: O(n) without a factorisation of length n. Same
keys as the LAPACK factorisation on every shared clip and at 100,000 frames (intensities within
1.4e-7 relative). Offline solves go through LAPACK (`HPBank`, which holds its lambdas only);
the online kernels read the same first and converged columns from `packed_factors` (2.4 MB
at 120 fps with the defaults, shared by every stream with equal parameters, never pickled).
Shared compiled steps (`speed_kernels`, offline and online alike, exact): the band DP, the
1-D Ward (`ward_1d`) and the rest of Mojena's rule. Memory per keyframer is bounded by the
window (positions, speeds), the carried forward values (the region's rows x 144 lambdas,
0.47 MB) and the cut-off sample (the candidates of `cutoff_history` frames); pickled after
30 s: 1.44-1.51 MB.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, SupportsIndex, cast

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.linalg import get_blas_funcs, get_lapack_funcs

from ..errors import UsageError
from ..features import DEFAULT_NOISE_CUTOFF_HZ, Features, compute_features
from ..keyframes import KeyframeEvent, Keyframes
from ..motion import Motion, Skeleton, detect_reference_frame
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock, OnlineKeyframer
from ..roles import MIURA_ROLES
from ..signal import HP_SETTLE, hp_factor, hp_filter, hp_lambda, hp_prefix, hp_settle, local_minima
from ..units import Duration, DurationLike, whole_frames
from .ring import RingWindow
from .speed_kernels import (
    band_offsets,
    chain_totals,
    dropped_threshold,
    hp_advance,
    hp_tail,
    tail_minima,
    ward_labels,
    ward_levels,
)

__all__ = ["extract", "scale_frequencies", "speed_signal", "HPBank", "scale_minima",
           "match_minima", "intensities", "mojena_threshold", "MojenaResult", "METHOD", "Online",
           "scale_lambdas", "settle_frames", "ward_1d", "WARD_1D_FROM", "scale_minimum", "Chain",
           "speed_tail", "packed_factors", "REST_SPEED", "candidates_of", "LOOKAHEAD", "MAX_HOP",
           "HISTORY", "CUTOFF_HISTORY"]

METHOD = "speed"
_PBTRS = get_lapack_funcs("pbtrs", (np.empty(1),))
_TBSV = get_blas_funcs("tbsv", (np.empty(1),))


def _check_params(f_c: float, f_max: float, f_min: float, r: float, mojena_k: float) -> None:
    if not (f_c > 0 and f_max > 0 and 0 < f_min <= f_max):
        raise UsageError("speed: need f_c > 0 and 0 < f_min <= f_max")
    if not 0 < r < 1:
        raise UsageError("speed: the scale ratio r must lie in (0, 1)")
    if not np.isfinite(mojena_k):
        raise UsageError("speed: mojena_k must be finite")


def scale_frequencies(f_max: float = 8.0, f_min: float = 0.2, r: float = 0.95) -> np.ndarray:
    """Cut-offs f_i = f_max r^(i-1), i = 1..i_max, the last one >= f_min (Miura §3.2 (3))."""
    i_max = int(np.floor(np.log(f_min / f_max) / np.log(r) + 1e-9)) + 1
    return f_max * r ** np.arange(i_max)


def speed_signal(positions: np.ndarray, frame_time: float, f_c: float = 10.0) -> np.ndarray:
    """Miura eq. 2-3: HP low-pass of (n, 48) positions at f_c, then the norm of the step / dt."""
    pf = hp_filter(positions, hp_lambda(f_c, frame_time))
    speed: np.ndarray = np.linalg.norm(np.diff(pf, axis=0), axis=1) / frame_time
    return speed


_PACKED: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # lambdas -> tables
# No locks (algorithm modules import no threading): the engine drives every keyframer from
# one thread, and a race between threads could at worst build a table twice.


class _WorkRows:
    """A keyframer's reused `hp_tail` work rows (no page faults per analysis; per keyframer,
    as the kernels release the GIL). Derived: pickled empty."""

    def __init__(self) -> None:
        self.rows = np.empty((0, 0))

    def __reduce__(self) -> tuple[type, tuple[()]]:
        return (_WorkRows, ())

    def get(self, n: int, width: int) -> np.ndarray:
        """At least n rows of `width` values (contents undefined)."""
        if len(self.rows) < n or self.rows.shape[1] != width:
            self.rows = np.empty((n, width))
        return self.rows


def packed_factors(lams: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The interior columns of every lambda's HP factor (`signal.hp_factor`) side by side for
    `speed_kernels.hp_tail`: LAPACK's first columns of lambda i at `off[i]:off[i + 1]` of
    `pre` (3, total), and the converged columns `conv` (4, len(lams): the fourth row holds the
    reciprocals of the diagonal; the kernels multiply where the columns are constant).
    Derived data shared by every stream with the same lambdas (2.4 MB at 120 fps with the
    defaults), never pickled.
    """
    key = np.asarray(lams, dtype=np.float64).tobytes()
    got = _PACKED.get(key)
    if got is None:
        cols = [hp_prefix(float(lam)) for lam in lams]
        off = np.concatenate([[0], np.cumsum([c.shape[1] for c in cols])]).astype(np.int64)
        pre = np.ascontiguousarray(np.concatenate(cols, axis=1))
        conv = np.stack([c[:, -1] for c in cols], axis=1)
        conv = np.ascontiguousarray(np.vstack([conv, 1.0 / conv[2:]]))
        if len(_PACKED) >= 16:
            _PACKED.clear()
        got = _PACKED[key] = (pre, off, conv)
    return got


_TAILS: dict[tuple[float, int, int], np.ndarray] = {}  # (lambda, n, k) -> step operator


def speed_tail(positions: np.ndarray, frame_time: float, f_c: float, k: int) -> np.ndarray:
    """The last k values of `speed_signal(positions)` through one cached matrix product:
    the HP smoother's last k + 1 rows, differenced ((k, n), shared like the HP factors)."""
    n = len(positions)
    key = (hp_lambda(f_c, frame_time), n, k)
    op = _TAILS.get(key)
    if op is None:
        rows = hp_filter(np.eye(n), key[0])[n - k - 1 :]
        op = rows[1:] - rows[:-1]
        if len(_TAILS) >= 64:
            _TAILS.clear()
        _TAILS[key] = op
    speed: np.ndarray = np.linalg.norm(op @ positions, axis=1) / frame_time
    return speed


class HPBank:
    """HP solves for several lambdas at any length (factors from `signal.hp_factor`, O(n),
    no factorisation). A bank holds its lambdas only (a snapshot carries nothing else)."""

    def __init__(self, lams: np.ndarray) -> None:
        self.lams = np.asarray(lams, dtype=np.float64)

    def __reduce__(self) -> tuple[type, tuple[np.ndarray]]:
        return (HPBank, (self.lams,))

    def factor(self, n: int, i: int) -> np.ndarray:
        """Upper banded Cholesky factor (3, n) of the length-n HP system for lambda i."""
        return hp_factor(int(n), float(self.lams[i]))

    def solve(self, v: np.ndarray, i: int, tail: int | None = None) -> np.ndarray:
        """HP trend of the 1-D signal `v` for the i-th lambda (its last `tail` values only:
        the back substitution stops there; the same numbers as the whole solve's)."""
        v = np.asarray(v, dtype=np.float64)
        n = len(v)
        if n < 3:
            return v[n - (n if tail is None else min(tail, n)) :].copy()
        c = self.factor(n, i)
        if tail is not None and tail < n:  # dpbtrs is these two dtbsv calls, on all rows
            y = _TBSV(2, c, v, trans=1)
            return np.asarray(_TBSV(2, c[:, n - tail :], y[n - tail :], trans=0,
                                    overwrite_x=1))
        x, info = _PBTRS(c, v, lower=0)  # less overhead than scipy's
        if info != 0:
            raise UsageError(f"HP solve failed (LAPACK info {info})")
        return np.asarray(x)


def scale_lambdas(freqs: np.ndarray, frame_time: float) -> np.ndarray:
    """HP lambdas for every scale f followed by those for f/2 (Miura eq. 4), shape (2 S,)."""
    return np.array([hp_lambda(f, frame_time) for f in np.concatenate([freqs, freqs / 2])])


def scale_minima(v: np.ndarray, bank: HPBank) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per scale: local minima of HP(v, f) and the speed descent u there (Miura eq. 4).

    `bank` holds the lambdas of `scale_lambdas`: f_i at i, f_i / 2 at S + i.
    """
    return [scale_minimum(v, bank, i) for i in range(len(bank.lams) // 2)]


def scale_minimum(v: np.ndarray, bank: HPBank, i: int) -> tuple[np.ndarray, np.ndarray]:
    """Scale i of `scale_minima`: minima of HP(v, f_i) (rest left out), and u there."""
    trend = bank.solve(v, i)
    m = local_minima(trend)
    m = m[trend[m] >= REST_SPEED]
    if len(m) == 0:  # no minimum: the f/2 trend is not needed
        return m, np.zeros(0)
    return m, np.abs(trend[m] - bank.solve(v, len(bank.lams) // 2 + i)[m])


SETTLE = HP_SETTLE

# Speeds below this (body heights per second, the norm over the 16 joints) are rest: no
# candidate and no scale minimum lies there. An exact hold (a calibration pose, a take that
# stops) leaves only rounding noise and the HP filters' ringing, whose minima are not motion:
# 3 s of stillness added ~140 candidates (nearly all of zero intensity) to every shared clip
# at 120 Hz, and their count moved Mojena's cut-off; the HP trends' ringing minima there took
# over the chains of real candidates (06_02 at 30 Hz: every key moved by a step). The slowest
# candidate of a captured take on the shared clips moves at 0.042 (49_18).
REST_SPEED = 0.02


def candidates_of(v: np.ndarray) -> np.ndarray:
    """Keypose candidates: local minima of the speed `v`, rest (`REST_SPEED`) left out."""
    m = local_minima(v)
    kept: np.ndarray = m[v[m] >= REST_SPEED]
    return kept


def settle_frames(lams: np.ndarray) -> np.ndarray:
    """Frames after which an HP filter forgets a boundary to ~1e-6 (`signal.hp_settle`)."""
    return hp_settle(lams)


REGION_MARGIN = Duration.seconds(2.0)  # DP context left of the decision zone in an update
LOOKAHEAD = Duration.seconds(1.0)  # online defaults; at 120 Hz: 120, 24, 2400 and 7200 frames
MAX_HOP = Duration.seconds(0.2)
HISTORY = Duration.seconds(20.0)
CUTOFF_HISTORY = Duration.seconds(60.0)
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


def intensities(candidates: np.ndarray, per_scale: list[tuple[np.ndarray, np.ndarray]]
                ) -> np.ndarray:
    """Intensity U of each candidate: u summed along its chain of matched minima (Miura §3.2)."""
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
        """Match the next scale's minima to the chain ends; add their u to the live chains."""
        if len(minima) != len(self.prev):  # equal lengths: each end matches its own rank
            partner = match_minima(self.prev, minima)
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
    """Ward clustering of intensities, Mojena rule one, dropped cluster -> threshold (§3.2)."""
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


def _reference_lead(skeleton: Skeleton, first: np.ndarray, second: np.ndarray) -> bool:
    """Is `first`, followed by `second`, a reference T-pose (or an all-zero dropout) frame
    rather than a captured one (`motion.detect_reference_frame`)? A sender that streams a
    whole cgspeed BVH starts with it: its one-frame jump into the take would be the largest
    speed of the stream and leave a single cluster above Mojena's cut."""
    return detect_reference_frame(skeleton, np.stack([first, second])) > 0


def _first_captured(motion: Motion) -> int:
    """`motion.first_frame`, past a reference frame there too (as `Online` skips it)."""
    first = motion.first_frame
    if motion.n_frames - first >= 2 and _reference_lead(
            motion.skeleton, motion.channels[first], motion.channels[first + 1]):
        first += 1
    return first


def _positions(motion: Motion, features: Features | None, first: int | None = None
               ) -> np.ndarray:
    feats = features if features is not None else compute_features(motion)
    p = feats.role_positions(MIURA_ROLES)[motion.first_frame if first is None else first :]
    return p.reshape(len(p), -1) / feats.body_height


def extract(motion: Motion, *, features: Features | None = None, f_c: float = 10.0,
            f_max: float = 8.0, f_min: float = 0.2, r: float = 0.95,
            mojena_k: float = 2.75,
            noise_cutoff_hz: float | None = DEFAULT_NOISE_CUTOFF_HZ) -> Keyframes:
    """Keyposes at speed minima whose multiscale intensity survives Ward + Mojena (Miura §3)."""
    _check_params(f_c, f_max, f_min, r, mojena_k)
    features = features or compute_features(motion, noise_cutoff_hz=noise_cutoff_hz)
    params: dict[str, Any] = {"f_c": f_c, "f_max": f_max, "f_min": f_min, "r": r,
                              "mojena_k": mojena_k}
    dt = motion.frame_time
    off = _first_captured(motion)
    v = speed_signal(_positions(motion, features, off), dt, f_c)
    freqs = scale_frequencies(f_max, f_min, r)
    bank = HPBank(scale_lambdas(freqs, dt))
    cand = candidates_of(v)
    u = intensities(cand, scale_minima(v, bank))
    res = mojena_threshold(u, mojena_k)
    keep = u > res.threshold
    info = {"candidates": cand + off, "intensities": u, "n_clusters": res.n_clusters,
            "level_cutoff": res.level_cutoff, "threshold": res.threshold,
            "contiguous_clusters": res.contiguous, "n_scales": len(freqs)}
    return Keyframes(METHOD, cand[keep] + off, u[keep], params, motion.n_frames, info)


# --- online (bounded lookahead: a key at frame f is sent by frame f + lookahead) -------------

class _Job:
    """One regular re-analysis, done in steps over the frames after its anchor frame.

    Everything it needs is taken at the anchor (the newest position rows, the older speeds,
    the cut-off sample), so when a step runs does not change its result; plain attributes
    (pickled with the keyframer). Steps (`Online._step`): the speed signal, its candidates and
    the HP forward passes carried over the speeds that became final; the HP trends of the
    region and their minima; the chains (intensities); Ward + Mojena and the decisions.
    `cost` is each step's estimated cost (integers, so the schedule is exact).
    """

    def __init__(self, anchor: int, zone_end: int, lo: int, base: int, g0: int,
                 rows: np.ndarray, old: np.ndarray | None, sample: np.ndarray,
                 cost: np.ndarray) -> None:
        self.anchor, self.zone_end, self.lo, self.base, self.g0 = anchor, zone_end, lo, base, g0
        self.rows, self.old, self.sample = rows, old, sample
        self.cum = np.cumsum(cost).tolist()
        self.step = 0
        self.v = self.cand = self.new = self.cut = self.total = self.minima = np.empty(0)
        self.u = np.empty(0)
        self.counts = np.zeros(0, dtype=np.int64)
        self.start = self.lo_trend = 0


class Online(OnlineKeyframer):
    """Online speed-minima keyposes: `push` frames, get keypose events within `lookahead`.

    Durations (`lookahead`, `hop`, `history`, `cutoff_history`) are `Duration`s or integer
    frame counts; the defaults are in seconds (1 s, a fifth of the lookahead but at most
    0.2 s, 20 s and 60 s: 120, 24, 2400 and 7200 frames at 120 Hz), so a stream at another
    rate sees the same motion. `lookahead` (the attribute) is the latency bound in frames.
    Every `hop` frames an analysis of the window
    (`history` + `lookahead` + `hop` frames) starts; its work is spread over the next `delay`
    frames (two thirds of the hop, fewer if the lookahead is short: four steps on four
    frames instead of a burst) and it decides the candidates whose deadline (frame + `lookahead`)
    comes before the next analysis is done. Each decision is sent when its deadline frame
    arrives, so latency_frames == lookahead for every event except those of `flush()`, which
    analyses the whole window and decides the rest (decisions not yet sent included). A
    decision sees at least lookahead - hop - delay frames after its candidate; its deadline
    is after the frame that finishes its analysis, so the analysis never holds up an event.
    `cutoff_history` frames of candidate intensities feed the Ward + Mojena cut-off; below
    `warmup_candidates` a one-cluster verdict becomes two.
    The module docstring lists what replaces each global step of the offline method.
    """

    method = METHOD

    def __init__(self, skeleton: Skeleton, fps: float, *, f_c: float = 10.0, f_max: float = 8.0,
                 f_min: float = 0.2, r: float = 0.95, mojena_k: float = 2.75,
                 lookahead: DurationLike = LOOKAHEAD, hop: DurationLike | None = None,
                 history: DurationLike = HISTORY, cutoff_history: DurationLike = CUTOFF_HISTORY,
                 warmup_candidates: int = 20, stream: str = "default",
                 role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES) -> None:
        _check_params(f_c, f_max, f_min, r, mojena_k)
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
                  "warmup_candidates": int(warmup_candidates)}
        super().__init__(skeleton, fps, lookahead=lookahead, stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params=params)
        self.f_c, self.mojena_k, self.hop = f_c, mojena_k, int(hop)
        self.history, self.cutoff_history = int(history), int(cutoff_history)
        self.warmup_candidates = int(warmup_candidates)
        # Frames an analysis is spread over; its zone ends lookahead - hop - delay frames back.
        # Two thirds of the hop: the mean online/offline F1 on the shared clips is 0.867 with
        # no spread, 0.856 / 0.854 / 0.853 / 0.849 spread over 8 / 12 / 16 / 23 frames.
        self.delay = max(0, min(2 * self.hop // 3, self.lookahead - self.hop - 2))
        self._joints = [self.features.roles[name] for name in MIURA_ROLES]
        self._height = self.features.body_height
        self._lams = scale_lambdas(scale_frequencies(f_max, f_min, r), 1.0 / self.fps)
        # Region re-analysed by a regular update: the lookahead plus room for the DP context.
        self._region = self.lookahead + 2 * self.hop + whole_frames(REGION_MARGIN, self.fps)
        self._pos_settle = int(settle_frames(np.array([hp_lambda(f_c, 1.0 / self.fps)]))[0])
        # Speeds redone by a regular update: those a frame of the last hop can still change.
        self._fresh = min(self._region, self.hop + self._pos_settle + 1)
        self._ring = RingWindow(self.history + self.lookahead + self.hop + 2, 3 * len(MIURA_ROLES))
        self._bank = HPBank(self._lams)
        packed_factors(self._lams)  # built now (shared, derived), not on a streaming frame
        self._work = _WorkRows()
        self.reset()

    def _reset_carry(self, base: int) -> None:
        """HP forward passes start afresh at window speed `base` (global numbering)."""
        self._hp_base = base  # the carried systems' first row: this speed
        self._hp_done = 0  # rows carried (forward values of the last ones in `_hp_y`)
        self._hp_y = np.zeros((self._region + 4, len(self._lams)))

    def reset(self) -> None:
        """Forget the window and the cut-off history; keep parameters."""
        self._ring.clear()
        self._count = 0
        self._analysis_due = False
        self._last_seq = 0
        self._scheduled_upto: int | None = None  # candidates <= this have a decision
        self._scheduled: deque[tuple[int, float, bool]] = deque()  # (frame, U, keep) not sent
        self._v = np.empty(0)
        self._hist_seq: deque[int] = deque()
        self._hist_u: deque[float] = deque()
        self._job: _Job | None = None
        self._resume_after: int | None = None  # last seq before a restart (history kept)
        self._pending: list[tuple[int, float, float]] = []  # provisional hook
        self._g0 = 0  # speeds dropped from the window since the reset
        self._lead_pending = True  # the stream's first frame is not yet known to be captured
        self._lead: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._reset_carry(0)

    def restart(self, keep_statistics: bool = True) -> None:
        """A new window after a long gap or a source restart (after `finish()`): the cut-off
        history (candidate intensities of the last `cutoff_history` frames) is kept, so the
        Ward + Mojena cut-off needs no second warm-up. Without it: `reset()`."""
        kept = self._hist_seq, self._hist_u, self._last_seq
        self.reset()
        if keep_statistics:
            self._hist_seq, self._hist_u, self._resume_after = kept

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Append frames, doing each frame's share of the running analysis; every `hop`
        frames start the next one. The block's last frame leaves its share to `idle`."""
        rows = block.pelvis_points(self._joints).reshape(len(block), -1) / self._height
        seqs, times = np.asarray(block.seq), np.asarray(block.time)
        if self._lead_pending:  # the stream's first frame waits for its second
            if self._lead is None and len(block):
                self._lead = (rows[:1].copy(), seqs[:1].copy(), times[:1].copy(),
                              np.array(block.channels[0], dtype=np.float64))
                rows, seqs, times = rows[1:], seqs[1:], times[1:]
                channels = block.channels[1:]
            else:
                channels = block.channels
            if not len(rows):
                return []
            lead, self._lead, self._lead_pending = self._lead, None, False
            assert lead is not None
            if not _reference_lead(self.skeleton, lead[3], channels[0]):
                rows = np.concatenate([lead[0], rows])
                seqs, times = np.concatenate([lead[1], seqs]), np.concatenate([lead[2], times])
        return self._ingest(rows, seqs, times)

    def _ingest(self, rows: np.ndarray, seqs: np.ndarray, times: np.ndarray
                ) -> list[KeyframeEvent]:
        """`process` on the rows kept (the stream's reference frame left out)."""
        if self._resume_after is not None and len(rows):
            shift = int(seqs[0]) - 1 - self._resume_after
            if shift < 0:  # the source started over: the kept history stays in the past
                self._hist_seq = deque(seq + shift for seq in self._hist_seq)
            self._resume_after = None
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
            if self._scheduled:
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
        return self._emit() if self._scheduled else []

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: analyse the whole window and decide every candidate not yet sent.

        Decisions scheduled but not sent (their frame + lookahead never arrived) are redone
        with the whole window, like everything else still pending; so is a running analysis.
        """
        events = self.idle()  # normally already run by the driver
        if self._lead is not None:  # a one-frame stream: its frame is all there is
            lead, self._lead, self._lead_pending = self._lead, None, False
            events += self._ingest(lead[0], lead[1], lead[2]) + self.idle()
        self._job = None
        if not len(self._ring):
            return events
        self._scheduled.clear()
        t = self._last_seq
        if self._scheduled_upto is not None:  # what was sent: candidates <= t - lookahead
            self._scheduled_upto = min(self._scheduled_upto, t - self.lookahead)
        base = self._ring.first_seq
        v = self._speed()
        cand = candidates_of(v)
        u = intensities(cand, scale_minima(v, self._bank))
        seqs = cand + base
        new = seqs > (base - 1 if self._scheduled_upto is None else self._scheduled_upto)
        self._scheduled_upto = t
        if not np.any(new):
            return events
        threshold = self._threshold(np.concatenate([self._history(t), u[new]]), final=True)
        self._hist_seq.extend(seqs[new].tolist())  # decided: history for a restart
        self._hist_u.extend(u[new].tolist())
        return events + [self.event(int(c), self._ring.time(int(c)), float(x), t)
                         for c, x in zip(seqs[new], u[new], strict=True) if x > threshold]

    def _emit(self) -> list[KeyframeEvent]:
        """Send the scheduled decisions whose frame + lookahead has arrived (their deadline)."""
        events = []
        while self._scheduled and self._scheduled[0][0] + self.lookahead <= self._last_seq:
            c, u, keep = self._scheduled.popleft()
            self._hist_seq.append(c)
            self._hist_u.append(u)
            if keep:
                events.append(self.event(c, self._ring.time(c), u, c + self.lookahead))
        return events

    def _schedule(self) -> None:
        """Start the analysis deciding the candidates whose deadline comes after it is done
        (`delay` frames from now) and before the next one is."""
        if self._job is not None:  # only when delay >= hop: never with the checked parameters
            self._advance(self._job.anchor + self.delay)
        t = self._last_seq
        zone_end = t + self.hop + self.delay - self.lookahead
        if zone_end < self._ring.first_seq or (self._scheduled_upto is not None
                                               and zone_end <= self._scheduled_upto):
            return  # nothing is due yet
        # The speeds older than the newest `_fresh` are final (to ~1e-6): kept, not redone.
        rows = self._ring.rows()
        n = len(rows)
        seg = self._fresh + self._pos_settle
        old: np.ndarray | None = self._v[self._ring.dropped_since :][: n - 1 - self._fresh]
        if n <= seg or old is None or len(old) < n - 1 - self._fresh:
            snap, old = rows.copy(), None
        else:
            snap = rows[n - seg :].copy()
        self._g0 += self._ring.dropped_since
        self._ring.dropped_since = 0
        # Decided (sent or not) in the last `cutoff_history` frames: intensities as decided.
        sample = np.concatenate([self._history(t), [u for _, u, _ in self._scheduled]])
        # Step costs, ~µs (measured at the defaults: speed signal, HP trends, chains,
        # Ward + Mojena and decisions).
        cost = np.array([50 if old is not None else 50 + len(snap) // 4,
                         40 + min(self._region, n) // 4, 40, 60 + len(sample) // 8])
        lo = self._ring.first_seq - 1 if self._scheduled_upto is None else self._scheduled_upto
        self._job = _Job(self._count, zone_end, lo, self._ring.first_seq, self._g0, snap, old,
                         sample, cost)
        self._advance(self._count)

    def _advance(self, count: int) -> None:
        """Run the running analysis' steps due by frame `count` (its share per frame)."""
        job = self._job
        if job is None or (count <= job.anchor and self.delay > 0):
            return
        k, total = count - job.anchor, job.cum[-1]
        while self._job is job and (k >= self.delay
                                    or job.cum[job.step] * self.delay <= total * k):
            self._step(job)

    def _step(self, job: _Job) -> None:
        """Run the next step of the analysis `job`."""
        s = len(self._lams) // 2
        i = job.step
        job.step += 1
        if i == 0:  # speed signal, candidates, the HP forward passes over final speeds
            if job.old is None:
                v = speed_signal(job.rows, 1.0 / self.fps, self.f_c)
            else:
                v = np.concatenate([job.old, speed_tail(job.rows, 1.0 / self.fps, self.f_c,
                                                        self._fresh)])
            self._v = job.v = v
            job.start = max(0, len(v) - self._region)
            job.lo_trend = max(job.start - 1, 0)  # a minimum needs its left neighbour
            job.cand = candidates_of(v[job.lo_trend :]) + job.lo_trend
            g0 = job.g0 - self._hp_base
            if self._hp_done < g0:  # the window outran the carried passes (tiny windows)
                self._reset_carry(job.g0)
                g0 = 0
            upto = g0 + len(v) - self._fresh  # the speeds older than `_fresh` are final
            if upto > self._hp_done:
                self._hp_done = hp_advance(v, g0, self._hp_done, upto, self._hp_y,
                                           *packed_factors(self._lams))
        elif i == 1:  # HP trends of the region, every scale; their minima
            v, g0 = job.v, job.g0 - self._hp_base
            if g0 + len(v) >= 5:
                pre, off, conv = packed_factors(self._lams)
                rows = g0 + len(v) - min(g0 + job.lo_trend, self._hp_done)
                trends = hp_tail(v, g0, job.lo_trend, self._hp_done, self._hp_y, pre, off,
                                 conv, self._lams, self._work.get(rows, len(self._lams)))
            else:  # a system too short for the corner formulas (g0 is 0): whole solves
                trends = np.stack([self._bank.solve(v, j)[job.lo_trend :]
                                   for j in range(2 * s)], axis=1)
            job.minima, job.u, job.counts = tail_minima(trends, s, job.lo_trend, job.start,
                                                        REST_SPEED)
        elif i == 2:  # the chains: intensities
            job.total = chain_totals(job.cand, job.minima, job.u, job.counts, BAND_BUDGET)
            if len(job.total) != len(job.cand):  # long lookaheads: the windowed DP
                cuts = np.cumsum(job.counts)[:-1]
                job.total = intensities(job.cand, list(zip(np.split(job.minima, cuts),
                                                           np.split(job.u, cuts), strict=True)))
        else:  # Ward + Mojena, the decisions
            self._scheduled_upto = job.zone_end
            self._job = None
            u, seqs = job.total, job.cand + job.base
            new = (seqs > job.lo) & (seqs <= job.zone_end)
            if np.any(new):
                cut = np.concatenate([job.sample, u[new], u[seqs > job.zone_end]])
                threshold = self._threshold(cut, False)
                self._scheduled.extend(zip(seqs[new].tolist(), u[new].tolist(),
                                           (u[new] > threshold).tolist(), strict=True))
                ahead = (seqs > job.zone_end) & (u > threshold)
                self._pending = [(c, self._ring.time(c), x) for c, x in  # provisional hook
                                 zip(seqs[ahead].tolist(), u[ahead].tolist(), strict=True)]

    def _speed(self) -> np.ndarray:
        """Speed over the whole window (at flush)."""
        self._v = speed_signal(self._ring.rows(), 1.0 / self.fps, self.f_c)
        self._ring.dropped_since = 0
        return self._v

    def _history(self, t: int) -> np.ndarray:
        """Intensities (as decided) of the candidates sent in the last `cutoff_history` frames
        before frame t - lookahead."""
        while self._hist_seq and self._hist_seq[0] < t - self.lookahead - self.cutoff_history:
            self._hist_seq.popleft()
            self._hist_u.popleft()
        return np.fromiter(self._hist_u, float, len(self._hist_u))

    def _threshold(self, sample: np.ndarray, final: bool) -> float:
        """Ward + Mojena threshold over a cut-off sample: the candidates decided in the last
        `cutoff_history` frames (intensities as decided), the ones being decided and the
        window's pending ones (current intensities)."""
        res = mojena_threshold(sample, self.mojena_k)
        if res.n_clusters == 1 and not final and len(sample) < self.warmup_candidates:
            return _two_cluster_threshold(sample)
        return res.threshold

    def candidates(self) -> list[tuple[int, float, float]]:
        """Provisional hook: keys decided but not yet sent, and the window's later minima
        whose intensity clears the cut-off at the last analysis."""
        t = self._last_seq - self.lookahead
        return ([(c, self._ring.time(c), u) for c, u, keep in self._scheduled if keep]
                + [p for p in self._pending if p[0] > t])


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


def _two_cluster_threshold(u: np.ndarray) -> float:
    """Warm-up cut-off: Ward forced to two clusters, the one with the smallest value dropped."""
    if len(u) < 2 or np.all(u == u[0]):
        return 0.0
    z = linkage(u.reshape(-1, 1), method="ward")
    labels = fcluster(z, 2, criterion="maxclust")
    return float(u[labels == labels[np.argmin(u)]].max())
