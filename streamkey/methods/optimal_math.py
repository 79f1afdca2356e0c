"""Pure maths of optimal keys (DESIGN §4.5): segment costs from prefix sums and the dynamic
programme over them. Shared by `streamkey.methods.optimal` (offline and online) and by
`--max-gap`; its module docstring states the definitions settled here. No I/O; the one
stateful piece (`Pricer`) holds plain arrays.

The curve is x (one row per captured frame, D columns); the cost of a segment (a, b) is
Σ_{a<f<b} |x_f − x_a − (f−a)/(b−a) (x_b − x_a)|². With prefix sums of x, f·x and |x|² over a
window this costs O(D) per segment; `Pricer` prices every segment ending in a chunk of
frames with four matrix products (never materialising a segment).
"""

from __future__ import annotations

import numpy as np

from ..jit import kernel, warmer
from ..kinematics import root_relative_joints

__all__ = ["CHUNK", "EPOCH", "Pricer", "point_scale", "body_rows", "band_costs", "pair_costs",
           "chain_costs", "dp_rows", "chain", "best_split", "fill_gaps"]

CHUNK = 16  # frames priced together (online: the DP runs when a chunk of frames is complete)
EPOCH = 512  # frames between re-based prefix sums (a multiple of CHUNK)


def point_scale(n_joints: int, height: float, weights: np.ndarray | None = None,
                root_translation: bool = False) -> np.ndarray:
    """Factor of each curve point (points, 1): 1 / (body height · √joints), times √weight."""
    scale = np.full(n_joints + int(root_translation), 1.0 / (height * np.sqrt(n_joints)))
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64)
        scale[: len(w)] *= np.sqrt(w)
    return scale[:, None]


def body_rows(positions: np.ndarray, scale: np.ndarray,
              root_translation: bool = False) -> np.ndarray:
    """Curve rows of FK positions (n, points, 3): the skeleton's joints (ROOT and JOINT, not
    End Sites; `scale` has one row a joint, `point_scale`) minus the root, world
    orientation — the points of the evaluation's E — divided by body height and √joints, so
    |row difference|² is a frame's mean squared joint error in body heights². With
    `root_translation` the root's own world position is one more point."""
    n_joints = len(scale) - int(root_translation)
    rel = root_relative_joints(positions, n_joints)
    if root_translation:
        rel = np.concatenate([rel, positions[:, :1]], axis=1)
    return (rel * scale).reshape(len(rel), -1)


def _prefix(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exclusive prefix sums of w, u·w (u the local row) and |w|² (first row zero)."""
    n, d = w.shape
    u = np.arange(n, dtype=np.float64)[:, None]
    q0, q1, q2 = np.zeros((n + 1, d)), np.zeros((n + 1, d)), np.zeros(n + 1)
    np.cumsum(w, axis=0, out=q0[1:])
    np.cumsum(u * w, axis=0, out=q1[1:])
    np.cumsum(np.einsum("ij,ij->i", w, w), out=q2[1:])
    return q0, q1, q2


def _rowdot(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", p, q)


class Pricer:
    """Segment costs of a stream, chunk by chunk (plain attributes).

    Prefix sums run from an origin o, re-based every `EPOCH` frames (o = chunk start − L,
    rows re-centred on x_o: costs are shift invariant and smaller sums round less), so their
    size stays bounded on endless streams. Every quantity of one frame alone (|x|², x·Q0,
    x·Q1, R = Σ_{f≤a} (f − a) x_f) is kept per row; a chunk then costs four matrix products
    over the window and O(window × chunk) elementwise work. Offline and online feed the
    same chunks, so their costs are bit-identical.
    """

    def __init__(self, max_len: int) -> None:
        self.max_len = int(max_len)
        self.o = 0  # stream index of local row 0
        self.n = 0  # rows appended (stream index of the next one)
        self.c = np.empty(0)  # centre row
        self.w = np.empty((0, 0))

    def _alloc(self, d: int) -> None:
        size = EPOCH + self.max_len + CHUNK + 1
        self.w = np.zeros((size, d))
        self.q0 = np.zeros((size + 1, d))
        self.q1 = np.zeros((size + 1, d))
        self.q2 = np.zeros(size + 1)
        self.na = np.zeros(size)
        self.h1 = np.zeros(size)
        self.h3 = np.zeros(size)
        self.mr = np.zeros((size, d))  # -R per row

    def _append(self, rows: np.ndarray) -> None:
        lo = self.n - self.o
        hi = lo + len(rows)
        wc = rows - self.c
        u = np.arange(lo, hi, dtype=np.float64)[:, None]
        self.w[lo:hi] = wc
        self.q0[lo + 1 : hi + 1] = self.q0[lo] + np.cumsum(wc, axis=0)
        self.q1[lo + 1 : hi + 1] = self.q1[lo] + np.cumsum(u * wc, axis=0)
        na = _rowdot(wc, wc)
        self.q2[lo + 1 : hi + 1] = self.q2[lo] + np.cumsum(na)
        q0, q1 = self.q0[lo + 1 : hi + 1], self.q1[lo + 1 : hi + 1]
        self.na[lo:hi] = na
        self.h1[lo:hi] = _rowdot(wc, q0)
        self.h3[lo:hi] = _rowdot(wc, q1)
        self.mr[lo:hi] = u * q0 - q1
        self.n += len(rows)

    def price(self, x: np.ndarray, xbase: int, b0: int, b1: int) -> np.ndarray:
        """Costs C[i, j] of the segments (a, b), b = b0 + i < b1, a = b − L + j; inf where
        a < 0. `x` holds the stream's rows from stream index `xbase` (at least from b0 − L).
        Chunks must come in order, b0 = the previous b1."""
        L = self.max_len
        if len(self.w) == 0:
            self._alloc(x.shape[1])
            self.c = x[0 - xbase].copy()
        if b0 > 0 and b0 % EPOCH == 0:  # re-base: origin b0 - L, rows re-centred
            self.o = self.n = max(0, b0 - L)
            self.c = x[self.o - xbase].copy()
            self._append(x[self.o - xbase : b0 - xbase])
        self._append(x[b0 - xbase : b1 - xbase])
        o = self.o
        ls, lb0, lb1 = max(o, b0 - L) - o, b0 - o, b1 - o
        nb = lb1 - lb0
        win = self.w[ls:lb1]
        pb, q0b, q1b = self.w[lb0:lb1], self.q0[lb0:lb1], self.q1[lb0:lb1]
        u = np.arange(ls, lb1, dtype=np.float64)[:, None]
        ub = np.arange(lb0, lb1, dtype=np.float64)
        # Window space (row: a, column: b), four products (one per right-hand side: a
        # concatenated one crosses BLAS's threading threshold and runs far slower on a busy
        # machine).
        x1, x2, x3 = win @ pb.T, win @ q0b.T, win @ q1b.T
        x4 = self.mr[ls:lb1] @ pb.T
        g0, g1 = _rowdot(pb, q0b), _rowdot(pb, q1b)
        s2, cx1, two_m = (t[L + nb - len(win) :] for t in _tables(L, nb))
        na = self.na[ls:lb1, None]
        cost = (cx1 * x1 - 2.0 * x2 - self.q2[ls + 1 : lb1 + 1, None]
                + s2 * (na + self.na[lb0:lb1]) + (self.q2[lb0:lb1] - 2.0 * g0)
                + two_m * ((ub * g0 - g1) + ub * self.h1[ls:lb1, None] - self.h3[ls:lb1, None]
                           - u * x2 + x3 - x4))
        np.maximum(cost, 0.0, out=cost)
        if len(win) < L + nb:  # stream start: segments from before frame 0 do not exist
            cost = np.concatenate([np.full((L + nb - len(win), nb), np.inf), cost])
        # band[i, j] = cost[i + j, i]: a = b - L + j (a strided view, no gather)
        step, col = cost.strides
        band = np.lib.stride_tricks.as_strided(cost, (nb, L), (step + col, step)).copy()
        band[:, -1] = 0.0  # m = 1: no frame inside
        return band


_TABLES: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}


def _tables(max_len: int, nb: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Window-space factors of a full chunk window (rows a = 0 .. L + nb − 1, column i the
    end L + i, m = L + i − a): Σt² = (m−1)(2m−1)/6m, 2Σt − 2Σt², 2/m (0 where m ≤ 0)."""
    key = (max_len, nb)
    if key not in _TABLES:
        m = (max_len + np.arange(nb))[None, :] - np.arange(max_len + nb)[:, None]
        m = m.astype(np.float64)
        ok = m >= 1.0
        mm = np.where(ok, m, 1.0)
        s2 = np.where(ok, (mm - 1.0) * (2.0 * mm - 1.0) / (6.0 * mm), 0.0)
        _TABLES[key] = (s2, np.where(ok, (mm - 1.0) - 2.0 * s2, 0.0),
                        np.where(ok, 2.0 / mm, 0.0))
    return _TABLES[key]


def band_costs(x: np.ndarray, max_len: int) -> np.ndarray:
    """Costs of every segment of at most `max_len` frames ending at each frame (n, max_len),
    priced chunk by chunk as a stream would be."""
    n = len(x)
    out = np.empty((n, max_len))
    pricer = Pricer(max_len)
    for b0 in range(0, n, CHUNK):
        b1 = min(n, b0 + CHUNK)
        out[b0:b1] = pricer.price(x, 0, b0, b1)
    return out


def pair_costs(x: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Costs of arbitrary segments (a[i], b[i]) of `x` (a < b), O(D) each from prefix sums."""
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    if len(a) == 0:
        return np.zeros(0)
    s, e = int(a.min()), int(b.max()) + 1
    w = x[s:e] - x[s:e].mean(axis=0)
    q0, q1, q2 = _prefix(w)
    ua, ub = a - s, b - s
    m = (ub - ua).astype(np.float64)
    pa, pb = w[ua], w[ub]
    d = pb - pa
    a0 = q0[ub] - q0[ua + 1]
    a1 = q1[ub] - q1[ua + 1]
    t = (a1 - ua[:, None] * a0) / m[:, None]

    def dot(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        return np.einsum("ij,ij->i", p, q)

    s1 = (m - 1.0) / 2.0
    s2 = (m - 1.0) * (2.0 * m - 1.0) / (6.0 * m)
    cost = (q2[ub] - q2[ua + 1] + (m - 1.0) * dot(pa, pa) + s2 * dot(d, d)
            - 2.0 * dot(pa, a0) - 2.0 * dot(d, t) + 2.0 * s1 * dot(pa, d))
    return np.where(m <= 1.0, 0.0, np.maximum(cost, 0.0))


@kernel
def chain_costs(x: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Cost of each segment (rows[i − 1], rows[i]) of `x` summed directly, frame by frame
    (out[0] = 0): one compiled loop, no prefix sums, the same bits on any call path."""
    out = np.zeros(len(rows))
    for i in range(1, len(rows)):
        a, b = rows[i - 1], rows[i]
        total = 0.0
        for f in range(a + 1, b):
            t = (f - a) / (b - a)
            for j in range(x.shape[1]):
                r = (x[f, j] - x[a, j]) - t * (x[b, j] - x[a, j])
                total += r * r
        out[i] = total
    return out


def dp_rows(costs: np.ndarray, f: np.ndarray, bp: np.ndarray, keys: np.ndarray, b0: int,
            b1: int, lam: float, floor: int = 0, tolerance: float | None = None,
            c0: int = 0) -> None:
    """Advance the DP over frames b0 .. b1 − 1 in place (`f`, `bp`, `keys` indexed by frame,
    `costs[b − c0]` is frame b's band).

    Penalised form: F(b) = min_a F(a) + cost(a, b) + λ over floor ≤ a < b, b − a ≤ L, ties to
    the earliest a. Tolerance form (`tolerance` given): among a with cost(a, b) ≤ tolerance ·
    (b − a), fewest keys, then least F (summed cost). `keys[b]` counts the chain's keys.
    """
    if tolerance is None:
        _dp_penalised(costs, f, bp, keys, b0, b1, float(lam), floor, c0)
        return
    max_len = costs.shape[1]
    b = b0
    while b < b1:
        if b >= max_len:
            e = min(b1, b + CHUNK)
            _dp_block_tolerance(costs[b - c0 : e - c0], f, bp, keys, b, tolerance, floor)
            b = e
            continue
        lo = max(b - max_len, floor)
        c = costs[b - c0, max_len - (b - lo):]
        vals = f[lo:b] + c
        ok = c <= tolerance * np.arange(b - lo, 0, -1)
        ok &= np.isfinite(vals)
        if not ok.any():
            f[b], bp[b], keys[b] = np.inf, -1, 0
            b += 1
            continue
        k = np.where(ok, keys[lo:b], np.iinfo(np.int64).max)
        best = np.flatnonzero(k == k.min())
        i = int(best[np.argmin(vals[best])])
        f[b] = vals[i]
        bp[b] = lo + i
        keys[b] = keys[lo + i] + 1
        b += 1


@kernel
def _dp_penalised(costs: np.ndarray, f: np.ndarray, bp: np.ndarray, keys: np.ndarray, b0: int,
                  b1: int, lam: float, floor: int, c0: int) -> None:
    """Penalised DP rows b0 .. b1 − 1 (`dp_rows`), one compiled loop: F(a) + cost(a, b) summed
    as before, candidates in increasing a with a strict `<` (the earliest minimum, as
    `np.argmin`), so the bits and back-pointers of the numpy version it replaced. A row with
    no finite candidate points at its first one (a = b − L, or `floor` near the start)."""
    max_len = costs.shape[1]
    for b in range(b0, b1):
        start = b - max_len if b >= max_len else max(b - max_len, floor)
        best, arg = np.inf, start
        for a in range(max(start, floor), b):
            v = f[a] + costs[b - c0, max_len - (b - a)]
            if v < best:
                best, arg = v, a
        f[b] = best + lam
        bp[b] = arg
        keys[b] = keys[arg] + 1


@warmer
def _warm() -> None:
    f, bp, keys = np.zeros(4), np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int64)
    chain_costs(np.zeros((4, 3)), np.array([0, 3], dtype=np.int64))
    for dtype in (np.float64, np.float32):
        _dp_penalised(np.zeros((4, 2), dtype=dtype), f, bp, keys, 1, 4, 1.0, 0, 0)


def _dp_block_tolerance(band: np.ndarray, f: np.ndarray, bp: np.ndarray, keys: np.ndarray,
                        b: int, tolerance: float, floor: int) -> None:
    """Tolerance DP rows b .. b + len(band) − 1 (b >= L): the candidates before the block in
    one vectorised pass, the ones inside it in plain Python; fewest keys, then least F, then
    the earliest a; the same comparisons as the row-by-row loop."""
    nb, max_len = band.shape
    fs, ks = f.strides[0], keys.strides[0]
    fv = np.ndarray((nb, max_len), f.dtype, f, (b - max_len) * fs, (fs, fs))
    kv = np.ndarray((nb, max_len), keys.dtype, keys, (b - max_len) * ks, (ks, ks))
    vals = fv + band
    ok = band <= tolerance * np.arange(max_len, 0, -1)
    ok &= np.isfinite(vals)
    ok &= ~_inside(nb, max_len)
    if floor > b - max_len:
        ok &= np.arange(max_len)[None, :] >= floor - b + max_len - np.arange(nb)[:, None]
    big = np.iinfo(np.int64).max
    kk = np.where(ok, kv, big)
    kmin = kk.min(axis=1)
    arg = np.argmin(np.where(kk == kmin[:, None], vals, np.inf), axis=1)
    pre = vals[np.arange(nb), arg].tolist()
    pre_k = kmin.tolist()
    rows = band[:, max_len - nb :].tolist()
    done: list[float] = []
    done_k: list[int] = []
    for i in range(nb):
        best, best_k = pre[i], pre_k[i]
        a = b - max_len + i + int(arg[i]) if best_k != big else -1
        row = rows[i]
        for k in range(max(0, floor - b), i):  # candidate a = b + k
            c = row[nb - i + k]
            v = done[k] + c
            if c <= tolerance * (i - k) and v < np.inf and (
                    done_k[k] < best_k or (done_k[k] == best_k and v < best)):
                best, best_k, a = v, done_k[k], b + k
        if a < 0:
            best, kb = np.inf, 0
        else:
            kb = int(keys[a]) + 1
        done.append(best)
        done_k.append(kb)
        f[b + i], bp[b + i], keys[b + i] = best, a, kb


_INSIDE: dict[tuple[int, int], np.ndarray] = {}


def _inside(nb: int, max_len: int) -> np.ndarray:
    """Mask of band entries whose segment starts inside the block (a >= b of row 0)."""
    key = (nb, max_len)
    if key not in _INSIDE:
        _INSIDE[key] = np.arange(max_len)[None, :] >= max_len - np.arange(nb)[:, None]
    return _INSIDE[key]


def chain(bp: np.ndarray, end: int, stop: int = -1) -> list[int]:
    """Frames of the back-pointer chain from `end` down to (excluding) frames ≤ `stop`,
    increasing."""
    out = []
    k = end
    while k > stop:
        out.append(int(k))
        k = int(bp[k])
    return out[::-1]


def best_split(x: np.ndarray, a: int, e: int, last: int) -> int:
    """Frame k in (a, last] minimising cost(a, k) + cost(k, e) (ties: earliest)."""
    ks = np.arange(a + 1, last + 1)
    total = pair_costs(x, np.full(len(ks), a), ks) + pair_costs(x, ks, np.full(len(ks), e))
    return int(ks[int(np.argmin(total))])


def fill_gaps(x: np.ndarray, keys: np.ndarray, max_gap: int) -> np.ndarray:
    """Keys (rows, sorted) with a key inserted wherever consecutive keys lie more than
    `max_gap` frames apart: left to right, at the best frame k of (a, a + max_gap] by
    cost(a, k) + cost(k, a + max_gap + 1)."""
    keys = [int(k) for k in np.asarray(keys, dtype=np.int64)]
    out: list[int] = []
    for i, a in enumerate(keys):
        out.append(a)
        if i + 1 == len(keys):
            break
        b = keys[i + 1]
        while b - a > max_gap:
            a = best_split(x, a, a + max_gap + 1, a + max_gap)
            out.append(a)
    return np.array(out, dtype=np.int64)
