"""Adaptive speed-minima keyposes — Miura et al. 2014 (seed 002, §3; DESIGN §4.2, §5).

Offline: `extract(motion)`. Definitions this module settles (the paper leaves them open):

- Speed (Miura eq. 3): the 16 joints of `MIURA_ROLES` in the pelvis frame, divided by body
  height, stacked into one 48-vector p(n) per captured frame and HP-filtered at f_c (eq. 2);
  v(n) = |p_F(n+1) - p_F(n)| / dt, the Euclidean norm over all 48 coordinates (eq. 3). v has
  one value fewer than the motion has captured frames and v(n) is reported at frame n (the
  first frame of the forward difference).
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

Online (`Online`): every `hop` frames the window (the last `history + lookahead + hop` frames)
is re-analysed and the candidates whose deadline (frame + lookahead) falls before the next
analysis are decided; a decision is sent when its deadline frame arrives (latency_frames ==
lookahead), and `flush()` redoes whatever was not sent yet. Windowed replacements of the
offline global steps:

- HP filters over the whole clip -> HP filters over the window. A regular update re-analyses
  only the newest `lookahead + 2 hop + 240` frames: the 10 Hz position filter is redone on that
  part plus its settling length (older speeds are final), and each scale f is solved on that
  part plus 20 lambda^(1/4) frames (the filter's memory; capped by the window, so the 0.1 Hz
  filter sees 20 s), minima outside the part are ignored. The Cholesky factors are computed
  once per lambda (`HPBank`).
- Candidate correspondence over the whole clip -> the same DP over the re-analysed part.
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

Memory is bounded by the window (positions, speeds), the Cholesky factors (one per lambda at
window length, ~9 MB with the defaults, plus one copy per lambda at the length it is solved
at) and the cut-off sample (the candidates of `cutoff_history` frames).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.cluster.hierarchy import fcluster, linkage
from scipy.linalg import cholesky_banded, get_lapack_funcs

from ..errors import UsageError
from ..features import Features, compute_features
from ..keyframes import KeyframeEvent, Keyframes
from ..motion import Motion, Skeleton
from ..online import DEFAULT_MAX_BRIDGE_FRAMES, FeatureBlock, OnlineKeyframer
from ..roles import MIURA_ROLES
from ..signal import hp_banded, hp_filter, hp_lambda, local_minima

__all__ = ["extract", "scale_frequencies", "speed_signal", "HPBank", "scale_minima",
           "match_minima", "intensities", "mojena_threshold", "MojenaResult", "METHOD", "Online",
           "scale_lambdas", "settle_frames", "ward_1d", "WARD_1D_FROM"]

METHOD = "speed"
_PBTRS = get_lapack_funcs("pbtrs", (np.empty(1),))


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
    return np.linalg.norm(np.diff(pf, axis=0), axis=1) / frame_time


class HPBank:
    """Cholesky factors of the HP systems I + lam D'D for several lambdas, for any length.

    The upper banded factor of the length-n system agrees, bit for bit, with that of any longer
    one in its first n - 2 columns (LAPACK's banded Cholesky only looks back); the last two
    columns carry the bottom corner (D'D has 5 and 1 there) and are finished here by the same
    arithmetic every time. So one factorisation at `capacity` serves every window length up to
    it, and the offline method (capacity = n) and the online keyframer get identical numbers.
    With `keep` (online) factors are kept for reuse; without (offline), each is used once.
    """

    def __init__(self, lams: np.ndarray, capacity: int, keep: bool = False) -> None:
        self.lams = np.asarray(lams, dtype=np.float64)
        self.keep = keep
        self._build(int(capacity))

    def _build(self, capacity: int) -> None:
        self.capacity = capacity
        self._prefix: list[np.ndarray | None] = [None] * len(self.lams)
        self._cache: dict[int, tuple[int, np.ndarray]] = {}

    def reserve(self, n: int, limit: int) -> None:
        """Grow the capacity (doubling, at most `limit`) until length n fits."""
        if n > self.capacity:
            self._build(max(n, min(2 * self.capacity, limit)))

    def factor(self, n: int, i: int) -> np.ndarray:
        """Upper banded Cholesky factor (3, n) of the length-n HP system for lambda i."""
        got = self._cache.get(i)
        if got is not None and got[0] == n:
            return got[1]
        c = self._factor(n, i)
        if self.keep:  # one length per lambda: after warm-up each lambda asks for one length
            self._cache[i] = (n, c)
        return c

    def _factor(self, n: int, i: int) -> np.ndarray:
        lam = float(self.lams[i])
        if n < 5:
            return cholesky_banded(hp_banded(n, lam), check_finite=False)
        if n > self.capacity:
            raise UsageError(f"HPBank of capacity {self.capacity} asked for length {n}")
        prefix = self._prefix[i]
        if prefix is None:
            prefix = cholesky_banded(hp_banded(self.capacity + 2, lam), check_finite=False)
            if self.keep:
                self._prefix[i] = prefix
        c = np.empty((3, n))
        c[:, : n - 2] = prefix[:, : n - 2]
        c[:2, n - 2 :] = prefix[:2, n - 2 : n]
        # Bottom corner rows n-2, n-1 of I + lam D'D: 1 + 5 lam, -2 lam, 1 + lam.
        u0, u1 = c[0, n - 2], c[1, n - 2]          # U[n-4, n-2], U[n-3, n-2]
        v0 = c[0, n - 1]                            # U[n-3, n-1]
        d2 = np.sqrt((1.0 + 5.0 * lam) - u0 * u0 - u1 * u1)
        e = ((-2.0 * lam) - u1 * v0) / d2
        c[2, n - 2], c[1, n - 1] = d2, e
        c[2, n - 1] = np.sqrt((1.0 + lam) - v0 * v0 - e * e)
        return c

    def solve(self, v: np.ndarray, i: int) -> np.ndarray:
        """HP trend of the 1-D signal `v` for the i-th lambda."""
        v = np.asarray(v, dtype=np.float64)
        if len(v) < 3:
            return v.copy()
        x, info = _PBTRS(self.factor(len(v), i), v, lower=0)  # cho_solve_banded, less overhead
        if info != 0:
            raise UsageError(f"HP solve failed (LAPACK info {info})")
        return np.asarray(x)


def scale_lambdas(freqs: np.ndarray, frame_time: float) -> np.ndarray:
    """HP lambdas for every scale f followed by those for f/2 (Miura eq. 4), shape (2 S,)."""
    return np.array([hp_lambda(f, frame_time) for f in np.concatenate([freqs, freqs / 2])])


def scale_minima(v: np.ndarray, bank: HPBank, lengths: np.ndarray | None = None,
                 start: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per scale: local minima of HP(v, f) and the speed descent u there (Miura eq. 4).

    `bank` holds the lambdas of `scale_lambdas`: f_i at i, f_i / 2 at S + i. Online, lambda j
    is solved on the last `lengths[j]` samples only and minima before `start` are ignored.
    """
    n, s = len(v), len(bank.lams) // 2
    tail = np.full(2 * s, n) if lengths is None else np.minimum(lengths, n)
    out = []
    for i in range(s):
        a, b = n - tail[i], n - tail[s + i]
        trend = bank.solve(v[a:], i)
        m = local_minima(trend) + a
        m = m[m >= start]
        if len(m) == 0:  # no minimum in the part that counts: the f/2 trend is not needed
            out.append((m, np.zeros(0)))
            continue
        out.append((m, np.abs(trend[m - a] - bank.solve(v[b:], s + i)[m - b])))
    return out


SETTLE = 20.0  # time constants an HP filter needs to forget a boundary (e^(-20/sqrt 2) ~ 7e-7)


def settle_frames(lams: np.ndarray) -> np.ndarray:
    """Frames after which an HP filter forgets a boundary to ~1e-6: SETTLE time constants.

    The HP smoother's impulse response decays with time constant lambda^(1/4) frames.
    """
    return np.ceil(SETTLE * np.asarray(lams) ** 0.25).astype(int) + 8


REGION_MARGIN = 240  # frames of DP context left of the decision zone in a regular update
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
    return np.arange(len(short)) + _band_dp(long_, short)


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

    Column-wise over the band offset d, vectorised over j: C[j, d] = c[j, d] + min(M[j-1, d-1],
    C[j-1, d]) with M the running minimum over d; the recurrence x_j = c_j + min(b_j, x_{j-1})
    is solved in closed form with cumulative sums and a cumulative minimum (integer costs, exact).
    `arg[d, j]` is the first offset <= d reaching M[j, d]; backtracking follows it.
    """
    p, k = len(short), len(long_) - len(short)
    arg = np.empty((k + 1, p), dtype=np.int64)
    m_prev = np.full(p, np.inf)
    arg_prev = np.zeros(p, dtype=np.int64)
    b = np.empty(p)
    for d in range(k + 1):
        c = np.abs(long_[d : d + p] - short).astype(np.float64)
        b[0] = 0.0
        b[1:] = m_prev[:-1]
        s = np.cumsum(c)
        x = s + np.minimum.accumulate(b - (s - c))
        better = x < m_prev  # strict: ties keep the smaller offset (earlier partner)
        arg_prev = np.where(better, d, arg_prev)
        m_prev = np.where(better, x, m_prev)
        arg[d] = arg_prev
    offsets = np.empty(p, dtype=np.int64)
    flat = arg.ravel()
    hi = k
    for j in range(p - 1, -1, -1):
        hi = int(flat[hi * p + j])
        offsets[j] = hi
    return offsets


def intensities(candidates: np.ndarray, per_scale: list[tuple[np.ndarray, np.ndarray]]
                ) -> np.ndarray:
    """Intensity U of each candidate: u summed along its chain of matched minima (Miura §3.2)."""
    total = np.zeros(len(candidates))
    chain = np.arange(len(candidates))
    prev = np.asarray(candidates)
    alive = np.ones(len(candidates), dtype=bool)
    for minima, u in per_scale:
        partner = match_minima(prev, minima)
        chain = np.where(alive, partner[np.where(alive, chain, 0)] if len(prev) else -1, -1)
        alive = chain >= 0
        total[alive] += u[chain[alive]]
        prev = minima
    return total


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
    = 2 d, scipy's squared heights, computed directly instead of by Lance-Williams updates.
    """
    import heapq

    order = np.argsort(u, kind="stable")
    v = u[order].tolist()
    n = len(v)
    size, total = [1.0] * n, list(v)
    left, right = list(range(-1, n - 1)), list(range(1, n + 1))
    alive = [True] * n
    heap = [(0.5 * (v[i + 1] - v[i]) ** 2, i, i + 1, 2.0) for i in range(n - 1)]
    heapq.heapify(heap)
    alpha, bounds = np.empty(n - 1), np.empty(n - 1, dtype=np.int64)
    done = 0
    while done < n - 1:
        d, a, b, both = heapq.heappop(heap)
        if not (alive[a] and alive[b]) or right[a] != b or size[a] + size[b] != both:
            continue  # stale: one side has grown since
        alpha[done], bounds[done] = 2.0 * d, b
        done += 1
        # b joins a (clusters are runs of sorted positions named by their first one)
        alive[b] = False
        size[a] += size[b]
        total[a] += total[b]
        right[a] = right[b]
        if right[a] < n:
            left[right[a]] = a
        for x, y in ((left[a], a), (a, right[a])):
            if 0 <= x and y < n:
                nx, ny = size[x], size[y]
                diff = total[x] / nx - total[y] / ny
                heapq.heappush(heap, (nx * ny / (nx + ny) * diff * diff, x, y, nx + ny))
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
        merged = np.zeros(len(u), dtype=bool)  # boundary before sorted position i merged
        cut = alpha[len(u) - 1 - n_clusters]
        merged[bounds[alpha <= cut]] = True
        labels = np.empty(len(u), dtype=np.int64)
        labels[order] = np.cumsum(~merged) - 1
    else:
        labels = fcluster(z, z[len(u) - 1 - n_clusters, 2], criterion="distance") - 1
    zero = np.flatnonzero(u == 0)
    if len(zero):
        drop = labels[zero[0]]
    else:
        means = np.bincount(labels, weights=u) / np.bincount(labels)
        drop = int(np.argmin(means))
    threshold = float(u[labels == drop].max())
    contiguous = bool(np.all((u > threshold) == (labels != drop)))
    return MojenaResult(threshold, n_clusters, cutoff, contiguous)


def _positions(motion: Motion, features: Features | None) -> np.ndarray:
    feats = features if features is not None else compute_features(motion)
    p = feats.role_positions(MIURA_ROLES)[motion.first_frame :]
    return p.reshape(len(p), -1) / feats.body_height


def extract(motion: Motion, *, features: Features | None = None, f_c: float = 10.0,
            f_max: float = 8.0, f_min: float = 0.2, r: float = 0.95,
            mojena_k: float = 2.75) -> Keyframes:
    """Keyposes at speed minima whose multiscale intensity survives Ward + Mojena (Miura §3)."""
    _check_params(f_c, f_max, f_min, r, mojena_k)
    params: dict[str, Any] = {"f_c": f_c, "f_max": f_max, "f_min": f_min, "r": r,
                              "mojena_k": mojena_k}
    dt = motion.frame_time
    v = speed_signal(_positions(motion, features), dt, f_c)
    freqs = scale_frequencies(f_max, f_min, r)
    bank = HPBank(scale_lambdas(freqs, dt), len(v))
    cand = local_minima(v)
    u = intensities(cand, scale_minima(v, bank))
    res = mojena_threshold(u, mojena_k)
    keep = u > res.threshold
    off = motion.first_frame
    info = {"candidates": cand + off, "intensities": u, "n_clusters": res.n_clusters,
            "level_cutoff": res.level_cutoff, "threshold": res.threshold,
            "contiguous_clusters": res.contiguous, "n_scales": len(freqs)}
    return Keyframes(METHOD, cand[keep] + off, u[keep], params, motion.n_frames, info)


# --- online (DESIGN §5) ----------------------------------------------------------------------

class _Ring:
    """Rows of the last `capacity` frames (positions and times), amortised O(1) append."""

    def __init__(self, capacity: int, width: int) -> None:
        self.capacity = capacity
        self.width = width
        self.clear()

    def clear(self) -> None:
        """Forget every row."""
        self._rows = np.empty((0, self.width))
        self._times = np.empty(0)
        self._start = self._end = 0
        self.first_seq = 0
        self.dropped_since = 0

    def __len__(self) -> int:
        return self._end - self._start

    def extend(self, first_seq: int, rows: np.ndarray, times: np.ndarray) -> None:
        """Append consecutive frames starting at `first_seq`; drop the oldest beyond capacity."""
        if len(self) == 0:
            self.first_seq = first_seq
        need = len(self) + len(rows)
        if self._end + len(rows) > len(self._rows):
            size = max(16, min(2 * self.capacity, 2 * need))
            keep = slice(self._start, self._end)
            rows_new = np.empty((max(size, need), self.width))
            times_new = np.empty(len(rows_new))
            rows_new[: len(self)] = self._rows[keep]
            times_new[: len(self)] = self._times[keep]
            self._rows, self._times = rows_new, times_new
            self._start, self._end = 0, len(self)
        self._rows[self._end : self._end + len(rows)] = rows
        self._times[self._end : self._end + len(rows)] = times
        self._end += len(rows)
        drop = max(0, len(self) - self.capacity)
        self._start += drop
        self.first_seq += drop
        self.dropped_since += drop

    def rows(self) -> np.ndarray:
        """The held rows, oldest first (a view)."""
        return self._rows[self._start : self._end]

    def time(self, seq: int) -> float:
        """Time of held frame `seq`."""
        return float(self._times[self._start + seq - self.first_seq])


class Online(OnlineKeyframer):
    """Online speed-minima keyposes: `push` frames, get keypose events within `lookahead`.

    Every `hop` frames (default lookahead // 5, at most 24) the window (`history` +
    `lookahead` + `hop` frames) is re-analysed and the candidates whose deadline (frame +
    `lookahead`) comes before the next analysis are decided; each decision is sent when its
    deadline frame arrives, so latency_frames == lookahead for every event except those of
    `flush()`, which analyses the whole window and decides the rest (decisions not yet sent
    included). A decision sees at least lookahead - hop frames after its candidate; its
    deadline is never the analysis frame itself (after warm-up), so a re-analysis does not
    hold up the event it decides.
    `cutoff_history` frames of candidate intensities feed the Ward + Mojena cut-off; below
    `warmup_candidates` a one-cluster verdict becomes two.
    The module docstring lists what replaces each global step of the offline method.
    """

    method = METHOD

    def __init__(self, skeleton: Skeleton, fps: float, *, f_c: float = 10.0, f_max: float = 8.0,
                 f_min: float = 0.2, r: float = 0.95, mojena_k: float = 2.75,
                 lookahead: int = 120, hop: int | None = None, history: int = 2400,
                 cutoff_history: int = 7200, warmup_candidates: int = 20,
                 stream: str = "default", role_mapping: dict[str, str] | None = None,
                 max_bridge_frames: int = DEFAULT_MAX_BRIDGE_FRAMES) -> None:
        _check_params(f_c, f_max, f_min, r, mojena_k)
        _check_count("lookahead", lookahead, 3)
        if hop is None:  # a fifth of the lookahead, at most 0.2 s at 120 fps
            hop = max(1, min(24, int(lookahead) // 5))
        _check_count("hop", hop, 1)
        _check_count("lookahead", lookahead, int(hop) + 2)
        _check_count("history", history, 0)
        _check_count("cutoff_history", cutoff_history, 0)
        _check_count("warmup_candidates", warmup_candidates, 0)
        params = {"f_c": f_c, "f_max": f_max, "f_min": f_min, "r": r, "mojena_k": mojena_k,
                  "hop": int(hop), "history": int(history),
                  "cutoff_history": int(cutoff_history),
                  "warmup_candidates": int(warmup_candidates)}
        super().__init__(skeleton, fps, lookahead=int(lookahead), stream=stream,
                         role_mapping=role_mapping, max_bridge_frames=max_bridge_frames,
                         params=params)
        self.f_c, self.mojena_k, self.hop = f_c, mojena_k, int(hop)
        self.history, self.cutoff_history = int(history), int(cutoff_history)
        self.warmup_candidates = int(warmup_candidates)
        self._joints = [self.features.roles[name] for name in MIURA_ROLES]
        self._height = self.features.body_height
        self._lams = scale_lambdas(scale_frequencies(f_max, f_min, r), 1.0 / self.fps)
        # Region re-analysed by a regular update: the lookahead plus room for the DP context.
        self._region = self.lookahead + 2 * self.hop + REGION_MARGIN
        self._lengths = self._region + settle_frames(self._lams)
        self._pos_settle = int(settle_frames(np.array([hp_lambda(f_c, 1.0 / self.fps)]))[0])
        self._ring = _Ring(self.history + self.lookahead + self.hop + 2, 3 * len(MIURA_ROLES))
        self._bank = HPBank(self._lams, min(self._ring.capacity, 1024), keep=True)
        self.reset()

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
        self._pending: list[tuple[int, float, float]] = []  # provisional hook

    def process(self, block: FeatureBlock) -> list[KeyframeEvent]:
        """Append frames; every `hop` frames re-analyse the window and decide what is due."""
        rows = block.pelvis_positions[:, self._joints].reshape(len(block), -1) / self._height
        events: list[KeyframeEvent] = []
        i = 0
        while i < len(block):
            take = min(len(block) - i, self.hop - self._count % self.hop)
            self._ring.extend(int(block.seq[i]), rows[i : i + take], block.time[i : i + take])
            self._count += take
            i += take
            self._last_seq = int(block.seq[i - 1])
            events.extend(self._emit())
            if self._count % self.hop == 0:
                if i < len(block):
                    self._schedule()
                    events.extend(self._emit())
                else:  # the block's last frame: re-analyse in `idle`, after due events left
                    self._analysis_due = True
        return events

    def idle(self) -> list[KeyframeEvent]:
        """The re-analysis deferred from the last `process` (same frame, same decisions)."""
        if not self._analysis_due:
            return []
        self._analysis_due = False
        self._schedule()
        return self._emit()

    def finish(self) -> list[KeyframeEvent]:
        """End of stream: analyse the whole window and decide every candidate not yet sent.

        Decisions scheduled but not sent (their frame + lookahead never arrived) are redone
        with the whole window, like everything else still pending.
        """
        events = self.idle()  # normally already run by the driver
        if not len(self._ring):
            return events
        self._scheduled.clear()
        t = self._last_seq
        if self._scheduled_upto is not None:  # what was sent: candidates <= t - lookahead
            self._scheduled_upto = min(self._scheduled_upto, t - self.lookahead)
        u, seqs, new = self._analyse(t, final=True)
        if not np.any(new):
            return events
        threshold = self._cutoff(u[new], u[seqs > t], t, final=True)
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
        """Decide the candidates whose deadline comes before the next update; send at deadline."""
        t = self._last_seq
        zone_end = t + self.hop - self.lookahead
        if zone_end < self._ring.first_seq or (self._scheduled_upto is not None
                                               and zone_end <= self._scheduled_upto):
            return  # nothing is due yet
        u, seqs, new = self._analyse(zone_end, final=False)
        if np.any(new):
            threshold = self._cutoff(u[new], u[seqs > zone_end], t, final=False)
            self._scheduled.extend(zip(seqs[new].tolist(), u[new].tolist(),
                                       (u[new] > threshold).tolist(), strict=True))
            ahead = (seqs > zone_end) & (u > threshold)
            self._pending = [(c, self._ring.time(c), x) for c, x in
                             zip(seqs[ahead].tolist(), u[ahead].tolist(), strict=True)]

    def _analyse(self, zone_end: int, final: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Intensities of the window's candidates; mask of those in (scheduled, zone_end]."""
        base = self._ring.first_seq
        v = self._speed(final)
        self._bank.reserve(len(v), self._ring.capacity)
        start = 0 if final else max(0, len(v) - self._region)
        cand = local_minima(v)
        cand = cand[cand >= start]
        u = intensities(cand, scale_minima(v, self._bank, None if final else self._lengths,
                                           start))
        seqs = cand + base
        lo = base - 1 if self._scheduled_upto is None else self._scheduled_upto
        self._scheduled_upto = zone_end
        return u, seqs, (seqs > lo) & (seqs <= zone_end)

    def _speed(self, final: bool) -> np.ndarray:
        """Speed over the window: whole-window HP at flush, else only the newest part redone.

        The 10 Hz HP forgets a boundary within `_pos_settle` frames, so speeds older than the
        re-analysed region are final (to ~1e-6) and kept from the previous update.
        """
        rows, dt = self._ring.rows(), 1.0 / self.fps
        n = len(rows)
        seg = self._region + self._pos_settle
        if final or n <= seg or len(self._v) == 0:
            self._v = speed_signal(rows, dt, self.f_c)
        else:
            fresh = speed_signal(rows[n - seg :], dt, self.f_c)[-self._region :]
            old = self._v[self._ring.dropped_since :]  # aligned with the window's first frame
            self._v = np.concatenate([old[: n - 1 - self._region], fresh])
        self._ring.dropped_since = 0
        return self._v

    def _cutoff(self, u: np.ndarray, pending: np.ndarray, t: int, final: bool) -> float:
        """Ward + Mojena threshold over the candidate intensities of the last `cutoff_history`.

        The sample: every candidate sent in the last `cutoff_history` frames (intensity as
        decided), the ones being decided and the window's pending ones (current intensities).
        """
        while self._hist_seq and self._hist_seq[0] < t - self.lookahead - self.cutoff_history:
            self._hist_seq.popleft()
            self._hist_u.popleft()
        sample = np.concatenate([np.fromiter(self._hist_u, float, len(self._hist_u)), u,
                                 pending])
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


def _two_cluster_threshold(u: np.ndarray) -> float:
    """Warm-up cut-off: Ward forced to two clusters, the one with the smallest value dropped."""
    if len(u) < 2 or np.all(u == u[0]):
        return 0.0
    z = linkage(u.reshape(-1, 1), method="ward")
    labels = fcluster(z, 2, criterion="maxclust")
    return float(u[labels == labels[np.argmin(u)]].max())
