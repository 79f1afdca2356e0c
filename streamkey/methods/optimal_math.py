"""Pure maths of optimal keys: segment costs from prefix sums and the dynamic
programme over them. Shared by `streamkey.methods.optimal` (offline and online) and by
`--max-gap`; its module docstring states the definitions settled here. No I/O; the one
stateful piece (`Pricer`) holds plain arrays.

The curve is x (one row per captured frame, D columns); the cost of a segment (a, b) is
Σ_{a<f<b} |x_f − x_a − (f−a)/(b−a) (x_b − x_a)|². With prefix sums of x, f·x and |x|² over a
window this costs O(D) per segment; `Pricer` prices the L segments ending at a frame when
it arrives, from four dot products per start (w_a·w_b, w_a·Q0_b, w_a·Q1_b, −R_a·w_b) in
one compiled loop over the window (never materialising a segment), frame after frame in a
fixed order: a frame at a time online, a chunk or the whole take offline, the same bits.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..jit import kernel, warmer
from ..kinematics import root_relative_joints

__all__ = ["CHUNK", "EPOCH", "Pricer", "point_scale", "body_rows", "band_costs", "pair_costs",
           "chain_costs", "edge_costs", "no_marks", "Marks", "dp_rows", "broken_chains", "chain",
           "best_split", "fill_gaps"]

CHUNK = 16  # frames solved together (the DP runs when a chunk of frames is complete)
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
    flat: np.ndarray = (rel * scale).reshape(len(rel), -1)
    return flat


def _prefix(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exclusive prefix sums of w, u·w (u the local row) and |w|² (first row zero)."""
    n, d = w.shape
    u = np.arange(n, dtype=np.float64)[:, None]
    q0, q1, q2 = np.zeros((n + 1, d)), np.zeros((n + 1, d)), np.zeros(n + 1)
    np.cumsum(w, axis=0, out=q0[1:])
    np.cumsum(u * w, axis=0, out=q1[1:])
    np.cumsum(np.einsum("ij,ij->i", w, w), out=q2[1:])
    return q0, q1, q2


class Pricer:
    """Segment costs of a stream, frame by frame (plain attributes).

    Prefix sums run from an origin o, re-based every `EPOCH` frames (o = frame − L, rows
    re-centred on x_o: costs are shift invariant and smaller sums round less), so their size
    stays bounded on endless streams. Every quantity of one frame alone (|x|², x·Q0, x·Q1,
    R = Σ_{f≤a} (f − a) x_f) is kept per row, the rows and −R transposed (one column a
    frame); pricing frame b's segments then takes four dot products per start a, summed
    over coordinates in a fixed order (`_price_rows`). Appending and pricing run strictly
    frame after frame, so any split of the stream into calls (a frame a push online, a
    chunk or the whole take offline) gives the same bits.
    """

    def __init__(self, max_len: int) -> None:
        self.max_len = int(max_len)
        self.o = 0  # stream index of local row 0
        self.n = 0  # rows appended (stream index of the next one)
        self.c = np.empty(0)  # centre row
        self.wt = np.empty((0, 0))
        m = np.arange(self.max_len + 1, dtype=np.float64)
        mm = np.where(m >= 1.0, m, 1.0)
        s2 = (mm - 1.0) * (2.0 * mm - 1.0) / (6.0 * mm)
        # per segment length m: Σt² = (m−1)(2m−1)/6m, 2Σt − 2Σt², 2/m
        self.tables = np.stack([s2, (mm - 1.0) - 2.0 * s2, 2.0 / mm])

    def prepare(self, d: int) -> None:
        """Allocate (and touch) the buffers for rows of `d` columns now, before the stream,
        instead of on its first frame."""
        size = EPOCH + self.max_len + CHUNK + 1
        self.wt = np.zeros((d, size))  # centred rows, transposed
        self.mrt = np.zeros((d, size))  # −R, transposed
        self.q0 = np.zeros((size + 1, d))
        self.q1 = np.zeros((size + 1, d))
        self.q2 = np.zeros(size + 1)
        # per row: |w|², w·Q0 and w·Q1 through the row, w·Q0 and w·Q1 before it
        self.rowdots = np.zeros((5, size))
        self.acc = np.zeros((4, self.max_len))
        for a in (self.wt, self.mrt, self.q0, self.q1):
            a.fill(0.0)  # first touch of fresh pages: here, not on a frame

    def price(self, x: np.ndarray, xbase: int, b0: int, b1: int,
              out: np.ndarray | None = None) -> np.ndarray:
        """Costs C[i, j] of the segments (a, b), b = b0 + i < b1, a = b − L + j; inf where
        a < 0 (into `out` if given). `x` holds the stream's rows from stream index `xbase`
        (at least from b0 − L). Frames must come in order, b0 = the previous b1."""
        L = self.max_len
        if out is None:
            out = np.empty((b1 - b0, L))
        if self.wt.shape[0] != x.shape[1]:
            self.prepare(x.shape[1])
        if len(self.c) == 0:
            self.c = np.array(x[0 - xbase], dtype=np.float64)
        b = b0
        while b < b1:
            if b > 0 and b % EPOCH == 0:  # re-base: origin b − L, rows re-centred
                self.o = max(0, b - L)
                self.c = np.array(x[self.o - xbase], dtype=np.float64)
                _append_rows(x, xbase, self.o, b, self.o, self.c, self.wt, self.mrt, self.q0,
                             self.q1, self.q2, self.rowdots)
            e = min(b1, (b // EPOCH + 1) * EPOCH)
            _price_rows(x, xbase, b, e, self.o, self.c, self.wt, self.mrt, self.q0, self.q1,
                        self.q2, self.rowdots, self.tables, self.acc, out[b - b0 : e - b0])
            b = e
        self.n = b1
        return out


@kernel
def _append_rows(x: np.ndarray, xbase: int, r0: int, r1: int, o: int, c: np.ndarray,
                 wt: np.ndarray, mrt: np.ndarray, q0: np.ndarray, q1: np.ndarray,
                 q2: np.ndarray, rowdots: np.ndarray) -> None:
    """Append stream rows r0 .. r1 − 1 (x row r − xbase, local row r − o) to the prefix sums,
    one row after another, each sum over coordinates in order."""
    d = x.shape[1]
    for r in range(r0, r1):
        i = r - o
        u = float(i)
        na = h1 = h3 = g0 = g1 = 0.0
        for k in range(d):
            v = x[r - xbase, k] - c[k]
            p0, p1 = q0[i, k], q1[i, k]
            n0, n1 = p0 + v, p1 + u * v
            q0[i + 1, k], q1[i + 1, k] = n0, n1
            wt[k, i], mrt[k, i] = v, u * n0 - n1
            na += v * v
            h1 += v * n0
            h3 += v * n1
            g0 += v * p0
            g1 += v * p1
        q2[i + 1] = q2[i] + na
        rowdots[0, i], rowdots[1, i], rowdots[2, i] = na, h1, h3
        rowdots[3, i], rowdots[4, i] = g0, g1


@kernel
def _price_rows(x: np.ndarray, xbase: int, b0: int, b1: int, o: int, c: np.ndarray,
                wt: np.ndarray, mrt: np.ndarray, q0: np.ndarray, q1: np.ndarray, q2: np.ndarray,
                rowdots: np.ndarray, tables: np.ndarray, acc: np.ndarray,
                out: np.ndarray) -> None:
    """Append and price frames b0 .. b1 − 1, one after another (`Pricer.price`): for end b,
    the four window products w_a·w_b, w_a·Q0_b, w_a·Q1_b, −R_a·w_b of every start a, summed
    over coordinates in order (the loop over a innermost, so it vectorises), then the cost
    of each segment (a, b) from them and the per-row sums."""
    max_len = out.shape[1]
    d = x.shape[1]
    x1, x2, x3, x4 = acc[0], acc[1], acc[2], acc[3]
    for b in range(b0, b1):
        _append_rows(x, xbase, b, b + 1, o, c, wt, mrt, q0, q1, q2, rowdots)
        lb = b - o
        la0 = max(b - max_len, 0) - o  # first start a (local)
        na = lb - la0
        x1[:na] = 0.0
        x2[:na] = 0.0
        x3[:na] = 0.0
        x4[:na] = 0.0
        k = 0
        while k < d:  # four coordinates a pass, added in order: the bits of one at a time
            e = min(k + 4, d)
            p = wt[k:e, lb]
            s = q0[lb, k:e]
            t = q1[lb, k:e]
            if e - k == 4:
                w0, w1 = wt[k, la0:lb], wt[k + 1, la0:lb]  # rows: contiguous, vectorised
                w2, w3 = wt[k + 2, la0:lb], wt[k + 3, la0:lb]
                m0, m1 = mrt[k, la0:lb], mrt[k + 1, la0:lb]
                m2, m3 = mrt[k + 2, la0:lb], mrt[k + 3, la0:lb]
                p0, p1, p2, p3 = p[0], p[1], p[2], p[3]
                s0, s1, s2, s3 = s[0], s[1], s[2], s[3]
                t0, t1, t2, t3 = t[0], t[1], t[2], t[3]
                for j in range(na):
                    v0, v1, v2, v3 = w0[j], w1[j], w2[j], w3[j]
                    x1[j] = (((x1[j] + v0 * p0) + v1 * p1) + v2 * p2) + v3 * p3
                    x2[j] = (((x2[j] + v0 * s0) + v1 * s1) + v2 * s2) + v3 * s3
                    x3[j] = (((x3[j] + v0 * t0) + v1 * t1) + v2 * t2) + v3 * t3
                    x4[j] = (((x4[j] + m0[j] * p0) + m1[j] * p1) + m2[j] * p2) + m3[j] * p3
            else:
                for i in range(e - k):
                    w, mr = wt[k + i, la0:lb], mrt[k + i, la0:lb]
                    for j in range(na):
                        x1[j] += w[j] * p[i]
                        x2[j] += w[j] * s[i]
                        x3[j] += w[j] * t[i]
                        x4[j] += mr[j] * p[i]
            k = e
        row = out[b - b0]
        ub = float(lb)
        nb, gb = rowdots[0, lb], rowdots[3, lb]
        tail = q2[lb] - 2.0 * gb
        gg = ub * gb - rowdots[4, lb]
        j0 = max_len - na  # a = b − L + j; a < 0 before j0: segments from before frame 0
        row[:j0] = np.inf
        for i in range(na):  # start a = la0 + i (local), m = b − a = na − i
            la = la0 + i
            cost = (tables[1, na - i] * x1[i] - 2.0 * x2[i] - q2[la + 1]
                    + tables[0, na - i] * (rowdots[0, la] + nb) + tail
                    + tables[2, na - i] * (gg + ub * rowdots[1, la] - rowdots[2, la]
                                           - float(la) * x2[i] + x3[i] - x4[i]))
            row[j0 + i] = 0.0 if cost < 0.0 else cost
        row[max_len - 1] = 0.0  # m = 1: no frame inside


def band_costs(x: np.ndarray, max_len: int) -> np.ndarray:
    """Costs of every segment of at most `max_len` frames ending at each frame (n, max_len),
    priced frame by frame as a stream would be."""
    return Pricer(max_len).price(np.asarray(x, dtype=np.float64), 0, 0, len(x))


def pair_costs(x: np.ndarray, starts: np.ndarray | Sequence[int],
               ends: np.ndarray | Sequence[int]) -> np.ndarray:
    """Costs of arbitrary segments (a[i], b[i]) of `x` (a < b), O(D) each from prefix sums."""
    a = np.asarray(starts, dtype=np.int64)
    b = np.asarray(ends, dtype=np.int64)
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
        dots: np.ndarray = np.einsum("ij,ij->i", p, q)
        return dots

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


Marks = tuple[np.ndarray, np.ndarray, np.ndarray]  # keyable, edge, edge_cost (by frame)


def no_marks(n: int) -> Marks:
    """Hold marks of `n` frames outside any hold: every frame may be a key, no long edge."""
    return np.ones(n, dtype=np.bool_), np.full(n, -1, dtype=np.int64), np.full(n, np.nan)


@kernel
def edge_costs(x: np.ndarray, edge: np.ndarray, out: np.ndarray, b0: int, b1: int,
               max_len: int) -> None:
    """cost(edge[b], b) of rows b0 .. b1 − 1 whose hold edge is longer than `max_len` and not
    priced yet (`out[b]` NaN). With y = x − x[a], u = g − a, m = b − a: Σ|y_g|² − (2/m)
    y_b·Σ u y_g + (|y_b|²/m²) Σ u², the sums over g in (a, b) running from a in order on
    every call (so the same bits on any call path), O(D) a row."""
    d = x.shape[1]
    q = np.zeros(d)
    cur, nxt, p = -1, 0, 0.0
    for b in range(b0, b1):
        a = edge[b]
        if a < 0 or b - a <= max_len or not np.isnan(out[b]):
            continue
        if a != cur:
            cur, nxt, p = a, a + 1, 0.0
            q[:] = 0.0
        while nxt < b:
            u = nxt - a
            for j in range(d):
                y = x[nxt, j] - x[a, j]
                p += y * y
                q[j] += u * y
            nxt += 1
        m = b - a
        yq = 0.0
        yy = 0.0
        for j in range(d):
            y = x[b, j] - x[a, j]
            yq += y * q[j]
            yy += y * y
        s2 = (m - 1.0) * m * (2.0 * m - 1.0) / 6.0
        out[b] = max(0.0, p - 2.0 * yq / m + s2 * yy / (m * m))


def dp_rows(costs: np.ndarray, f: np.ndarray, bp: np.ndarray, keys: np.ndarray, b0: int,
            b1: int, lam: float, floor: int = 0, tolerance: float | None = None,
            c0: int = 0, marks: Marks | None = None) -> None:
    """Advance the DP over frames b0 .. b1 − 1 in place (`f`, `bp`, `keys` indexed by frame,
    `costs[b − c0]` is frame b's band).

    Penalised form: F(b) = min_a F(a) + cost(a, b) + λ over floor ≤ a < b, b − a ≤ L, ties to
    the earliest a. With `marks` (holds, penalised form only): only frames with `keyable`
    set are candidates a, and a frame b inside a hold or at its end (`edge[b]` = s ≥ floor,
    the hold's first frame) has the one candidate s, at `edge_cost[b]` = cost(s, b) if
    b − s > L: a chain enters a hold at its first frame, or jumps over all of it.
    Tolerance form (`tolerance` given): among a with cost(a, b) ≤ tolerance ·
    (b − a), fewest keys, then least F (summed cost). `keys[b]` counts the chain's keys.
    """
    if tolerance is None:
        keyable, edge, edge_cost = marks if marks is not None else no_marks(len(f))
        _dp_penalised(costs, f, bp, keys, b0, b1, float(lam), floor, c0, keyable, edge,
                      edge_cost)
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
                  b1: int, lam: float, floor: int, c0: int, keyable: np.ndarray,
                  edge: np.ndarray, edge_cost: np.ndarray) -> None:
    """Penalised DP rows b0 .. b1 − 1 (`dp_rows`), one compiled loop: F(a) + cost(a, b) summed
    as before, candidates in increasing a with a strict `<` (the earliest minimum, as
    `np.argmin`), so the bits and back-pointers of the numpy version it replaced. A row with
    no finite candidate points at its first one (a = b − L, or `floor` near the start)."""
    max_len = costs.shape[1]
    for b in range(b0, b1):
        start = b - max_len if b >= max_len else max(b - max_len, floor)
        best, arg = np.inf, start
        s = edge[b]
        if s >= floor:  # in a hold, or its last frame: from the hold's first frame only
            c = costs[b - c0, max_len - (b - s)] if b - s <= max_len else edge_cost[b]
            f[b] = f[s] + c + lam
            bp[b] = s
            keys[b] = keys[s] + 1
            continue
        for a in range(max(start, floor), b):
            if not keyable[a]:
                continue
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
    edge_costs(np.zeros((4, 3)), np.array([-1, 0, 0, 0], dtype=np.int64), np.full(4, np.nan),
               0, 4, 1)
    band_costs(np.zeros((EPOCH + 1, 3)), 2)  # across a re-base: `_append_rows` called alone
    broken_chains(np.array([-1, 0, 1, 0], dtype=np.int64), 0, 1, 4)
    for dtype in (np.float64, np.float32):
        _dp_penalised(np.zeros((4, 2), dtype=dtype), f, bp, keys, 1, 4, 1.0, 0, 0,
                      *no_marks(4))


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


@kernel
def broken_chains(bp: np.ndarray, lo: int, hi: int, end: int) -> tuple[int, int]:
    """First and last frame in (hi, end) whose back-pointer chain skips the decided key `lo`
    (points at or before `hi`, not at `lo`) or passes through such a frame; (−1, −1) if
    none. One pass: back-pointers point backwards."""
    broken = np.zeros(max(0, end - hi - 1), dtype=np.bool_)
    first = last = -1
    for i in range(len(broken)):
        a = bp[hi + 1 + i]
        if (a <= hi and a != lo) or (a > hi and broken[a - hi - 1]):
            broken[i] = True
            last = hi + 1 + i
            if first < 0:
                first = last
    return first, last


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


def fill_gaps(x: np.ndarray, rows: np.ndarray, max_gap: int) -> np.ndarray:
    """Keys (rows, sorted) with a key inserted wherever consecutive keys lie more than
    `max_gap` frames apart: left to right, at the best frame k of (a, a + max_gap] by
    cost(a, k) + cost(k, a + max_gap + 1)."""
    keys = [int(k) for k in np.asarray(rows, dtype=np.int64)]
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
